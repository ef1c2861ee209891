"""An independent check of every cvxpy solution of a quadratic or regularized fit.

Clarabel can stop with status ``optimal`` on an objective well above the optimum: on log-det / pullback fits
whose prior is on the consistency boundary it was 1e-5 … 4e-2 above (stress corpus), with nothing in its status
to say so. Its stopping test is relative to the size of the conic reformulation (the cone variables of the log-det
and the quadratic terms, scaled by the prior's near-null directions), not to the fit's objective; so a tolerance met
there is no guarantee in f.

So every cvxpy solution is polished by dualid's own interior-point method (``quadratic_newton``) started from it
(moved just inside the cones, close to the central path): a primal–dual method whose stopping test is the duality
gap plus the Newton decrement of the Lagrangian, relative to f itself (tol 1e-9; not a strict bound: two end points
of the same fit were seen 5e-9 apart, well inside ``TOL``). Then
- the polish is lower by more than ``TOL`` (relative): the polished θ is returned, the chain says by how much the
  cvxpy solution was above;
- otherwise the cvxpy solution is kept, certified by the polish (the measured gap is recorded);
- the polish fails: the cvxpy status is kept only as ``optimal_inaccurate`` (uncertified), the chain says why.

A least-squares fit (no prior) whose f is already below ``ROUNDING`` · f(0) — exact data — is certified without
the polish: f ≥ 0, so it is that close to the optimum; relative tests on f itself are meaningless there (f ~ 1e-26).

With ``closure`` (dm's fits) and a parameter the closure projects out (``newton.closure``: the infimum is approached
only as it grows), the polish on the closed set is the answer whatever the two objectives: there cvxpy's θ is a
stopping point along that ray, within its tolerance of the infimum but placed by rounding (a certified cvxpy θ
kept within ``TOL`` used to leave dm's prediction depending on where Clarabel stopped, and without the completed
parameter's note). The chain says so ("→ newton on the closed set"). Not when the closed run ends above cvxpy's θ
by more than ``TOL`` and cvxpy's θ is in the set exactly (a point of the closed set, so that run missed its infimum):
then as above. A cvxpy θ below the infimum but outside the set (far along the ray a tolerance relative to the block's
size admits a slightly negative axis inertia) does not count: the closed run's θ is returned, the chain says
"outside the set by rounding"; the completed parameter's note always describes the θ returned. Nor on
exact data (the shortcut above): f is at the rounding floor, the infimum is attained (f = 0 at a consistent θ), and a
polish there is rounding-dominated (a WLS pilot on the stress corpus's exact RR chain, weights Σ̂⁻¹ ~ 1e23, came back
1.4e7 times higher in f and moved dm's weights by 1e7).
"""

from __future__ import annotations

import numpy as np

from dualid.errors import SolverError

TOL = 1e-7  # a cvxpy objective this far (relative) above the certified optimum is not optimal
ROUNDING = 1e-12  # a least-squares f(θ) ≤ this × f(0) (exact data) is optimal to that accuracy: f ≥ 0 (no iterations)


def certified_objective(stats, parameters, regularizer):
    """f(θ) of quadratic_newton (∞ outside log det's domain): the value both solutions are compared in."""
    from dualid.estimators.newton.objective import NotPositiveDefinite
    from dualid.estimators.quadratic_newton import quadratic_objective

    objective, _ = quadratic_objective(stats.H, stats.g, stats.c, parameters, regularizer)

    def f(theta):
        try:
            return objective(np.asarray(theta, dtype=float), 0).f
        except NotPositiveDefinite:
            return np.inf
    return f


def polish(theta_cvx, stats, parameters, constrained, regularizer, solver, closure: bool = False):
    """(θ, label, polished, certified, info) — see the module doc."""
    from dualid.estimators.quadratic_newton import fit_quadratic_newton
    from dualid.model.consistency import feasible_set

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
        where = " on the closed set (newton.closure)" if closed else ""
        return theta_cvx, f"{solver} optimal, not certified: newton check{where} failed ({exc.status})", False, False, {}
    f_new = f(theta)
    above = (f_cvx - f_new) / max(abs(f_new), 1e-300) if np.isfinite(f_cvx) else np.inf
    info = {"certified_gap": float(ipm["relative_gap"]), "cvxpy_above_certified": float(above),
            "certify_iterations": int(ipm["iterations"])}
    # the closure's completion (describes θ, not θ_cvx): present exactly when the fit ran on a closed set that
    # projected a parameter out (newton.closure.on_closure, enabled by closure without a prior)
    projected = {k: v for k, v in ipm.items() if k.startswith("projected_")}
    if projected:
        outside = feasible_set(parameters, True).margin(theta_cvx) < 0
        if above >= -TOL or outside:  # cvxpy's θ counts against the closed run only as a point of the set (exactly,
            # no tolerance: along the ray a relative one admits an axis inertia below 0, i.e. f below the infimum)
            why = "outside the set by rounding" if above < -TOL else f"{above:.1e} above"
            return theta, f"{solver} optimal ({why}) → newton on the closed set (newton.closure)", True, True, \
                {**info, **projected}
        # else the closed run did not reach its infimum and cvxpy's θ is checked as below
    if above > TOL:
        return theta, f"{solver} optimal but {above:.1e} above → newton polished", True, True, {**info, **projected}
    return theta_cvx, f"{solver} optimal (certified by newton: {max(above, 0.0):.1e})", False, True, info


def projects(stats, parameters) -> bool:
    """Does the closure project some parameter out of this fit (``newton.closure.close`` on its statistics)?"""
    from dualid.estimators.newton.closure import close
    from dualid.model.consistency import feasible_set

    return bool(close(feasible_set(parameters, True), stats.H, stats.c)[1])
