"""fit_dual_metric_newton: constraints, start (optionally warm, from a subsample), iterations, result."""

from __future__ import annotations

import time
import warnings

import numpy as np

from dualid.errors import OptimumAtInfinityWarning, SolverError
from dualid.estimators.newton.interior_point import _interior_point
from dualid.estimators.newton.objective import (
    _force_scale,
    _NotPositiveDefinite,
    dual_metric_derivatives,
)
from dualid.estimators.newton.start import starting_point
from dualid.estimators.result import IdentificationResult
from dualid.model.consistency import feasible_set
from dualid.problem import IdentificationProblem

WARM_TOL = 1e-8  # the subsample's tolerance (a tight one costs iterations on 50,000 samples, not passes over N) …
WARM_GAP = 1e-6  # … and the duality gap (× f) the full problem's dual variables are re-centred at


def check_bounds(problem: IdentificationProblem, constrained: bool) -> None:
    """SolverError (status infeasible) when some parameter's bounds admit no strictly feasible θ."""
    if not constrained:
        return
    p = problem.p
    lo = np.asarray(problem.parameters.lower if problem.parameters.lower is not None else [-np.inf] * p)
    hi = np.asarray(problem.parameters.upper if problem.parameters.upper is not None else [np.inf] * p)
    bad = np.flatnonzero(lo >= hi)
    if len(bad):
        k = int(bad[0])
        raise SolverError(
            f"dual-metric Newton: the bounds admit no strictly feasible θ: {problem.parameters.names[k]} has "
            f"lower bound {lo[k]:g} ≥ upper bound {hi[k]:g}",
            status="infeasible",
        )


def fit_dual_metric_newton(
    problem: IdentificationProblem,
    *,
    constrained: bool = True,
    tol: float = 1e-9,
    max_iter: int = 100,
    chunk: int = 4096,
    warm_start_samples: int = 50_000,
    method: str = "dual_metric",
    verbose: bool = False,
) -> IdentificationResult:
    """Dual-metric least squares by a primal–dual interior-point Newton method (see module doc).

    tol: relative tolerance on f for (duality gap + squared Newton decrement of the Lagrangian);
    chunk: samples per pass (memory O(chunk·n·p)); raises SolverError after max_iter iterations.
    warm_start_samples: when N > 4× this, first solve on an evenly strided subsample of about this
    size (to WARM_TOL = 1e-8) and start the full problem from its θ, with the dual variables re-centred
    there at a small gap (WARM_GAP = 1e-6 f) and the objective's scale from the subsample; 0 disables
    it. On the benchmark Crazyflie at N = 300,000 this takes 3 passes over the data instead of 7 (the
    earlier 1e-4 / 1e-3: 5 full iterations plus a scale pass), with the same objective to 12 digits.
    """
    t0 = time.perf_counter()
    cons = feasible_set(problem.parameters, constrained)
    check_bounds(problem, constrained)
    warm, failed_warm = None, ""
    if warm_start_samples and problem.N > 4 * warm_start_samples:
        sub = problem.subset(slice(0, None, problem.N // warm_start_samples))
        theta, start = starting_point(sub, cons, chunk)
        try:
            th, _, _, info_sub = _interior_point(sub, cons, theta, None, None, WARM_TOL, max_iter, chunk, verbose)
            try:  # the objective's scale, from the subsample (saves a pass over all samples)
                f_scale = _force_scale(sub, th, chunk) * problem.N / sub.N
            except np.linalg.LinAlgError:
                f_scale = None
            der = dual_metric_derivatives(problem, th, 2, chunk)  # M_i(θ) ≻ 0 on every sample?
            warm = (th, der)
            start = f"warm start from {sub.N} samples ({info_sub['iterations']} iterations)"
        except SolverError as exc:  # recorded in info["start"]; the cold start below decides
            warm, failed_warm = None, f"warm start from {sub.N} samples failed ({exc.status}); "
        except _NotPositiveDefinite:
            warm, failed_warm = None, f"warm start from {sub.N} samples left some M_i(θ) indefinite; "
    if warm is not None:
        # primal warm start; duals re-centred at θ with a small gap (WARM_GAP f): the subsample's own duals sit
        # too close to its boundary for the full problem and would jam the iterations
        try:
            theta, Z, z, info = _interior_point(problem, cons, warm[0], None, None, tol, max_iter, chunk, verbose,
                                                der=warm[1], gap0=WARM_GAP, f_scale=f_scale)
        except SolverError as exc:  # the subsample's optimum can sit near a boundary the full data move away from
            warm = None
            failed_warm = f"{start} failed ({exc.status}); "
    if warm is None:
        theta, start = starting_point(problem, cons, chunk)
        theta, Z, z, info = _interior_point(problem, cons, theta, None, None, tol, max_iter, chunk, verbose)
        start = failed_warm + start
    f = info.pop("objective")
    info["start"] = start
    if info.get("optimum_at_infinity"):
        d = info.pop("diverging_direction")
        names = problem.parameters.names
        top = [k for k in np.argsort(-np.abs(d))[:4] if abs(d[k]) > 1e-3]
        info["diverging_direction"] = " ".join(f"{d[k]:+.3f}·{names[k]}" for k in top)
        warnings.warn(OptimumAtInfinityWarning(
            f"{method}: the objective was still decreasing as θ grew without bound along {info['diverging_direction']} "
            f"(|θ| grew {info['theta_norm_growth']:.3g}× over the last {info['diverging_steps']} iterations): the "
            "infimum is at infinity and θ̂ is where the solver stopped; bound or fix these parameters"), stacklevel=2)
    return IdentificationResult(
        method, theta, problem.parameters, f, "optimal", "newton", time.perf_counter() - t0, info["iterations"],
        constrained, info,
    )
