"""Dual-metric least squares: min_θ Σ r_iᵀ M_i(θ)⁻¹ r_i, invariant to coordinates, units and scaling.

Reference formulation (``solver="cvxpy"``): with slacks s_i, minimise Σ s_i subject to

    [[M_i(θ), r_i], [r_iᵀ, s_i]] ⪰ 0     (Schur complement, one (n+1)×(n+1) LMI per sample)

and the physical-consistency constraints. All N blocks are one batched PSD constraint.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from dualid.errors import MetricError, SolverError, SolverOptionError
from dualid.estimators.base import (
    SOLVER_NAMES,
    captured_warnings,
    check_solver,
    freeze_options,
    is_problem_property,
    parameter_scale,
    solve_cvxpy,
)
from dualid.estimators.least_squares import wls_reference
from dualid.estimators.newton import feasible_set, fit_dual_metric_newton, starting_point
from dualid.estimators.newton.start import frozen_metric_ls
from dualid.estimators.result import IdentificationResult
from dualid.identifiability import check_identifiable
from dualid.metric_guard import (
    DEFAULT_BOUND,
    check_guard_options,
    given_reference,
    guard_sample,
    reference_guard,
)
from dualid.model.consistency import cvxpy_constraints
from dualid.problem import IdentificationProblem


def schur_psd(B0: np.ndarray, B: np.ndarray, Y: np.ndarray, tau: np.ndarray, s_theta: np.ndarray, s_slack: float):
    """(φ, σ, one batched PSD constraint) [[A_i(θ), r_i], [r_iᵀ, s_i]] ⪰ 0, i.e. s_i ≥ r_iᵀ A_i⁻¹ r_i, for every sample:
    A_i = B0_i + Σ_k θ_k B_ik (B0 (N, n, n), B (N, p, n, n)), r_i = Y_i θ − τ_i, θ = s_θ ⊙ φ, s_i = s_slack σ_i; stored
    sparse (row-major blocks). The SDP of ``dm-paper`` (A = M) and of each step of ``dm``'s conic reference."""
    import cvxpy as cp
    import scipy.sparse as sp

    N, n, p = Y.shape
    m = n + 1
    base = (np.arange(N) * m * m)[:, None, None]
    ij = np.arange(n)[:, None] * m + np.arange(n)[None, :]  # (n, n) positions of A in a block
    rows_M = (base + ij[None]).reshape(N, n * n)  # (N, n²)
    # A part: entry (i, a, b) depends on φ_k with coefficient B[i, k, a, b] s_k
    coef = np.transpose(B, (0, 2, 3, 1)).reshape(N, n * n, p) * s_theta  # (N, n², p)
    nz = coef != 0
    r_idx, e_idx, k_idx = np.nonzero(nz)
    rows = [rows_M[r_idx, e_idx]]
    cols = [k_idx]
    vals = [coef[nz]]
    # r part: entries (i, a, n) and (i, n, a) are Y_i[a] θ − τ_i[a]
    Ys = Y * s_theta  # (N, n, p)
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
    b[:, :n, :n] = B0
    b[:, :n, n] = -tau
    b[:, n, :n] = -tau
    phi, sigma = cp.Variable(p), cp.Variable(N)
    blocks = cp.reshape(A_theta @ phi + A_s @ sigma + b.reshape(-1), (N, m, m), order="C")
    return phi, sigma, cp.constraints.PSD(blocks)


def reference_theta(problem: IdentificationProblem) -> np.ndarray:
    """Unconstrained least-squares θ in scaled variables: only used to pick numerical scalings."""
    s = parameter_scale(problem)
    A = problem.Y.reshape(-1, problem.p) * s
    return s * np.linalg.lstsq(A, problem.tau.reshape(-1), rcond=None)[0]


def internal_chart(problem: IdentificationProblem) -> np.ndarray:
    """B_i (N, n, n) diagonal, such that B_iᵀ M_i(θ_ref) B_i has unit diagonal: the objective is the same in every
    chart (r̃ᵀM̃⁻¹r̃ = rᵀM⁻¹r), and this one keeps the LMI entries O(1). The median diagonal where M_i(θ_ref) has a
    non-positive diagonal entry."""
    M = problem.metric.evaluate(reference_theta(problem))
    d = np.diagonal(M, axis1=1, axis2=2).copy()  # (N, n)
    med = np.median(np.abs(d), axis=0)
    med[~(med > 0)] = 1.0
    bad = ~(d > 1e-12 * med)
    d[bad] = np.broadcast_to(med, d.shape)[bad]
    B = np.zeros_like(M)
    idx = np.arange(problem.n)
    B[:, idx, idx] = 1.0 / np.sqrt(d)
    return B


def _slack_scale(problem: IdentificationProblem) -> float:
    """Typical size of s_i ≈ τ_iᵀ M_i⁻¹ τ_i in the internal chart (M_i has unit diagonal there)."""
    t_scale = float(np.mean(np.sum(problem.tau**2, axis=1)))
    return t_scale if np.isfinite(t_scale) and t_scale > 0 else 1.0


def whitening_chart(problem: IdentificationProblem, chunk: int = 4096) -> tuple[np.ndarray, float, str]:
    """(B (N, n, n), slack scale, description): B_i = L_i⁻ᵀ with M_i(θ_s) = L_i L_iᵀ, so M̃_i(θ_s) = I.

    θ_s is the Newton solver's chart-invariant start, so the whitened problem is the same in every chart up to a
    rotation per sample, which the PSD cone does not see. The slack scale: the frozen-metric least-squares objective
    at θ_s per sample (a chart-invariant estimate of f*/N), floored at 1e-12 of the signal size τ̃ᵀτ̃.
    """
    cons = feasible_set(problem.parameters, True)
    theta_s, _ = starting_point(problem, cons, chunk)
    B = np.empty((problem.N, problem.n, problem.n))
    for start in range(0, problem.N, chunk):
        rows = slice(start, start + chunk)
        L = np.linalg.cholesky(problem.metric.evaluate(theta_s, rows))
        B[rows] = np.swapaxes(np.linalg.inv(L), 1, 2)  # L⁻ᵀ
    whitened = problem.in_coordinates(B, problem.coordinates)
    theta_f = frozen_metric_ls(problem, theta_s, chunk)
    signal = float(np.mean(np.sum(whitened.tau**2, axis=1)))
    residual = np.nan
    if theta_f is not None:
        r = whitened.residual(theta_f)
        residual = float(np.mean(np.sum(r * r, axis=1)))
    scale = max(residual if np.isfinite(residual) else signal, 1e-12 * signal, 1e-300)
    return B, scale, "whitened at the Newton start"


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

    original = problem
    try:
        B, s_slack, chart = whitening_chart(problem)
    except (MetricError, SolverError, np.linalg.LinAlgError) as exc:  # no interior start: the diagonal chart
        problem = problem.in_coordinates(internal_chart(problem), problem.coordinates)
        s_slack, chart = _slack_scale(problem), f"diagonal (whitening failed: {exc})"
    else:
        problem = problem.in_coordinates(B, problem.coordinates)
    N = problem.N
    s_theta = parameter_scale(problem)
    phi, sigma, psd = schur_psd(*problem.metric.basis(), problem.Y, problem.tau, s_theta, s_slack)
    constraints = [psd]
    if constrained:
        constraints += cvxpy_constraints(cp.multiply(s_theta, phi), problem.parameters)
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
    objective = original.dual_metric_objective(theta)
    if not np.isfinite(objective):
        lam = np.linalg.eigvalsh(original.metric.evaluate(theta))[:, 0]
        raise MetricError(
            f"dual-metric SDP: M_i(θ̂) is not positive definite at {int(np.sum(lam <= 0))} of {N} samples "
            f"(smallest eigenvalue {lam.min():.3g}); the data do not keep the metric away from singular"
        )
    return IdentificationResult(
        method, theta, problem.parameters, objective, solved.status, f"sdp/{solver}",
        solved.solve_time, solved.iterations, constrained,
        {"sdp_objective": float(np.sum(s_slack * np.asarray(sigma.value))), "sdp_chart": chart, "slack_scale": s_slack},
    )


NEWTON_OPTIONS = ("tol", "max_iter", "chunk", "warm_start_samples", "verbose")
SDP_FALLBACK_MAX_N = 20_000  # an SDP fallback beyond this would take minutes and GBs (one LMI per sample)


@dataclass(frozen=True)
class DualMetric:
    """Dual-metric weighted least squares, Σ r_iᵀ M_i(θ)⁻¹ r_i.

    solver: "newton" (default: the interior-point method of dualid.estimators.newton, O(N·n·p) memory) or "cvxpy"
    (the Schur-complement SDP with ``cvxpy_solver``, "CLARABEL" or "SCS": the reference, one LMI per sample, slow
    for large N); both solve the same convex problem. tol, max_iter: the first solver's (None: its defaults).
    fallback: solvers tried in order when the one before fails (SolverError) or returns only
    ``optimal_inaccurate``, recorded in ``info["solver_chain"]``; ``status`` is the producing solver's. An SDP
    fallback is skipped (and recorded) above SDP_FALLBACK_MAX_N samples. solver_options: for the first solver only
    (Newton: NEWTON_OPTIONS; the SDP: cvxpy/solver options), checked in the constructor (SolverOptionError).
    """

    constrained: bool = True
    solver: str = "newton"
    cvxpy_solver: str = "CLARABEL"  # the SDP's conic solver: "CLARABEL" or "SCS"
    solver_options: Mapping[str, Any] | None = None  # stored as sorted (key, value) pairs (hashable)
    allow_unidentifiable: bool = False
    tol: float | None = None
    max_iter: int | None = None
    fallback: tuple[str, ...] = ("cvxpy",)
    # metric guard in every result (dualid.metric_guard): against this θ_ref, else against a WLS fit
    guard_reference: tuple | None = field(default=None, kw_only=True)
    guard_bound: float = field(default=DEFAULT_BOUND, kw_only=True)
    name = "dual_metric"

    def __post_init__(self) -> None:
        check_solver(self.solver, self.cvxpy_solver, "DualMetric")
        fallback = (self.fallback,) if isinstance(self.fallback, str) else self.fallback
        try:
            fallback = tuple(fallback or ())
        except TypeError:
            raise SolverOptionError(f"fallback: expected a tuple of solver names, got {self.fallback!r}") from None
        bad = [f for f in fallback if f not in SOLVER_NAMES]
        if bad:
            raise SolverOptionError(f"fallback: expected solver names from {SOLVER_NAMES}, got {bad}")
        object.__setattr__(self, "fallback", fallback)
        if self.tol is not None and not (isinstance(self.tol, (int, float)) and 0 < self.tol < 1):
            raise SolverOptionError(f"tol: expected a relative tolerance in (0, 1), got {self.tol!r}")
        if self.max_iter is not None and not (isinstance(self.max_iter, (int, np.integer)) and self.max_iter >= 1):
            raise SolverOptionError(f"max_iter: expected a positive integer, got {self.max_iter!r}")
        options = self.solver_options or {}
        if not isinstance(options, (dict, tuple)):
            raise SolverOptionError(f"solver_options: expected a dict, got {type(options).__name__}")
        options = dict(options)
        object.__setattr__(self, "solver_options", freeze_options(options, "DualMetric: solver_options"))
        if self.solver == "newton":
            unknown = sorted(set(options) - set(NEWTON_OPTIONS))
            if unknown:
                raise SolverOptionError(f"solver_options: the Newton solver accepts {NEWTON_OPTIONS}, got {unknown}")
        ref, bound = check_guard_options(self.guard_reference, self.guard_bound, "DualMetric")
        object.__setattr__(self, "guard_reference", ref)
        object.__setattr__(self, "guard_bound", bound)
        both = [k for k in ("tol", "max_iter") if k in options and getattr(self, k) is not None]
        if both:
            raise SolverOptionError(f"{both[0]}: given both as an argument and in solver_options; give it once")

    def _chain(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys((self.solver, *self.fallback)))

    def _fit_with(self, problem: IdentificationProblem, solver: str, first: bool) -> IdentificationResult:
        options = dict(self.solver_options or {}) if first else {}
        if solver == "newton":
            if first and self.tol is not None:
                options["tol"] = self.tol
            if first and self.max_iter is not None:
                options["max_iter"] = self.max_iter
            return fit_dual_metric_newton(problem, constrained=self.constrained, method=self.name, **options)
        cvx_solver = self.cvxpy_solver
        if not isinstance(problem, IdentificationProblem):  # streamed: the SDP needs every sample at once
            problem = problem.materialise()
        if first and self.tol is not None:
            options.update({"tol_gap_abs": self.tol, "tol_gap_rel": self.tol, "tol_feas": self.tol}
                           if cvx_solver == "CLARABEL" else {"eps": self.tol})
        if first and self.max_iter is not None:
            options["max_iter" if cvx_solver == "CLARABEL" else "max_iters"] = self.max_iter
        return fit_dual_metric_sdp(problem, constrained=self.constrained, solver=cvx_solver,
                                   solver_options=options or None, method=self.name)

    def fit(self, problem: IdentificationProblem) -> IdentificationResult:
        """The fit (``_solve``), with the metric guard against guard_reference or a WLS fit in its info."""
        result = self._solve(problem)
        ref, label = given_reference(problem, self.guard_reference, "DualMetric"), "given guard_reference"
        solved_by = {}
        if ref is None:
            some, count = guard_sample(problem)  # the reference on the samples the guard looks at
            try:  # dualid's interior point on the statistics (cvxpy only if it fails: least_squares.wls_reference)
                ref, how = wls_reference(some, self.constrained)
                label = "wls fit" + ("" if count is None else f" on {count} strided samples")
                solved_by = {"metric_guard_solver": how}
            except SolverError as exc:  # recorded: the fit is then not certified
                label = f"the WLS reference failed: {str(exc)[:160]}"
        guard = reference_guard(problem, result.theta, ref, label, self.guard_bound)
        return replace(result, info={**result.info, **guard, **solved_by})

    def _solve(self, problem: IdentificationProblem) -> IdentificationResult:
        if not self.allow_unidentifiable:
            check_identifiable(problem)
        chain, failures, inaccurate = self._chain(), [], None
        for k, solver in enumerate(chain):
            if k and solver != "newton" and problem.N > SDP_FALLBACK_MAX_N:
                failures.append(f"{solver} skipped (N = {problem.N} > {SDP_FALLBACK_MAX_N}: too large for a fallback SDP)")
                continue
            with captured_warnings() as notes:  # e.g. cvxpy's "Solution may be inaccurate"
                try:
                    result = self._fit_with(problem, solver, first=k == 0)
                except SolverError as exc:
                    if is_problem_property(exc):
                        raise
                    failures.append(f"{solver} failed ({exc.status}): {exc}")
                    continue
            if result.status == "optimal_inaccurate" and k + 1 < len(chain):
                failures.append(f"{solver} returned optimal_inaccurate (objective {result.objective:.10g})")
                inaccurate = inaccurate or (result, notes)
                continue
            return _with_chain(result, failures, notes)
        if inaccurate is not None:  # no later solver did better: the inaccurate result, reported as such
            result, notes = inaccurate
            return _with_chain(result, failures, notes)
        raise SolverError(
            "dual-metric fit: every solver failed: " + "; then ".join(failures), status="all_solvers_failed"
        )


def _with_chain(result: IdentificationResult, failures: list[str], notes: list[str]) -> IdentificationResult:
    """result with info: solver_chain (what failed first, why, and which solver produced θ̂), fallback_used,
    solver_warnings (captured instead of printed)."""
    info = dict(result.info)
    info["solver_chain"] = " → ".join(failures + [f"{result.solver} {result.status}"])
    info["fallback_used"] = bool(failures)
    if failures:
        info["fallback_reason"] = failures[0]
    if notes:
        info["solver_warnings"] = " | ".join(notes)
    return replace(result, info=info)
