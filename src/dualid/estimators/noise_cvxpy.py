"""``dm``'s conic reference (``NoiseModelDM(solver="cvxpy")``): its θ-solves by majorize–minimize, each step one
batched SDP, the reference dualid's interior point is checked against (tests/test_dm_cvxpy.py)."""

from __future__ import annotations

import numpy as np

from dualid.errors import MetricError, SolverError
from dualid.estimators.base import captured_warnings, solve_cvxpy
from dualid.estimators.dual_metric import schur_psd
from dualid.estimators.noise_model import noise_model_objective
from dualid.model.closure import ZERO_CURVATURE
from dualid.model.consistency import cvxpy_feasible_set, lifted_blocks
from dualid.problem import IdentificationProblem

LIFT = 1e-12  # θ's consistency blocks end at least this far (relative) inside (``lifted_blocks``)


def majorizer_blocks(problem, theta_k, sigma_tau, sigma_a) -> tuple[np.ndarray, np.ndarray]:
    """(A0 (N, n, n), A (N, p, n, n)) with A0_i + Σ_j θ_j A_ij = Σ_τ + L_k,i(θ), the majorizer's covariance at θ_k:
    L_k(θ) = M_k Σ_a M(θ) + M(θ) Σ_a M_k − M_k Σ_a M_k (M_k = M(θ_k), M affine in θ). As (M − M_k) Σ_a (M − M_k) ⪰ 0,
    M Σ_a M ⪰ L_k(θ), so C_i(θ) ⪰ Σ_τ + L_k,i(θ), with equality at θ_k."""
    M0, Mj = problem.metric.basis()
    Mk = problem.metric.evaluate(theta_k)
    K = Mk @ sigma_a  # M_k Σ_a
    KM = K @ M0
    A0 = sigma_tau + KM + np.swapaxes(KM, 1, 2) - K @ Mk
    KMj = K[:, None] @ Mj
    return 0.5 * (A0 + np.swapaxes(A0, 1, 2)), KMj + np.swapaxes(KMj, 2, 3)


def _majorizer_step(problem, cons, theta_k, f_k, sigma_tau, sigma_a, solver, options):
    """argmin g_k on ``cons``: min Σ t_i s.t. [[A_i(θ), r_i(θ)], [r_iᵀ, t_i]] ⪰ 0 (``dual_metric.schur_psd``, A_i ⪰ 0
    with it), each block whitened by C_i(θ_k) = L_i L_iᵀ (I at θ_k), θ and t on their scales. (θ, cvxpy status)."""
    import cvxpy as cp

    A0, Aj = majorizer_blocks(problem, theta_k, sigma_tau, sigma_a)
    Li = np.linalg.inv(np.linalg.cholesky(A0 + np.einsum("j,ijab->iab", theta_k, Aj)))
    N, n, p = problem.Y.shape
    B = np.einsum("iac,ijcd,ibd->iabj", Li, Aj, Li)
    B = np.moveaxis(0.5 * (B + np.swapaxes(B, 1, 2)), 3, 1)  # L_i⁻¹ A_ij L_i⁻ᵀ (N, p, n, n)
    B0 = Li @ A0 @ np.swapaxes(Li, 1, 2)
    Yw, tw = Li @ problem.Y, np.einsum("iab,ib->ia", Li, problem.tau)
    s = np.linalg.norm(Yw.reshape(N * n, p), axis=0)  # θ = s ⊙ φ: unit whitened regressor columns, but
    s = 1.0 / np.where(s**2 > ZERO_CURVATURE * np.sum(tw**2), s, 1.0)  # 1 where f cannot see θ_k (model.closure)
    slack = f_k / N  # t_i = slack · σ_i: σ is O(1) near θ_k
    phi, sigma, psd = schur_psd(0.5 * (B0 + np.swapaxes(B0, 1, 2)), B, Yw, tw, s, slack)
    constraints = [psd] + cvxpy_feasible_set(cp.multiply(s, phi), cons)
    with captured_warnings():  # "Solution may be inaccurate": the status says so, and f is checked by the caller
        solved = solve_cvxpy(cp.Problem(cp.Minimize(cp.sum(sigma) / N), constraints), phi, solver, options,
                             what="dm majorizer")
    return s * solved.value, solved.status


def solve_noise_model_cvxpy(problem, cons, theta0, sigma_tau, sigma_a, tol: float = 1e-9, max_iter: int = 300,
                            cvxpy_solver: str = "CLARABEL", solver_options: dict | None = None):
    """θ minimising f(θ) = Σ r_iᵀ (Σ_τ + M_i(θ) Σ_a M_i(θ))⁻¹ r_i on the FeasibleSet ``cons`` by majorize–minimize:
    step k minimises the jointly convex g_k ≥ f (``majorizer_blocks``; g_k(θ_k) = f(θ_k)) by cvxpy, so f never
    increases, and a fixed point is a KKT point of f on ``cons`` (g_k and f touch at θ_k, where A_i = C_i ≻ 0, so the
    majorizer's own domain A_i ⪰ 0 is inactive). Stops when f decreases by less than tol·f (or not at all: the conic
    solver's accuracy); SolverError after max_iter solves, as the interior point (``fit`` then restarts from the paper's
    optimum). (θ, info): iterations (conic solves), objective, history (f at the start and at every step, the last one
    rejected when it did not decrease f), status (why it stopped), cvxpy_status (per solve)."""
    if not isinstance(problem, IdentificationProblem):  # streamed: the conic problem needs every sample at once
        problem = problem.materialise()
    S, A = np.asarray(sigma_tau, dtype=float), np.asarray(sigma_a, dtype=float)
    theta = np.asarray(theta0, dtype=float)
    f = noise_model_objective(problem, theta, S, A)
    if not np.isfinite(f):
        raise MetricError("dm: the noise model's covariance is not positive definite at the start")
    history, statuses, status = [f], [], "converged: f = 0"
    for _ in range(max_iter if f > 0 else 0):
        step, cvx_status = _majorizer_step(problem, cons, theta, f, S, A, cvxpy_solver, solver_options)
        statuses.append(cvx_status)
        f_step = noise_model_objective(problem, step, S, A)
        history.append(f_step)
        if not f_step < f:  # no decrease left that the conic solver resolves: θ_k stays
            status = "converged: no decrease"
            break
        theta, decrease, f = step, f - f_step, f_step
        if decrease < tol * f:
            status = "converged: decrease < tol·f"
            break
    else:
        if f > 0:
            last = (history[-2] - f) / f if len(history) > 1 else np.nan
            raise SolverError(f"dm majorize–minimize: no convergence in {max_iter} conic solves (f {f:.10g}, last "
                              f"relative decrease {last:.3g}, tol {tol:g})", status="max_iterations")
    lifted = lifted_blocks(theta, cons, LIFT)
    if np.any(lifted != theta):
        theta, f = lifted, noise_model_objective(problem, lifted, S, A)
    return theta, {"iterations": len(statuses), "objective": f, "history": history, "status": status,
                   "cvxpy_status": statuses}


__all__ = ["majorizer_blocks", "solve_noise_model_cvxpy"]
