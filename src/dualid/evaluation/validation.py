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
from dualid.evaluation.prediction import PredictionData, forward_dynamics, measured_signal
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


def _check_run(model: Model, traj: Trajectory) -> None:
    if model.kind == "inertia" and traj.a is None:
        raise DataError(
            f"validate: run {traj.name!r} has no accelerations; differentiate it first (preprocessing step "
            "'differentiate')"
        )
    if tuple(traj.coordinates) != tuple(model.coordinates):
        raise DataError(f"validate: run {traj.name!r} has coordinates {traj.coordinates}, the model {model.coordinates}")


@dataclass(frozen=True, eq=False)
class PreparedRun:
    """A run with what its validation needs that does not depend on θ: the regressor Y(q, v, a) and the forward
    dynamics' metric and bias regressor (``PredictionData``). Built once per run (``prepare_runs``), then validated
    for every θ: the Pinocchio passes are not repeated per fit."""

    traj: Trajectory
    Y: np.ndarray  # (T, n, p)
    prediction: PredictionData

    @staticmethod
    def of(model: Model, traj: Trajectory) -> "PreparedRun":
        _check_run(model, traj)
        return PreparedRun(traj, model.regressor(traj.q, traj.v, traj.a),
                           PredictionData.of(model, traj.q, traj.v, traj.tau))


PREPARED_MAX_FLOATS = 25_000_000  # prepare_runs keeps at most this many regressor entries (200 MB) in memory


def prepare_runs(model: Model, trajectories: list[Trajectory]) -> tuple[PreparedRun, ...] | list[Trajectory]:
    """``PreparedRun.of`` every run, for ``validate`` of several θ on the same runs; the runs as given when their
    regressors together would exceed PREPARED_MAX_FLOATS (then each validation rebuilds them, one run at a time)."""
    if sum(len(t.t) for t in trajectories) * len(model.coordinates) * model.parameters.p > PREPARED_MAX_FLOATS:
        return list(trajectories)
    return tuple(PreparedRun.of(model, t) for t in trajectories)


def validate_each(model: Model, thetas: dict[str, np.ndarray], trajectories: list[Trajectory],
                  xcorr_window: float = 0.02) -> dict[str, Validation]:
    """``validate`` of every labelled θ on the same runs, each run prepared once (one run in memory at a time)."""
    if not trajectories and thetas:
        raise DataError("validate: no held-out runs given")
    runs: dict[str, list[RunValidation]] = {label: [] for label in thetas}
    for traj in trajectories if thetas else ():
        prepared = PreparedRun.of(model, traj)
        for label, theta in thetas.items():
            runs[label].append(validate_run(model, theta, prepared, xcorr_window))
    return {label: Validation(label, tuple(model.coordinates), tuple(r)) for label, r in runs.items()}


def validate_run(model: Model, theta: np.ndarray, traj: Trajectory | PreparedRun,
                 xcorr_window: float = 0.02) -> RunValidation:
    """Effort and acceleration predictions of θ̂ on one run (which must carry accelerations; for a drag
    model: effort and velocity predictions); ``traj`` may be a ``PreparedRun`` of the same model."""
    prepared = traj if isinstance(traj, PreparedRun) else None
    if prepared is not None:
        traj = prepared.traj
    else:
        _check_run(model, traj)
    theta = np.asarray(theta, dtype=float)
    dt = float(np.median(np.diff(traj.t)))
    max_shift = int(round(xcorr_window / dt))
    tau_pred = (model.regressor(traj.q, traj.v, traj.a) if prepared is None else prepared.Y) @ theta
    signal = measured_signal(model, traj)  # a (inertia) or v (drag)
    note = ""
    try:
        if prepared is None:
            a_pred = forward_dynamics(model, theta, traj.q, traj.v, traj.tau)
        else:
            a_pred = prepared.prediction.predict(theta)
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
    model: Model, theta: np.ndarray, trajectories: list[Trajectory] | tuple[PreparedRun, ...], label: str = "",
    xcorr_window: float = 0.02,
) -> Validation:
    """``validate_run`` on every run (Trajectory, or PreparedRun to validate several θ on the same runs)."""
    if not trajectories:
        raise DataError("validate: no held-out runs given")
    runs = tuple(validate_run(model, theta, t, xcorr_window) for t in trajectories)
    return Validation(label, tuple(model.coordinates), runs)
