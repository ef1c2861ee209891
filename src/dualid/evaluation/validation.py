"""Validation of an identified model on held-out runs.

Two comparisons per run and joint, each scored by RMSE and by the normalized cross-correlation
(maximum over shifts within ±``xcorr_window`` seconds, ``evaluation.scores.max_normalized_xcorr``):

- effort (the standard check on real robots): the inverse-dynamics prediction τ̂ = Y(q, v, a) θ̂
  from measured q, v and *differentiated* a, against the measured effort τ [N m];
- acceleration: the forward-dynamics prediction â = M̂(q)⁻¹ (τ − ĥ(q, v)) from measured q, v, τ,
  against the differentiated accelerations a [rad/s²] (the paper's score). Differentiated a is
  noisy: its RMSE is dominated by differentiation noise, its NCC much less.
  For a drag model (τ = D(q)v) the forward prediction is v̂ = D̂(q)⁻¹τ against the measured velocity v:
  the fields ``a``/``a_pred``/``a_*`` then hold velocities (no accelerations are needed).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from dualid.data.trajectory import Trajectory
from dualid.errors import DataError, MetricError
from dualid.evaluation.prediction import forward_dynamics, measured_signal
from dualid.evaluation.scores import max_normalized_xcorr, rmse
from dualid.model.base import Model


def _ncc(pred: np.ndarray, meas: np.ndarray, max_shift: int) -> np.ndarray:
    """Per joint; NaN (undefined) where either signal is constant, e.g. an unactuated joint's zero torque."""
    out = np.full(pred.shape[1], np.nan)
    for j in range(pred.shape[1]):
        if np.ptp(pred[:, j]) == 0 or np.ptp(meas[:, j]) == 0:
            continue
        out[j] = max_normalized_xcorr(pred[:, j], meas[:, j], min(max_shift, pred.shape[0] - 2))
    return out


@dataclass(frozen=True, eq=False)
class RunValidation:
    """One held-out run: measured and predicted effort and acceleration, and their scores per joint."""

    run: str
    t: np.ndarray  # (T,) [s]
    tau: np.ndarray  # (T, n) measured effort [N m]
    tau_pred: np.ndarray  # (T, n) inverse dynamics Y(q, v, a) θ̂ [N m]
    a: np.ndarray  # (T, n) differentiated acceleration [rad/s²]
    a_pred: np.ndarray | None  # (T, n) forward dynamics M̂⁻¹(τ − ĥ) [rad/s²]; None if M̂ is singular there
    tau_rmse: np.ndarray  # (n,) [N m]
    tau_ncc: np.ndarray  # (n,) in [−1, 1] (NaN where a signal is constant)
    a_rmse: np.ndarray  # (n,) [rad/s²] (NaN if no forward prediction)
    a_ncc: np.ndarray  # (n,)
    note: str = ""


@dataclass(frozen=True, eq=False)
class Validation:
    """A model's validation on held-out runs (``label``: the method or reference it belongs to)."""

    label: str
    coordinates: tuple[str, ...]
    runs: tuple[RunValidation, ...]

    def _stack(self, key: str) -> np.ndarray:
        return np.array([getattr(r, key) for r in self.runs])

    def mean(self, key: str) -> np.ndarray:
        """Mean over runs of a per-joint score: "tau_rmse", "tau_ncc", "a_rmse" or "a_ncc"."""
        x = self._stack(key)
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a joint with NaN in every run (e.g. a passive one's τ NCC)
            return np.nanmean(x, axis=0) if np.isfinite(x).any() else np.full(len(self.coordinates), np.nan)

    def std(self, key: str) -> np.ndarray:
        x = self._stack(key)
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return np.nanstd(x, axis=0) if np.isfinite(x).any() else np.full(len(self.coordinates), np.nan)

    def as_dict(self) -> dict:
        def clean(x):
            return [None if not np.isfinite(v) else float(v) for v in np.asarray(x)]

        return {
            "label": self.label,
            "coordinates": list(self.coordinates),
            "mean": {k: dict(zip(self.coordinates, clean(self.mean(k)))) for k in ("tau_rmse", "tau_ncc", "a_rmse", "a_ncc")},
            "runs": [
                {
                    "run": r.run,
                    "tau_rmse": clean(r.tau_rmse),
                    "tau_ncc": clean(r.tau_ncc),
                    "a_rmse": clean(r.a_rmse),
                    "a_ncc": clean(r.a_ncc),
                    **({"note": r.note} if r.note else {}),
                }
                for r in self.runs
            ],
        }


def validate_run(model: Model, theta: np.ndarray, traj: Trajectory, xcorr_window: float = 0.02) -> RunValidation:
    """Effort and acceleration predictions of θ̂ on one run (which must carry accelerations; for a drag
    model: effort and velocity predictions)."""
    if model.kind == "inertia" and traj.a is None:
        raise DataError(
            f"validate: run {traj.name!r} has no accelerations; differentiate it first (preprocessing step "
            "'differentiate')"
        )
    if tuple(traj.coordinates) != tuple(model.coordinates):
        raise DataError(f"validate: run {traj.name!r} has coordinates {traj.coordinates}, the model {model.coordinates}")
    theta = np.asarray(theta, dtype=float)
    dt = float(np.median(np.diff(traj.t)))
    max_shift = int(round(xcorr_window / dt))
    tau_pred = model.regressor(traj.q, traj.v, traj.a) @ theta
    signal = measured_signal(model, traj)  # a (inertia) or v (drag)
    note = ""
    try:
        a_pred = forward_dynamics(model, theta, traj.q, traj.v, traj.tau)
        a_rmse, a_ncc = rmse(a_pred, signal), _ncc(a_pred, signal, max_shift)
    except MetricError as exc:
        a_pred, note = None, str(exc)
        a_rmse = a_ncc = np.full(traj.n, np.nan)
    return RunValidation(
        run=traj.name,
        t=traj.t,
        tau=traj.tau,
        tau_pred=tau_pred,
        a=signal,
        a_pred=a_pred,
        tau_rmse=rmse(tau_pred, traj.tau),
        tau_ncc=_ncc(tau_pred, traj.tau, max_shift),
        a_rmse=a_rmse,
        a_ncc=a_ncc,
        note=note,
    )


def validate(
    model: Model, theta: np.ndarray, trajectories: list[Trajectory], label: str = "", xcorr_window: float = 0.02
) -> Validation:
    """``validate_run`` on every run."""
    if not trajectories:
        raise DataError("validate: no held-out runs given")
    runs = tuple(validate_run(model, theta, t, xcorr_window) for t in trajectories)
    return Validation(label, tuple(model.coordinates), runs)
