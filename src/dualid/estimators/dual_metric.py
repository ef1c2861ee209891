"""Dual-metric least squares: min_θ Σ r_iᵀ M_i(θ)⁻¹ r_i, invariant to coordinates, units and scaling.

Reference formulation (``solver="sdp"``): with slacks s_i, minimise Σ s_i subject to

    [[M_i(θ), r_i], [r_iᵀ, s_i]] ⪰ 0     (Schur complement, one (n+1)×(n+1) LMI per sample)

and the physical-consistency constraints. All N blocks are one batched PSD constraint.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from dualid.errors import MetricError, SolverError
from dualid.estimators.base import check_identifiable, consistency_constraints, parameter_scale, solve_cvxpy
from dualid.estimators.result import IdentificationResult
from dualid.problem.problem import IdentificationProblem


def _schur_blocks(problem: IdentificationProblem, s_theta: np.ndarray, s_slack: float):
    """Sparse A_θ, A_s, b with vec([[M_i, r_i], [r_iᵀ, s_i]]) = A_θ φ + A_s σ + b, θ = s_θ ⊙ φ, s = s_slack σ.

    Row-major vectorisation of N blocks of size m = n + 1.
    """
    N, n, p = problem.N, problem.n, problem.p
    m = n + 1
    M0, Mk = problem.metric.basis()  # (N, n, n), (N, p, n, n)
    base = (np.arange(N) * m * m)[:, None, None]
    ij = np.arange(n)[:, None] * m + np.arange(n)[None, :]  # (n, n) positions of M in a block
    rows_M = (base + ij[None]).reshape(N, n * n)  # (N, n²)
    # M part: entry (i, a, b) depends on φ_k with coefficient Mk[i, k, a, b] s_k
    coef = np.transpose(Mk, (0, 2, 3, 1)).reshape(N, n * n, p) * s_theta  # (N, n², p)
    nz = coef != 0
    r_idx, e_idx, k_idx = np.nonzero(nz)
    rows = [rows_M[r_idx, e_idx]]
    cols = [k_idx]
    vals = [coef[nz]]
    # r part: entries (i, a, n) and (i, n, a) are Y_i[a] θ − τ_i[a]
    Ys = problem.Y * s_theta  # (N, n, p)
    for pos in (np.arange(n) * m + n, n * m + np.arange(n)):
        rows_r = (base[:, :, 0] + pos[None]).reshape(N, n)
        nzr = Ys != 0
        i_idx, a_idx, k_idx = np.nonzero(nzr)
        rows.append(rows_r[i_idx, a_idx])
        cols.append(k_idx)
        vals.append(Ys[nzr])
    size = N * m * m
    A_theta = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(size, p))
    A_s = sp.csr_matrix((np.full(N, s_slack), (np.arange(N) * m * m + n * m + n, np.arange(N))), shape=(size, N))
    b = np.zeros((N, m, m))
    b[:, :n, :n] = M0
    b[:, :n, n] = -problem.tau
    b[:, n, :n] = -problem.tau
    return A_theta, A_s, b.reshape(-1)


def _slack_scale(problem: IdentificationProblem) -> float:
    """Typical size of s_i ≈ τ_iᵀ M_i⁻¹ τ_i, with M at the unconstrained least-squares θ (for scaling only)."""
    A = problem.Y.reshape(-1, problem.p)
    theta_ref = np.linalg.lstsq(A, problem.tau.reshape(-1), rcond=None)[0]
    M = problem.metric.evaluate(theta_ref)
    m_scale = float(np.median(np.trace(M, axis1=1, axis2=2))) / problem.n
    t_scale = float(np.mean(np.sum(problem.tau**2, axis=1)))
    if not (np.isfinite(m_scale) and m_scale > 0 and t_scale > 0):
        return 1.0
    return t_scale / m_scale


def fit_dual_metric_sdp(
    problem: IdentificationProblem,
    *,
    constrained: bool = True,
    solver: str = "CLARABEL",
    solver_options: dict | None = None,
    method: str = "dual_metric",
) -> IdentificationResult:
    """The Schur-complement SDP in cvxpy; the reference solution of the dual-metric problem."""
    import cvxpy as cp

    N, n, p = problem.N, problem.n, problem.p
    s_theta = parameter_scale(problem)
    s_slack = _slack_scale(problem)
    A_theta, A_s, b = _schur_blocks(problem, s_theta, s_slack)
    phi = cp.Variable(p)
    sigma = cp.Variable(N)
    blocks = cp.reshape(A_theta @ phi + A_s @ sigma + b, (N, n + 1, n + 1), order="C")
    constraints = [cp.constraints.PSD(blocks)]
    if constrained:
        constraints += consistency_constraints(cp.multiply(s_theta, phi), problem.parameters)
    cvx = cp.Problem(cp.Minimize(cp.sum(sigma) / N), constraints)
    try:
        solved = solve_cvxpy(cvx, phi, solver, solver_options, what="dual-metric SDP")
    except SolverError as exc:
        if exc.status is not None and "infeasible" in exc.status:
            raise MetricError(
                "dual-metric SDP: no θ makes every M_i(θ) positive semidefinite under the constraints "
                f"({solver} status {exc.status!r}); check the metric's constant part and the parameter bounds"
            ) from exc
        raise
    theta = s_theta * solved.value
    objective = problem.dual_metric_objective(theta)
    if not np.isfinite(objective):
        lam = np.linalg.eigvalsh(problem.metric.evaluate(theta))[:, 0]
        raise MetricError(
            f"dual-metric SDP: M_i(θ̂) is not positive definite at {int(np.sum(lam <= 0))} of {N} samples "
            f"(smallest eigenvalue {lam.min():.3g}); the data do not keep the metric away from singular"
        )
    return IdentificationResult(
        method, theta, problem.parameters, objective, solved.status, f"sdp/{solver}",
        solved.solve_time, solved.iterations, constrained,
        {"sdp_objective": float(np.sum(s_slack * np.asarray(sigma.value)))},
    )


@dataclass(frozen=True)
class DualMetric:
    """Dual-metric weighted least squares, Σ r_iᵀ M_i(θ)⁻¹ r_i.

    solver: "sdp" (the Schur-complement SDP through cvxpy; the reference) or "newton" (the
    structure-exploiting interior-point method, when available).
    """

    constrained: bool = True
    solver: str = "sdp"
    sdp_solver: str = "CLARABEL"  # cvxpy solver for solver="sdp": "CLARABEL" or "SCS"
    solver_options: dict | None = None
    allow_unidentifiable: bool = False
    name = "dual_metric"

    def fit(self, problem: IdentificationProblem) -> IdentificationResult:
        if not self.allow_unidentifiable:
            check_identifiable(problem)
        if self.solver == "sdp":
            return fit_dual_metric_sdp(
                problem, constrained=self.constrained, solver=self.sdp_solver, solver_options=self.solver_options,
                method=self.name,
            )
        raise ValueError(f"solver: expected 'sdp', got {self.solver!r}")
