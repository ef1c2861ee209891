"""The interior-point method on a *constant* metric, from sufficient statistics: argmin Σ r_iᵀ C_i⁻¹ r_i.

With M_i(θ) = C_i independent of θ the dual-metric objective is the quadratic

    f(θ) = θᵀHθ − 2gᵀθ + c,   H = Σ Y_iᵀ C_i⁻¹ Y_i,  g = Σ Y_iᵀ C_i⁻¹ τ_i,  c = Σ τ_iᵀ C_i⁻¹ τ_i,

so one pass over the samples (C_i = L_i L_iᵀ, whitened rows L_i⁻¹ Y_i, one GEMM per chunk) reduces the
fit to a p-sized problem. The iterations, the start and the stopping rule are those of
``fit_dual_metric_newton`` on the problem with M_i = C_i (the same chart-invariant start: energy LS →
central point → frozen-metric LS, here the weighted LS itself), so the result is the same θ up to
rounding, at the cost of two passes over the data instead of two per iteration. C_i is given as a
function of a block of rows, so no N-sized (N, n, n) array is formed.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from dualid.errors import MetricError
from dualid.estimators.newton.closure import close, complete
from dualid.estimators.newton.interior_point import _interior_point
from dualid.estimators.newton.linalg import _solve_psd
from dualid.estimators.newton.objective import _Derivatives, _tri_inverse
from dualid.estimators.newton.start import _central_point, constant_metric_start
from dualid.estimators.result import IdentificationResult
from dualid.model.consistency import feasible_set
from dualid.problem import IdentificationProblem, sample_blocks

# (block, rows) → C_i (c, n, n) symmetric positive definite, for the samples ``rows`` of the in-memory ``block``
# (see dualid.problem.sample_blocks; for an in-memory problem the block is the problem itself)
Weight = Callable[[IdentificationProblem, slice], np.ndarray]


def _weight(weight: Weight, block: IdentificationProblem, rows: slice) -> np.ndarray:
    return np.broadcast_to(weight(block, rows), (len(range(block.N)[rows]), block.n, block.n))


def _whitened(problem, block: IdentificationProblem, weight: Weight, rows: slice, what: str, whiten=None):
    """(L_i⁻¹ Y_i (c, n, p), L_i⁻¹ τ_i (c, n)) for C_i = L_i L_iᵀ; MetricError if some C_i is not ≻ 0.
    whiten: (block, rows) → W_i (c, n, n) with C_i⁻¹ = W_iᵀ W_i, when the caller has that factor (no Cholesky)."""
    if whiten is not None:
        W = whiten(block, rows)
        return np.matmul(W, block.Y[rows]), np.einsum("cab,cb->ca", W, block.tau[rows])
    try:
        L = np.linalg.cholesky(_weight(weight, block, rows))
    except np.linalg.LinAlgError:
        L = None
    if L is None or not np.all(np.isfinite(L)):
        bad, low = 0, np.inf
        for b, r, _ in sample_blocks(problem, 4096):  # the whole count, for the message
            lam = np.linalg.eigvalsh(_weight(weight, b, r))[:, 0]
            bad, low = bad + int(np.sum(~(lam > 0))), min(low, float(lam.min()))
        raise MetricError(
            f"{what} must be positive definite at every sample, but it is not at {bad} of {problem.N} samples "
            f"(smallest eigenvalue {low:.3g}); give a positive-definite Σ or a pilot with a positive-definite metric"
        )
    Li = _tri_inverse(L)
    return np.matmul(Li, block.Y[rows]), np.einsum("cab,cb->ca", Li, block.tau[rows])


def weighted_statistics(problem: IdentificationProblem, weight: Weight, chunk: int = 4096,
                        what: str = "the weight's covariance", energy: bool = False, whiten=None):
    """(H, g, c) = Σ Y_iᵀC_i⁻¹Y_i, Σ Y_iᵀC_i⁻¹τ_i, Σ τ_iᵀC_i⁻¹τ_i accumulated over chunks of samples; with
    energy=True also (H_e, g_e) of the energy residual v_iᵀ r_i, from the same pass."""
    p = problem.p
    H, g, c = np.zeros((p, p)), np.zeros(p), 0.0
    He, ge = np.zeros((p, p)), np.zeros(p)
    for block, rows, _ in sample_blocks(problem, chunk):
        if energy:
            e = np.einsum("nap,na->np", block.Y[rows], block.v[rows])
            He += e.T @ e
            ge += e.T @ np.einsum("na,na->n", block.tau[rows], block.v[rows])
        Z, z = _whitened(problem, block, weight, rows, what, whiten)
        Z2, z1 = Z.reshape(-1, p), z.reshape(-1)
        H += Z2.T @ Z2
        g += Z2.T @ z1
        c += float(z1 @ z1)
    if energy:
        return 0.5 * (H + H.T), g, c, He, ge
    return 0.5 * (H + H.T), g, c


def weighted_objective(problem: IdentificationProblem, weight: Weight, theta: np.ndarray, chunk: int = 4096) -> float:
    """Σ r_iᵀ C_i⁻¹ r_i from the residuals (no cancellation, unlike θᵀHθ − 2gᵀθ + c)."""
    f = 0.0
    for block, rows, _ in sample_blocks(problem, chunk):
        Z, z = _whitened(problem, block, weight, rows, "the weight")
        e = Z @ theta - z
        f += float(np.sum(e * e))
    return f


def fit_weighted_newton(
    problem: IdentificationProblem,
    weight: Weight,
    *,
    constrained: bool = True,
    tol: float = 1e-9,
    max_iter: int = 100,
    chunk: int = 4096,
    method: str = "dual_metric",
    verbose: bool = False,
    warm_start_samples: int | None = None,  # accepted for option compatibility; unused (no pass per iteration)
    what: str = "the weight's covariance",
    whiten=None,
    objective_pass: bool = True,
) -> IdentificationResult:
    """argmin Σ r_iᵀ C_i⁻¹ r_i under the constraints (module doc); when the cheap start fails, from the weighted
    LS's central point or a phase I on the same (closed) feasible set (``newton.start.constant_metric_start``).
    whiten: as in ``_whitened``; objective_pass=False skips the pass for the result's objective (NaN: the
    caller computes it, e.g. the bounded fixed point in its own pass)."""
    from dualid.estimators.newton.fit import check_bounds

    t0 = time.perf_counter()
    check_bounds(problem, constrained)
    cons = feasible_set(problem.parameters, constrained)
    H, g, c, H_e, g_e = weighted_statistics(problem, weight, chunk, what, energy=True, whiten=whiten)
    full, (cons, projected) = cons, close(cons, H, c)  # parameters f cannot see that only loosen a block: newton.closure
    theta_f = _solve_psd(H, g, rtol=1e-10)  # the unconstrained weighted LS (min-norm): the frozen-metric LS
    f_min = max(c - 2.0 * float(g @ theta_f) + float(theta_f @ H @ theta_f), 0.0)

    def f_of(th):
        e = th - theta_f
        return float(e @ H @ e) + f_min

    def objective(th, order):
        if not order:
            return _Derivatives(f_of(th))
        return _Derivatives(f_of(th), 2.0 * (H @ th - g), 2.0 * H)

    start = None
    theta_c = _central_point(_solve_psd(H_e, g_e, rtol=1e-10), cons)
    if cons.margin(theta_c) > 0:  # as newton.start.starting_point with the energy seed; every θ is in the domain
        d = theta_f - theta_c
        beta = min(1.0, 0.9 * cons.max_step(theta_c, d))
        line = theta_c + beta * d if beta > 1e-3 else theta_c
        lifted = _central_point(theta_f, cons)
        f_lifted = f_of(lifted) if cons.margin(lifted) > 0 else np.inf
        label = "energy→frozen-metric→central"
        start, theta0 = ((f"{label}→lifted", lifted) if f_lifted < f_of(line) else (label, line))
    if start is None:  # the same closed problem from the weighted LS's central point or phase I (not a fit without
        # the closure: newton.closure)
        theta0, start = constant_metric_start(problem, cons, theta_f)
    theta, _, _, info = _interior_point(problem, cons, theta0, None, None, tol, max_iter, chunk, verbose,
                                        objective=objective, f_scale=c)
    info.pop("objective")
    info.update(start=start, statistics="one pass (H = Σ YᵀC⁻¹Y)")
    theta, completed = complete(theta, full, projected, problem.parameters.names)
    info.update(completed)
    f = weighted_objective(problem, weight, theta, chunk) if objective_pass else float("nan")
    return IdentificationResult(method, theta, problem.parameters, f, "optimal", "newton", time.perf_counter() - t0,
                                info["iterations"], constrained, info)

