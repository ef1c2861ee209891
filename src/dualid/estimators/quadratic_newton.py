"""Least squares and geometric-prior fits by dualid's own interior-point method (solver "newton"; cvxpy's fallback).

    min_θ f(θ) = (θ − θ_ls)ᵀ H (θ − θ_ls) + f_min  [+ γ R(θ)]     s.t. the physical-consistency constraints

with H, g, c the sufficient statistics of a (weighted) least-squares fit (θ_ls = H⁺g, f_min = c − gᵀθ_ls,
so f is accurate where it is small compared with c) and R one of the priors of Lee, Wensing & Park (2020):

    pullback: Σ_b (θ_b − θ_b0)ᵀ g_b (θ_b − θ_b0)                         (quadratic)
    logdet:   Σ_b −log det C_b(θ) + log det C_b0 + tr(C_b0⁻¹ C_b(θ)) − m_b   (smooth and convex on C_b ≻ 0)

The iterations are those of the dual-metric solver (``newton.interior_point.run_interior_point``: primal–dual HKM steps on the
pseudo-inertia LMIs, a line search that keeps every C_b ≻ 0); only f, ∇f, ∇²f differ:

    ∇f = 2H(θ − θ_ls) [+ γ (2 g_b (θ_b − θ_b0))]  [+ γ (−tr(C_b⁻¹V_k) + tr(C_b0⁻¹V_k))_k]
    ∇²f = 2H [+ 2γ g_b] [+ γ tr(C_b⁻¹V_k C_b⁻¹V_l)]

Newton steps are affine-invariant, so the badly scaled cones that make Clarabel stop ("CLARABEL failed",
``optimal_inaccurate``) on arms with thin links or priors on the cone boundary cost nothing here.

``polish``: the check of every cvxpy solution (``solver="cvxpy"``, the reference): Clarabel can stop ``optimal``
well above the optimum (its test is relative to the conic reformulation, not to f), so its θ is polished by
``fit_quadratic_newton`` started from it (tol 1e-9 on the gap plus the Newton decrement, relative to f). Lower by more
than ``TOL``: the polished θ, and the chain says by how much cvxpy was above; else cvxpy's θ, certified; the polish
fails: cvxpy's status only as ``optimal_inaccurate``. Exact data (f below ``ROUNDING`` · f(0)) are certified without
it. With ``closure`` and a parameter it projects out, the closed run is the answer unless it ends more than ``TOL``
above a cvxpy θ that is in the set exactly (docs/estimators.md, "Solvers, options and fallbacks").
"""

from __future__ import annotations

import numpy as np

from dualid.errors import SolverError
from dualid.estimators.newton.start import run_quadratic, toward_start
from dualid.estimators.newton.objective import ROUNDING, Derivatives, stopping_scale, value_or_inf
from dualid.linalg import NotPositiveDefinite, solve_psd
from dualid.model.closure import close, on_closure
from dualid.model.consistency import central_point, feasible_set, prior_blocks, pullback_metric

TOL = 1e-7  # a cvxpy objective this far (relative) above the certified optimum is not optimal


def _blocks(regularizer, parameters):
    """[(idx, V (k, m, m), C0 (m, m), C0⁻¹, g (k, k))] of the prior's blocks (empty without a prior)."""
    if regularizer is None:
        return []
    kind, theta0, _ = regularizer
    out = []
    for idx, V, C0 in prior_blocks(kind, parameters, theta0):
        idx = np.asarray(idx)
        out.append((idx, np.asarray(V, dtype=float), C0, np.linalg.inv(C0), pullback_metric(V, C0)))
    return out


def quadratic_objective(H: np.ndarray, g: np.ndarray, c: float, parameters, regularizer=None):
    """objective(θ, order) → Derivatives for the module's f; raises NotPositiveDefinite outside log det's domain."""
    H = 0.5 * (H + H.T)
    theta_ls = solve_psd(H, g, rtol=1e-12)
    f_min = max(float(c - g @ theta_ls), 0.0)
    kind, theta0, gamma = regularizer if regularizer is not None else (None, None, 0.0)
    blocks = _blocks(regularizer, parameters)

    def objective(theta: np.ndarray, order: int) -> Derivatives:
        d = theta - theta_ls
        Hd = H @ d
        f = float(d @ Hd) + f_min
        grad = 2.0 * Hd if order else None
        hess = 2.0 * H.copy() if order else None
        for idx, V, C0, C0inv, G in blocks:
            th = theta[idx]
            if kind == "pullback":
                e = th - theta0[idx]
                f += gamma * float(e @ G @ e)
                if order:
                    grad[idx] += 2.0 * gamma * (G @ e)
                    hess[np.ix_(idx, idx)] += 2.0 * gamma * G
                continue
            C = np.tensordot(th, V, axes=1)
            try:
                L = np.linalg.cholesky(0.5 * (C + C.T))
            except np.linalg.LinAlgError:
                raise NotPositiveDefinite from None
            m = C.shape[0]
            f += gamma * (-2.0 * float(np.sum(np.log(np.diag(L)))) + np.linalg.slogdet(C0)[1]
                          + float(np.sum(C0inv * C)) - m)
            if order:
                Cinv = np.linalg.inv(C)
                grad[idx] += gamma * (np.einsum("kab,ba->k", V, C0inv - Cinv))
                CV = np.einsum("ab,kbc->kac", Cinv, V)  # C⁻¹ V_k
                hess[np.ix_(idx, idx)] += gamma * np.einsum("kab,lba->kl", CV, CV)
        if not np.isfinite(f):
            raise NotPositiveDefinite
        return Derivatives(f, grad, None if hess is None else 0.5 * (hess + hess.T))

    return objective, theta_ls


def fit_quadratic_newton(H, g, c, parameters, *, constrained: bool = True, regularizer=None, tol: float = 1e-9,
                         max_iter: int = 300, start: np.ndarray | None = None,
                         closure: bool = False) -> tuple[np.ndarray, dict]:
    """(θ̂, info) minimising the module's f under the constraints; raises SolverError when it does not converge.

    ``start`` (e.g. a cvxpy solution on the cone's boundary): tried first, moved just inside the cones and started
    close to the central path (a polish); when that does not converge, the cold start below runs as without it.
    closure=True (without a prior): on the closed feasible set of ``model.closure`` (dm's cvxpy path; WLS fits such a
    problem by ``quadratic_fit.closed_fit``; OLS, energy and the priors keep the original set)."""
    cons, done = on_closure(feasible_set(parameters, constrained), np.asarray(H), c, parameters.names,
                            enabled=closure and regularizer is None)
    objective, theta_ls = quadratic_objective(H, g, c, parameters, regularizer)

    def value(theta):
        if not cons.empty and cons.margin(theta) <= 0:
            return np.inf
        return value_or_inf(objective, theta)

    f_scale = stopping_scale(c - g @ theta_ls, c)
    failure = None
    if start is not None:
        warm = central_point(np.asarray(start, dtype=float), cons, eps=1e-7)
        if np.isfinite(value(warm)):
            try:
                theta, info = run_quadratic(cons, warm, tol, max_iter, objective, f_scale, gap0=1e-6)
                info["start"] = "warm"
                return done(theta, info)
            except SolverError as exc:
                failure = f"warm start failed ({exc.status})"
    candidates = [central_point(theta_ls, cons)]
    if regularizer is not None:
        candidates.append(np.asarray(regularizer[1], dtype=float))  # θ₀ (strictly consistent)
        candidates.append(central_point(candidates[-1], cons))
    values = [value(t) for t in candidates]
    k = int(np.argmin(values))
    if not np.isfinite(values[k]):
        raise SolverError("quadratic Newton: found no strictly feasible start", status="no_start")
    theta, info = run_quadratic(cons, candidates[k], tol, max_iter, objective, f_scale)
    info["start"] = "cold" + (f" ({failure})" if failure else "")
    return done(theta if regularizer is not None else toward_start(theta, candidates[k], H, cons, value), info)


# --- the certificate of a cvxpy solution ---------------------------------------------------------------------------


def certified_objective(stats, parameters, regularizer):
    """f(θ) of quadratic_newton (∞ outside log det's domain): the value both solutions are compared in."""
    objective, _ = quadratic_objective(stats.H, stats.g, stats.c, parameters, regularizer)
    return lambda theta: value_or_inf(objective, np.asarray(theta, dtype=float))


def polish(theta_cvx, stats, parameters, constrained, regularizer, solver, closure: bool = False):
    """(θ, label, polished, certified, info) — see the module doc."""
    f = certified_objective(stats, parameters, regularizer)
    f_cvx = f(theta_cvx)
    floor = ROUNDING * max(float(stats.c), 0.0)
    if regularizer is None and abs(f_cvx) <= floor:  # f ≥ 0 (below 0: rounding), so f(θ_cvx) − f* ≤ f(θ_cvx): a certificate by itself
        info = {"certified_gap": float(abs(f_cvx) / max(float(stats.c), 1e-300)), "cvxpy_above_certified": 0.0,
                "certify_iterations": 0}
        return theta_cvx, f"{solver} optimal (certified: f at the rounding floor, {info['certified_gap']:.1e} of f(0))", \
            False, True, info
    try:
        theta, ipm = fit_quadratic_newton(stats.H, stats.g, stats.c, parameters, constrained=constrained,
                                          regularizer=regularizer, start=theta_cvx, closure=closure)
    except SolverError as exc:
        closed = closure and regularizer is None and constrained and projects(stats, parameters)
        where = " on the closed set (model.closure)" if closed else ""
        return theta_cvx, f"{solver} optimal, not certified: newton check{where} failed ({exc.status})", False, False, {}
    f_new = f(theta)
    above = (f_cvx - f_new) / max(abs(f_new), 1e-300) if np.isfinite(f_cvx) else np.inf
    info = {"certified_gap": float(ipm["relative_gap"]), "cvxpy_above_certified": float(above),
            "certify_iterations": int(ipm["iterations"])}
    # the closure's completion (describes θ, not θ_cvx): present exactly when the fit ran on a closed set that
    # projected a parameter out (model.closure.on_closure, enabled by closure without a prior)
    projected = {k: v for k, v in ipm.items() if k.startswith("projected_")}
    if projected:
        outside = feasible_set(parameters, True).margin(theta_cvx) < 0
        if above >= -TOL or outside:  # cvxpy's θ counts against the closed run only as a point of the set (exactly,
            # no tolerance: along the ray a relative one admits an axis inertia below 0, i.e. f below the infimum)
            why = "outside the set by rounding" if above < -TOL else f"{above:.1e} above"
            return theta, f"{solver} optimal ({why}) → newton on the closed set (model.closure)", True, True, \
                {**info, **projected}
        # else the closed run did not reach its infimum and cvxpy's θ is checked as below
    if above > TOL:
        return theta, f"{solver} optimal but {above:.1e} above → newton polished", True, True, {**info, **projected}
    return theta_cvx, f"{solver} optimal (certified by newton: {max(above, 0.0):.1e})", False, True, info


def projects(stats, parameters) -> bool:
    """Does the closure project some parameter out of this fit (``model.closure.close`` on its statistics)?"""
    return bool(close(feasible_set(parameters, True), stats.H, stats.c)[1])
