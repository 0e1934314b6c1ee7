"""Studies that run many simulations: ``ladder`` (the speed–accuracy table of the model
ladder against a converged reference, with its Pareto plot) and ``contact`` (the contact
rungs' trade on a scene with a wall)."""
