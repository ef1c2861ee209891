"""fit_dual_metric_newton: constraints, start (optionally warm, from a subsample), iterations, result."""

from __future__ import annotations

import time
import warnings
from dataclasses import replace

import numpy as np

from dualid.errors import OptimumAtInfinityWarning, SolverError
from dualid.estimators.newton.interior_point import direction_label, run_interior_point
from dualid.estimators.newton.objective import CHUNK, dual_metric_derivatives, force_scale, objective_value
from dualid.estimators.newton.start import starting_point
from dualid.estimators.result import IdentificationResult
from dualid.linalg import NotPositiveDefinite
from dualid.model.consistency import feasible_set
from dualid.problem import IdentificationProblem

WARM_TOL = 1e-6  # the subsample's tolerance (its optimum is far from the full one anyway; 1e-8 cost 2 of its passes) …
MIN_WARM = 1_000  # smallest default warm-start subsample (so from N = 8,000 on)
WARM_GAP = 1e-8  # … and the gap (× f) the full problem's duals are re-centred at (1e-6: a third full pass; Crazyflie 1e6)
WARM_MAX_ITER = 10  # full-data iterations a warm start may take before the cold start takes over (it needs 2–4 where
# it helps; where the subsample's optimum is no guide — e.g. an optimum at infinity — each further one is a wasted pass)
PUSH = 10.0  # the re-solve's lower bound: this many times the main components' values at θ̂


def pushed_out(problem, theta, f, d, tol, max_iter, chunk) -> dict | None:
    """Is f lower still farther out along the direction d the iterations ran off in? Re-solve from θ̂ with the main
    components of d (≥ 5 % of its largest; e.g. Joint1's mass) bounded below at PUSH × their values at θ̂, the other
    parameters free to follow. If that optimum is lower than f(θ̂) by more than the tolerance, the infimum lies
    beyond θ̂: {"objective_pushed_out", "pushed_out_bound"}; else (or if it cannot be tested) None."""
    if not isinstance(problem, IdentificationProblem):
        return None
    main = np.flatnonzero(np.abs(d) >= 0.05 * np.abs(d).max())
    if not np.all(d[main] * theta[main] > 0):  # only components growing away from zero in their own sign
        return None
    lower, upper = problem.parameters.bounds
    target = PUSH * theta[main]
    pos = target > 0
    lower[main[pos]] = np.maximum(lower[main[pos]], target[pos])
    upper[main[~pos]] = np.minimum(upper[main[~pos]], target[~pos])
    if np.any(lower >= upper):
        return None
    pushed = replace(problem, parameters=problem.parameters.with_bounds(lower, upper))
    cons = feasible_set(pushed.parameters, True)
    start = theta.copy()
    start[main] = PUSH * (1 + 1e-3) * theta[main]
    near = cons.margin(start) > 0 and np.isfinite(objective_value(pushed, start, chunk))
    if not near:  # θ̂ on a cone's boundary (DFKI: a margin of ±4e-12, its sign set by rounding): the pushed problem's
        # own strictly feasible start instead, solved cold below
        try:
            start, _ = starting_point(pushed, cons, chunk)
        except (SolverError, NotPositiveDefinite, np.linalg.LinAlgError):
            return None
        if cons.margin(start) <= 0 or not np.isfinite(objective_value(pushed, start, chunk)):
            return None
    info = None
    if near:  # θ̂ pushed out is usually near the pushed optimum (f cannot see the pushed directions): duals centred at
        # a small gap, as the warm start's; the cold re-solve if that fails (same optimum)
        try:
            _, _, _, info = run_interior_point(pushed, cons, start, None, None, tol, min(max_iter, WARM_MAX_ITER), chunk,
                                            False, gap0=WARM_GAP, balance=0.0)
        except (SolverError, NotPositiveDefinite):
            info = None
    if info is None:
        try:
            _, _, _, info = run_interior_point(pushed, cons, start, None, None, tol, max_iter, chunk, False)
        except (SolverError, NotPositiveDefinite):
            return None
    if info["objective"] < f - 10 * tol * abs(f):
        return {"objective_pushed_out": float(info["objective"]), "pushed_out_bound": float(PUSH)}
    return None


def check_bounds(problem: IdentificationProblem, constrained: bool) -> None:
    """SolverError (status infeasible) when some parameter's bounds admit no strictly feasible θ."""
    if not constrained:
        return
    lo, hi = problem.parameters.bounds
    bad = np.flatnonzero(lo >= hi)
    if len(bad):
        k = int(bad[0])
        raise SolverError(
            f"dual-metric Newton: the bounds admit no strictly feasible θ: {problem.parameters.names[k]} has "
            f"lower bound {lo[k]:g} ≥ upper bound {hi[k]:g}",
            status="infeasible",
        )


def _solve(problem, cons, tol, max_iter, chunk, verbose, warm_start_samples) -> tuple[np.ndarray, dict, str]:
    """(θ, info, start) by the interior point from a warm start on a strided subsample (itself solved so) or cold."""
    warm, failed_warm = None, ""  # the subsample: warm_start_samples when N > 4× that, else N/8 from 8 × MIN_WARM on
    m = warm_start_samples if problem.N > 4 * warm_start_samples else problem.N // 8
    if warm_start_samples and m >= min(warm_start_samples, MIN_WARM) and problem.N > 4 * m:
        sub = problem.subset(slice(0, None, problem.N // m))
        try:  # the subsample solved the same way (from its own subsample if it is large: 6,250 of 50,000 samples)
            th, info_sub, start_sub = _solve(sub, cons, WARM_TOL, max_iter, chunk, verbose, warm_start_samples)
            try:  # the objective's scale, from the subsample (saves a pass over all samples)
                f_scale = force_scale(sub, th, chunk) * problem.N / sub.N
            except np.linalg.LinAlgError:
                f_scale = None
            warm = (th, dual_metric_derivatives(problem, th, 2, chunk))  # M_i(θ) ≻ 0 on every sample?
            start = f"warm start from {sub.N} samples ({info_sub['iterations']} iterations)" + (
                f", itself from a {start_sub}" if start_sub.startswith("warm") else "")
        except SolverError as exc:  # recorded in info["start"]; the cold start below decides
            warm, failed_warm = None, f"warm start from {sub.N} samples failed ({exc.status}); "
        except NotPositiveDefinite:
            warm, failed_warm = None, f"warm start from {sub.N} samples left some M_i(θ) indefinite; "
    if warm is not None:
        try:  # duals re-centred at θ at WARM_GAP: the subsample's own sit too close to its boundary (they would jam)
            theta, _, _, info = run_interior_point(problem, cons, warm[0], None, None, tol, min(max_iter, WARM_MAX_ITER),
                                                chunk, verbose, der=warm[1], gap0=WARM_GAP, f_scale=f_scale,
                                                balance=0.0)
        except SolverError as exc:  # the subsample's optimum can sit near a boundary the full data move away from
            warm = None
            failed_warm = f"{start} failed ({exc.status}); "
    if warm is None:
        theta, start = starting_point(problem, cons, chunk)
        theta, _, _, info = run_interior_point(problem, cons, theta, None, None, tol, max_iter, chunk, verbose)
        start = failed_warm + start
    return theta, info, start


def fit_dual_metric_newton(
    problem: IdentificationProblem,
    *,
    constrained: bool = True,
    tol: float = 1e-9,
    max_iter: int = 100,
    chunk: int = CHUNK,
    warm_start_samples: int = 50_000,
    method: str = "dual_metric",
    verbose: bool = False,
) -> IdentificationResult:
    """Dual-metric least squares by a primal–dual interior-point Newton method (see module doc).

    tol: relative tolerance on f for (duality gap + squared Newton decrement of the Lagrangian); chunk: samples per
    pass (memory O(chunk·n·p)); raises SolverError after max_iter iterations. warm_start_samples: when N > 4× this (or
    N ≥ 8 × MIN_WARM: N/8), first solve an evenly strided subsample of that size so (to WARM_TOL), start from its θ."""
    t0 = time.perf_counter()
    cons = feasible_set(problem.parameters, constrained)
    check_bounds(problem, constrained)
    theta, info, start = _solve(problem, cons, tol, max_iter, chunk, verbose, warm_start_samples)
    f = info.pop("objective")
    info["start"] = start
    candidate = info.pop("diverging_candidate", None)
    if candidate is not None and constrained and not info.get("optimum_at_infinity"):
        pushed = pushed_out(problem, theta, f, candidate, tol, max_iter, chunk)
        if pushed is not None:
            info.update(optimum_at_infinity=True, diverging_direction=candidate, **pushed)
    if info.get("optimum_at_infinity"):
        d = info.pop("diverging_direction")
        names = problem.parameters.names
        info["diverging_direction"] = direction_label(d, names)
        detail = f"|θ| grew {info['theta_norm_growth']:.3g}× over {info['diverging_steps']} aligned iterations"
        if "objective_pushed_out" in info:
            detail += (f"; with its main components bounded at {PUSH:g}× their values the optimum is lower still "
                       f"({info['objective_pushed_out']:.10g} < {f:.10g})")
        warnings.warn(OptimumAtInfinityWarning(
            f"{method}: the objective was still decreasing as θ grew without bound along {info['diverging_direction']} "
            f"({detail}): the "
            "infimum is at infinity and θ̂ is where the solver stopped; bound or fix these parameters"), stacklevel=2)
    return IdentificationResult(
        method, theta, problem.parameters, f, "optimal", "newton", time.perf_counter() - t0, info["iterations"],
        constrained, info,
    )
