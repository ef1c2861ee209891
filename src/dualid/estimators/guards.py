"""Degeneracy guard: how far an identified metric M_i(θ̂) has collapsed or blown up against a reference.

For each sample the generalised eigenvalues λ of the pencil (M_i(θ̂), M_i(θ_ref)), i.e. the
eigenvalues of L_i⁻¹ M_i(θ̂) L_i⁻ᵀ with M_i(θ_ref) = L_i L_iᵀ, say by how much the kinetic energy
(or dissipated power) of every velocity direction changed. They are chart-invariant: under
q = φ(q̃), M̃ = BᵀMB for both matrices and the pencil's eigenvalues do not move. We record

    metric_ratio_min = min_i λ_min,i      metric_ratio_max = max_i λ_max,i

and flag ``degenerate`` when either leaves [1/c, c], with c = ``DEFAULT_BOUND`` = 100 unless told.

Why 100: a well-posed fit moves the metric by noise-sized amounts; the worst non-degenerate
behaviour measured here (the paper's DM under 10 % torque noise, armatures off ×3–12, issue 11)
stays inside ×12, while the ghost optima the guard exists for (the Crazyflie pendulum made
massless, M_αα ≈ 1e-12 against 1.5e-4; a wrist mass matrix shrunk ×70 by the fixed point) are
outside ×70 and usually by many orders of magnitude. The bound is a flag, not a constraint.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from dualid.errors import ConfigError, DataError, MetricError
from dualid.estimators.result import IdentificationResult
from dualid.problem import IdentificationProblem, sample_blocks

DEFAULT_BOUND = 100.0  # c: generalised eigenvalues outside [1/c, c] flag the fit as degenerate


def _check_bound(bound: float) -> float:
    bound = float(bound)
    if not (np.isfinite(bound) and bound > 1.0):
        raise ConfigError(f"bound: expected a finite number > 1 (the factor c of [1/c, c]), got {bound!r}")
    return bound


def generalized_eigenvalues(
    problem: IdentificationProblem, theta: np.ndarray, theta_ref: np.ndarray, chunk: int = 8192
) -> np.ndarray:
    """(N, n) eigenvalues of M_i(θ_ref)⁻¹ M_i(θ), ascending per sample (chart-invariant).

    Raises MetricError when M_i(θ_ref) is not positive definite at some sample (no reference there).
    """
    theta = np.asarray(theta, dtype=float)
    theta_ref = np.asarray(theta_ref, dtype=float)
    if theta.shape != (problem.p,) or theta_ref.shape != (problem.p,):
        raise DataError(f"θ and θ_ref: expected shape ({problem.p},), got {theta.shape} and {theta_ref.shape}")
    out = np.empty((problem.N, problem.n))
    for block, rows, start in sample_blocks(problem, chunk):
        M_ref = block.metric.evaluate(theta_ref, rows)
        M = block.metric.evaluate(theta, rows)
        try:
            L = np.linalg.cholesky(M_ref)
        except np.linalg.LinAlgError as exc:
            lam = np.linalg.eigvalsh(M_ref)[:, 0]
            bad = int(np.sum(~(lam > 0)))
            raise MetricError(
                f"metric guard: the reference metric M_i(θ_ref) must be positive definite at every sample, "
                f"but it is not at {bad} of {len(lam)} samples in rows {start}.. (smallest eigenvalue "
                f"{lam.min():.3g}); choose a reference with every body massive (a WLS fit or the prior)"
            ) from exc
        X = np.linalg.solve(L, M)  # L⁻¹ M
        A = np.linalg.solve(L, np.swapaxes(X, 1, 2))  # L⁻¹ (L⁻¹ M)ᵀ = L⁻¹ M L⁻ᵀ
        out[start : start + M.shape[0]] = np.linalg.eigvalsh(0.5 * (A + np.swapaxes(A, 1, 2)))
    return out


def guard_info(
    problem: IdentificationProblem,
    theta: np.ndarray,
    theta_ref: np.ndarray,
    bound: float = DEFAULT_BOUND,
    reference: str = "",
) -> dict:
    """{"metric_ratio_min", "metric_ratio_max", "degenerate", "metric_guard_bound", "metric_guard_reference"}."""
    bound = _check_bound(bound)
    lam = generalized_eigenvalues(problem, theta, theta_ref)
    lo, hi = float(lam[:, 0].min()), float(lam[:, -1].max())
    return {
        "metric_ratio_min": lo,
        "metric_ratio_max": hi,
        "degenerate": bool(not (lo >= 1.0 / bound and hi <= bound)),  # NaN counts as degenerate
        "metric_guard_bound": bound,
        "metric_guard_reference": reference,
    }


def with_guard(
    result: IdentificationResult,
    problem: IdentificationProblem,
    theta_ref: np.ndarray,
    bound: float = DEFAULT_BOUND,
    reference: str = "",
) -> IdentificationResult:
    """A copy of ``result`` whose info carries the metric guard against θ_ref (see ``guard_info``)."""
    info = dict(result.info)
    info.update(guard_info(problem, result.theta, theta_ref, bound, reference))
    return dataclasses.replace(result, info=info)


@dataclass(frozen=True)
class Guarded:
    """Any estimator, with its result carrying the metric guard against a reference fit.

    reference: an estimator whose fit is the reference θ (default: covariance WLS under the same
    constraints), or a fixed θ_ref given as a tuple (e.g. the prior). The reference's own fit is
    recorded in the result (``metric_guard_reference``).
    """

    estimator: object
    reference: object = None  # an estimator with .fit, a tuple θ_ref, or None (WLS)
    bound: float = DEFAULT_BOUND

    def __post_init__(self) -> None:
        if not hasattr(self.estimator, "fit"):
            raise ConfigError(f"Guarded: estimator must have a fit(problem) method, got {type(self.estimator).__name__}")
        _check_bound(self.bound)
        ref = self.reference
        if ref is not None and not hasattr(ref, "fit"):
            ref = tuple(float(x) for x in np.asarray(ref, dtype=float).ravel())
            object.__setattr__(self, "reference", ref)

    @property
    def name(self) -> str:
        return getattr(self.estimator, "name", type(self.estimator).__name__)

    def fit(self, problem: IdentificationProblem) -> IdentificationResult:
        result = self.estimator.fit(problem)
        if isinstance(self.reference, tuple):
            theta_ref, label = np.array(self.reference), "given θ_ref"
        else:
            from dualid.estimators.least_squares import WLS

            ref = self.reference if self.reference is not None else WLS(
                constrained=getattr(self.estimator, "constrained", True),
                allow_unidentifiable=getattr(self.estimator, "allow_unidentifiable", False),
            )
            theta_ref, label = ref.fit(problem).theta, getattr(ref, "name", type(ref).__name__)
        return with_guard(result, problem, theta_ref, self.bound, label)
