"""Preprocessing defaults derived from a log's own rate and motion band (used when a fit's config
names no ``preprocessing``), and warnings when configured steps are far from the data.

From the first training log: its rate fs (median time step) and its motion band f_m (the frequency
below which 99 % of the power of the detrended joint positions lies, the largest over joints;
Welch's estimate). Then: resample at fs; differentiate q by Savitzky–Golay over 0.2 / f_m seconds
(v and a from q); low-pass τ at 5 f_m; downsample to about 10 × that cutoff. On the DFKI pendulum
(fs = 500 Hz, f_m ≈ 2 Hz) this gives the steps of examples/dfki/fit.yaml.
"""

from __future__ import annotations

import warnings

import numpy as np

from dualid.data.trajectory import Trajectory
from dualid.errors import DataError, DualidWarning

MIN_RATE = 10.0  # [Hz] slower logs get no derived defaults (time in ms read as s?)
MIN_SAMPLES = 100
BAND_POWER = 0.99  # the motion band holds this fraction of the detrended q's power
# the fixed preprocessing dualid 0.1 applied whatever the log (500 Hz, 0.05 s window, 20 Hz τ filter): kept
# for reproducing results measured with it (the Newton solver's convergence corpus uses it on DFKI data)
FIXED_PREPROCESSING_0_1 = (
    {"resample": {"rate": 500.0}},
    {"differentiate": {"method": "savgol", "window": 0.05}},
    {"filter_lowpass": {"cutoff": 20.0, "fields": ["tau"]}},
    {"downsample": {"factor": 5}},
)


def _round(x: float, digits: int = 2) -> float:
    return float(f"{x:.{digits}g}")


def log_rate_and_band(traj: Trajectory) -> tuple[float, float]:
    """(fs [Hz] from the median time step, f_m [Hz] the motion band of q)."""
    from scipy import signal  # here: scipy.signal costs ~0.7 s to import

    fs = 1.0 / float(np.median(np.diff(traj.t)))
    t_uniform = traj.t[0] + np.arange(int((traj.t[-1] - traj.t[0]) * fs) + 1) / fs
    band = 0.0
    for j in range(traj.q.shape[1]):
        q = signal.detrend(np.interp(t_uniform, traj.t, traj.q[:, j]))
        f, P = signal.welch(q, fs=fs, nperseg=min(4096, q.size))
        if P.sum() <= 0:
            continue
        band = max(band, float(f[np.searchsorted(np.cumsum(P) / P.sum(), BAND_POWER)]))
    if band <= 0:
        raise DataError(f"run {traj.name!r}: the joints do not move, so no motion band (and no default preprocessing) "
                        "can be derived; give 'preprocessing' steps in a config")
    return fs, band


def adaptive_preprocessing(traj: Trajectory) -> tuple[tuple[dict, ...], str]:
    """The default steps for a log (see the module docstring) and a sentence saying what was chosen."""
    if traj.T < MIN_SAMPLES:
        raise DataError(f"{traj.name}: {traj.T} samples are too few to derive default preprocessing (need {MIN_SAMPLES}); "
                        "give 'preprocessing' steps in a config")
    fs, band = log_rate_and_band(traj)
    if fs < MIN_RATE:
        raise DataError(
            f"{traj.name}: the log's rate is {fs:.3g} Hz (median step {1 / fs:.3g} s), too slow to derive default "
            "preprocessing for a robot log; if time is logged in ms set the column map's units: {time: ms}, "
            "otherwise give 'preprocessing' steps in a config")
    rate = _round(fs, 3)
    cutoff = min(_round(5 * band), 0.4 * rate)
    window = _round(0.2 / band)
    factor = max(1, int(rate // (10 * cutoff)))
    steps = (
        {"resample": {"rate": rate}},
        {"differentiate": {"method": "savgol", "window": window, "velocity": True}},
        {"filter_lowpass": {"cutoff": cutoff, "fields": ["tau"]}},
        {"downsample": {"factor": factor}},
    )
    note = (f"derived from {traj.name}: rate {fs:.4g} Hz, motion band {band:.3g} Hz (99 % of q's power) → "
            f"resample at {rate:g} Hz, v and a by Savitzky–Golay over {window:g} s, τ low-passed at {cutoff:g} Hz, "
            f"downsampled ×{factor}")
    return steps, note


def warn_far_from_data(traj: Trajectory, steps) -> None:
    """DualidWarnings for configured steps that would remove the motion itself (a low-pass below the
    motion band, a differentiation window longer than its period)."""
    try:
        _, band = log_rate_and_band(traj)
    except DataError:
        return
    for step in steps:
        if not isinstance(step, dict) or len(step) != 1:
            continue
        (name, params), = step.items()
        params = params or {}
        cutoff = params.get("cutoff") if isinstance(params, dict) else None
        if name == "filter_lowpass" and isinstance(cutoff, (int, float)) and cutoff < band:
            warnings.warn(f"preprocessing: filter_lowpass cutoff {cutoff} Hz is below the motion band {band:.3g} Hz of "
                          f"{traj.name}: it removes part of the motion itself", DualidWarning, stacklevel=2)
        window = params.get("window") if isinstance(params, dict) else None
        if name == "differentiate" and isinstance(window, (int, float)) and window > 1.0 / band:
            warnings.warn(f"preprocessing: a differentiate window of {window} s is longer than the period 1/{band:.3g} Hz "
                          f"of {traj.name}'s fastest motion: derivatives are smoothed away", DualidWarning, stacklevel=2)
