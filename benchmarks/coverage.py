"""Coverage of the 95 % intervals of the base parameters: do they contain the truth 95 % of the time?

A random 3-joint arm of dualid.bench.arms (true viscous/Coulomb friction and armature; the identification
model has the same terms, so Y θ_true is the noise-free torque exactly). One excitation (fixed design, exact
q, v, a: the intervals are about torque noise, not about differentiation), and in each repetition a new draw
of the torque noise. Each method is fitted (physically consistent, allow_unidentifiable) and the intervals of
dualid.evaluation.uncertainty are checked against the true base parameters β = C θ_true.

Cases:
- white: Gaussian noise, σ_j = NOISE × rms(τ_j), independent samples; sandwich with one sample per block,
  for ols/wls also the textbook form (kind="model"), and for ols the intervals projected on the active
  constraints (constraints="project", conditional; the default ignores them);
- white, ols_unconstrained: the sandwich without constraints (is it calibrated, rms z ≈ 1?);
- white, bootstrap (--bootstrap R): block bootstrap of ols over 50 contiguous segments, percentile intervals;
- ar1: the same noise filtered by an AR(1) with ρ = 0.9 (correlated over ~10–20 samples, as after low-pass
  filtering); sandwich with one sample per block (expected to under-cover) and with 50 contiguous blocks.

    python benchmarks/coverage.py --bootstrap 50       # 100 repetitions, writes benchmarks/coverage/results.{md,json}
    python benchmarks/coverage.py --reps 10 --out /tmp/cov   # smoke run

Coverage per method: the fraction of (repetition, base parameter) pairs whose interval holds the truth, its
spread over the base parameters (min–max of the per-parameter coverage), and rms of z = (β̂ − β)/se (1 when
the standard errors are right and the estimate unbiased). Failed fits are counted, not dropped.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import sys
import time
import traceback
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from dualid.report.outdir import check_output_files  # noqa: E402
from dualid.report.metadata import git_commit  # noqa: E402
from dualid.bench import arms  # noqa: E402
from dualid.data.trajectory import Trajectory  # noqa: E402
from dualid.estimators.methods import make_estimator  # noqa: E402
from dualid.evaluation.uncertainty import base_uncertainty, bootstrap  # noqa: E402
from dualid.problem import build_problem  # noqa: E402

NOISE = 0.05
RHO = 0.9
AR_BLOCKS = 50
# (case, method, uncertainty kind, blocks) rows of the table
ROWS = (
    ("white", "ols", "sandwich", None), ("white", "ols", "model", None),
    ("white", "wls", "sandwich", None), ("white", "wls", "model", None),
    ("white", "ols", "sandwich, projected", None), ("white", "ols_unconstrained", "sandwich", None),
    ("white", "ols", "bootstrap", AR_BLOCKS),
    ("white", "dm", "sandwich", None), ("white", "dm-paper", "sandwich", None),
    ("ar1", "ols", "sandwich", None), ("ar1", "ols", "sandwich", AR_BLOCKS),
    ("ar1", "dm", "sandwich", None), ("ar1", "dm", "sandwich", AR_BLOCKS),
)


def setup(seed: int, seconds: float):
    rng = np.random.default_rng(seed)
    arm = arms.random_arm(rng, 3)
    t, q, v, a = arms.excitation(rng, arm.n, seconds)
    tau = arm.torque(q, v, a)
    traj = Trajectory(t=t, q=q, v=v, a=a, tau=tau, coordinates=arm.ident.coordinates)
    problem = build_problem(arm.ident, traj)
    gap = np.max(np.abs(problem.Y @ arm.theta_true - tau)) / np.max(np.abs(tau))
    assert gap < 1e-9, f"the identification model does not reproduce the true torque ({gap:.2g})"
    return arm, problem


def noise(rng: np.random.Generator, sigma: np.ndarray, N: int, case: str) -> np.ndarray:
    e = rng.normal(size=(N, sigma.size))
    if case == "ar1":
        for i in range(1, N):
            e[i] = RHO * e[i - 1] + np.sqrt(1 - RHO**2) * e[i]
    return e * sigma


def run(reps: int, seed: int, seconds: float, methods: tuple[str, ...], resamples: int = 0) -> dict:
    arm, problem = setup(seed, seconds)
    base = problem.identifiability().base
    beta_true = base.values(arm.theta_true)
    tau0 = problem.tau
    sigma = NOISE * np.sqrt(np.mean(tau0**2, axis=0))
    rows = [r for r in ROWS if r[1] in methods and (resamples or r[2] != "bootstrap")]
    stats = {r: {"hits": np.zeros(base.rank), "z2": [], "ok": 0, "failures": 0, "errors": [], "time": 0.0}
             for r in rows}
    rng = np.random.default_rng(seed + 1000)
    for rep in range(reps):
        draws = {case: noise(rng, sigma, problem.N, case) for case in ("white", "ar1")}
        fits = {}
        for row in rows:
            case, method, kind, blocks = row
            st = stats[row]
            t0 = time.perf_counter()
            try:
                key = (case, method)
                if key not in fits:
                    prob = dataclasses.replace(problem, tau=tau0 + draws[case])
                    est = make_estimator(method, allow_unidentifiable=True)
                    fits[key] = (prob, est, est.fit(prob))
                prob, est, result = fits[key]
                projected = kind.endswith("projected")
                if kind == "bootstrap":
                    u = bootstrap(prob, result, est, base, blocks=blocks, resamples=resamples, seed=rep)
                else:
                    u = base_uncertainty(prob, result, est, base, blocks=blocks, kind=kind.split(",")[0],
                                         constraints="project" if projected else "ignore")
            except Exception as exc:  # a benchmark counts failures of any kind
                st["failures"] += 1
                st["errors"].append(f"rep {rep}: {type(exc).__name__}: {str(exc)[:200]}")
                if len(st["errors"]) == 1:
                    traceback.print_exc()
                continue
            finally:
                st["time"] += time.perf_counter() - t0
            st["ok"] += 1
            st["hits"] += (u.lower <= beta_true) & (beta_true <= u.upper)
            st["z2"].append(((u.values - beta_true) / np.where(u.std_error > 0, u.std_error, np.inf)) ** 2)
        if (rep + 1) % 10 == 0:
            print(f"{rep + 1}/{reps} repetitions", flush=True)
    out = []
    for row, st in stats.items():
        case, method, kind, blocks = row
        per = st["hits"] / max(st["ok"], 1)
        z2 = np.array(st["z2"]) if st["z2"] else np.full((1, base.rank), np.nan)
        out.append({
            "case": case, "method": method, "kind": kind, "blocks": "per sample" if blocks is None else blocks,
            "fits": st["ok"], "failures": st["failures"], "errors": st["errors"][:5],
            "coverage": float(np.mean(per)), "coverage_min": float(per.min()), "coverage_max": float(per.max()),
            "rms_z": float(np.sqrt(np.mean(z2))), "rms_z_max_param": float(np.sqrt(np.max(np.mean(z2, axis=0)))),
            "time_s": st["time"],
        })
    return {"arm_joints": arm.n, "samples": problem.N, "parameters": problem.p, "base_parameters": base.rank,
            "noise": NOISE, "rho": RHO, "reps": reps, "seed": seed, "rows": out,
            "base": [b.expression() for b in base.items]}


def to_markdown(res: dict) -> str:
    lines = [
        "# Coverage of the 95 % intervals of the base parameters",
        "",
        f"Command: `{res['command']}` (dualid {res['commit']}, {res['machine']}; {res['wall_s']:.0f} s wall on a "
        "machine shared with other jobs: timings are not speed measurements).",
        "",
        f"A random {res['arm_joints']}-joint arm (dualid.bench.arms, seed {res['seed']}), {res['samples']} samples "
        f"(exact q, v, a), {res['parameters']} parameters, {res['base_parameters']} base parameters; torque noise "
        f"{100 * res['noise']:.0f} % of each joint's rms; {res['reps']} repetitions (new noise each, same motion). "
        "Coverage: share of (repetition, base parameter) pairs whose 95 % interval holds the true β (target "
        "0.90–0.98); min–max: over the base parameters; rms z: of (β̂ − β)/se (1 when calibrated and unbiased).",
        "",
        "| case | method | interval | blocks | coverage | min–max | rms z (worst parameter) | fits | failed | time [s] |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in res["rows"]:
        lines.append(f"| {r['case']} | {r['method']} | {r['kind']} | {r['blocks']} | **{r['coverage']:.3f}** | "
                     f"{r['coverage_min']:.2f}–{r['coverage_max']:.2f} | {r['rms_z']:.3g} ({r['rms_z_max_param']:.3g}) | "
                     f"{r['fits']} | {r['failures']} | {r['time_s']:.0f} |")
    errors = [(r["method"], e) for r in res["rows"] for e in r["errors"]]
    if errors:
        lines += ["", "Failures (first of each row):", ""] + [f"- {m}: {e}" for m, e in errors]
    lines += ["", "Base parameters:", ""] + [f"- {b}" for b in res["base"]]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reps", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--seconds", type=float, default=5.0, help="length of the excitation [s] at 200 Hz")
    ap.add_argument("--methods", default="ols,ols_unconstrained,wls,dm,dm-paper")
    ap.add_argument("--bootstrap", type=int, default=0, metavar="R",
                    help="also a block bootstrap of ols with R resamples of 50 segments (refits: costly)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "coverage"))
    ap.add_argument("--force", action="store_true", help="replace existing output files")
    args = ap.parse_args(argv)
    # before the work: an existing result is not replaced without --force
    check_output_files([Path(args.out) / "results.json", Path(args.out) / "results.md"], args.force, ap)
    t0 = time.time()
    res = run(args.reps, args.seed, args.seconds, tuple(args.methods.split(",")), args.bootstrap)
    commit = git_commit() or "unknown"
    res.update(command=" ".join(["python benchmarks/coverage.py", *(argv if argv is not None else sys.argv[1:])]),
               commit=commit, machine=f"{platform.machine()}, {os.cpu_count()} cores", wall_s=time.time() - t0)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(res, indent=1, default=float))
    (out / "results.md").write_text(to_markdown(res))
    print(to_markdown(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
