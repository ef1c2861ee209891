"""The quadratic fit engine of every least-squares estimator: one weighted problem, solved.

``fit_quadratic``: min θᵀHθ − 2gᵀθ + c (+ γ R(θ)) from the sufficient statistics, by dualid's interior point
(solver "newton", the default; the conic reference takes over when it fails), or by a cvxpy solver certified (or
polished) by that interior point, which also takes over when the solver fails (``quadratic_newton.polish``).
``fit_weighted``: argmin Σ r_iᵀ C_i⁻¹ r_i for a per-sample or constant covariance C_i, by dualid's Newton method or by
whitening and ``fit_quadratic``. ``closed_fit``: a constant-weight fit that goes to the closed feasible set where
its infimum is not attained (``model.closure``), as ``dm``'s pilot does.
The chart of the conic problem: ``signal_scale``.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from dualid.errors import SolverError
from dualid.estimators import quadratic_newton
from dualid.estimators.base import (
    captured_warnings,
    is_problem_property,
    parameter_scale,
    solve_cvxpy,
)
from dualid.estimators.newton.objective import Statistics, statistics
from dualid.estimators.newton.weighted import fit_weighted_newton, whitener
from dualid.estimators.result import IdentificationResult
from dualid.identifiability import check_identifiable
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
    closure: bool = False,  # Newton polish / fallback on the closed feasible set (model.closure; dm)
) -> IdentificationResult:
    """min θᵀHθ − 2gᵀθ + c (+ γ R(θ)) under the problem's constraints. solver: "newton" (dualid's interior point
    from its cold start; Clarabel when it fails) or a cvxpy solver ("CLARABEL", "SCS": in scaled variables θ = s ⊙ φ, then certified)."""
    info = {**(info or {}), "rank": gram_rank(stats.H)}
    if regularizer is None and not allow_unidentifiable:
        check_identifiable(problem, rank=info["rank"], what=f"{method} weighted regressor")
    if not constrained and regularizer is None:
        t0 = time.perf_counter()
        s = _chart(problem, stats, constrained, regularizer)
        phi = np.linalg.lstsq(s[:, None] * stats.H * s[None, :], s * stats.g, rcond=None)[0]  # minimum-norm minimiser
        theta = s * phi  # (in scaled variables)
        return IdentificationResult(
            method, theta, problem.parameters, stats.objective(problem, theta), "optimal", "lstsq",
            time.perf_counter() - t0, None, False, info,
        )
    failed = ""
    if solver == "newton":  # dualid's interior point, from its cold start (options: tol, max_iter) …
        t0 = time.perf_counter()
        try:
            theta_hat, ipm = quadratic_newton.fit_quadratic_newton(
                stats.H, stats.g, stats.c, problem.parameters, constrained=constrained, regularizer=regularizer,
                closure=closure, **dict(solver_options or {}))
            info.update(solver_chain="newton optimal", fallback_used=False, relative_gap=ipm["relative_gap"],
                        **{k: v for k, v in ipm.items() if k.startswith("projected_")})  # model.closure's completion
            status, used, iterations, solve_time = "optimal", "newton", ipm["iterations"], time.perf_counter() - t0
        except SolverError as exc:  # … and when it fails, the conic reference, recorded in the result
            failed, solver, solver_options = f"newton failed ({exc.status})", "CLARABEL", None
    if solver != "newton":
        s = _chart(problem, stats, constrained, regularizer)
        cvx, phi = _cvxpy_problem(problem, stats, s, constrained, regularizer)
        theta_hat, status, used, iterations, solve_time = _solve_with_fallback(
            cvx, phi, s, stats, problem, method, constrained, solver, solver_options, regularizer, info, closure
        )
        if failed:
            info.update(solver_chain=f"{failed} → {info['solver_chain']}", fallback_used=True, fallback_reason=failed)
    value = stats.objective(problem, theta_hat)
    if regularizer is not None:
        kind, theta0, gamma = regularizer
        info["data_objective"] = value
        value += gamma * regularizer_value(kind, problem.parameters, theta_hat, theta0)
    return IdentificationResult(
        method, theta_hat, problem.parameters, value, status, used, solve_time, iterations, constrained, info,
    )


def _chart(problem, stats: Statistics, constrained: bool, regularizer) -> np.ndarray:
    """s (p,) of the chart θ = s ⊙ φ the fit is solved in."""
    if stats.W is None and not stats.energy:  # H = Σ YᵀY: its diagonal holds the squared column norms (no pass)
        s = np.sqrt(np.clip(np.diag(stats.H), 0.0, None))
        s[s > 0] = 1.0 / s[s > 0]
        s[s == 0] = 1.0
        return s
    if constrained or regularizer is not None:  # weighted or energy conic fit: the chart of its own statistics,
        # invariant to units and noise level (``signal_scale``; the column norms of Y are neither)
        return signal_scale(stats.H, stats.c, problem.parameters, regularizer)
    return parameter_scale(problem)


def _cvxpy_problem(problem, stats: Statistics, s: np.ndarray, constrained: bool, regularizer):
    """(cvxpy problem, its variable φ) of the fit in the chart s."""
    import cvxpy as cp

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
        objective = cp.sum_squares(R @ phi - b) / norm + (gamma / norm) * _cvxpy_prior(problem, theta, regularizer)
    constraints = cvxpy_constraints(theta, problem.parameters) if constrained else []
    return cp.Problem(cp.Minimize(objective), constraints), phi


def _cvxpy_prior(problem, theta, regularizer):
    """R(θ) of the prior (kind, θ₀, γ) as a cvxpy expression."""
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


def _solve_with_fallback(cvx, phi, s, stats, problem, method, constrained, solver, solver_options, regularizer, info,
                         closure=False):
    """cvxpy first; when it fails or returns only optimal_inaccurate, dualid's own interior-point method
    (estimators.quadratic_newton). What happened is recorded in info (solver_chain, fallback_used,
    solver_warnings); an inaccurate cvxpy result is returned only, and labelled, if that fails too."""
    solved, failure, claim = None, None, None
    with captured_warnings() as notes:  # cvxpy's warnings go into the result, not the terminal
        try:
            solved = solve_cvxpy(cvx, phi, solver, solver_options, what=f"{method} fit")
        except SolverError as exc:
            if not is_problem_property(exc):
                failure = f"{solver} failed ({exc.status}): {exc}"
            elif "infeasible" in exc.status:  # checked: a badly scaled conic problem can be called infeasible
                claim, failure = exc, f"{solver} claimed {exc.status}"
            else:
                raise
    if notes:
        info["solver_warnings"] = " | ".join(notes)
    if solved is not None and solved.status == "optimal":  # certified (or polished) by dualid's interior point
        t0 = time.perf_counter()
        theta, label, polished, certified, checked = quadratic_newton.polish(s * solved.value, stats, problem.parameters,
                                                            constrained, regularizer, solver, closure=closure)
        info.update(checked, solver_chain=label, fallback_used=polished)
        if polished:
            info["fallback_reason"] = label
            return theta, "optimal", "newton", checked["certify_iterations"], time.perf_counter() - t0
        status = "optimal" if certified else "optimal_inaccurate"
        return theta, status, solved.solver, solved.iterations, solved.solve_time
    first = failure or f"{solver} returned {solved.status}"
    t0 = time.perf_counter()
    try:
        newton = {"constrained": constrained, "regularizer": regularizer, "closure": closure}
        try:  # cold start first (the same path whatever rounding cvxpy's end point has), then from that end point
            theta, ipm = quadratic_newton.fit_quadratic_newton(stats.H, stats.g, stats.c, problem.parameters, **newton)
        except SolverError:
            if solved is None:
                raise
            theta, ipm = quadratic_newton.fit_quadratic_newton(stats.H, stats.g, stats.c, problem.parameters,
                                                               start=s * solved.value, **newton)
    except SolverError as exc:
        if claim is not None and exc.status == "no_start":  # no strictly feasible θ either: the claim stands
            raise claim from exc
        if claim is not None:
            raise SolverError(f"{method} fit: {first}; dualid's interior-point method could not check it (it failed: "
                              f"{exc})", status="all_solvers_failed") from exc
        if solved is None:
            raise SolverError(f"{method} fit: {first}; then dualid's interior-point method failed: {exc}",
                              status="all_solvers_failed") from exc
        info.update(solver_chain=f"{first} → newton failed ({exc.status}) → {solver} {solved.status}",
                    fallback_used=False, fallback_reason=first)
        return s * solved.value, solved.status, solved.solver, solved.iterations, solved.solve_time
    info.update(solver_chain=f"{first} → newton optimal", fallback_used=True, fallback_reason=first,
                relative_gap=ipm["relative_gap"])
    info.update({k: v for k, v in ipm.items() if k.startswith("projected_")})  # model.closure's completion
    return theta, "optimal", "newton", ipm["iterations"], time.perf_counter() - t0


def closed_fit(problem: IdentificationProblem, stats: Statistics, S: np.ndarray, method: str, est,
               info: dict | None = None, null_step: bool = True) -> IdentificationResult:
    """The weighted fit argmin Σ r_iᵀ S⁻¹ r_i (stats: its statistics, W = S⁻¹; est: the estimator, for constrained,
    engine, solver_options, allow_unidentifiable) by ``fit_quadratic``, except where its infimum is not attained: a
    constrained fit in which the closure projects a parameter out (an unseen mass whose growth only loosens its block,
    ``model.closure``). There a cvxpy solver can only stop along that ray, where rounding places it, so the fit is
    ``fit_weighted`` by dualid's Newton method on the closed set, the unseen parameter completed and flagged as not
    determined by the data: the same data and weight give ``dm``'s pilot and WLS the same θ, bit for bit."""
    info = dict(info or {})
    if not (est.constrained and quadratic_newton.projects(stats, problem.parameters)):
        return fit_quadratic(problem, stats, method=method, constrained=est.constrained, solver=est.engine,
                             solver_options=est.solver_options, allow_unidentifiable=est.allow_unidentifiable,
                             info=info)
    info["solver_chain"] = "newton on the closed set (model.closure)" + (
        "" if est.engine == "newton" else f": the infimum is approached only as an unseen parameter grows, where "
        f"{est.engine} stops by rounding, so {est.engine} was not run")
    common = {"constrained": True, "solver": "newton", "solver_options": {},
              "allow_unidentifiable": est.allow_unidentifiable}
    return fit_weighted(problem, S, method, common, info, null_step=null_step)


def fit_weighted(sensor: IdentificationProblem, C, method: str, common: dict, info: dict,
                 what: str = "the weight's covariance", null_step: bool = True) -> IdentificationResult:
    """argmin Σ r_iᵀ C⁻¹ r_i, C (n, n) ≻ 0, under the constraints. Solver "newton": the interior point on the constant
    metric M_i = C from the weighted sufficient statistics (``newton.weighted``); a cvxpy solver: whitening,
    C = L Lᵀ, r̃_i = L⁻¹ r_i, then OLS in ``fit_quadratic``."""
    C = np.asarray(C, dtype=float)
    if common["solver"] == "newton":
        if not common["allow_unidentifiable"]:
            check_identifiable(sensor, what=f"{method} regressor")
        try:  # from the weighted statistics (two passes over the data; phase I on the closed set if the cheap
            # start fails: no fit of the materialised metric without the closure, model.closure)
            result = fit_weighted_newton(sensor, C, constrained=common["constrained"], method=method,
                                         what=f"{method}: {what}", null_step=null_step, **common["solver_options"])
            return dataclasses.replace(result, info={**result.info, **info})
        except SolverError as exc:  # the same problem by cvxpy (whitened); recorded in the result
            info = {**info, "solver_fallback": f"CLARABEL after newton failed: {str(exc)[:200]}"}
            common = {**common, "solver": "CLARABEL", "solver_options": {}}
    if not isinstance(sensor, IdentificationProblem):  # streamed: whitening needs every sample at once
        sensor = sensor.materialise()
    white = sensor.in_coordinates(whitener(sensor, C, f"{method}: {what}").T)
    return fit_quadratic(
        white, statistics(white), method=method, constrained=common["constrained"], solver=common["solver"],
        solver_options=common["solver_options"], allow_unidentifiable=common["allow_unidentifiable"], info=info,
        closure=True,  # the polish of the cvxpy answer on the closed feasible set, as the Newton fit (model.closure)
    )


def signal_scale(H: np.ndarray, c: float, parameters=None, regularizer=None) -> np.ndarray:
    """s (p,) of the diagonal chart θ = s ⊙ φ in which a weighted or energy least-squares fit (with or without a
    geometric prior) is handed to cvxpy; H (p, p) and c the fit's weighted statistics, regularizer (kind, θ₀, γ) or None.

        s_k = √(c / (H_kk + γ g_kk))   where H_kk > 0,  so without a prior  φ_k = ‖Y_k θ_k‖_W / ‖τ‖_W

    the share of the weighted torques that θ_k alone carries, with g the prior's pullback metric (the log-det
    divergence's Hessian at θ₀ too): invariant to a change of coordinates (H and c move together), to the noise level
    (W = Σ̂⁻¹ scales both) and to N, unlike the OLS chart 1/‖Y_k‖ (a coordinate in units ×1e±6 spread the scaled
    Hessian's diagonal over 12 decades and stopped Clarabel) or the Jacobi chart 1/√H_kk (not noise-invariant). A
    parameter the data do not see keeps 1/√g_kk when a prior sees it, else its physical unit, 1. With a prior the
    chart depends on the balance of data and prior, which is part of the problem (docs/performance.md, "What keeps
    the solvers converging").
    """
    d = np.clip(np.diag(H).astype(float), 0.0, None)
    seen = d > 0
    g = np.zeros_like(d)  # diag of the prior's pullback metric (the log-det divergence's Hessian at θ₀ too)
    gamma = 0.0
    if regularizer is not None:
        kind, theta0, gamma = regularizer
        for idx, V, C0 in prior_blocks(kind, parameters, np.asarray(theta0, dtype=float)):
            g[np.asarray(idx)] += np.clip(np.diag(pullback_metric(V, C0)), 0.0, None)
    s = np.ones_like(d)
    s[seen] = np.sqrt(max(float(c), 1e-300) / (d[seen] + float(gamma) * g[seen]))
    prior_only = ~seen & (g > 0)
    s[prior_only] = 1.0 / np.sqrt(g[prior_only])
    return s
