"""Excitation benchmark: optimised Fourier trajectories against the best of 20 random ones.

    python benchmarks/excitation.py --out benchmarks/excitation            # the committed run
    python benchmarks/excitation.py --out /tmp/excitation --quick          # a smoke run (1 seed, small)

Robots: the 7-DoF arm of the statistical benchmark (``dualid.bench.arms.random_arm`` seed 0: the design
and the fits use its CAD-like identification model, the data its true inertias, friction and armature)
and the DFKI pendulum's URDF (truth: its URDF inertials plus viscous 0.05/0.03 N m s/rad, Coulomb
0.10/0.08 N m and armature 0.002/0.001 kg m²). Limits: arm ±2 rad, 2 rad/s, 8 rad/s², effort 0.7 × the
largest |τ| over random states; DFKI ±π / ±2.5 rad, 8 rad/s, 30 rad/s², 5 N m on both joints (the URDF
says 6 and 0: its second joint is passive, the rig has two motors). Period 10 s, 5 harmonics.

Per seed: each criterion (dm, logdet, cond) is optimised (SLSQP, ``--restarts`` starts); 20 random
series of the same period, harmonics and limits (each scaled to the largest amplitude that keeps every
limit at 1 kHz) give the baseline, the best by column-scaled condition number. Every limit is checked at
1 kHz. Simulated identification on each trajectory (one period at 200 Hz, exact q, v, a; τ of the true
robot plus Gaussian noise σ_j = 1 % of joint j's effort limit; ``--draws`` noise draws) with OLS, WLS and
dm (allow_unidentifiable): the held-out torque NRMSE (clean true torque on a common random trajectory,
``dualid.bench.arms.torque_nrmse``) and the Monte-Carlo standard deviation of each base parameter β̂.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from dualid.report.outdir import check_output_files
from dualid.bench.arms import aggregate, random_arm, torque_nrmse
from dualid.data.trajectory import Trajectory
from dualid.errors import DualidError
from dualid.estimators.methods import make_estimator
from dualid.excite import ExciteConfig, build_design, check_limits, optimize, random_trajectory
from dualid.excite.design import random_states
from dualid.excite.predict import base_condition
from dualid.model.rigid_body import RigidBodyModel
from dualid.problem import build_problem

ROOT = Path(__file__).resolve().parents[1]
DFKI_URDF = ROOT / "examples" / "dfki" / "data" / "pendubot_model_2.1.urdf"
CRITERIA = ("dm", "logdet", "cond")
METHODS = ("ols", "wls", "dm")
RANDOM = 20
RATE = 200.0


def arm_setup(common: dict):
    arm = random_arm(np.random.default_rng(0), 7)
    rigid = arm.ident.base  # CAD-like inertias: what the user has
    names = rigid.coordinates
    limits = {j: {"lower": -2.0, "upper": 2.0, "velocity": 2.0, "acceleration": 8.0} for j in names}
    cfg = ExciteConfig.from_dict({**common, "limits": limits})
    probe = build_design(rigid, cfg.with_overrides(joint_terms=None))
    q, v, a = random_states(np.random.default_rng(1), probe.limits, probe.q_start, 2000)
    effort = 0.7 * np.abs(probe.torque(q, v, a)).max(axis=0)
    cfg = ExciteConfig.from_dict({**common, "limits": {j: {**limits[j], "effort": float(effort[k])}
                                                       for k, j in enumerate(names)}})

    def true_torque(q, v, a):
        return arm.torque(q, v, a)

    return rigid, cfg, arm.theta_true, true_torque


def dfki_setup(common: dict):
    rigid = RigidBodyModel.from_urdf(DFKI_URDF)
    lim = {"Joint1": {"velocity": 8, "effort": 5}, "Joint2": {"velocity": 8, "effort": 5, "lower": -2.5, "upper": 2.5}}
    cfg = ExciteConfig.from_dict({**common, "acceleration": 30, "limits": lim})
    b, fc, Ia = np.array([0.05, 0.03]), np.array([0.10, 0.08]), np.array([0.002, 0.001])
    theta_true = np.concatenate([rigid.nominal, b, fc, Ia])
    data = rigid.model.createData()

    def true_torque(q, v, a):
        import pinocchio as pin

        tau = np.stack([pin.rnea(rigid.model, data, q[t], v[t], a[t]) for t in range(q.shape[0])])
        return tau + b * v + fc * np.tanh(v / 0.01) + Ia * a

    return rigid, cfg, theta_true, true_torque


def conds(design, traj) -> dict:
    q, v, a = traj.evaluate(traj.times(RATE))
    scaled, raw = base_condition(design.base.regressor(design.regressor(q, v, a)))
    return {"cond": scaled, "cond_raw": raw, **{f"criterion_{c}": design.criterion(c, q, v, a) for c in CRITERIA}}


def identify(design, traj, theta_true, true_torque, sigma, rng, draws, held_out) -> dict:
    """Per method: held-out NRMSE (mean over draws) and the std of each base parameter over draws."""
    t = traj.times(RATE)
    q, v, a = traj.evaluate(t)
    tau_clean = true_torque(q, v, a)
    hq, hv, ha = held_out
    Yh = design.regressor(hq, hv, ha)
    tau_h = true_torque(hq, hv, ha)
    out = {m: {"nrmse": [], "beta": [], "failed": 0} for m in METHODS}
    for _ in range(draws):
        tau = tau_clean + sigma * rng.normal(size=tau_clean.shape)
        problem = build_problem(design.model, Trajectory(t, q, v, tau, a, design.joints))
        for m in METHODS:
            try:
                theta = make_estimator(m, allow_unidentifiable=True).fit(problem).theta
            except (DualidError, ValueError, np.linalg.LinAlgError) as exc:  # counted, not dropped
                out[m]["failed"] += 1
                out[m].setdefault("errors", []).append(f"{type(exc).__name__}: {exc}"[:200])
                continue
            out[m]["nrmse"].append(aggregate(torque_nrmse(Yh, theta, tau_h)))
            out[m]["beta"].append(design.base.values(theta))
    beta_true = design.base.values(theta_true)
    res = {}
    for m, r in out.items():
        B = np.array(r["beta"])
        res[m] = {"nrmse": float(np.mean(r["nrmse"])) if r["nrmse"] else None,
                  "beta_std": B.std(axis=0, ddof=1).tolist() if len(B) > 1 else None,
                  "beta_rmse": np.sqrt(np.mean((B - beta_true) ** 2, axis=0)).tolist() if len(B) else None,
                  "failed": r["failed"], "errors": r.get("errors", [])}
    return res


def run_robot(name, setup, seeds, restarts, maxiter, draws, common, log) -> dict:
    rigid, cfg, theta_true, true_torque = setup(common)
    design = build_design(rigid, cfg)
    sigma = 0.01 * design.limits.effort
    rows = []
    for seed in seeds:
        rng = np.random.default_rng(1000 + seed)
        held_out = random_trajectory(design, cfg, np.random.default_rng(999)).evaluate(
            np.arange(0, cfg.period, 1 / RATE))
        randoms = [random_trajectory(design, cfg, rng) for _ in range(RANDOM)]
        rc = [conds(design, r) for r in randoms]
        best = int(np.argmin([c["cond"] for c in rc]))
        trajs = {"random": (randoms[best], rc[best], check_limits(design, randoms[best], 1000.0), 0.0, None)}
        for crit in CRITERIA:
            t0 = time.perf_counter()
            res = optimize(design, cfg.with_overrides(criterion=crit, seed=seed, restarts=restarts, maxiter=maxiter))
            dt = time.perf_counter() - t0
            trajs[crit] = (res.trajectory, conds(design, res.trajectory), check_limits(design, res.trajectory, 1000.0), dt,
                           [{"status": r.status, "iterations": r.iterations, "value": r.value, "scale": r.scale}
                            for r in res.restarts])
            log(f"{name} seed {seed} {crit}: cond {trajs[crit][1]['cond']:.4g} (best random {rc[best]['cond']:.4g}), "
                f"{dt:.0f} s")
        for label, (traj, c, check, dt, restarts_info) in trajs.items():
            ident = identify(design, traj, theta_true, true_torque, sigma, np.random.default_rng(seed), draws, held_out)
            rows.append({"robot": name, "seed": seed, "trajectory": label, **c, "limits_1khz": check.worst,
                         "limits_ok": check.ok, "optimise_s": dt, "restarts": restarts_info, "identification": ident,
                         "random_conds": [x["cond"] for x in rc] if label == "random" else None})
            log(f"  {label}: " + ", ".join(f"{m} nrmse {ident[m]['nrmse']}" for m in METHODS))
    return {"robot": name, "n": design.n, "p": design.model.parameters.p, "base": list(design.base.names),
            "limits": {k: getattr(design.limits, k).tolist() for k in ("lower", "upper", "velocity", "acceleration",
                                                                          "effort")},
            "sigma": sigma.tolist(), "rows": rows}


def _geo(x) -> float:
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x) & (x > 0)]
    return float(np.exp(np.mean(np.log(x)))) if x.size else float("nan")


def to_markdown(result: dict) -> str:
    lines = ["# Excitation benchmark", "", f"Command: `{result['command']}`", "",
             f"Settings: {json.dumps(result['settings'])}. Times measured on a loaded 2-core machine.", ""]
    for robot in result["robots"]:
        rows = robot["rows"]
        seeds = sorted({r["seed"] for r in rows})
        lines += [f"## {robot['robot']} (n = {robot['n']}, p = {robot['p']}, {len(robot['base'])} base parameters)", "",
                  "Condition number of the base regressor (columns scaled to unit norm; raw in brackets), "
                  "the ratio best-random / optimised, and the worst |value|/limit at 1 kHz:", "",
                  "| seed | trajectory | cond | ratio random/this | limits at 1 kHz (worst ratio) | optimise [s] |",
                  "|---|---|---|---|---|---|"]
        for s in seeds:
            rnd = next(r for r in rows if r["seed"] == s and r["trajectory"] == "random")
            for r in (x for x in rows if x["seed"] == s):
                worst = max(r["limits_1khz"].values())
                lines.append(f"| {s} | {r['trajectory']} | {r['cond']:.3g} ({r['cond_raw']:.3g}) | "
                             f"{rnd['cond'] / r['cond']:.2f} | {worst:.4f} {'ok' if r['limits_ok'] else 'VIOLATED'} | "
                             f"{r['optimise_s']:.0f} |")
        lines += ["", "Simulated identification (mean over seeds): held-out torque NRMSE, and the geometric mean "
                  "over base parameters of std(β̂)/std(β̂ on the best random trajectory) (< 1: tighter than random); "
                  "failed fits counted:", "",
                  "| trajectory | " + " | ".join(f"{m} NRMSE | {m} std ratio" for m in METHODS) + " | failed fits |",
                  "|---|" + "---|---|" * len(METHODS) + "---|"]
        for label in ["random", *CRITERIA]:
            cells = []
            failed = 0
            for m in METHODS:
                nr, ratios = [], []
                for s in seeds:
                    r = next(x for x in rows if x["seed"] == s and x["trajectory"] == label)
                    rnd = next(x for x in rows if x["seed"] == s and x["trajectory"] == "random")
                    ident = r["identification"][m]
                    failed += ident["failed"]
                    if ident["nrmse"] is not None:
                        nr.append(ident["nrmse"])
                    if ident["beta_std"] is not None and rnd["identification"][m]["beta_std"] is not None:
                        ratios.append(_geo(np.array(ident["beta_std"]) / np.array(rnd["identification"][m]["beta_std"])))
                cells += [f"{np.mean(nr):.4f}" if nr else "—", f"{_geo(ratios):.3f}" if ratios else "—"]
            lines.append(f"| {label} | " + " | ".join(cells) + f" | {failed} |")
        lines.append("")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "excitation")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--restarts", type=int, default=2)
    ap.add_argument("--maxiter", type=int, default=100)
    ap.add_argument("--draws", type=int, default=4)
    ap.add_argument("--robots", default="arm7,dfki")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--force", action="store_true", help="replace existing output files")
    args = ap.parse_args(argv)
    # before the work: an existing result is not replaced without --force
    check_output_files([args.out / "results.json", args.out / "results.md"], args.force, ap)
    if args.quick:
        args.seeds, args.restarts, args.maxiter, args.draws = 1, 1, 20, 2
    common = {"period": 10.0, "harmonics": 5, "grid": 100}
    setups = {"arm7": arm_setup, "dfki": dfki_setup}
    log = lambda msg: print(msg, file=sys.stderr, flush=True)  # noqa: E731
    robots = [run_robot(name, setups[name], range(args.seeds), args.restarts, args.maxiter, args.draws, common, log)
              for name in args.robots.split(",")]
    result = {"command": "python benchmarks/excitation.py " + " ".join(argv if argv is not None else sys.argv[1:]),
              "settings": {**common, "seeds": args.seeds, "restarts": args.restarts, "maxiter": args.maxiter,
                           "draws": args.draws, "random": RANDOM, "rate": RATE, "methods": METHODS},
              "robots": robots}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.json").write_text(json.dumps(result, indent=1, default=float) + "\n")
    (args.out / "results.md").write_text(to_markdown(result))
    print(to_markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
