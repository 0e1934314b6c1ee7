"""Studies that run many simulations: ``ladder`` (the speed–accuracy table of the model
ladder against a converged reference, with its Pareto plot), ``contact`` (the contact
rungs' trade on a scene with a wall), ``bearings_seed000`` (seed 000's air-bearing
friction, tools/bearing_friction_seed000.py) and ``bounce_seed000`` (what sets Case 1's
first bounce, tools/bounce_candidates_seed000.py). Their runs are tasks of the ensemble
runner."""
