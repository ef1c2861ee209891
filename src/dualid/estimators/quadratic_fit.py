"""The quadratic fit engine of every least-squares estimator: one weighted problem, solved.

``fit_quadratic``: min θᵀHθ − 2gᵀθ + c (+ γ R(θ)) from the sufficient statistics, by dualid's interior point
(solver "newton", ``estimators.quadratic_newton``) or by cvxpy (solver "cvxpy", the reference: Clarabel or SCS).
``fit_weighted``: argmin Σ r_iᵀ C_i⁻¹ r_i for a per-sample or constant covariance C_i, by dualid's Newton method or by
whitening and ``fit_quadratic``. ``closed_fit``: WLS's constant-weight fit, by Newton on the closed feasible set
where its infimum is not attained (``newton.closure``), as ``dm``'s pilot.
What the caller asked for runs; there is no fallback to the other solver: a failure is a SolverError.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from dualid.errors import MetricError, SolverError
from dualid.estimators.base import (
    captured_warnings,
    check_identifiable,
    check_solver,
    cvxpy_solver,
    parameter_scale,
    solve_cvxpy,
)
from dualid.estimators.quadratic_chart import signal_scale
from dualid.estimators.quadratic_newton import fit_quadratic_newton
from dualid.estimators.result import IdentificationResult
from dualid.estimators.statistics import Statistics, statistics
from dualid.linalg import gram_eigh, gram_rank
from dualid.model.consistency import cvxpy_constraints, prior_blocks, pullback_metric, regularizer_value
from dualid.problem import IdentificationProblem


def fit_quadratic(
    problem: IdentificationProblem,
    stats: Statistics,
    *,
    method: str,
    constrained: bool,
    solver: str,
    solver_options: dict | None,
    allow_unidentifiable: bool,
    regularizer: tuple[str, np.ndarray, float] | None = None,
    info: dict | None = None,
) -> IdentificationResult:
    """min θᵀHθ − 2gᵀθ + c (+ γ R(θ)) under the problem's constraints, by ``solver`` ("newton" | "cvxpy")."""
    check_solver(solver, f"{method} fit")
    info = dict(info or {})
    rank = gram_rank(stats.H)
    info["rank"] = rank
    if regularizer is None and not allow_unidentifiable:
        check_identifiable(problem, rank=rank, what=f"{method} weighted regressor")
    if not constrained and regularizer is None:
        t0 = time.perf_counter()
        theta = _least_squares(problem, stats, constrained)
        return IdentificationResult(
            method, theta, problem.parameters, stats.objective(problem, theta), "optimal", "lstsq",
            time.perf_counter() - t0, None, False, info,
        )
    exact, loose = (None, {})
    if regularizer is None and solver == "newton":
        exact, loose = exact_fit(problem, stats, constrained, method, info)
    if exact is not None:
        return exact
    if solver == "newton":
        t0 = time.perf_counter()
        theta_hat, ipm = fit_quadratic_newton(stats.H, stats.g, stats.c, problem.parameters, constrained=constrained,
                                              regularizer=regularizer, **{**loose, **dict(solver_options or ())})
        info.update({k: v for k, v in ipm.items() if k in ("relative_gap", "start", "newton_retry")
                     or k.startswith("projected_")})
        status, used, iterations, solve_time = "optimal", "newton", ipm["iterations"], time.perf_counter() - t0
    else:
        theta_hat, status, used, iterations, solve_time = _fit_cvxpy(
            problem, stats, method, constrained, solver_options, regularizer, info)
    value = stats.objective(problem, theta_hat)
    if regularizer is not None:
        kind, theta0, gamma = regularizer
        info["data_objective"] = value
        value += gamma * regularizer_value(kind, problem.parameters, theta_hat, theta0)
    return IdentificationResult(
        method, theta_hat, problem.parameters, value, status, used, solve_time, iterations, constrained, info,
    )


ROUNDING = 1e-12  # a least-squares f(θ) ≤ this × f(0) (exact data) is at the rounding floor: f ≥ 0


def _least_squares(problem: IdentificationProblem, stats: Statistics, constrained: bool) -> np.ndarray:
    """The unconstrained minimiser of minimum norm in the solver's variables, θ = s ⊙ φ."""
    s = _scale(problem, stats, constrained, None)
    return s * np.linalg.lstsq(s[:, None] * stats.H * s[None, :], s * stats.g, rcond=None)[0]


EXACT_TOL = 1e-3  # Newton's relative tolerance on exact data: its gap is relative to max(f, 1e-12·f(0)), so 1e-15·f(0)


def exact_fit(problem: IdentificationProblem, stats: Statistics, constrained: bool, method: str,
              info: dict) -> tuple[IdentificationResult | None, dict]:
    """Exact data (no prior; the unconstrained least-squares f at the rounding floor, ≤ ROUNDING · f(0)): an interior
    point has no relative test left there (f ~ 1e-26), and its line search fails on such fits (energy, and WLS whose
    weights Σ̂⁻¹ are ~1e23 on the stress corpus's exact RR chain). (result, newton options): the unconstrained θ when
    it is consistent (f ≥ 0, so optimal to that accuracy without an iteration), else None and the tolerance EXACT_TOL,
    whose gap is ≤ 1e-15·f(0); not exact data: (None, {})."""
    from dualid.model.consistency import feasible_set

    t0 = time.perf_counter()
    theta = _least_squares(problem, stats, constrained)
    f = stats.objective(problem, theta)
    if not f <= ROUNDING * max(float(stats.c), 0.0):
        return None, {}
    note = f"f at the rounding floor ({f / max(float(stats.c), 1e-300):.1e} of f(0))"
    cons = feasible_set(problem.parameters, constrained)
    if not cons.empty and not cons.margin(theta) >= 0:
        info["exact_data"] = f"{note} at an inconsistent least-squares θ: newton to tol {EXACT_TOL:g}"
        return None, {"tol": EXACT_TOL}
    info["exact_data"] = f"{note} at the consistent least-squares θ: optimal without iterations"
    return IdentificationResult(method, theta, problem.parameters, f, "optimal", "newton", time.perf_counter() - t0,
                                0, constrained, info), {}


def _scale(problem: IdentificationProblem, stats: Statistics, constrained: bool, regularizer) -> np.ndarray:
    """θ = s ⊙ φ: the solver's variables."""
    if stats.W is None and not stats.energy:  # H = Σ YᵀY: its diagonal holds the squared column norms (no pass)
        s = np.sqrt(np.clip(np.diag(stats.H), 0.0, None))
        s[s > 0] = 1.0 / s[s > 0]
        s[s == 0] = 1.0
        return s
    if constrained or regularizer is not None:  # weighted or energy conic fit: the chart of its own statistics,
        # invariant to units and noise level (estimators.quadratic_chart; the column norms of Y are neither)
        return signal_scale(stats.H, stats.c, problem.parameters, regularizer)
    return parameter_scale(problem)


def _fit_cvxpy(problem, stats, method, constrained, solver_options, regularizer, info):
    """(θ, status, solver, iterations, time) by cvxpy in scaled variables; cvxpy's warnings go into info."""
    import cvxpy as cp

    s = _scale(problem, stats, constrained, regularizer)
    Hs = s[:, None] * stats.H * s[None, :]
    gs = s * stats.g
    w, U, keep = gram_eigh(Hs)
    R = np.sqrt(w[keep])[:, None] * U[:, keep].T
    b = (U[:, keep].T @ gs) / np.sqrt(w[keep])
    # f(θ) = ‖Rφ − b‖² + f_min with f_min the unconstrained minimum; normalise by f_min so the
    # solver's tolerances are relative to the attainable fit even when the data fit exactly
    f_min = max(stats.c - float(b @ b), 0.0)
    gamma = regularizer[2] if regularizer is not None else 0.0  # R is O(1) per block near θ₀
    norm = max(f_min, gamma, 1e-10 * stats.c, 1e-300)
    phi = cp.Variable(problem.p)
    theta = cp.multiply(s, phi)
    if regularizer is None:
        objective = cp.norm(R @ phi - b) / np.sqrt(norm)  # same minimiser, better conditioned
    else:
        objective = cp.sum_squares(R @ phi - b) / norm + (gamma / norm) * _cvxpy_prior(theta, problem, regularizer)
    constraints = cvxpy_constraints(theta, problem.parameters) if constrained else []
    name, options = cvxpy_solver(solver_options)
    with captured_warnings() as notes:  # cvxpy's warnings go into the result, not the terminal
        solved = solve_cvxpy(cp.Problem(cp.Minimize(objective), constraints), phi, name, options,
                             what=f"{method} fit")
    if notes:
        info["solver_warnings"] = " | ".join(notes)
    return s * solved.value, solved.status, solved.solver, solved.iterations, solved.solve_time


def _cvxpy_prior(theta, problem: IdentificationProblem, regularizer):
    """R(θ) of the prior as a cvxpy expression."""
    import cvxpy as cp

    kind, theta0, _ = regularizer
    reg = 0
    for idx, V, C0 in prior_blocks(kind, problem.parameters, theta0):
        th = theta[idx]
        k, m, _ = V.shape
        if kind == "logdet":
            # whitened block L⁻¹ C L⁻ᵀ with C0 = L Lᵀ (the prior's own chart, I at θ₀): the cone sees O(1)
            # entries even for an ill-conditioned C0, and −log det C + tr(C0⁻¹C) changes only by a constant
            Li = np.linalg.inv(np.linalg.cholesky(0.5 * (C0 + C0.T)))
            VS = np.einsum("ab,kbc,dc->kad", Li, V, Li)
            C = cp.reshape(VS.reshape(k, m * m).T @ th, (m, m), order="C")
            reg = reg - cp.log_det(0.5 * (C + C.T)) + cp.trace(C)
        else:
            G = pullback_metric(V, C0)
            # G = F Fᵀ exactly (eigen-factor): a ridge added for a Cholesky factor (1e-12·tr G) changes the
            # objective by ~1e-4 relative on thin links, where tr G is dominated by a near-null direction of C0
            w, U = np.linalg.eigh(0.5 * (G + G.T))
            F = U * np.sqrt(np.maximum(w, 0.0))
            reg = reg + cp.sum_squares(F.T @ (th - theta0[idx]))
    return reg


def closed_fit(problem: IdentificationProblem, stats: Statistics, S: np.ndarray, method: str, est,
               info: dict | None = None) -> IdentificationResult:
    """The weighted fit argmin Σ r_iᵀ S⁻¹ r_i (stats: its statistics, W = S⁻¹; est: the estimator, for constrained,
    solver, solver_options, allow_unidentifiable). Solver "newton": ``fit_weighted`` by dualid's Newton method, on
    the closed feasible set where the infimum is not attained (a constrained fit in which the closure projects a
    parameter out: an unseen mass whose growth only loosens its block, ``newton.closure``), the unseen parameter
    completed and flagged as not determined by the data; it is ``dm``'s WLS pilot's fit, so the same data and weight
    give both the same θ, bit for bit. Solver "cvxpy": ``fit_quadratic`` on the original set, where such a fit stops
    along that ray where rounding places it (on the statistical benchmark's sensor-error arms WLS's held-out torque
    error moved by up to 2e-3 relative between that stopping point and the infimum)."""
    info = dict(info or {})
    if est.solver != "newton" or not est.constrained:
        return fit_quadratic(problem, stats, method=method, constrained=est.constrained, solver=est.solver,
                             solver_options=est.solver_options, allow_unidentifiable=est.allow_unidentifiable,
                             info=info)
    rank = gram_rank(stats.H)
    if not est.allow_unidentifiable:  # from the statistics at hand (fit_weighted's check would take a pass)
        check_identifiable(problem, rank=rank, what=f"{method} weighted regressor")
    info["rank"] = rank
    exact, loose = exact_fit(problem, stats, True, method, info)
    if exact is not None:
        return exact
    common = {"constrained": True, "solver": "newton", "solver_options": {**loose, **dict(est.solver_options or ())},
              "allow_unidentifiable": True}
    return fit_weighted(problem, np.asarray(S, dtype=float)[None], method, common, info)


def fit_weighted(sensor: IdentificationProblem, C, method: str, common: dict, info: dict,
                 what: str = "the weight's covariance") -> IdentificationResult:
    """argmin Σ r_iᵀ C_i⁻¹ r_i (C (N, n, n) or (1, n, n), ≻ 0, or a function rows → C_i of a block of
    samples, so no N-sized array is needed) under the constraints.

    solver "newton": the dual-metric interior-point method of ``estimators.newton`` on the problem
    with the constant metric M_i = C_i (its objective is then exactly this one), run on the weighted
    sufficient statistics (``newton.weighted``); it converges to 1e-9 relative, also where the data
    determine θ only up to a null space. Solver "cvxpy": by whitening, C_i = L_i L_iᵀ, the per-sample chart
    B_i = L_i⁻ᵀ (r̃_i = L_i⁻¹ r_i), then OLS in ``fit_quadratic``.
    """
    weight = C if callable(C) else (lambda block, rows, C=np.asarray(C): C if C.shape[0] == 1 else C[rows])
    failure = None
    if common["solver"] == "newton":
        from dualid.estimators.newton.weighted import fit_weighted_newton

        if not common["allow_unidentifiable"]:
            check_identifiable(sensor, what=f"{method} regressor")
        try:  # from the weighted statistics (two passes over the data; phase I on the closed set if the cheap
            # start fails: no fit of the materialised metric without the closure, newton.closure)
            result = fit_weighted_newton(sensor, weight, constrained=common["constrained"], method=method,
                                         what=f"{method}: {what}", **common["solver_options"])
            return dataclasses.replace(result, info={**result.info, **info})
        except np.linalg.LinAlgError as exc:
            failure = exc  # the message below, or a SolverError where C is positive definite
    if not isinstance(sensor, IdentificationProblem):  # streamed: whitening needs every sample at once
        sensor = sensor.materialise()
    C = np.broadcast_to(weight(sensor, slice(None)), (sensor.N, sensor.n, sensor.n))
    try:
        L = np.linalg.cholesky(0.5 * (C + np.swapaxes(C, 1, 2)))
    except np.linalg.LinAlgError as exc:
        lam = np.linalg.eigvalsh(C)[:, 0]
        raise MetricError(
            f"{method}: {what} must be positive definite at every sample, but it is not at "
            f"{int(np.sum(~(lam > 0)))} of {sensor.N} samples (smallest eigenvalue {lam.min():.3g}); give a "
            "positive-definite Σ or a pilot with a positive-definite metric"
        ) from exc
    if failure is not None:
        raise SolverError(f"{method}: dualid's interior point failed: {failure}", status="numerical_error") from failure
    white = sensor.in_coordinates(np.swapaxes(np.linalg.inv(L), 1, 2))
    return fit_quadratic(
        white, statistics(white), method=method, constrained=common["constrained"], solver=common["solver"],
        solver_options=common["solver_options"], allow_unidentifiable=common["allow_unidentifiable"], info=info,
    )
