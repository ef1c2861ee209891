"""Every method of the method table at large N on the benchmark Crazyflie: wall time, peak memory and the
ratio to numpy lstsq on the same data.

    OPENBLAS_NUM_THREADS=1 python benchmarks/large_n.py --out benchmarks/large_n.md

Each (method, N) runs in its own Python process (its peak resident set is that run's: data build + fit);
"lstsq" is ``numpy.linalg.lstsq`` on the stacked (N·n, p) regressor and τ of the same problem. The problem
is ``dualid.bench.runner.build_problem`` (the study's Crazyflie, 20,000 distinct random states, larger N
repeat them with fresh 5 % force noise); logdet/pullback use the true θ as the prior. Wall time is the
fit only (``estimator.fit(problem)``), the data build excluded; "build RSS" is the peak before the fit.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

METHODS = ("ols", "ols_unconstrained", "wls", "energy", "logdet", "pullback", "dm", "dm-paper")
SIZES = (10_000, 100_000, 1_000_000)


def _rss_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6  # kB → GB


def run_one(method: str, N: int, cache: Path) -> dict:
    import numpy as np

    from dualid.bench.runner import base_samples, build_problem

    path = base_samples("crazyflie", cache, min(N, 20_000))
    problem = build_problem(path, N)
    theta_true = np.load(path)["theta"]
    row = {"method": method, "N": N, "build_rss_GB": _rss_gb(), "Y_GB": problem.Y.nbytes / 1e9}
    t0 = time.perf_counter()
    try:
        if method == "lstsq":
            theta = np.linalg.lstsq(problem.Y.reshape(-1, problem.p), problem.tau.reshape(-1), rcond=None)[0]
            status, extra = "lstsq", {}
        else:
            from dualid.estimators.methods import make_estimator

            est = make_estimator(method, theta0=theta_true, allow_unidentifiable=True)
            result = est.fit(problem)
            theta, status = result.theta, result.status
            extra = {"iterations": result.iterations, "solver": result.solver,
                     "solver_chain": result.info.get("solver_chain")}
    except Exception as exc:  # recorded, not hidden
        return {**row, "error": f"{type(exc).__name__}: {str(exc)[:300]}", "wall_time_s": time.perf_counter() - t0,
                "peak_rss_GB": _rss_gb()}
    wall = time.perf_counter() - t0
    r = problem.Y.reshape(-1, problem.p) @ theta - problem.tau.reshape(-1)
    return {**row, "wall_time_s": wall, "peak_rss_GB": _rss_gb(), "status": status,
            "ls_objective": float(r @ r), **extra}


def run_in_subprocess(method: str, N: int, cache: Path, timeout: float) -> dict:
    cmd = [sys.executable, __file__, "--child", method, str(N), str(cache)]
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"method": method, "N": N, "error": f"timeout after {timeout:g} s"}
    try:
        return json.loads(out.stdout.strip().splitlines()[-1])
    except (IndexError, json.JSONDecodeError):
        return {"method": method, "N": N, "error": out.stderr.strip()[-500:] or f"exit code {out.returncode}"}


def to_markdown(result: dict) -> str:
    rows = result["runs"]
    lstsq = {r["N"]: r["wall_time_s"] for r in rows if r["method"] == "lstsq" and "error" not in r}
    m = result["machine"]
    lines = [
        "# Every method at large N (crazyflie, one BLAS thread)", "",
        f"Command: `{result['command']}`", "",
        f"Machine: {m['cpu']}, {m['cores']} cores; load average {m['load_start']} at the start, "
        f"{m['load_end']} at the end (the machine was shared with other jobs: times are pessimistic).", "",
        "| method | N | time [s] | peak RSS [GB] | build RSS [GB] | Y [GB] | ÷ lstsq | status / iterations |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['method']} | {r['N']:,} | — | — | — | — | — | error: {r['error'][:120]} |")
            continue
        ratio = r["wall_time_s"] / lstsq[r["N"]] if r["N"] in lstsq else float("nan")
        it = r.get("iterations")
        lines.append(
            f"| {r['method']} | {r['N']:,} | {r['wall_time_s']:.2f} | {r['peak_rss_GB']:.2f} | "
            f"{r['build_rss_GB']:.2f} | {r['Y_GB']:.2f} | {ratio:.2f}× | {r['status']}"
            f"{f' ({it})' if it is not None else ''} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        print(json.dumps(run_one(sys.argv[2], int(sys.argv[3]), Path(sys.argv[4]))), flush=True)
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/large_n.md"))
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--sizes", default=",".join(str(n) for n in SIZES))
    ap.add_argument("--timeout", type=float, default=150.0, help="kill a run after this many seconds (recorded)")
    ap.add_argument("--force", action="store_true", help="overwrite --out and its .json")
    args = ap.parse_args()
    out_json = args.out.with_suffix(".json")
    if not args.force and (args.out.exists() or out_json.exists()):
        sys.exit(f"{args.out} exists; pass --force to overwrite it")
    methods = ["lstsq"] + [m for m in args.methods.split(",") if m]
    sizes = [int(float(s)) for s in args.sizes.split(",")]
    import platform

    cpu = next((ln.split(":", 1)[1].strip() for ln in Path("/proc/cpuinfo").read_text().splitlines()
                if ln.startswith("model name")), platform.processor())
    machine = {"cpu": cpu, "cores": os.cpu_count(), "load_start": [round(x, 2) for x in os.getloadavg()],
               "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS", "(default)")}
    runs = []
    with tempfile.TemporaryDirectory(prefix="dualid-large-n-") as tmp:
        slow: set[str] = set()  # methods that timed out: not run at larger N (recorded)
        for N in sizes:
            for method in methods:
                if method in slow:
                    runs.append({"method": method, "N": N, "error": "skipped: timed out at a smaller N"})
                    print(f"{method:18s} N={N:>9,}: skipped (timed out at a smaller N)", flush=True)
                    continue
                row = run_in_subprocess(method, N, Path(tmp), args.timeout)
                if str(row.get("error", "")).startswith("timeout"):
                    slow.add(method)
                runs.append(row)
                what = row.get("error") or f"{row['wall_time_s']:.2f} s, {row['peak_rss_GB']:.2f} GB"
                print(f"{method:18s} N={N:>9,}: {what}", flush=True)
    machine["load_end"] = [round(x, 2) for x in os.getloadavg()]
    result = {"command": "OPENBLAS_NUM_THREADS=1 python " + " ".join(sys.argv), "machine": machine, "runs": runs}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    out_json.write_text(json.dumps(result, indent=1))
    args.out.write_text(to_markdown(result))
    print(to_markdown(result))


if __name__ == "__main__":
    main()
