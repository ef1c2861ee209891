"""Does the dense M_ik (``AffineMetric.dense``) beat the factored products, and up to how many coordinates?

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python benchmarks/metric_dense.py --out benchmarks/metric_dense.md

Per n = 2…8: a metric of n rigid bodies (random body Jacobians, the spatial-inertia basis) plus one armature term per
joint (p = 11 n), 4,000 samples; the time of M_i(θ) (``evaluate``) and of [M_ik w_i]_k (``apply``) on a block of 1,024
samples (the kernels' chunk), factored and dense, and the one-time cost of building the dense form (best of 3). Then
whole `dm` fits of the DFKI example's training runs (examples/dfki, n = 2) with the dense form allowed (DENSE_MAX_N as
shipped) and forbidden (0), alternately. Minimum over --repeat runs (the machine may be shared).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import dualid.model.metric as metric_module
from dualid.model.metric import AffineMetric, MetricTerm
from dualid.model.rigid_body import spatial_inertia_basis
from dualid.report.outdir import check_output_files
from dualid.report.metadata import git_commit

HERE = Path(__file__).resolve().parent


def best(f, repeat: int) -> float:
    f()
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        f()
        times.append(time.perf_counter() - t)
    return min(times)


def arm_metric(n: int, N: int = 4000, seed: int = 0) -> AffineMetric:
    rng = np.random.default_rng(seed)
    E = spatial_inertia_basis()
    terms = [MetricTerm(tuple(range(10 * b, 10 * b + 10)), E, rng.normal(size=(N, 6, n))) for b in range(n)]
    terms += [MetricTerm((10 * n + j,), np.ones((1, 1, 1)), np.repeat(np.eye(n)[None, j:j + 1], N, 0))
              for j in range(n)]
    return AffineMetric(11 * n, tuple(terms))


def kernels(n: int, repeat: int) -> dict:
    rng = np.random.default_rng(1)
    rows, theta, w = slice(0, 1024), rng.normal(size=11 * n), rng.normal(size=(1024, n))
    out = {}
    for label, limit in (("factored", 0), ("dense", n)):
        metric_module.DENSE_MAX_N, metric_module.DENSE_MAX_FLOATS, metric_module.DENSE_AFTER = limit, 10**9, 0
        builds = []
        for _ in range(3):  # a fresh metric each time: the dense form is built on first use
            m = arm_metric(n)
            t = time.perf_counter()
            m.dense_rows(slice(None))
            builds.append(time.perf_counter() - t)
        out[f"{label}_build"] = min(builds)
        out[f"{label}_evaluate"] = best(lambda: m.evaluate(theta, rows, symmetric=False), repeat)
        out[f"{label}_apply"] = best(lambda: m.apply(w, rows), repeat)
    return out


DFKI_FIT = """
import sys, time
sys.path.insert(0, {bench!r})
import dualid, dualid.model.metric as mm
mm.DENSE_MAX_N = {limit}
from dfki_splits import DATA, COLUMNS, STEPS, RUNS
rigid = dualid.RigidBodyModel.from_urdf(DATA / "pendubot_model_2.1.urdf")
model = dualid.with_joint_terms(rigid, viscous=True, coulomb=True, coulomb_velocity=0.01, armature=True)
logs = [dualid.preprocess(dualid.load_log(DATA / f"{{n}}.csv", COLUMNS, tuple(rigid.coordinates)), STEPS) for n in RUNS[:4]]
problem = dualid.build_problem(model, logs)
est = dualid.make_estimator("dm", allow_unidentifiable=True)
est.fit(problem)
times = []
for _ in range({repeat}):
    t = time.process_time(); est.fit(problem); times.append(time.process_time() - t)
print(min(times))
"""


def dfki_fit(limit: int, repeat: int) -> float:
    code = DFKI_FIT.format(bench=str(HERE), limit=limit, repeat=repeat)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=HERE / "metric_dense.md")
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--rounds", type=int, default=3, help="alternations of the DFKI fits")
    ap.add_argument("--force", action="store_true", help="replace an existing result")
    args = ap.parse_args(argv)
    check_output_files([args.out], args.force, ap)
    shipped = metric_module.DENSE_MAX_N
    rows = [(n, kernels(n, args.repeat)) for n in range(2, 9)]
    fits = {"dense": [], "factored": []}
    for _ in range(args.rounds):
        fits["dense"].append(dfki_fit(shipped, 5))
        fits["factored"].append(dfki_fit(0, 5))
    commit = git_commit()
    lines = ["# The dense M_ik against the factored products", "",
             f"Command: `OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python benchmarks/metric_dense.py --repeat {args.repeat} "
             f"--rounds {args.rounds}` (dualid {commit or 'unknown'}; minimum over the repeats; DENSE_MAX_N = {shipped}).", "",
             "Milliseconds per block of 1,024 samples (n rigid bodies and n armature terms, p = 11 n):", "",
             "| n | evaluate factored | evaluate dense | apply factored | apply dense | dense build, 4,000 samples (best of 3) |",
             "| ---: | ---: | ---: | ---: | ---: | ---: |"]
    for n, r in rows:
        lines.append(f"| {n} | {1e3 * r['factored_evaluate']:.3f} | {1e3 * r['dense_evaluate']:.3f} | "
                     f"{1e3 * r['factored_apply']:.3f} | {1e3 * r['dense_apply']:.3f} | {1e3 * r['dense_build']:.1f} |")
    lines += ["", "`dm` on the DFKI example's training runs (4,000 samples, n = 2), CPU seconds per fit, best of 5 in each "
              f"of {args.rounds} alternating processes:", "",
              f"- dense allowed: {', '.join(f'{t:.3f}' for t in fits['dense'])}",
              f"- factored only: {', '.join(f'{t:.3f}' for t in fits['factored'])}", ""]
    args.out.write_text("\n".join(lines))
    print(args.out.read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
