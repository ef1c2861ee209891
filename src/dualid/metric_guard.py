"""Degeneracy guard: how far an identified metric M_i(θ̂) has collapsed or blown up against a reference.

For each sample the generalised eigenvalues λ of the pencil (M_i(θ̂), M_i(θ_ref)), i.e. the
eigenvalues of L_i⁻¹ M_i(θ̂) L_i⁻ᵀ with M_i(θ_ref) = L_i L_iᵀ, say by how much the kinetic energy
(or dissipated power) of every velocity direction changed. They are chart-invariant: under
q = φ(q̃), M̃ = BᵀMB for both matrices and the pencil's eigenvalues do not move. We record

    metric_ratio_min = min_i λ_min,i      metric_ratio_max = max_i λ_max,i

and flag ``degenerate`` when either leaves [1/c, c], with c = ``DEFAULT_BOUND`` = 100 unless told.

Why 100: a well-posed fit moves the metric by noise-sized amounts; the worst non-degenerate
behaviour measured here (the paper's DM under 10 % torque noise, armatures off ×3–12)
stays inside ×12, while the ghost optima the guard exists for (the Crazyflie pendulum made
massless, M_αα ≈ 1e-12 against 1.5e-4; a wrist mass matrix shrunk ×70 by the fixed point) are
outside ×70 and usually by many orders of magnitude. The bound is a flag, not a constraint.
"""

from __future__ import annotations

import numpy as np

from dualid.errors import ConfigError, DataError, MetricError
from dualid.linalg import tri_inverse
from dualid.problem import IdentificationProblem, sample_blocks, stacked, strided_rows


DEFAULT_BOUND = 100.0  # c: generalised eigenvalues outside [1/c, c] flag the fit as degenerate
GUARD_SAMPLES = 20_000  # the guard an estimator records itself looks at most this many evenly strided samples
# (at N = 10⁶ the full pass costs more than a least-squares fit); recorded in info["metric_guard_samples"]


def check_bound(bound: float) -> float:
    bound = float(bound)
    if not (np.isfinite(bound) and bound > 1.0):
        raise ConfigError(f"bound: expected a finite number > 1 (the factor c of [1/c, c]), got {bound!r}")
    return bound


@stacked
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
        Li = tri_inverse(L)  # batched L⁻¹ (np.linalg.solve ran a general LU per sample)
        A = Li @ M @ np.swapaxes(Li, 1, 2)  # L⁻¹ M L⁻ᵀ
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
    lam = generalized_eigenvalues(problem, theta, theta_ref)
    return guard_from_ratios(float(lam[:, 0].min()), float(lam[:, -1].max()), bound, reference)


def guard_from_ratios(lo: float, hi: float, bound: float = DEFAULT_BOUND, reference: str = "") -> dict:
    """``guard_info`` from the extreme generalised eigenvalues, when the caller has them (e.g. dm-bfp's pencil)."""
    bound = check_bound(bound)
    return {
        "metric_ratio_min": lo,
        "metric_ratio_max": hi,
        "degenerate": bool(not (lo >= 1.0 / bound and hi <= bound)),  # NaN counts as degenerate
        "metric_guard_bound": bound,
        "metric_guard_reference": reference,
    }


def guard_sample(problem: IdentificationProblem, max_samples: int = GUARD_SAMPLES):
    """(problem, None) when it has at most ``max_samples`` samples, else (every k-th sample as a problem, its
    count): a collapse the guard exists for (a body made massless) shows at every sample."""
    if problem.N <= max_samples:
        return problem, None
    some = problem.subset(strided_rows(problem.N, max_samples))
    return some, some.N


def reference_guard(
    problem: IdentificationProblem,
    theta: np.ndarray,
    theta_ref: np.ndarray | None,
    reference: str,
    bound: float = DEFAULT_BOUND,
) -> dict:
    """The guard info an estimator records itself: against θ_ref (a prior or the estimator's own pilot).

    No reference: says so (``metric_guard_reference``: "none …") and flags nothing. A reference whose
    metric is not positive definite somewhere: the fit is not certified (``degenerate`` True, with the
    reason in ``metric_guard_error``).
    """
    if theta_ref is None:
        return {"metric_guard_reference": f"none ({reference})", "metric_guard_bound": float(bound)}
    some, count = guard_sample(problem)
    extra = {} if count is None else {"metric_guard_samples": count}
    try:
        return {**guard_info(some, theta, theta_ref, bound, reference), **extra}
    except MetricError as exc:
        return {"degenerate": True, "metric_guard_error": str(exc), "metric_guard_reference": reference,
                "metric_guard_bound": float(bound), **extra}


def check_guard_options(guard_reference, guard_bound, name: str) -> tuple[tuple | None, float]:
    """(θ_ref as a tuple or None, bound), checked at construction (ConfigError)."""
    if guard_reference is not None:
        ref = np.asarray(guard_reference, dtype=float)
        if ref.ndim != 1 or not np.all(np.isfinite(ref)):
            raise ConfigError(f"{name}: guard_reference must be a finite vector θ_ref (p,), got shape {ref.shape}")
        guard_reference = tuple(float(x) for x in ref)
    try:
        bound = check_bound(guard_bound)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{name}: guard_bound: expected a finite number > 1, got {guard_bound!r}") from exc
    except ConfigError as exc:
        raise ConfigError(f"{name}: guard_{exc}") from exc
    return guard_reference, bound


def given_reference(problem: IdentificationProblem, guard_reference: tuple | None, name: str) -> np.ndarray | None:
    """The constructor's θ_ref as an array of the problem's size (DataError otherwise), or None."""
    if guard_reference is None:
        return None
    ref = np.array(guard_reference)
    if ref.shape != (problem.p,):
        raise DataError(f"{name}: guard_reference has {ref.size} entries, the problem has p = {problem.p} parameters")
    return ref
