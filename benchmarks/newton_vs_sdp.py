"""dm-paper by Newton against the SDP (Clarabel), side by side in one run, at any N.

    OPENBLAS_NUM_THREADS=1 python benchmarks/newton_vs_sdp.py --sizes 1000,20000 --out benchmarks/newton_vs_sdp.md

``dualid bench`` only runs N = 100, 1,000, 10,000, …; the targets are at 1,000 and 20,000. Every (problem,
solver, N) runs in its own Python process, one at a time (``dualid.bench.runner.run_in_subprocess``: the same
problems, estimators and timing as ``dualid bench``: wall time of ``estimator.fit(problem)`` as a user calls
it, the metric guard included). The machine's load average is recorded before and after each run.

Where Newton's time goes (``breakdown``, in this process after the runs, best of 3): one pass of the derivatives
(f, ∇f, ∇²f over every sample) at θ̂, and the metric guard that ``DualMetric.fit`` adds (its WLS reference fit and
the generalised-eigenvalue pass). A fit needs about one pass per iteration (plus, with a warm start, the
subsample's): passes × pass + guard is what the fit cannot go below with these kernels.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
import timeit
from pathlib import Path

from dualid.bench.runner import BASE_SAMPLES, base_samples, build_problem, machine, run_in_subprocess
from dualid.estimators import DualMetric
from dualid.estimators.least_squares import wls_reference
from dualid.estimators.newton import dual_metric_derivatives
from dualid.metric_guard import guard_sample, reference_guard
from dualid.report.metadata import git_commit


def _load() -> float:
    return os.getloadavg()[0]


def breakdown(name: str, N: int, cache: Path) -> dict:
    """{"pass_s": one order-2 derivative pass over all samples at θ̂, "guard_s": the metric guard of ``DualMetric.fit``}."""
    problem = build_problem(base_samples(name, cache, min(N, BASE_SAMPLES)), N)
    theta = DualMetric(allow_unidentifiable=True).fit(problem).theta
    some, _ = guard_sample(problem)
    return {"pass_s": min(timeit.repeat(lambda: dual_metric_derivatives(problem, theta, 2), number=1, repeat=3)),
            "guard_s": min(timeit.repeat(lambda: reference_guard(problem, theta, wls_reference(some, True)[0], "wls fit"),
                                         number=1, repeat=3))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/newton_vs_sdp.md"))
    ap.add_argument("--problems", default="crazyflie,arm7")
    ap.add_argument("--solvers", default="newton,sdp_clarabel")
    ap.add_argument("--sizes", default="1000,20000")
    ap.add_argument("--timeout", type=float, default=1200.0)
    ap.add_argument("--force", action="store_true", help="overwrite --out and its .json")
    args = ap.parse_args()
    out_json = args.out.with_suffix(".json")
    if not args.force and (args.out.exists() or out_json.exists()):
        raise SystemExit(f"{args.out} exists; pass --force to overwrite it")
    sizes = [int(s) for s in args.sizes.split(",")]
    cache = Path(tempfile.mkdtemp(prefix="dualid-bench-"))
    rows = []
    for name in args.problems.split(","):
        for N in sizes:
            for solver in args.solvers.split(","):
                before, t0 = _load(), time.strftime("%H:%M:%S", time.gmtime())
                row = run_in_subprocess(name, solver, N, cache, min(N, BASE_SAMPLES), args.timeout)
                row.update(started_utc=t0, load_before=before, load_after=_load())
                print(json.dumps(row), flush=True)
                rows.append(row)
            if "newton" in args.solvers.split(","):
                parts = {"problem": name, "N": N, "solver": "newton breakdown", **breakdown(name, N, cache)}
                print(json.dumps(parts), flush=True)
                rows.append(parts)
    command = "OPENBLAS_NUM_THREADS=1 python benchmarks/newton_vs_sdp.py " + " ".join(
        f"--{k.replace('_', '-')} {v}" for k, v in vars(args).items() if k not in ("out", "force"))
    out_json.write_text(json.dumps({"command": command, "machine": machine(), "rows": rows}, indent=1))
    commit = git_commit()
    m = machine()
    lines = ["# The paper's DM: dualid's Newton against the Clarabel SDP", "",
             f"Command: `{command}` (dualid {commit or 'unknown'}, {m['cpu']}, {m['cores']} cores; one process per run, "
             "one run at a time).", "",
             "| problem | N | Newton [s] (it.) | Clarabel [s] (it.) | Clarabel ÷ Newton | objective gap (N − C)/C | "
             "peak RSS N / C [GB] | load before → after | one pass / guard [ms] |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | --- | ---: |"]
    by = {(r["problem"], r["N"], r["solver"]): r for r in rows}
    for name in args.problems.split(","):
        for N in sizes:
            a, b = by.get((name, N, "newton"), {}), by.get((name, N, "sdp_clarabel"), {})

            def cell(r):
                return r["error"][:60] if "error" in r else f"{r['wall_time_s']:.3f} ({r['iterations']})"

            ratio = gap = "—"
            if "wall_time_s" in a and "wall_time_s" in b:
                ratio = f"{b['wall_time_s'] / a['wall_time_s']:.0f}×"
                fa, fb = a.get("dual_metric_objective"), b.get("dual_metric_objective")
                if fa is not None and fb:
                    gap = f"{(fa - fb) / fb:.1e}"
            rss = f"{a.get('peak_rss_GB', float('nan')):.2f} / {b.get('peak_rss_GB', float('nan')):.2f}"
            loads = f"{a.get('load_before', float('nan')):.1f} → {b.get('load_after', float('nan')):.1f}"
            parts = by.get((name, N, "newton breakdown"), {})
            split = f"{1e3 * parts['pass_s']:.1f} / {1e3 * parts['guard_s']:.1f}" if parts else "—"
            lines.append(f"| {name} | {N:,} | {cell(a)} | {cell(b)} | {ratio} | {gap} | {rss} | {loads} | {split} |")
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
