"""Comparison of a run with a reference (twin vs experiment), pure numpy/scipy.

:mod:`flexarm_ros.analysis.spectra` estimates dominant frequencies and amplitude spectra;
:mod:`flexarm_ros.analysis.metrics` aligns two records in time and computes the error
measures the source papers used by hand (impact time, bounce height, RMS / peak /
amplitude errors, Gannon's normalized tip-amplitude and frequency errors, the 10 % test).
Nothing here imports rclpy or the physics core.
"""
