"""Run every method of the method table, with each solver where there is a choice, on one corpus problem.

Runs per problem (``fits``):
- ols, wls, energy: the library default (dualid's interior point, Clarabel as recorded fallback);
- logdet, pullback: with a CAD-like prior, and with a prior on the consistency boundary (the constrained
  OLS fit), the latter also with the prior floor off (``prior_floor=0``: the behaviour before the lift);
- dm: dualid's interior point (its only solver);
- dm-paper: Newton and the SDP through Clarabel, each without fallback, so a failure shows.

The reference of each run (``ref_objective``, ``rel_gap`` = (f − f_ref)/|f_ref|, ``pred_diff`` = ‖Y(θ − θ_ref)‖/‖Yθ_ref‖):
dm-paper: the SDP (Clarabel) when it is optimal; dm: its own objective (its noise levels are estimated from the data);
quadratic and regularized fits: the same estimator with solver="cvxpy" (Clarabel, certified or polished by the interior
point) when it ends optimal; else SCS to 1e-9 when it says optimal, else SCS's end point polished by the interior point
(``quadratic_newton`` on the same sufficient statistics); or the fit itself if lower.
Failures are rows, never dropped; raw warnings reaching the caller are counted.
"""

from __future__ import annotations

import dataclasses
import time
import warnings

import numpy as np

from dualid.errors import SolverError

SDP_MAX_N = 1000
SCS_TIGHT = {"eps_abs": 1e-9, "eps_rel": 1e-9, "max_iters": 20_000}


def _record(est, problem):
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            r = est.fit(problem)
        except Exception as exc:  # a row, not an omission
            return None, {"status": "FAILED", "error": f"{type(exc).__name__}: {exc}"[:300],
                          "time_s": time.perf_counter() - t0, "raw_warnings": len(caught)}
    chain = str(r.info.get("solver_chain", ""))
    return r, {"status": str(r.status), "solver": str(r.solver), "iterations": r.iterations,
               "time_s": time.perf_counter() - t0, "objective": float(r.objective), "chain": chain,
               "raw_warnings": len(caught), "prior_lifted": sorted(r.info.get("prior_lifted") or {})}


def _quadratic_reference(est, problem, start=None):
    """(objective, θ) of est's problem solved by dualid's interior point on the same statistics."""
    from dualid.estimators.least_squares import OLS, WLS, EnergyLS, RegularizedWLS, covariance_weight
    from dualid.estimators.quadratic_newton import fit_quadratic_newton
    from dualid.estimators.newton.objective import energy_statistics, statistics
    from dualid.model.consistency import regularizer_value
    from dualid.model.prior_lift import lift_prior

    reg = None
    if isinstance(est, OLS):
        stats = statistics(problem)
    elif isinstance(est, EnergyLS):
        stats = energy_statistics(problem)
    elif isinstance(est, (WLS, RegularizedWLS)):  # Σ̂ from OLS on the closed set (covariance_weight); WLS too
        stats = statistics(problem, covariance_weight(problem, None, est)[0])
        if isinstance(est, RegularizedWLS):
            th0 = lift_prior(problem.parameters, np.asarray(est.theta0), float(est.prior_floor))[0]
            reg = (est.regularizer, th0, float(est.gamma) * problem.N * problem.n)
    else:
        return None, None
    theta, _ = fit_quadratic_newton(stats.H, stats.g, stats.c, problem.parameters, regularizer=reg, start=start,
                                    closure=isinstance(est, (WLS, EnergyLS)))
    f = stats.objective(problem, theta)
    if reg is not None:
        f += reg[2] * regularizer_value(reg[0], problem.parameters, theta, reg[1])
    return float(f), theta


def _agreement(row, r, f_ref, theta_ref, problem):
    if r is None or f_ref is None or not np.isfinite(f_ref):
        return
    row["ref_objective"] = f_ref
    row["rel_gap"] = (row["objective"] - f_ref) / max(abs(f_ref), 1e-300)
    Y = problem.Y.reshape(-1, problem.p)
    base = np.linalg.norm(Y @ theta_ref)
    row["pred_diff"] = float(np.linalg.norm(Y @ (np.asarray(r.theta) - theta_ref)) / max(base, 1e-300))


def fits(problem, theta_true, sdp: bool = True, prior_seed: int = 0, sdp_max_n: int = SDP_MAX_N, prior=None,
         methods=None) -> list[dict]:
    """Every (method, variant, solver) run on ``problem`` (see the module doc), as row dicts. ``prior``: the CAD-like
    prior (default: ``cad_prior(theta_true)``); ``methods``: run only these (large N: ols, wls, dm, dm-paper by
    Newton: no prior fits, no CLARABEL solve of dm, no SDP)."""
    from dualid.bench.corpus import cad_prior
    from dualid.estimators.dual_metric import DualMetric
    from dualid.estimators.methods import make_estimator

    rows = []

    def quad(method, variant, est):
        r, row = _record(est, problem)
        row.update(method=method, variant=variant, solver_choice="default")
        same = {}  # the fit's own weights: the reference's pilot OLS would give slightly different ones (another problem)
        if r is not None and "covariance_matrix" in r.info and hasattr(est, "covariance"):
            same["covariance"] = np.asarray(r.info["covariance_matrix"])
        try:  # the conic reference (Clarabel, certified or polished by the interior point)
            ref = dataclasses.replace(est, solver="cvxpy", **same).fit(problem)
            if ref.status != "optimal":
                raise SolverError(f"{ref.info.get('solver_chain', '')}: {ref.status}")
            f_ref, th_ref, row["reference"] = float(ref.objective), np.asarray(ref.theta), "cvxpy"
        except Exception as exc:  # then SCS to a tight tolerance, if it is optimal
            f_ref, th_ref = None, None
            row["ref_error"] = f"{type(exc).__name__}: {exc}"[:200]
            scs, _ = _record(dataclasses.replace(est, solver="cvxpy", cvxpy_solver="SCS", solver_options=SCS_TIGHT, **same), problem)
            if scs is not None and scs.status == "optimal" and scs.solver == "SCS":
                f_ref, th_ref, row["reference"] = float(scs.objective), np.asarray(scs.theta), "SCS"
            elif scs is not None:  # SCS's end point polished by the interior point (a different start than the fit's)
                try:
                    f_ref, th_ref = _quadratic_reference(est, problem, start=np.asarray(scs.theta))
                    row["reference"] = "SCS + newton polish"
                except Exception as exc2:
                    row["ref_error"] += f"; from SCS: {type(exc2).__name__}: {exc2}"[:200]
        if r is not None and f_ref is not None and row["objective"] < f_ref:
            f_ref, th_ref = row["objective"], np.asarray(r.theta)
        _agreement(row, r, f_ref, th_ref, problem)
        rows.append(row)
        return r

    kw = dict(allow_unidentifiable=True)
    run = set(methods or ("ols", "wls", "energy", "logdet", "pullback", "dm", "dm-paper"))
    ols = quad("ols", "", make_estimator("ols", **kw)) if "ols" in run else None
    for m in ("wls", "energy"):
        if m in run:
            quad(m, "", make_estimator(m, **kw))
    priors = {"prior CAD-like": cad_prior(theta_true, prior_seed) if prior is None else np.asarray(prior)}
    if ols is not None:
        priors["prior = constrained OLS"] = np.asarray(ols.theta)
    for m in ("logdet", "pullback"):
        if m not in run:
            continue
        for label, th0 in priors.items():
            quad(m, label, make_estimator(m, theta0=th0, **kw))
            if label != "prior CAD-like":
                quad(m, label + ", floor off", make_estimator(m, theta0=th0, options={"prior_floor": 0.0}, **kw))
    if "dm" in run:
        r, row = _record(make_estimator("dm", **kw), problem)
        row.update(method="dm", variant="", solver_choice="newton")
        rows.append(row)
        if r is not None:
            _agreement(row, r, row["objective"], np.asarray(r.theta), problem)
    if "dm-paper" not in run:
        return _sized(rows, problem)
    newton, nrow = _record(DualMetric(solver="newton", fallback=(), **kw), problem)
    nrow.update(method="dm-paper", variant="", solver_choice="newton")
    rows.append(nrow)
    if sdp and problem.N <= sdp_max_n:
        s, srow = _record(DualMetric(solver="cvxpy", fallback=(), **kw), problem)
        srow.update(method="dm-paper", variant="", solver_choice="sdp_clarabel")
        rows.append(srow)
        if s is not None and s.status == "optimal":
            _agreement(nrow, newton, srow["objective"], np.asarray(s.theta), problem)
            _agreement(srow, s, srow["objective"], np.asarray(s.theta), problem)
        else:  # no reference: said, so the row is not taken for an agreement
            nrow["ref_error"] = f"the SDP reference ended {srow['status'] if s is not None else 'with an error'}"
    return _sized(rows, problem)


def _sized(rows, problem):
    for row in rows:
        row.update(N=problem.N, n=problem.n, p=problem.p)
    return rows
