"""A strictly feasible, chart-invariant starting point (and phase I when the cheap one fails); the interior point on a
given objective (``run_quadratic``) and the move of its end along the data's null space (``toward_start``)."""

from __future__ import annotations

import numpy as np

from dualid.errors import MetricError, SolverError
from dualid.estimators.base import parameter_scale, solve_cvxpy
from dualid.estimators.newton.interior_point import run_interior_point
from dualid.estimators.newton.objective import Derivatives, energy_statistics, objective_value, statistics
from dualid.linalg import gram_eigh, jacobi_scale, solve_psd
from dualid.model.consistency import LMI, FeasibleSet, central_point
from dualid.problem import IdentificationProblem, additive, sample_blocks


def _ols(problem: IdentificationProblem, chunk: int) -> np.ndarray:
    """Unconstrained least squares from the sufficient statistics (min-norm where rank deficient)."""
    stats = statistics(problem, chunk=chunk)
    return solve_psd(stats.H, stats.g, rtol=1e-10)


def _phase_one(problem, cons: FeasibleSet, theta_ref: np.ndarray, samples: np.ndarray) -> tuple[np.ndarray, float]:
    """max t s.t. C_b(θ) ⪰ t·c_b I, Gθ + h ≥ t·c, M_i(θ) ⪰ t·m_i I (i in samples), t ≤ 1.

    A small conic problem (size p plus the listed samples), solved by cvxpy only when the cheap
    start fails. Returns (θ, t); t ≤ 0 means no strictly feasible θ exists for these samples (``_infeasible``).
    """
    import cvxpy as cp

    s = parameter_scale(problem)
    phi = cp.Variable(problem.p)
    t = cp.Variable()
    theta = cp.multiply(s, phi)
    cons_list = [t <= 1, cp.norm(phi - theta_ref / s, "inf") <= 1e6]
    for c in cons.lmis:
        k, m, _ = c.V.shape
        scale = float(np.abs(c.V * s[c.idx, None, None]).sum(axis=0).max())
        C = c.C0 + cp.reshape(c.V.reshape(k, m * m).T @ theta[c.idx], (m, m), order="C")
        cons_list.append(0.5 * (C + C.T) >> t * scale * np.eye(m))
    if len(cons.h):
        scale = np.abs(cons.G * s).sum(axis=1)
        cons_list.append(cons.G @ theta + cons.h >= t * scale)
    if len(samples):
        M0, Mk = problem.metric.basis(samples)
        n = problem.n
        for i in range(len(samples)):
            scale = float(np.abs(Mk[i] * s[:, None, None]).sum(axis=0).max()) or 1.0
            Mi = M0[i] + cp.reshape(Mk[i].reshape(problem.p, n * n).T @ theta, (n, n), order="C")
            cons_list.append(0.5 * (Mi + Mi.T) >> t * scale * np.eye(n))
    cvx = cp.Problem(cp.Maximize(t), cons_list)
    try:
        solved = solve_cvxpy(cvx, phi, "CLARABEL", None, what="dual-metric phase I")
    except SolverError as exc:
        raise SolverError(f"dual-metric Newton: phase I failed ({exc}); the constraints may admit no strictly "
                          "feasible θ", status=exc.status) from exc
    return s * solved.value, float(t.value)


def _infeasible(t: float) -> SolverError:
    return SolverError("dual-metric Newton: the constraints (physical consistency and bounds) admit no strictly "
                       f"feasible θ (phase-I margin {t:.3g} ≤ 0)", status="infeasible")


def _not_pd_samples(problem, theta, chunk, limit=50) -> np.ndarray:
    """Indices of (up to limit of the worst) samples where M_i(θ) is not positive definite."""
    bad, worst = [], []
    for block, rows, start in sample_blocks(problem, chunk):
        lam = np.linalg.eigvalsh(block.metric.evaluate(theta, rows))[:, 0]
        scale = np.abs(lam).max() if lam.size else 1.0
        i = np.flatnonzero(lam <= 1e-12 * scale)
        bad.append(start + i)
        worst.append(lam[i])
    bad, worst = np.concatenate(bad), np.concatenate(worst)
    return bad[np.argsort(worst)[:limit]]


def _energy_ls(problem: IdentificationProblem, chunk: int) -> np.ndarray:
    """min-norm argmin Σ (v_iᵀ r_i)²: v_iᵀr_i is the same in every chart, so is this θ."""
    stats = energy_statistics(problem, chunk=chunk)
    return solve_psd(stats.H, stats.g, rtol=1e-10)


def frozen_metric_ls(problem: IdentificationProblem, theta_c: np.ndarray, chunk: int) -> np.ndarray | None:
    """min-norm argmin Σ r_iᵀ M_i(θ_c)⁻¹ r_i (the metric frozen at θ_c): chart-invariant; None if some
    M_i(θ_c) is not positive definite."""
    H, g, failed = _frozen_metric_sums(problem, theta_c, chunk)
    return None if failed else solve_psd(H, g, rtol=1e-10)


@additive
def _frozen_metric_sums(problem, theta_c: np.ndarray, chunk: int) -> tuple[np.ndarray, np.ndarray, int]:
    """(Σ Y_iᵀM_i(θ_c)⁻¹Y_i, Σ Y_iᵀM_i(θ_c)⁻¹τ_i, 1 if some M_i(θ_c) is not positive definite else 0)."""
    p = problem.p
    H, g = np.zeros((p, p)), np.zeros(p)
    for block, rows, _ in sample_blocks(problem, chunk):
        try:
            L = np.linalg.cholesky(block.metric.evaluate(theta_c, rows))
        except np.linalg.LinAlgError:
            return H, g, 1
        Z = np.linalg.solve(L, block.Y[rows])  # L⁻¹ Y_i (n, p)
        z = np.linalg.solve(L, block.tau[rows][..., None])[..., 0]
        H += np.einsum("nap,naq->pq", Z, Z)
        g += np.einsum("nap,na->p", Z, z)
    return H, g, 0


def toward(cons: FeasibleSet, theta_c, target, label: str, value, f_c: float | None = None) -> tuple[np.ndarray, str]:
    """(θ, label): θ_c + β (target − θ_c), β ≤ 0.9 of the way to the boundary, halved while value (f, +inf outside
    its domain; f_c its value at θ_c if known) is infinite there; or the target with its blocks' eigenvalues lifted (it
    keeps the target's well-determined directions, where the segment can stop far from it), whichever has smaller f."""
    d = target - theta_c
    beta = min(1.0, 0.9 * cons.max_step(theta_c, d))
    line, f_line = theta_c, f_c
    while beta > 1e-3:
        if np.isfinite(f_beta := value(theta_c + beta * d)):
            line, f_line = theta_c + beta * d, f_beta
            break
        beta *= 0.5
    lifted = central_point(target, cons)
    f_line = value(line) if f_line is None else f_line
    f_lifted = value(lifted) if cons.margin(lifted) > 0 else np.inf
    return (lifted, f"{label}→lifted") if f_lifted < f_line else (line, label)


def constant_metric_start(problem, cons: FeasibleSet, seed: np.ndarray) -> tuple[np.ndarray, str]:
    """A strictly feasible θ for a fit whose metric does not depend on θ (M_i = C_i ≻ 0, e.g. ``newton.weighted``),
    where only the constraints ``cons`` (possibly the closed set of ``model.closure``) decide: the seed's central
    point, else phase I over the constraints alone (no sample can leave the domain). SolverError (status
    infeasible) when they admit no strictly feasible θ."""
    theta_c = central_point(seed, cons)
    if cons.margin(theta_c) > 0:
        return theta_c, "weighted LS→central"
    theta, t = _phase_one(problem, cons, theta_c, np.zeros(0, dtype=int))
    if t <= 1e-9 or cons.margin(theta) <= 0:
        raise _infeasible(t)
    return theta, "phase-I"


def starting_point(problem, cons: FeasibleSet, chunk: int) -> tuple[np.ndarray, str]:
    """A strictly feasible θ with every M_i(θ) ≻ 0, computed from chart-invariant quantities only.

    The energy least-squares θ picks a central point θ_c (each block's eigenvalues lifted); the frozen-metric estimate
    argmin Σ rᵀM(θ_c)⁻¹r is then moved toward θ_c until it is strictly feasible. Both are the same in every chart and
    Newton steps are affine-invariant, so the iteration (and the point chosen on a non-unique optimal face) does not
    depend on coordinates, units or scaling. Falls back to the OLS seed (and phase I) only when that fails.
    """
    for seed_name, seed in (("energy", _energy_ls), ("ols", _ols)):
        theta_seed = seed(problem, chunk)
        theta_c = central_point(theta_seed, cons)
        f_c = objective_value(problem, theta_c, chunk) if cons.margin(theta_c) > 0 else np.inf
        if not np.isfinite(f_c):
            continue
        theta_f = frozen_metric_ls(problem, theta_c, chunk) if seed_name == "energy" else theta_seed
        target, label = (theta_f, f"{seed_name}→frozen-metric→central") if theta_f is not None else (theta_seed, f"{seed_name}→central")
        return toward(cons, theta_c, target, label, lambda th: objective_value(problem, th, chunk), f_c)
    theta_c = central_point(_ols(problem, chunk), cons)
    # phase I: a small conic problem over the constraints and the samples where M_i(θ_c) is not ≻ 0
    samples = np.zeros(0, dtype=int)
    if cons.margin(theta_c) > 0:
        samples = _not_pd_samples(problem, theta_c, chunk)
    for _ in range(20):
        theta_c, t = _phase_one(problem, cons, theta_c, samples)
        if t <= 1e-9:
            if len(samples):
                raise MetricError(
                    f"dual-metric Newton: no θ satisfying the constraints makes M_i(θ) positive definite at "
                    f"samples {samples[:10].tolist()} (phase-I margin {t:.3g} ≤ 0); check the metric's "
                    "constant part and the parameter bounds"
                )
            raise _infeasible(t)
        more = _not_pd_samples(problem, theta_c, chunk)
        if not len(more):
            return theta_c, "phase-I"
        samples = np.union1d(samples, more)
    raise MetricError("dual-metric Newton: phase I did not find θ with every M_i(θ) positive definite")


def toward_start(theta, start, H, cons, value):
    """Of the minimisers θ + M z (M: the null space of H = ½∇²f, f unchanged) the one nearest ``start`` (the fit's start;
    Jacobi-scaled chart; to 1e-6 of that distance², strictly inside): an interior point drifts along unseen directions,
    pushed by its barrier alone (DFKI WLS: Joint1.Iyy = Izz = 110 kg m² → 0.0098, the same predictions). ``value``: θ → f."""
    d = jacobi_scale(H)
    _, U, keep = gram_eigh(H / np.outer(d, d))
    M, z0 = U[:, ~keep] / d[:, None], U[:, ~keep].T @ (d * (start - theta))
    if not np.any(z0):
        return theta
    reduced = FeasibleSet(tuple(LMI(c.name, np.arange(M.shape[1]), np.stack([c.dC(m) for m in M.T]), c.C(theta))
                                for c in cons.lmis), cons.G @ M, cons.G @ theta + cons.h, cons.names)
    try:
        z, _ = run_quadratic(reduced, np.zeros(M.shape[1]), 1e-6, 100, lambda z, order: Derivatives(
            float((z - z0) @ (z - z0)), 2.0 * (z - z0), 2.0 * np.eye(len(z))), float(z0 @ z0))
    except SolverError:
        return theta
    moved, f = theta + M @ z, value(theta)
    return moved if cons.margin(moved) > 0 and value(moved) <= f + 1e-12 * max(abs(f), 1e-300) else theta


# The retry of a failed Levenberg-damped run (1e-12 crawls along directions of Jacobi-scaled curvature below it): exact
# Newton steps, the eigen pseudo-inverse where Cholesky fails; rounding-dominated, chart-dependent (docs/performance.md)
RETRY_LEVENBERG = 0.0


def run_quadratic(cons, theta, tol, max_iter, objective, f_scale, gap0=1.0):
    """run_interior_point on ``objective`` (θ, order) → Derivatives, an arithmetic failure a SolverError (for the caller's
    fallback or certificate); a failed run is retried once with RETRY_LEVENBERG (info["newton_levenberg"])."""
    failure = None
    for levenberg in (1e-12, RETRY_LEVENBERG):
        try:
            theta_out, _, _, info = run_interior_point(None, cons, theta, None, None, tol, max_iter, 0, False, gap0=gap0,
                                                    objective=objective, f_scale=f_scale, levenberg=levenberg)
            info["newton_levenberg"] = levenberg
            if failure is not None:
                info["newton_retry"] = f"Levenberg 1e-12 failed ({failure.status}); exact Newton steps"
            break
        except (ArithmeticError, np.linalg.LinAlgError) as exc:
            failure = SolverError(f"quadratic Newton: numerical failure: {type(exc).__name__}: {exc}",
                                  status="numerical_error")
            failure.__cause__ = exc
        except SolverError as exc:
            failure = exc
    else:
        raise failure
    info.pop("f_history", None)
    return theta_out, info
