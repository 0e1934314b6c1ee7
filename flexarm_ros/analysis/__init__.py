"""Comparison of a run with a reference (twin vs experiment), pure numpy/scipy.

:mod:`flexarm_ros.analysis.spectra` estimates dominant frequencies and amplitude spectra;
:mod:`flexarm_ros.analysis.metrics` aligns two records in time and computes the error
measures the source papers used by hand (impact time, bounce height, RMS / peak /
amplitude errors, Gannon's normalized tip-amplitude and frequency errors, the 10 % test).
:mod:`flexarm_ros.analysis.channels` reads the inputs (twin bags through
:mod:`flexarm_ros.twin.recording`, mapped foreign bags, CSV tables) into named channels;
:mod:`flexarm_ros.analysis.compare` computes a
:class:`~flexarm_ros.analysis.comparison.Comparison` (result schema in
:mod:`flexarm_ros.analysis.comparison`), :mod:`flexarm_ros.analysis.report` draws it and
:mod:`flexarm_ros.analysis.compare_cli` is the ``flexarm compare`` command that calls both;
:mod:`flexarm_ros.analysis.control` measures a step or ramp response against its target
(final error, overshoot, rise and settling time, RMS tracking error);
:mod:`flexarm_ros.analysis.export` is ``flexarm bag export`` (a twin bag's channels as CSV).
Nothing here imports rclpy or the physics core (``flexarm_ros.model``, ``flexarm_ros.sim``);
scenes come from :mod:`flexarm_ros.scene`.
"""
