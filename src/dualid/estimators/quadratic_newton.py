"""Least squares and geometric-prior fits by dualid's own interior-point method (the fallback of cvxpy).

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
"""

from __future__ import annotations

import numpy as np

from dualid.errors import SolverError
from dualid.estimators.newton.closure import on_closure
from dualid.estimators.newton.interior_point import run_interior_point
from dualid.estimators.newton.linalg import solve_psd
from dualid.estimators.newton.objective import Derivatives, NotPositiveDefinite
from dualid.estimators.newton.start import central_point
from dualid.model.consistency import feasible_set


def _blocks(regularizer, parameters):
    """[(idx, V (k, m, m), C0 (m, m), C0⁻¹, g (k, k))] of the prior's blocks (empty without a prior)."""
    if regularizer is None:
        return []
    from dualid.model.consistency import prior_blocks, pullback_metric

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
    closure=True (without a prior): on the closed feasible set of ``newton.closure`` (dm's cvxpy path; OLS, energy
    and the priors keep the original set, whose stopping points along an unbounded unseen mass are moderate, e.g. as
    priors; WLS fits such a problem by ``quadratic_fit.closed_fit``)."""
    cons, done = on_closure(feasible_set(parameters, constrained), np.asarray(H), c, parameters.names,
                            enabled=closure and regularizer is None)
    objective, theta_ls = quadratic_objective(H, g, c, parameters, regularizer)

    def value(theta):
        if not cons.empty and cons.margin(theta) <= 0:
            return np.inf
        try:
            return objective(theta, 0).f
        except NotPositiveDefinite:
            return np.inf

    f_scale = max(float(c), 1e-300)
    failure = None
    if start is not None:
        warm = central_point(np.asarray(start, dtype=float), cons, eps=1e-7)
        if np.isfinite(value(warm)):
            try:
                theta, info = _run(cons, warm, tol, max_iter, objective, f_scale, gap0=1e-6)
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
    theta, info = _run(cons, candidates[k], tol, max_iter, objective, f_scale)
    info["start"] = "cold" + (f" ({failure})" if failure else "")
    return done(theta, info)


# Retried with exact Newton steps (no Levenberg term; the eigen pseudo-inverse only where Cholesky fails) when the
# Levenberg-damped run fails: with 1e-12 the fit crawls along directions whose Jacobi-scaled curvature is below it
# (LandSalp pullback/logdet with the OLS prior: pivots² ~1e-22, f falling 0.027 per iteration 1,000 above the
# optimum; units-1e6 pullback: 150 iterations). Not the first choice: those exact steps are rounding-dominated and
# chart-dependent (dm's re-chart change on the sensor-error arms 1e-11–1e-4 → 1e-7–3e-4 when used for every fit).
RETRY_LEVENBERG = 0.0


def _run(cons, theta, tol, max_iter, objective, f_scale, gap0=1.0):
    """run_interior_point on the module's f; an arithmetic failure inside it (e.g. a duality gap that underflows to 0)
    is a SolverError of this solver, so that the caller's fallback or certification sees a failed solve. A failed
    run is retried once with RETRY_LEVENBERG (recorded as info["newton_levenberg"])."""
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
    theta = theta_out
    info.pop("f_history", None)
    return theta, info
