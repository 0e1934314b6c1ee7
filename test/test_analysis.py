"""flexarm_ros.analysis against independent truths.

Truths: synthetic signals whose frequency, amplitude, shift, crossing time and bounce
height are set analytically (never computed by the code under test); Gannon 1986
(seed 002) Tables 4.2-4.5 for the 10 % pass mark; Pythagorean triples for the
tip-position distance.
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.signal import chirp

from flexarm_ros.analysis import metrics as mx
from flexarm_ros.analysis import spectra as sp


def _damped(fs, n, f_d, zeta, amp=1.5, phase=0.3):
    """y = A exp(-zeta w_n t) sin(w_d t + phase), w_d = 2 pi f_d = w_n sqrt(1 - zeta^2)."""
    t = np.arange(n) / fs
    w_n = 2 * np.pi * f_d / math.sqrt(1 - zeta**2)
    return t, amp * np.exp(-zeta * w_n * t) * np.sin(2 * np.pi * f_d * t + phase)


# --------------------------------------------------------------- dominant_frequency

def _noisy_cases():
    cases = []
    for n in (256, 700, 2048):
        for cycles in (3.37, 6.5, 17.83, 0.41 * n):       # non-integer cycle counts
            for zeta in (0.0, 0.01, 0.05):
                if zeta * 2 * np.pi * cycles / math.sqrt(1 - zeta**2) > 2.0:
                    continue                               # record > 2 envelope time constants
                for snr_db in (10.0, 20.0):
                    cases.append((n, cycles, zeta, snr_db))
    return cases


NOISY = _noisy_cases()


def test_noisy_grid_covers_the_brief():
    assert len(NOISY) >= 40
    assert {c[2] for c in NOISY} == {0.0, 0.01, 0.05}
    assert {c[3] for c in NOISY} == {10.0, 20.0}


@pytest.mark.parametrize("n,cycles,zeta,snr_db", NOISY)
def test_dominant_frequency_noisy_damped_within_bound(n, cycles, zeta, snr_db):
    fs = 250.0
    f_d = cycles * fs / n
    t, y = _damped(fs, n, f_d, zeta)
    rng = np.random.default_rng([n, int(cycles * 100), int(zeta * 100), int(snr_db)])
    sigma = np.sqrt(np.mean(y**2)) / 10 ** (snr_db / 20)     # SNR over the record
    y = y + rng.normal(0.0, sigma, n)
    pk = sp.dominant_frequency(t, y)
    assert pk.n_samples == n
    assert pk.sample_rate_hz == pytest.approx(fs, rel=1e-12)
    assert pk.resolution_hz == pytest.approx(fs / n, rel=1e-12)
    # the stated bound is a fixed small fraction of the bin spacing, so this can fail
    assert pk.bound_hz <= 0.1 * pk.resolution_hz * (1 + 1e-12)
    assert abs(pk.frequency_hz - f_d) < pk.bound_hz


@settings(max_examples=60, deadline=None)
@given(n=st.integers(64, 2048), frac=st.floats(0.0, 1.0), decay=st.floats(0.0, 3.0),
       phase=st.floats(0.0, 2 * np.pi), window=st.sampled_from(sp.PEAK_WINDOWS),
       zero_pad=st.sampled_from([2, 4, 8]), offset=st.floats(-5.0, 5.0),
       ramp=st.floats(-2.0, 2.0))
def test_dominant_frequency_clean_bias(n, frac, decay, phase, window, zero_pad, offset,
                                       ramp):
    """Clean signal anywhere in the stated domain: error < CLEAN_BIAS_FRACTION bins."""
    fs = 100.0
    cycles = 3.1 + frac * (n / 2 - 5.2)           # > 3 bins from DC, > 2 from Nyquist
    f = cycles * fs / n
    t = np.arange(n) / fs
    y = np.exp(-decay * t / (n / fs)) * np.cos(2 * np.pi * f * t + phase) + offset + ramp * t
    pk = sp.dominant_frequency(t, y, window=window, zero_pad=zero_pad)
    assert abs(pk.frequency_hz - f) < sp.CLEAN_BIAS_FRACTION * pk.resolution_hz
    assert pk.bound_hz == pytest.approx(sp.BOUND_FRACTION * pk.resolution_hz)


def test_bound_constants_are_tight_fractions_of_a_bin():
    assert sp.CLEAN_BIAS_FRACTION < sp.BOUND_FRACTION <= 0.1
    assert sp.BOUND_FRACTION_NO_PAD <= 0.15


def test_no_padding_bound_and_near_dc_widening():
    fs, n = 100.0, 512
    t, y = _damped(fs, n, 7.3 * fs / n, 0.0)
    pk = sp.dominant_frequency(t, y, zero_pad=1)
    assert pk.bound_hz == pytest.approx(0.15 * fs / n)
    assert abs(pk.frequency_hz - 7.3 * fs / n) < pk.bound_hz
    t, y = _damped(fs, n, 2.2 * fs / n, 0.0)                 # 2.2 bins: outside the domain
    pk = sp.dominant_frequency(t, y, detrend=None)
    assert pk.bound_hz == pytest.approx(fs / n)
    assert abs(pk.frequency_hz - 2.2 * fs / n) < pk.bound_hz


@pytest.mark.parametrize("cycles", [5.0, 12.25, 40.5, 101.71])
def test_dominant_frequency_amplitude_of_pure_sinusoid(cycles):
    fs, n = 400.0, 1000
    t, y = _damped(fs, n, cycles * fs / n, 0.0, amp=2.5)
    pk = sp.dominant_frequency(t, y)
    assert pk.amplitude == pytest.approx(2.5, rel=0.01)


def _two_tone():
    fs, n = 200.0, 2000
    t = np.arange(n) / fs
    y = 1.0 * np.sin(2 * np.pi * 12.34 * t) + 0.6 * np.sin(2 * np.pi * 31.7 * t + 1.0)
    return t, y


def test_two_tone_picks_the_larger():
    t, y = _two_tone()
    pk = sp.dominant_frequency(t, y)
    assert abs(pk.frequency_hz - 12.34) < pk.bound_hz
    assert pk.amplitude == pytest.approx(1.0, rel=0.02)


@pytest.mark.parametrize("band,f_true", [((20.0, None), 31.7), ((25.0, 40.0), 31.7),
                                         ((None, 20.0), 12.34), ((10.0, 15.0), 12.34)])
def test_band_limits_select_the_tone(band, f_true):
    t, y = _two_tone()
    pk = sp.dominant_frequency(t, y, f_min=band[0], f_max=band[1])
    assert abs(pk.frequency_hz - f_true) < pk.bound_hz


# --------------------------------------------------------------- spectrum

@pytest.mark.parametrize("window", sp.SPECTRUM_WINDOWS)
def test_spectrum_amplitude_at_bin_centre(window):
    fs, n = 500.0, 1000
    k = 37
    t = np.arange(n) / fs
    y = 0.8 + 3.2 * np.sin(2 * np.pi * k * fs / n * t + 0.4)
    f, a = sp.spectrum(t, y, window=window)
    assert f.shape == a.shape == (n // 2 + 1,)
    assert f[1] - f[0] == pytest.approx(fs / n)
    assert f[k] == pytest.approx(k * fs / n)
    assert a[k] == pytest.approx(3.2, rel=0.01)
    assert a[0] == pytest.approx(0.8, rel=0.01)              # DC is not doubled
    assert np.argmax(a[1:]) + 1 == k


# --------------------------------------------------------------- resample / uniform

def test_uniform_and_resample_are_exact_for_linear_data():
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.008, 0.012, 300))             # jittered stamps
    y = 2.0 - 0.7 * t
    tu, yu = sp.uniform(t, y, rate_hz=100.0)
    assert tu[0] == t[0] and tu[-1] <= t[-1]
    assert np.allclose(np.diff(tu), 0.01, rtol=1e-9)
    assert np.allclose(yu, 2.0 - 0.7 * tu, atol=1e-12)
    y2 = np.column_stack([y, 3 * y])
    out = sp.resample(t, y2, tu[:10])
    assert out.shape == (10, 2)
    assert np.allclose(out[:, 1], 3 * (2.0 - 0.7 * tu[:10]), atol=1e-12)


def test_uniform_grid_feeds_dominant_frequency():
    rng = np.random.default_rng(4)
    t = np.cumsum(rng.uniform(0.0045, 0.0055, 4000))          # ~200 Hz, 2 % jitter
    y = np.sin(2 * np.pi * 3.1 * t)
    with pytest.raises(ValueError, match="non-uniform sampling"):
        sp.dominant_frequency(t, y)
    tu, yu = sp.uniform(t, y)
    pk = sp.dominant_frequency(tu, yu)
    assert abs(pk.frequency_hz - 3.1) < pk.bound_hz


# --------------------------------------------------------------- estimate_offset

def _chirp(t):
    return chirp(t, f0=1.0, t1=4.0, f1=40.0) * np.exp(-(((t - 2.0) / 1.2) ** 2))


@pytest.mark.parametrize("shift", [0.0137, -0.0213])
@pytest.mark.parametrize("fs_ref,fs_run", [(1000.0, 1000.0), (4000.0, 400.0),
                                           (400.0, 1000.0)])
def test_estimate_offset_recovers_known_shift(shift, fs_ref, fs_run):
    t_ref = np.arange(0.0, 4.0, 1 / fs_ref)
    t_run = np.arange(0.0, 4.0, 1 / fs_run) + 0.00031       # grids need not match
    y_run = _chirp(t_run - shift)                            # run lags by `shift`
    off = mx.estimate_offset(t_ref, _chirp(t_ref), t_run, y_run, max_shift_s=0.05)
    dt = min(1 / fs_ref, 1 / fs_run)
    assert abs(off - shift) < 0.05 * dt
    # documented convention: y_run(t + offset) ≈ y_ref(t)
    t_mid = np.linspace(0.5, 3.5, 500)
    back = np.interp(t_mid + off, t_run, y_run)
    assert np.max(np.abs(back - _chirp(t_mid))) < 0.02


def test_estimate_offset_of_a_signal_with_itself_is_zero():
    t = np.arange(0.0, 4.0, 1e-3)
    assert abs(mx.estimate_offset(t, _chirp(t), t, _chirp(t), 0.1)) < 1e-9


def test_estimate_offset_then_channel_errors_small():
    t_ref = np.arange(0.0, 4.0, 1e-3)
    t_run = np.arange(0.0, 4.0, 2e-3)
    y_run = _chirp(t_run - 0.0137)
    off = mx.estimate_offset(t_ref, _chirp(t_ref), t_run, y_run, 0.05)
    err = mx.channel_errors(t_ref, _chirp(t_ref), t_run - off, y_run)
    assert err["relative_rms_error"] < 0.01
    raw = mx.channel_errors(t_ref, _chirp(t_ref), t_run, y_run)
    assert raw["relative_rms_error"] > 0.1


def test_estimate_offset_errors():
    t = np.arange(0.0, 4.0, 1e-3)
    with pytest.raises(ValueError, match="edge of the search range"):
        mx.estimate_offset(t, _chirp(t), t, _chirp(t - 0.03), max_shift_s=0.01)
    with pytest.raises(ValueError, match="max_shift_s"):
        mx.estimate_offset(t, _chirp(t), t, _chirp(t), max_shift_s=3.0)
    with pytest.raises(ValueError, match="max_shift_s must be a positive"):
        mx.estimate_offset(t, _chirp(t), t, _chirp(t), max_shift_s=0.0)
    with pytest.raises(ValueError, match="no overlapping time span"):
        mx.estimate_offset(t, _chirp(t), t + 10.0, _chirp(t), max_shift_s=0.1)
    with pytest.raises(ValueError, match="constant signals"):
        mx.estimate_offset(t, np.ones_like(t), t, _chirp(t), max_shift_s=0.1)


# --------------------------------------------------------------- channel_errors

def test_channel_errors_self_is_zero():
    t = np.linspace(0.0, 2.0, 801)
    y = 0.3 + np.sin(2 * np.pi * 1.7 * t)
    err = mx.channel_errors(t, y, t, y)
    assert set(err) == {"rms_error", "peak_error", "relative_rms_error", "amplitude_error"}
    assert all(v == 0.0 for v in err.values())


@pytest.mark.parametrize("scale", [1.07, 0.9])
def test_channel_errors_scaled_copy(scale):
    t = np.linspace(0.0, 2.0, 801)
    y = 0.3 + np.sin(2 * np.pi * 1.7 * t)
    err = mx.channel_errors(t, y, t, scale * y)
    s = scale - 1.0
    assert err["amplitude_error"] == pytest.approx(s, abs=1e-9)
    assert err["relative_rms_error"] == pytest.approx(abs(s), abs=1e-9)
    assert err["rms_error"] == pytest.approx(abs(s) * np.sqrt(np.mean(y**2)), rel=1e-9)
    assert err["peak_error"] == pytest.approx(abs(s) * np.max(np.abs(y)), rel=1e-9)


def test_channel_errors_uses_the_overlap_only():
    t_ref = np.linspace(0.0, 4.0, 401)                      # ref spans 0..4 s
    y_ref = 2.0 * t_ref
    t_run = np.linspace(1.0, 6.0, 51)                       # run spans 1..6 s, differs after 4 s
    y_run = np.where(t_run <= 4.0, 2.0 * t_run, 100.0)
    err = mx.channel_errors(t_ref, y_ref, t_run, y_run)
    assert err["peak_error"] < 1e-12                         # linear data: interpolation exact
    assert err["amplitude_error"] == pytest.approx(0.0, abs=1e-12)


def test_channel_errors_zero_reference_and_no_overlap():
    t = np.linspace(0.0, 1.0, 11)
    z = np.zeros_like(t)
    assert mx.channel_errors(t, z, t, z)["relative_rms_error"] == 0.0
    err = mx.channel_errors(t, z, t, z + 1e-3)
    assert err["relative_rms_error"] == math.inf
    assert not mx.passes(err["relative_rms_error"])
    with pytest.raises(ValueError, match="no overlapping time span"):
        mx.channel_errors(t, z, t + 5.0, z)


# --------------------------------------------------------------- event_time / bounce

def _gap_trace():
    """Tip approaching a wall at 0.1 m/s from 20 mm (impact at 0.2 s, 0.1 mm penetration),
    in contact until 0.22 s, a 5 mm parabolic bounce peaking at 0.27 s, contact from
    0.32 s to 0.5 s, an 8 mm bounce peaking at 0.6 s."""
    t = np.arange(0.0, 1.0, 1e-3) + 3e-4                    # impact falls between samples
    gap = np.full_like(t, -1e-4)                            # contact: slight penetration
    approach = t < 0.201
    gap[approach] = 0.02 - 0.1 * t[approach]                # reaches -1e-4 at 0.201 s
    b1 = (t > 0.22) & (t < 0.32)
    gap[b1] = 0.005 * 4 * (t[b1] - 0.22) * (0.32 - t[b1]) / 0.01
    b2 = (t > 0.5) & (t < 0.7)
    gap[b2] = 0.008 * 4 * (t[b2] - 0.5) * (0.7 - t[b2]) / 0.04
    return t, gap


def test_event_time_impact_and_contact_flag():
    t, gap = _gap_trace()
    t_imp = mx.event_time(t, gap, 0.0, direction=-1)
    assert t_imp == pytest.approx(0.2, abs=1e-12)             # linear approach: exact
    assert mx.event_time(t, gap, 0.01, direction=-1) == pytest.approx(0.1, abs=1e-12)
    flag = (gap <= 0.0).astype(float)
    t_flag = mx.event_time(t, flag, 0.5, direction=+1)
    assert abs(t_flag - 0.2) <= 1e-3                          # within one sample
    t_leave = mx.event_time(t, gap, 0.0, direction=+1)        # first lift-off after impact
    assert 0.219 < t_leave < 0.221


def test_event_time_none_and_start_beyond_threshold():
    t = np.linspace(0.0, 1.0, 101)
    assert mx.event_time(t, np.ones_like(t), 0.0, direction=-1) is None
    assert mx.event_time(t, 1.0 - t, 2.0, direction=-1) is None
    # starting at the threshold is not a crossing; the later one is found
    y = np.where(t < 0.5, 0.0, np.where(t < 0.7, 1.0, -1.0))
    assert mx.event_time(t, y, 0.0, direction=-1) == pytest.approx(0.695, abs=1e-12)
    with pytest.raises(ValueError, match="direction must be"):
        mx.event_time(t, y, 0.0, direction=0)


def test_bounce_height():
    t, gap = _gap_trace()
    t_imp = mx.event_time(t, gap, 0.0, direction=-1)
    assert mx.bounce_height(t, gap, t_imp, 0.2) == pytest.approx(0.005, abs=1e-6)
    assert mx.bounce_height(t, gap, t_imp, 0.6) == pytest.approx(0.008, abs=1e-6)
    assert mx.bounce_height(t, gap, 0.35, 0.1) == 0.0          # in contact: no rebound
    assert mx.bounce_height(t, gap, None, 0.2) is None
    no_impact = 0.02 + 0 * t
    assert mx.bounce_height(t, no_impact,
                            mx.event_time(t, no_impact, 0.0, direction=-1), 0.2) is None
    with pytest.raises(ValueError, match="no gap samples in the window"):
        mx.bounce_height(t, gap, 5.0, 0.2)
    with pytest.raises(ValueError, match="window_s must be a positive"):
        mx.bounce_height(t, gap, t_imp, -1.0)


# --------------------------------------------------------------- Gannon's criteria

def test_normalized_amplitude_error_is_distance_over_length():
    # 3-4-5 triangle: |d| = 0.05 m on a 1.25 m arm -> 4 %
    assert mx.normalized_amplitude_error([1.0, 0.5], [1.03, 0.54], 1.25) == \
        pytest.approx(0.04, rel=1e-12)
    ref = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 0.0]])
    run = ref + np.array([[0.0, 0.0], [0.6, 0.8], [0.3, 0.4]])   # distances 0, 1, 0.5
    assert mx.normalized_amplitude_error(ref, run, 10.0) == pytest.approx(0.1)
    assert mx.normalized_amplitude_error(ref, run, 10.0, reduce="rms") == \
        pytest.approx(math.sqrt(1.25 / 3) / 10.0)
    assert mx.normalized_amplitude_error(0.2, 0.17, 1.5) == pytest.approx(0.02)
    with pytest.raises(ValueError, match="length must be a positive"):
        mx.normalized_amplitude_error(0.2, 0.17, 0.0)
    with pytest.raises(ValueError, match="same shape"):
        mx.normalized_amplitude_error([0.0, 1.0], [0.0, 1.0, 2.0], 1.0)
    with pytest.raises(ValueError, match="reduce must be"):
        mx.normalized_amplitude_error(ref, run, 1.0, reduce="mean")


def test_frequency_and_relative_errors():
    assert mx.frequency_error(2.0, 2.1) == pytest.approx(0.05)
    assert mx.frequency_error(2.0, 1.9) == pytest.approx(-0.05)
    assert mx.relative_error(-4.0, -3.0) == pytest.approx(0.25)
    with pytest.raises(ValueError, match="f_ref must be a positive"):
        mx.frequency_error(0.0, 1.0)
    with pytest.raises(ValueError, match="reference value is zero"):
        mx.relative_error(0.0, 1.0)


def test_passes_matches_gannon_tables():
    # Table 4.2 (modal, tip amplitude) passes; Table 4.4 (modal, strain amplitude) fails;
    # Table 4.5 second-mode cubic 38 % fails, modal 7.5 % passes
    assert all(mx.passes(e) for e in (0.049, 0.063, 0.063, 0.075))
    assert not any(mx.passes(e) for e in (0.179, 0.174, 0.237, 0.38))
    assert mx.passes(0.10) and mx.passes(-0.10)
    assert not mx.passes(0.1000001)
    assert not mx.passes(float("nan"))
    assert mx.passes(0.15, threshold=0.2)
    with pytest.raises(ValueError, match="threshold must be a positive"):
        mx.passes(0.1, threshold=0.0)


# --------------------------------------------------------------- bad inputs

def test_bad_inputs_name_the_problem():
    t = np.arange(64) / 100.0
    y = np.sin(2 * np.pi * 10.0 * t)
    with pytest.raises(ValueError, match="at least 16 samples"):
        sp.dominant_frequency(t[:15], y[:15])
    with pytest.raises(ValueError, match="non-finite"):
        sp.dominant_frequency(t, np.where(t > 0.3, np.nan, y))
    with pytest.raises(ValueError, match="non-finite"):
        sp.spectrum(np.where(t > 0.3, np.inf, t), y)
    t_jit = t.copy()
    t_jit[10] += 1e-5
    with pytest.raises(ValueError, match=r"non-uniform sampling \(relative jitter"):
        sp.dominant_frequency(t_jit, y)
    with pytest.raises(ValueError, match="empty band"):
        sp.dominant_frequency(t, y, f_min=30.0, f_max=20.0)
    with pytest.raises(ValueError, match="empty band"):
        sp.dominant_frequency(t, y, f_min=80.0)               # above Nyquist (50 Hz)
    with pytest.raises(ValueError, match="no spectral peak"):
        sp.dominant_frequency(t, np.sin(2 * np.pi * 20.0 * t), f_min=0.5, f_max=1.0)
    with pytest.raises(ValueError, match="no oscillation"):
        sp.dominant_frequency(t, 3.0 + 2.0 * t)
    with pytest.raises(ValueError, match="unsupported window 'boxcar'"):
        sp.dominant_frequency(t, y, window="boxcar")
    with pytest.raises(ValueError, match="unsupported detrend"):
        sp.dominant_frequency(t, y, detrend="quadratic")
    with pytest.raises(ValueError, match="zero_pad must be an integer"):
        sp.dominant_frequency(t, y, zero_pad=0)
    with pytest.raises(ValueError, match="strictly increasing"):
        sp.spectrum(t[::-1], y)
    with pytest.raises(ValueError, match="same length"):
        sp.spectrum(t, y[:-1])
    with pytest.raises(ValueError, match="outside the data span"):
        sp.resample(t, y, [t[-1] + 0.1])
    with pytest.raises(ValueError, match="rate_hz must be a positive"):
        sp.uniform(t, y, rate_hz=-1.0)
    with pytest.raises(ValueError, match="non-finite"):
        mx.channel_errors(t, y, t, np.where(t > 0.3, np.nan, y))
    with pytest.raises(ValueError, match="strictly increasing"):
        mx.event_time(np.zeros(5), np.arange(5.0), 1.0)
