"""Crazyflie–pendulum: does modelling the base's linear drag remove the dual-metric ghost fit?

For each data-set seed: the study's high-data and low-data fits (reproduce.run_study) of
WLS, the paper's DM (``dm-paper``) and ``dm`` (estimators/noise_dm.py), with the
plain rigid-body model and with ``with_base_drag`` (3 parameters d ≥ 0 on vx, vy, vz). Every fit
carries the metric guard (metric_guard.py) against the truth and against the high-data WLS
fit of the same model. Prints a markdown table and writes JSON.

    PYTHONPATH=src python benchmarks/crazyflie_base_drag.py --data-seeds 0 1 2 3 4 --low-seeds 5 \
        --swing-scale 0.3 --out benchmarks/crazyflie_base_drag.json --force   # the ghost regime (docs/results.md)
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

import numpy as np

from dualid.report.outdir import check_output_files
from dualid.estimators.dual_metric import DualMetric
from dualid.estimators.least_squares import WLS
from dualid.estimators.noise_dm import NoiseModelDM
from dualid.metric_guard import generalized_eigenvalues
from dualid.model.extra_terms import with_base_drag
from dualid.paper.study import run_study
from dualid.problem import build_problem
from dualid.systems.crazyflie import CrazyflieNoise, make

METHODS = {
    "wls": WLS(allow_unidentifiable=True),
    "dm-paper": DualMetric(allow_unidentifiable=True),
    "dm": NoiseModelDM(allow_unidentifiable=True),
}


def with_drag(system):
    """The same data set with the base-drag identification model (as make(..., base_drag=True) builds it)."""
    from dualid.systems.crazyflie import NOMINAL_DRAG

    model = with_base_drag(system.model)
    drag = np.array(CrazyflieNoise().drag)
    return dataclasses.replace(
        system, model=model,
        theta_true=np.concatenate([system.theta_true, drag]),
        theta_nominal=np.concatenate([system.theta_nominal, NOMINAL_DRAG]),
    )


def ratios(problem, theta, theta_ref):
    lam = generalized_eigenvalues(problem, theta, theta_ref)
    return float(lam[:, 0].min()), float(lam[:, -1].max())


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--data-seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--low-seeds", type=int, default=5)
    ap.add_argument("--size", default="default")
    ap.add_argument("--swing-scale", type=float, default=None,
                    help="the first simulator's ghost regime (margin_crazyflie.barely_swinging): the pendulum-exciting "
                    "reference components × this, instantaneous motors")
    ap.add_argument("--out", default=None)
    ap.add_argument("--force", action="store_true", help="replace existing output files")
    args = ap.parse_args()
    # before the work: an existing result is not replaced without --force
    check_output_files([args.out] if args.out else [], args.force, ap)
    if args.swing_scale is None:
        system_of = lambda seed, size: make(seed=seed, size=size)  # noqa: E731
    else:
        import os
        import sys
        sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
        from margin_crazyflie import barely_swinging

        system_of = barely_swinging(args.swing_scale)
    rows = []
    for ds in args.data_seeds:
        t0 = time.time()
        base = system_of(ds, args.size)
        for variant, system in (("rigid", base), ("rigid+drag", with_drag(base))):
            res = run_study(system, case="both", seeds=args.low_seeds, methods=METHODS)
            problem = build_problem(system.model, list(system.train))
            wls_high = next(r for r in res.records if r.case == "high" and r.method == "wls")
            alpha = [res.coordinates.index(c) for c in system.shape_coordinates]
            for r in res.records:
                row = {"data_seed": ds, "variant": variant, "case": r.case, "method": r.method, "seed": r.seed,
                       "ok": r.ok}
                if r.ok:
                    th = np.array(r.theta)
                    row["ratio_truth"] = ratios(problem, th, system.theta_true)
                    row["ratio_wls"] = ratios(problem, th, np.array(wls_high.theta)) if wls_high.ok else None
                    row["score_alpha"] = r.scores[:, alpha].mean(0).tolist()
                    row["score_all"] = r.scores.mean(0).tolist()
                else:
                    row["error"] = r.error
                rows.append(row)
            truth = res.truth
            rows.append({"data_seed": ds, "variant": variant, "case": "truth", "method": "truth", "ok": True,
                         "score_alpha": truth.score_mean[alpha].tolist(), "ratio_truth": (1.0, 1.0)})
        print(f"data seed {ds}: {time.time() - t0:.0f} s", flush=True)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(rows, f, indent=1)
    print(table(rows))


def table(rows):
    out = ["| variant | case | method | fits ok | α1 NCC | α2 NCC | min λ vs truth (median, worst) | "
           "max λ vs truth (worst) | flagged (c=100, vs truth) |", "|" + "---|" * 9]
    keys = sorted({(r["variant"], r["case"], r["method"]) for r in rows}, key=lambda k: (k[0], k[1] != "truth", k[1], k[2]))
    for key in keys:
        rs = [r for r in rows if (r["variant"], r["case"], r["method"]) == key]
        ok = [r for r in rs if r["ok"]]
        if not ok:
            out.append(f"| {key[0]} | {key[1]} | {key[2]} | 0/{len(rs)} | | | | | |")
            continue
        a = np.array([r["score_alpha"] for r in ok])
        lo = np.array([r["ratio_truth"][0] for r in ok])
        hi = np.array([r["ratio_truth"][1] for r in ok])
        flagged = int(np.sum((lo < 1e-2) | (hi > 1e2)))
        out.append(
            f"| {key[0]} | {key[1]} | {key[2]} | {len(ok)}/{len(rs)} | {a[:, 0].mean():.3f} ± {a[:, 0].std():.3f} | "
            f"{a[:, 1].mean():.3f} ± {a[:, 1].std():.3f} | {np.median(lo):.2e}, {lo.min():.2e} | {hi.max():.2e} | "
            f"{flagged}/{len(ok)} |"
        )
    return "\n".join(out)


if __name__ == "__main__":
    main()
