"""The interior-point method on a *constant* weight, from sufficient statistics: argmin Σ r_iᵀ C⁻¹ r_i.

With M_i(θ) = C independent of θ and of the sample the dual-metric objective is the quadratic

    f(θ) = θᵀHθ − 2gᵀθ + c,   H = Σ Y_iᵀ C⁻¹ Y_i,  g = Σ Y_iᵀ C⁻¹ τ_i,  c = Σ τ_iᵀ C⁻¹ τ_i,

so one pass over the samples (whitened rows L⁻¹ Y_i, C = L Lᵀ factored once per fit) reduces the fit to a p-sized
problem, solved with the iterations, chart-invariant start and stopping rule of ``fit_dual_metric_newton`` on
M_i = C: the same θ up to rounding, for two passes over the data instead of two per iteration.
"""

from __future__ import annotations

import time

import numpy as np

from dualid.errors import MetricError
from dualid.estimators.newton.fit import check_bounds
from dualid.estimators.newton.interior_point import direction_label, direction_names, run_interior_point
from dualid.estimators.newton.objective import CHUNK, Derivatives, weighted_sums
from dualid.estimators.newton.start import constant_metric_start, toward, toward_start
from dualid.estimators.result import IdentificationResult
from dualid.linalg import solve_psd, tri_inverse
from dualid.model.closure import on_closure
from dualid.model.consistency import central_point, feasible_set
from dualid.problem import IdentificationProblem, additive, sample_blocks


def not_positive_definite(problem, what: str, bad: int, low: float) -> MetricError:
    """The error for a weight's covariance that is not ≻ 0 at ``bad`` of the problem's samples."""
    return MetricError(
        f"{what} must be positive definite at every sample, but it is not at {bad} of {problem.N} samples "
        f"(smallest eigenvalue {low:.3g}); give a positive-definite Σ or a pilot with a positive-definite metric"
    )


def whitener(problem, C: np.ndarray, what: str = "the weight's covariance") -> np.ndarray:
    """L⁻¹ (n, n), C = L Lᵀ (``weighted_sums`` with F = L⁻ᵀ sums the whitened rows); MetricError (every sample fails)
    when C is not positive definite."""
    C = np.asarray(C, dtype=float)
    try:
        L = np.linalg.cholesky(C)
    except np.linalg.LinAlgError:
        L = None
    if L is None or not np.all(np.isfinite(L)):
        raise not_positive_definite(problem, what, problem.N, float(np.linalg.eigvalsh(C)[0]))
    return tri_inverse(L[None])[0]


@additive
def weighted_objective(problem: IdentificationProblem, Li: np.ndarray, theta: np.ndarray, chunk: int = CHUNK) -> float:
    """Σ r_iᵀ C⁻¹ r_i from the residuals (no cancellation, unlike θᵀHθ − 2gᵀθ + c), C⁻¹ = Liᵀ Li."""
    f = 0.0
    for block, rows, _ in sample_blocks(problem, chunk):
        Y = block.Y[rows]
        e = ((Y.reshape(-1, Y.shape[-1]) @ theta).reshape(Y.shape[:2]) - block.tau[rows]) @ Li.T
        f += float(np.sum(e * e))
    return f


def fit_weighted_newton(
    problem: IdentificationProblem,
    C: np.ndarray,
    *,
    constrained: bool = True,
    tol: float = 1e-9,
    max_iter: int = 100,
    chunk: int = CHUNK,
    method: str = "dual_metric",
    verbose: bool = False,
    warm_start_samples: int | None = None,  # accepted for option compatibility; unused (no pass per iteration)
    what: str = "the weight's covariance",
    null_step: bool = True,  # False: no move along the null space (a pilot whose θ feeds only its residuals)
) -> IdentificationResult:
    """argmin Σ r_iᵀ C⁻¹ r_i under the constraints (module doc), C (n, n) ≻ 0; when the cheap start fails, from the
    weighted LS's central point or a phase I on the same (closed) feasible set
    (``newton.start.constant_metric_start``)."""
    t0 = time.perf_counter()
    check_bounds(problem, constrained)
    Li = whitener(problem, C, what)
    H, g, c, H_e, g_e = weighted_sums(problem, Li.T, chunk, energy=True)  # whitened rows L⁻¹Y_i, τ_i L⁻ᵀ
    H = 0.5 * (H + H.T)
    # parameters f cannot see that only loosen a block: solved on the closed set, then completed (model.closure)
    cons, done = on_closure(feasible_set(problem.parameters, constrained), H, c, problem.parameters.names)
    theta_f = solve_psd(H, g, rtol=1e-10)  # the unconstrained weighted LS (min-norm): the frozen-metric LS
    f_min = max(c - 2.0 * float(g @ theta_f) + float(theta_f @ H @ theta_f), 0.0)

    def f_of(th):
        e = th - theta_f
        return float(e @ H @ e) + f_min

    def objective(th, order):
        if not order:
            return Derivatives(f_of(th))
        return Derivatives(f_of(th), 2.0 * (H @ th - g), 2.0 * H)

    start = None
    theta_c = central_point(solve_psd(H_e, g_e, rtol=1e-10), cons)
    if cons.margin(theta_c) > 0:  # as newton.start.starting_point with the energy seed; every θ is in the domain
        theta0, start = toward(cons, theta_c, theta_f, "energy→frozen-metric→central", f_of)
    if start is None:  # the same closed problem from the weighted LS's central point or phase I (not a fit without
        # the closure: model.closure)
        theta0, start = constant_metric_start(problem, cons, theta_f)
    theta, _, _, info = run_interior_point(problem, cons, theta0, None, None, tol, max_iter, chunk, verbose,
                                        objective=objective, f_scale=c)
    theta = toward_start(theta, theta0, H, cons, f_of) if null_step else theta
    info.pop("objective")
    info.update(start=start, statistics="one pass (H = Σ YᵀC⁻¹Y)")
    names = problem.parameters.names  # the iterates' direction by parameter name (no arrays in info), as newton.fit
    if "diverging_candidate" in info:
        info["diverging_candidate"] = direction_names(info["diverging_candidate"], names)
    if "diverging_direction" in info:
        info["diverging_direction"] = direction_label(info["diverging_direction"], names)
    theta, info = done(theta, info)
    return IdentificationResult(method, theta, problem.parameters, weighted_objective(problem, Li, theta, chunk),
                                "optimal", "newton", time.perf_counter() - t0,
                                info["iterations"], constrained, info)

