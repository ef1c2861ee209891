"""Signal processing for trajectories: zero-phase low-pass filtering and numerical differentiation.

Every step applied to a ``Trajectory`` is appended to ``trajectory.meta['steps']`` so the output of
a fit records how its data were made.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from dualid.errors import DataError


def sample_rate(t: np.ndarray, rtol: float = 0.05) -> float:
    """The (uniform) sample rate of t [Hz]; DataError when the spacing varies by more than rtol."""
    dt = np.diff(np.asarray(t, dtype=float))
    med = float(np.median(dt))
    if med <= 0:
        raise DataError(f"time stamps must increase; median step is {med}")
    spread = float(np.max(np.abs(dt - med))) / med
    if spread > rtol:
        raise DataError(
            f"time stamps are not uniform: step varies by {spread:.0%} of the median {med:.4g} s "
            f"(tolerance {rtol:.0%}); resample first"
        )
    return 1.0 / med


def lowpass(x: np.ndarray, fs: float, cutoff: float, order: int = 4) -> np.ndarray:
    """Zero-phase Butterworth low-pass along axis 0 (filtfilt, second-order sections)."""
    if not 0 < cutoff < fs / 2:
        raise DataError(f"low-pass cutoff must be in (0, {fs / 2:.4g}) Hz (Nyquist at fs={fs:.4g} Hz), got {cutoff}")
    sos = signal.butter(order, cutoff, btype="low", fs=fs, output="sos")
    return signal.sosfiltfilt(sos, np.asarray(x, dtype=float), axis=0)


def savgol_derivatives(x: np.ndarray, fs: float, window: float, polyorder: int = 3):
    """Smoothed x and its first two time derivatives by a Savitzky–Golay fit over ``window`` seconds."""
    n = int(round(window * fs)) | 1  # odd number of samples
    n = max(n, polyorder + 2 + (polyorder % 2 == 0))
    if n > x.shape[0]:
        raise DataError(f"Savitzky–Golay window of {n} samples is longer than the signal ({x.shape[0]} samples)")
    dt = 1.0 / fs
    x = np.asarray(x, dtype=float)
    xs = signal.savgol_filter(x, n, polyorder, deriv=0, axis=0, mode="interp")
    dx = signal.savgol_filter(x, n, polyorder, deriv=1, delta=dt, axis=0, mode="interp")
    ddx = signal.savgol_filter(x, n, polyorder, deriv=2, delta=dt, axis=0, mode="interp")
    return xs, dx, ddx
