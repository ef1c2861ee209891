"""Plausible parameters on simulated 7-DoF arms with a CAD-like prior (over seeds).

System: ``dualid.bench.arms.random_arm(rng, 7)`` (random axes and boxes, friction and armature). Prior:
every body's 10 parameters scaled by one factor 1 ± U(0.2, 0.3) (a density error: a CAD-like prior that
is consistent but wrong); joint terms from the fit, floored and rounded as ``dualid fit`` does
(``robot.prior.prior_theta``, ``evaluation.plausible_newton.rounded_prior``). Two data cases per seed:
- exact: 4 s at the commanded states, noise-free τ, every 8th sample (100 samples): the data fix the
  identifiable combinations exactly; the null space is all that is unknown;
- noisy: 8 s as logged (16-bit encoder, Savitzky–Golay v and a, 2 % torque noise), every 2nd sample,
  fitted by ``dm`` (the dual-metric GLS);
- noisy-logdet: the same noisy data fitted by ``logdet`` (WLS + γ·N·n·log-det divergence to the same
  prior, γ = 0.1): the prior already inside the fit.
Per seed and case, the fit θ̂ (OLS on exact data, dm on noisy), its sandwich covariance of the base
parameters (``dualid fit``'s blocks), then three choices: ``exact`` (``plausible_parameters``: θ̂'s training
predictions), ``conf95`` (``plausible_in_region``, level 0.95, every linear combination of β within its own
interval: radius² χ²₁; the default of ``dualid fit``) and ``joint68`` (level 0.68, the joint region χ²_r).
Reported per choice: the masses the prior determines (its own prior share ≥ 0.5), their largest |θ/θ₀ − 1|,
how many are within 30 % of the prior, the objective and solver chain, the training τ RMSE change and the
held-out τ RMSE change (an independent 8 s run of the same arm, as logged) relative to θ̂'s.

    PYTHONPATH=src python -W ignore benchmarks/plausible_arm.py --seeds 10 --out benchmarks/plausible_arm.json
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from dualid.report.outdir import check_output_files
from dualid.bench.arms import make_run, random_arm
from dualid.data.trajectory import Trajectory
from dualid.errors import DualidError
from dualid.estimators.methods import make_estimator
from dualid.evaluation.plausible import PRIOR
from dualid.evaluation.plausible_newton import rounded_prior, torque_weights
from dualid.evaluation.plausible_region import plausible_in_region, training_rmse
from dualid.evaluation.uncertainty import base_uncertainty
from dualid.problem import build_problem
from dualid.robot.uncertainty import training_blocks

CHOICES = {"exact": (0.0, False), "conf95": (0.95, False), "joint68": (0.68, True)}


def choice(problem, test, raw, prior, unc, arm, level, joint, p0) -> dict:
    t0 = time.perf_counter()
    try:
        p = plausible_in_region(problem, raw, rounded_prior(problem.parameters, prior), unc, level, joint)  # as dualid fit
    except DualidError as exc:
        return {"error": f"plausible: {exc}"}
    masses = np.arange(0, p0, 10)
    by_prior = [int(i) for i in masses if p.determined_by[i] == PRIOR]
    dev = np.abs(p.theta[by_prior] / prior[by_prior] - 1)
    dev_raw = np.abs(raw[by_prior] / prior[by_prior] - 1)
    test_raw = training_rmse(test, raw)
    return {
        "time_s": time.perf_counter() - t0, "objective": p.objective, "solver_chain": p.solver_chain,
        "prediction_change": p.prediction_change, "consistent": p.consistent, "statistic": p.statistic,
        "radius2": p.radius2, "masses_by_prior": len(by_prior), "within_30": int(np.sum(dev <= 0.3)),
        "max_dev_plausible": float(dev.max()) if by_prior else None,
        "max_dev_raw": float(dev_raw.max()) if by_prior else None,
        "max_dev_true": float(np.abs(arm.theta_true[by_prior] / prior[by_prior] - 1).max()) if by_prior else None,
        "within_30_true": int(np.sum(np.abs(arm.theta_true[by_prior] / prior[by_prior] - 1) <= 0.3)),
        "training_rmse_change": p.training_rmse / p.training_rmse_hat - 1 if p.training_rmse_hat > 0 else 0.0,
        "heldout_rmse_raw": test_raw, "heldout_rmse_true": training_rmse(test, arm.theta_true),
        "heldout_rmse_change": training_rmse(test, p.theta) / test_raw - 1,
        "mass_ratio_plausible": (p.theta[masses] / prior[masses]).round(3).tolist(),
        "prior_share": p.prior_share[masses].round(3).tolist(),
    }


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
    test = build_problem(arm.ident, make_run(arm, np.random.default_rng(1000 + seed), 8.0, 0.02).measured)
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
            est = make_estimator("logdet", theta0=prior.copy(), gamma=0.1, per_equation=True, allow_unidentifiable=True)
        else:
            est = make_estimator(method, allow_unidentifiable=True)
        result = est.fit(problem)
        raw = result.theta
        base = problem.identifiability().base
        unc = base_uncertainty(problem, result, est, base, blocks=training_blocks([problem.N], base.rank))
    except DualidError as exc:
        return {**out, "error": f"fit: {exc}"}
    prior[p0:] = np.maximum(raw[p0:], 1e-3 / np.sqrt(torque_weights(problem)[p0:]))  # as dualid fit (robot.prior)
    out["mass_ratio_raw"] = (raw[np.arange(0, p0, 10)] / prior[np.arange(0, p0, 10)]).round(3).tolist()
    out["mass_ratio_true"] = (arm.theta_true[np.arange(0, p0, 10)] / prior[np.arange(0, p0, 10)]).round(3).tolist()
    for name, (level, joint) in CHOICES.items():
        out[name] = choice(problem, test, raw, prior, unc, arm, level, joint, p0)
    return out


def table(rows: list[dict]) -> str:
    """The Markdown table of benchmarks/plausible_arm.md."""
    head = ("| case | fit | choice | seeds ok | masses by prior | within 30 % | truth within 30 % | max dev median [max] "
            "| training RMSE change median [max] | held-out RMSE change median [min, max] | logdet/pullback |")
    lines = [head, "|" + " --- |" * (head.count("|") - 1)]
    for case in dict.fromkeys(r["case"] for r in rows):
        rs = [r for r in rows if r["case"] == case]
        for name in CHOICES:
            ok = [r[name] for r in rs if "error" not in r and "error" not in r[name]]
            if not ok:
                lines.append(f"| {case} | {rs[0]['method']} | {name} | 0/{len(rs)} | | | | | | | |")
                continue
            dev = [c["max_dev_plausible"] for c in ok if c["max_dev_plausible"] is not None]
            tr = [c["training_rmse_change"] for c in ok]
            ho = [c["heldout_rmse_change"] for c in ok]
            lines.append(
                f"| {case} | {rs[0]['method']} | {name} | {len(ok)}/{len(rs)} | {sum(c['masses_by_prior'] for c in ok)} "
                f"| {sum(c['within_30'] for c in ok)} | {sum(c['within_30_true'] for c in ok)} "
                f"| {np.median(dev):.2f} [{max(dev):.2f}] | {100 * np.median(tr):+.2f} % [{100 * max(tr):+.2f} %] "
                f"| {100 * np.median(ho):+.2f} % [{100 * min(ho):+.2f} %, {100 * max(ho):+.2f} %] "
                f"| {sum(c['objective'] == 'logdet' for c in ok)}/{sum(c['objective'] == 'pullback' for c in ok)} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--out", default="benchmarks/plausible_arm.json")
    ap.add_argument("--force", action="store_true", help="replace existing output files")
    args = ap.parse_args()
    # before the work: an existing result is not replaced without --force
    check_output_files([args.out], args.force, ap)
    rows = []
    for case in ("exact", "noisy", "noisy-logdet"):
        for seed in range(args.seeds):
            rows.append(one(seed, case))
            r = rows[-1]
            for name in CHOICES:
                c = r.get(name, r)
                print(case, seed, name, c.get("error") or f"{c['within_30']}/{c['masses_by_prior']} within 30 % "
                      f"(max {c['max_dev_plausible'] or 0:.2f}, raw {c['max_dev_raw'] or 0:.2f}) held-out "
                      f"{100 * c['heldout_rmse_change']:+.2f} % {c['solver_chain']}", flush=True)
    with open(args.out, "w") as f:
        json.dump(rows, f, indent=1)
    print(table(rows))


if __name__ == "__main__":
    main()
