"""The ``flexarm`` commands, one module each: ``add_parser(sub)`` registers the command on
the top-level parser's subparsers and sets ``main(args)`` as what it runs (exit code).
:mod:`flexarm_ros.cli` lists them; :mod:`~flexarm_ros.commands.common` holds what they
share. The ensembles and calibration register theirs from
:mod:`flexarm_ros.ensemble.cli` and :mod:`flexarm_ros.calibration.cli`."""
