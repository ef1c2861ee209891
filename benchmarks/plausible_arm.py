"""Plausible parameters on simulated 7-DoF arms with a CAD-like prior (issue 14's done-when, over seeds).

System: ``dualid.bench.arms.random_arm(rng, 7)`` (random axes and boxes, friction and armature). Prior:
every body's 10 parameters scaled by one factor 1 ± U(0.2, 0.3) (a density error: a CAD-like prior that
is consistent but wrong); joint terms from the fit (as ``dualid fit`` does). Two data cases per seed:
- exact: 4 s at the commanded states, noise-free τ, every 8th sample (100 samples): the data fix the
  identifiable combinations exactly; the null space is all that is unknown;
- noisy: 8 s as logged (16-bit encoder, Savitzky–Golay v and a, 2 % torque noise), every 2nd sample,
  fitted by ``dm`` (the dual-metric GLS);
- noisy-logdet: the same noisy data fitted by ``logdet`` (WLS + γ·N·n·log-det divergence to the same
  prior, γ = 0.1): the prior already inside the fit.
Per seed and case, the fit θ̂ (OLS on exact data, dm on noisy), then ``plausible_parameters``; reported:
the masses the prior determines (prior share ≥ 0.5), their largest |θ/θ₀ − 1| raw and plausible, how
many are within 30 % of the prior, the objective and solver chain, the training-prediction change.

    PYTHONPATH=src python -W ignore benchmarks/plausible_arm.py --seeds 10 --out benchmarks/plausible_arm.json
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from dualid.bench.arms import make_run, random_arm
from dualid.data.trajectory import Trajectory
from dualid.errors import DualidError
from dualid.estimators.methods import make_estimator
from dualid.estimators.plausible import PRIOR, plausible_parameters
from dualid.problem import build_problem


def one(seed: int, case: str) -> dict:
    rng = np.random.default_rng(seed)
    arm = random_arm(rng, 7)
    if case == "exact":
        run = make_run(arm, rng, 4.0, 0.0)
        k = slice(None, None, 8)
        data = Trajectory(run.measured.t[k], run.q[k], run.v[k], run.tau_clean[k], run.a[k], coordinates=arm.ident.coordinates)
        method = "ols"
    else:
        run = make_run(arm, rng, 8.0, 0.02)
        data = run.measured
        method = "dm" if case == "noisy" else "logdet"
    problem = build_problem(arm.ident, data)
    if case != "exact":
        problem = problem.subset(slice(None, None, 2))
    p0 = arm.ident.base.parameters.p
    factor = 1 + rng.choice([-1, 1], 7) * rng.uniform(0.2, 0.3, 7)
    prior = arm.theta_true.copy()
    prior[:p0] = (arm.theta_true[:p0].reshape(7, 10) * factor[:, None]).ravel()
    out = {"seed": seed, "case": case, "method": method, "N": problem.N}
    try:
        if method == "logdet":  # the prior inside the fit (γ = 0.1 per equation); joint terms from OLS, floored
            ols = make_estimator("ols", allow_unidentifiable=True).fit(problem).theta
            prior[p0:] = np.maximum(ols[p0:], 1e-3 * ols[p0:].max())
            raw = make_estimator("logdet", theta0=prior, gamma=0.1, per_equation=True,
                                 allow_unidentifiable=True).fit(problem).theta
        else:
            raw = make_estimator(method, allow_unidentifiable=True).fit(problem).theta
    except DualidError as exc:
        return {**out, "error": f"fit: {exc}"}
    prior[p0:] = np.maximum(raw[p0:], 1e-3 * raw[p0:].max())
    t0 = time.perf_counter()
    try:
        p = plausible_parameters(problem, raw, prior)
    except DualidError as exc:
        return {**out, "error": f"plausible: {exc}"}
    masses = np.arange(0, p0, 10)
    by_prior = [int(i) for i in masses if p.determined_by[i] == PRIOR]
    dev = np.abs(p.theta[by_prior] / prior[by_prior] - 1)
    dev_raw = np.abs(raw[by_prior] / prior[by_prior] - 1)
    return {
        **out, "time_s": time.perf_counter() - t0, "objective": p.objective, "solver_chain": p.solver_chain,
        "prediction_change": p.prediction_change, "consistent": p.consistent,
        "masses_by_prior": len(by_prior), "within_30": int(np.sum(dev <= 0.3)),
        "max_dev_plausible": float(dev.max()) if by_prior else None,
        "max_dev_raw": float(dev_raw.max()) if by_prior else None,
        "mass_ratio_plausible": (p.theta[masses] / prior[masses]).round(3).tolist(),
        "mass_ratio_raw": (raw[masses] / prior[masses]).round(3).tolist(),
        "mass_ratio_true": (arm.theta_true[masses] / prior[masses]).round(3).tolist(),
        "max_dev_true": float(np.abs(arm.theta_true[by_prior] / prior[by_prior] - 1).max()) if by_prior else None,
        "prior_share": p.prior_share[masses].round(3).tolist(),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--out", default="benchmarks/plausible_arm.json")
    args = ap.parse_args()
    rows = []
    for case in ("exact", "noisy", "noisy-logdet"):
        for seed in range(args.seeds):
            rows.append(one(seed, case))
            r = rows[-1]
            print(case, seed, r.get("error") or f"{r['within_30']}/{r['masses_by_prior']} within 30 % "
                  f"(max {r['max_dev_plausible']:.2f}, raw {r['max_dev_raw']:.2f}) {r['solver_chain']}", flush=True)
    with open(args.out, "w") as f:
        json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
