"""How well a predicted signal matches a measured one, per coordinate (the paper's §Experiments).

Primary score: the normalized cross-correlation of predicted and measured forward dynamics,
maximised over time shifts within ±5° of the slowest motion period (±T/72). For each shift the
score is the Pearson correlation of the overlapping parts (each part made zero-mean and divided by
its norm), so it lies in [−1, 1] and is invariant to any positive affine rescaling a·x + b of
either signal: units and offsets do not matter, phase and shape do.

Constant signals carry no shape, so their correlation is undefined: ``max_normalized_xcorr``
raises ``ValueError`` for a constant signal rather than inventing a value.

Secondary, chart-dependent: RMSE per coordinate; and the chart-invariant error norm
sqrt(mean_t e_tᵀ M_t e_t) with M the true metric (mass or drag matrix) at the measured states.
"""

from __future__ import annotations

import numbers

import numpy as np

from dualid.errors import DataError

# a signal whose centered norm is below this fraction of its raw norm is treated as constant
_CONSTANT_RTOL = 1e-12


def _is_constant(x: np.ndarray) -> bool:
    centered = np.linalg.norm(x - x.mean())
    return centered == 0.0 or centered <= _CONSTANT_RTOL * np.linalg.norm(x)


def _check_shift(max_shift, T: int) -> int:
    if isinstance(max_shift, (bool, np.bool_)) or not isinstance(max_shift, numbers.Integral):
        raise DataError(f"max_shift: expected an integer number of samples, got {max_shift!r}")
    max_shift = int(max_shift)
    if max_shift < 0 or max_shift > T - 2:
        raise DataError(
            f"max_shift: expected an integer in [0, {T - 2}] for signals of {T} samples "
            f"(at least 2 overlapping samples), got {max_shift}"
        )
    return max_shift


def max_normalized_xcorr(pred: np.ndarray, meas: np.ndarray, max_shift: int) -> float:
    """max over k ∈ [−max_shift, max_shift] of corr(pred[t + k], meas[t]) on the overlap; in [−1, 1].

    pred, meas: (T,) signals sampled at the same times. Raises ValueError for constant signals.
    """
    pred = np.asarray(pred, dtype=float)
    meas = np.asarray(meas, dtype=float)
    if pred.ndim != 1 or meas.ndim != 1:
        raise DataError(f"max_normalized_xcorr: expected two 1-D signals, got shapes {pred.shape} and {meas.shape}")
    if pred.shape != meas.shape:
        raise DataError(
            f"max_normalized_xcorr: signals must have the same length, got {pred.shape[0]} and {meas.shape[0]}"
        )
    T = pred.shape[0]
    if T < 2:
        raise DataError(f"max_normalized_xcorr: expected signals of at least 2 samples, got {T}")
    max_shift = _check_shift(max_shift, T)
    for name, x in (("pred", pred), ("meas", meas)):
        if not np.all(np.isfinite(x)):
            raise DataError(f"max_normalized_xcorr: {name} has non-finite values (NaN or inf)")
        if _is_constant(x):
            raise DataError(
                f"max_normalized_xcorr: {name} is constant (value {x[0]:.6g}); the correlation of a "
                "constant signal is undefined"
            )
    best = -np.inf
    for k in range(-max_shift, max_shift + 1):
        a = pred[k:] if k >= 0 else pred[: T + k]  # pred shifted by k samples against meas
        b = meas[: T - k] if k >= 0 else meas[-k:]
        a = a - a.mean()
        b = b - b.mean()
        denom = np.linalg.norm(a) * np.linalg.norm(b)
        if denom == 0.0:  # constant on this overlap only: no information at this shift
            continue
        best = max(best, float(a @ b) / denom)
    if best == -np.inf:
        raise DataError("max_normalized_xcorr: every overlap within the shift window is constant")
    return float(np.clip(best, -1.0, 1.0))


def shift_window(slowest_period: float, dt: float) -> int:
    """Samples in ±5° of the slowest period: round((T/72) / dt)."""
    for name, x in (("slowest_period", slowest_period), ("dt", dt)):
        if not (np.isfinite(x) and x > 0):
            raise DataError(f"shift_window: {name} must be a positive finite number of seconds, got {x!r}")
    return int(round((slowest_period / 72.0) / dt))


def _check_pair(pred, meas, what: str) -> tuple[np.ndarray, np.ndarray]:
    pred = np.asarray(pred, dtype=float)
    meas = np.asarray(meas, dtype=float)
    if pred.ndim != 2 or meas.ndim != 2 or pred.shape != meas.shape:
        raise DataError(
            f"{what}: pred and meas must both have shape (T, n) and agree, got {pred.shape} and {meas.shape}"
        )
    return pred, meas


def score_run(pred: np.ndarray, meas: np.ndarray, max_shift: int) -> np.ndarray:
    """Per-coordinate max normalized cross-correlation, (n,), of signals (T, n)."""
    pred, meas = _check_pair(pred, meas, "score_run")
    return np.array([max_normalized_xcorr(pred[:, j], meas[:, j], max_shift) for j in range(pred.shape[1])])


def rmse(pred: np.ndarray, meas: np.ndarray) -> np.ndarray:
    """Per-coordinate root-mean-square error, (n,), in the signal's units (chart-dependent)."""
    pred, meas = _check_pair(pred, meas, "rmse")
    return np.sqrt(np.mean((pred - meas) ** 2, axis=0))


def metric_rmse(pred: np.ndarray, meas: np.ndarray, M: np.ndarray) -> float:
    """sqrt(mean_t e_tᵀ M_t e_t), e = pred − meas, M (T, n, n): the chart-invariant error norm.

    With M the mass matrix and e an acceleration error, eᵀMe is invariant to the choice of
    coordinates (e is a vector, M a metric); the same holds for drag matrices and velocities.
    """
    pred, meas = _check_pair(pred, meas, "metric_rmse")
    M = np.asarray(M, dtype=float)
    T, n = pred.shape
    if M.shape != (T, n, n):
        raise DataError(f"metric_rmse: expected M of shape {(T, n, n)}, got {M.shape}")
    e = pred - meas
    quad = np.einsum("ta,tab,tb->t", e, M, e)
    return float(np.sqrt(max(float(np.mean(quad)), 0.0)))
