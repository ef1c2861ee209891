"""Crazyflie–pendulum: does the chart-invariant margin C_b(θ) ⪰ ε·C_b(θ_WLS) remove the massless-pendulum ghosts?

For each data-set seed and each ε (none, 0.01, 0.1): the study's high- and low-data fits (paper.study.run_study,
margin against a constrained WLS pilot on each training set) of every constrained method. Per fit: the metric
guard against the truth (min / max generalised eigenvalue of M_i(θ̂) against M_i(θ_true) over the training
samples; a ghost is min λ < 1e-2), the α1/α2 forward-dynamics score (NCC on the test runs) and the held-out
torque error (rms of Y θ̂ − τ on the 6 test runs per coordinate; the clean-torque error rms Y(θ̂ − θ_true) over
the noise floor rms(Y θ_true − τ), averaged over the coordinates). Prints a markdown table and
writes JSON.

    PYTHONPATH=src python benchmarks/margin_crazyflie.py --data-seeds 0 1 2 3 4 --low-seeds 5 \
        --out benchmarks/margin_crazyflie.json > benchmarks/margin_crazyflie.md
    PYTHONPATH=src python benchmarks/margin_crazyflie.py --swing-scale 0.3 ...   # the first simulator's ghost regime
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from dualid.report.outdir import check_output_files
from dualid.estimators.methods import make_estimator
from dualid.metric_guard import generalized_eigenvalues
from dualid.paper.study import run_study
from dualid.problem import build_problem
from dualid.systems.crazyflie import make


def barely_swinging(swing_scale: float):
    """The ghost regime of the first simulator (docs/results.md): the pendulum-exciting reference components
    scaled by swing_scale and instantaneous motors (motor_lag 0); returns a make(seed) for that regime."""
    import dataclasses

    import dualid.systems.crazyflie as cf
    from dualid.systems import crazyflie_control

    original = crazyflie_control.random_reference

    def reference(rng, B):
        ref = original(rng, B)
        amplitude = ref.amplitude.copy()
        amplitude[:, 4:] *= swing_scale  # the two short components that keep the pendulum swinging
        return dataclasses.replace(ref, amplitude=amplitude)

    cf.random_reference = reference
    noise = dataclasses.replace(cf.noise_preset("realistic"), motor_lag=0.0)
    return lambda seed, size: make(seed=seed, noise=noise, size=size)


KEYS = ("ols", "wls", "energy", "logdet", "pullback", "dm-paper", "dm")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--data-seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--low-seeds", type=int, default=5)
    ap.add_argument("--eps", type=float, nargs="+", default=[0.01, 0.1])
    ap.add_argument("--methods", nargs="+", default=list(KEYS))
    ap.add_argument("--size", default="default")
    ap.add_argument("--out", default=None)
    ap.add_argument("--swing-scale", type=float, default=None,
                    help="the first simulator's ghost regime: pendulum excitation × this, instantaneous motors")
    ap.add_argument("--force", action="store_true", help="replace existing output files")
    args = ap.parse_args()
    # before the work: an existing result is not replaced without --force
    check_output_files([args.out] if args.out else [], args.force, ap)
    system_of = (lambda seed, size: make(seed=seed, size=size)) if args.swing_scale is None else \
        barely_swinging(args.swing_scale)
    rows = []
    for ds in args.data_seeds:
        t0 = time.time()
        system = system_of(ds, args.size)
        print(system.description, flush=True)
        methods = {k: make_estimator(k, theta0=system.theta_nominal, gamma=system.gamma, allow_unidentifiable=True)
                   for k in args.methods}
        train = build_problem(system.model, list(system.train))
        test = build_problem(system.model, list(system.test))
        floor = np.sqrt(np.mean(test.residual(system.theta_true) ** 2, axis=0))
        rows.append({"data_seed": ds, "eps": None, "case": "truth", "method": "truth", "ok": True,
                     "rms": floor.tolist()})
        for eps in [None, *args.eps]:
            res = run_study(system, case="both", seeds=args.low_seeds, methods=methods, margin=eps)
            alpha = [res.coordinates.index(c) for c in system.shape_coordinates]
            for r in res.records:
                row = {"data_seed": ds, "eps": eps, "case": r.case, "method": r.method, "seed": r.seed, "ok": r.ok}
                if r.ok:
                    th = np.array(r.theta)
                    lam = generalized_eigenvalues(train, th, system.theta_true)
                    row["ratio_truth"] = (float(lam[:, 0].min()), float(lam[:, -1].max()))
                    row["score_alpha"] = r.scores[:, alpha].mean(0).tolist()
                    rms = np.sqrt(np.mean(test.residual(th) ** 2, axis=0))
                    row["rms"] = rms.tolist()  # held-out torque residual per coordinate [N or N m]
                    clean = np.sqrt(np.mean((test.Y @ (th - system.theta_true)) ** 2, axis=0))
                    row["clean_over_floor"] = (clean / floor).tolist()  # clean-torque error / noise floor
                    row["margin_active"] = r.info.get("margin_active", "")
                    row["margin_min_ratio"] = r.info.get("margin_min_ratio")
                else:
                    row["error"] = r.error
                rows.append(row)
        print(f"data seed {ds}: {time.time() - t0:.0f} s", flush=True)
        alpha_names = list(system.shape_coordinates)
        coords = list(res.coordinates)
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"coordinates": coords, "shape_coordinates": alpha_names, "rows": rows}, f, indent=1)
    print(table(rows, [coords.index(c) for c in alpha_names]))


def table(rows, alpha):
    out = ["| case | method | ε | fits ok | ghosts (min λ vs truth < 1e-2) | min λ vs truth (median) | α1 NCC | "
           "α2 NCC | held-out rms residual α1, α2 [mN m] | held-out clean-torque error / floor (mean over coords) | margin active (fits) |",
           "|" + "---|" * 11]
    keys = sorted({(r["case"], r["method"], r["eps"] or 0.0) for r in rows})
    for case, m, eps in keys:
        rs = [r for r in rows if (r["case"], r["method"], r["eps"] or 0.0) == (case, m, eps)]
        ok = [r for r in rs if r["ok"]]
        if m == "truth":
            e = np.array([r["rms"] for r in ok])
            out.append(f"| truth | truth θ (noise floor) | – | | | | | | {1e3 * e[:, alpha[0]].mean():.3f}, "
                       f"{1e3 * e[:, alpha[1]].mean():.3f} | 0 | |")
            continue
        if not ok:
            out.append(f"| {case} | {m} | {eps:g} | 0/{len(rs)} | | | | | | | |")
            continue
        a = np.array([r["score_alpha"] for r in ok])
        lo = np.array([r["ratio_truth"][0] for r in ok])
        e = np.array([r["rms"] for r in ok])
        ghosts = int(np.sum(lo < 1e-2))
        active = sum(1 for r in ok if r.get("margin_active"))
        out.append(
            f"| {case} | {m} | {eps:g} | {len(ok)}/{len(rs)} | {ghosts} | {np.median(lo):.2e} | "
            f"{a[:, 0].mean():.3f} ± {a[:, 0].std():.3f} | {a[:, 1].mean():.3f} ± {a[:, 1].std():.3f} | "
            f"{1e3 * e[:, alpha[0]].mean():.3f}, {1e3 * e[:, alpha[1]].mean():.3f} | "
            f"{np.mean([r['clean_over_floor'] for r in ok]):.3f} | "
            f"{active if eps else '–'} |"
        )
    return "\n".join(out)


if __name__ == "__main__":
    main()
