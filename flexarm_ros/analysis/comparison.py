"""What a comparison produces: the result document's schema (key sets), the frequency
estimator's settings and the :class:`Comparison` object.

:mod:`flexarm_ros.analysis.compare` computes a :class:`Comparison`;
:mod:`flexarm_ros.analysis.report` draws one. Both import this module, neither imports
the other (the ``flexarm compare`` command, :mod:`flexarm_ros.analysis.compare_cli`, calls
both). The key sets are documented in ``docs/compare.md`` and pinned by
``test/test_compare.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

from flexarm_ros.analysis.channels import ChannelSet

__all__ = ["CHANNEL_KEYS", "CONTACT_KEYS", "CONTROL_CRITERIA", "CONTROL_KEYS",
           "CONTROL_SIDE_KEYS", "Comparison", "EVENT_KEYS", "FINAL_BAND", "FREQ_DETREND",
           "FREQ_MIN_BINS", "FREQ_WINDOW", "FREQ_ZERO_PAD", "JUDGED_BY", "OFFSET_KEYS",
           "OVERSHOOT_POINTS", "SCHEMA", "SIGNAL_KINDS", "SOURCE_KEYS", "TIP_KEYS",
           "TOP_KEYS"]

#: 2: channels that track a command (a step or ramp in their target) are judged by the
#: control criteria (``judged_by``, ``control``), not by frequency and amplitude.
SCHEMA = "flexarm-compare/2"

#: Frequency estimator settings (see :func:`flexarm_ros.analysis.spectra.dominant_frequency`):
#: window, detrend, zero padding factor, lowest searched bin.
FREQ_WINDOW, FREQ_DETREND, FREQ_ZERO_PAD, FREQ_MIN_BINS = "hann", "linear", 4, 3

TOP_KEYS = ("schema", "run", "reference", "threshold", "offset", "window", "frequency_method",
            "control_method", "channels", "contact", "tip", "pass", "failed", "warnings")
SOURCE_KEYS = ("path", "kind", "scene", "truncated", "channels", "start_s", "end_s")
OFFSET_KEYS = ("mode", "offset_s", "method", "max_shift_s", "estimates_s", "sample_period_s")
CHANNEL_KEYS = ("unit", "signal", "span_s", "samples_run", "samples_reference",
                "sample_rate_run_hz", "sample_rate_reference_hz", "frequency_run_hz",
                "frequency_reference_hz", "frequency_resolution_hz", "frequency_bound_hz",
                "frequency_error", "events", "rms_error", "peak_error", "relative_rms_error",
                "amplitude_error", "control", "judged_by", "criteria", "pass", "null_reasons")
#: ``judged_by`` of a channel block: the oscillation criteria (frequency, amplitude) or,
#: for a channel that tracks a step or ramp command in the reference, the control ones.
JUDGED_BY = ("oscillation", "control")
#: Keys of a channel's ``control`` block (null for a channel without a target).
CONTROL_KEYS = ("target_channel", "target_from", "quantum", "run", "reference",
                "difference", "tolerance", "null_reasons")
#: Keys of ``control.run`` / ``control.reference``: the command seen and the metrics
#: (:func:`flexarm_ros.analysis.control.tracking_metrics`); ``control.difference`` and
#: ``control.tolerance`` have the metric keys.
CONTROL_SIDE_KEYS = ("command", "final_error", "overshoot", "rise_time_s", "settling_time_s",
                     "rms_tracking_error")
#: The criteria of a control-judged channel (``criteria`` keys, ``failed`` entries).
CONTROL_CRITERIA = ("final_error", "overshoot", "rise_time", "settling_time",
                    "rms_tracking_error")
#: Control tolerances that are not the relative ``threshold``: the final errors agree
#: within this fraction of the reference's step (or one encoder count, the larger), the
#: overshoots within these percentage points (or ``threshold`` of the reference's, the
#: larger).
FINAL_BAND = 0.02
OVERSHOOT_POINTS = 0.02
#: ``signal`` of a channel block: a 0/1 flag (``contact``) has events, not a frequency.
SIGNAL_KINDS = ("continuous", "boolean")
#: Keys of ``events.run`` / ``events.reference`` (:func:`flexarm_ros.analysis.metrics.step_events`).
EVENT_KEYS = ("rises", "falls", "duty", "first_rise_s")
CONTACT_KEYS = ("impact_source", "impact_time_run_s", "impact_time_reference_s",
                "impact_time_error_s", "bounce_window_s", "bounce_height_run_m",
                "bounce_height_reference_m", "bounce_height_abs_error_m",
                "bounce_height_error", "null_reasons")
TIP_KEYS = ("arm_length_m", "normalized_amplitude_error", "normalized_rms_amplitude_error",
            "frequency_channel", "frequency_error", "criteria", "pass", "null_reasons")


@dataclass
class Comparison:
    """The result document plus what the report needs to draw it: both inputs' channels
    (the run's times on its own clock), the compared names and the offset (s) that puts the
    run on the reference clock (``t - offset_s``)."""

    result: dict
    run: ChannelSet
    reference: ChannelSet
    names: list[str]
    offset_s: float

    @property
    def passed(self) -> bool:
        return bool(self.result["pass"])
