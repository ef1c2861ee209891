"""One pass of the dual-metric derivatives (f, ∇f, ∇²f over all samples), before and after the batched kernels,
side by side in one process, on the benchmark Crazyflie and arm7.

    OPENBLAS_NUM_THREADS=1 python benchmarks/derivatives_speed.py --sizes 20000,100000 --out benchmarks/derivatives_speed.json

"before" is the pass as it was on main 15bd74f (``AffineMetric.evaluate`` and ``apply_quad`` on a copy of Y,
4,096-sample chunks), re-stated here; "after" is ``dualid.estimators.newton.dual_metric_derivatives`` with its
default chunk. Both run alternately, ``--repeat`` times each, and the minimum is reported (the machine is
shared: the minimum is the least disturbed run). The two must agree: f, ∇f and ∇²f to 1e-10 relative.

Whole fits, before/after: ``--fits crazyflie:1000:newton,arm7:1000:newton,crazyflie:1000000:dm-paper`` with
``--baseline-src`` the ``src`` of a checkout of main (``git worktree add /tmp/main 15bd74f``): each fit runs in its own
process with PYTHONPATH set to that tree or to this one, alternately, ``--rounds`` times; a process fits ``--repeat``
times (once for N ≥ 100,000) and reports its fastest. "newton" is ``dualid bench``'s Newton estimator (the metric
guard included), any other name a method of the method table built as benchmarks/large_n.py does.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from dualid.report.outdir import check_output_files
from dualid.bench.runner import base_samples, build_problem
from dualid.estimators.newton.objective import cholesky_batch, tri_inverse, dual_metric_derivatives
from dualid.problem import sample_blocks


def before(problem, theta, chunk=4096):
    """The pass of main 15bd74f (objective.dual_metric_derivatives, order 2)."""
    n, p = problem.n, problem.p
    f, grad, hess = 0.0, np.zeros(p), np.zeros((p, p))
    for block, rows, _ in sample_blocks(problem, chunk):
        Y = block.Y[rows]
        c = Y.shape[0]
        r = (Y.reshape(c * n, p) @ theta).reshape(c, n) - block.tau[rows]
        L = cholesky_batch(block.metric.evaluate(theta, rows))
        Li = tri_inverse(L)
        z = np.einsum("cab,cb->ca", Li, r)
        f += float(np.sum(z * z))
        w = np.einsum("cba,cb->ca", Li, z)
        D, wMw = block.metric.apply_quad(w, rows, out=Y.copy())
        grad += 2.0 * (w.reshape(-1) @ Y.reshape(-1, p)) - wMw
        Z = np.matmul(Li, D).reshape(-1, p)
        hess += 2.0 * (Z.T @ Z)
    return f, grad, 0.5 * (hess + hess.T)


def after(problem, theta):
    d = dual_metric_derivatives(problem, theta, 2)
    return d.f, d.grad, d.hess


def fit_child(name: str, N: int, method: str, repeat: int, cache: Path) -> dict:
    """Fastest of ``repeat`` fits of one (problem, N, method), in this process (PYTHONPATH picks the code)."""
    path = base_samples(name, cache, min(N, 20_000))
    problem = build_problem(path, N)
    if method == "newton":
        from dualid.bench.runner import _estimator

        est = _estimator("newton")
    else:
        from dualid.estimators.methods import make_estimator

        est = make_estimator(method, theta0=np.load(path)["theta"], allow_unidentifiable=True)
    times = []
    for _ in range(repeat if N < 100_000 else 1):
        t0 = time.perf_counter()
        result = est.fit(problem)
        times.append(time.perf_counter() - t0)
    return {"problem": name, "N": N, "method": method, "time_s": min(times), "iterations": result.iterations,
            "objective": float(result.objective), "status": result.status}


def fits(args) -> list[dict]:
    cache = Path(tempfile.mkdtemp(prefix="dualid-speed-fits-"))
    here = str(Path(__file__).resolve().parents[1] / "src")
    rows = []
    for item in args.fits.split(","):
        name, N, method = item.split(":")
        for rnd in range(args.rounds):
            for label, src in (("before", str(args.baseline_src)), ("after", here)):
                env = {**os.environ, "PYTHONPATH": src}
                out = subprocess.run([sys.executable, __file__, "--child", name, N, method, str(args.repeat), str(cache)],
                                     capture_output=True, text=True, env=env)
                try:
                    row = json.loads(out.stdout.strip().splitlines()[-1])
                except (IndexError, json.JSONDecodeError):
                    row = {"problem": name, "N": int(N), "method": method, "error": out.stderr.strip()[-300:]}
                row.update(code=label, round=rnd, load=os.getloadavg()[0])
                rows.append(row)
                print(json.dumps(row), flush=True)
    return rows


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        name, N, method, repeat, cache = sys.argv[2:7]
        print(json.dumps(fit_child(name, int(float(N)), method, int(repeat), Path(cache))), flush=True)
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problems", default="crazyflie,arm7")
    ap.add_argument("--sizes", default="20000,100000")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--out", type=Path, default=None, help="also write the rows as JSON here")
    ap.add_argument("--fits", default="", help="PROBLEM:N:METHOD,… whole fits before/after (needs --baseline-src)")
    ap.add_argument("--baseline-src", type=Path, default=None, help="the src directory of the code to compare with")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--no-passes", action="store_true", help="only the whole fits")
    ap.add_argument("--force", action="store_true", help="replace existing output files")
    args = ap.parse_args()
    # before the work: an existing result is not replaced without --force
    check_output_files([args.out] if args.out else [], args.force, ap)
    if args.fits and args.baseline_src is None:
        raise SystemExit("--fits needs --baseline-src (the src of a checkout of the code to compare with)")
    fit_rows = fits(args) if args.fits else []
    if args.no_passes:
        args.sizes = ""
    cache = Path(tempfile.mkdtemp(prefix="dualid-speed-"))
    rows = []
    for name in args.problems.split(","):
        for N in [int(float(s)) for s in args.sizes.split(",") if s]:
            path = base_samples(name, cache, min(N, 20_000))
            problem = build_problem(path, N)
            theta = np.load(path)["theta"]
            times = {"before": [], "after": []}
            res = {}
            for _ in range(args.repeat):
                for key, fn in (("before", before), ("after", after)):
                    t0 = time.perf_counter()
                    res[key] = fn(problem, theta)
                    times[key].append(time.perf_counter() - t0)
            (f0, g0, H0), (f1, g1, H1) = res["before"], res["after"]
            agree = max(abs(f1 - f0) / abs(f0), np.abs(g1 - g0).max() / np.abs(g0).max(),
                        np.abs(H1 - H0).max() / np.abs(H0).max())
            row = {"problem": name, "N": N, "before_s": min(times["before"]), "after_s": min(times["after"]),
                   "before_us_per_sample": min(times["before"]) / N * 1e6,
                   "after_us_per_sample": min(times["after"]) / N * 1e6,
                   "speedup": min(times["before"]) / min(times["after"]), "max_rel_difference": float(agree),
                   "load": os.getloadavg()[0]}
            rows.append(row)
            print(json.dumps(row), flush=True)
            if agree > 1e-10:
                raise SystemExit(f"{name} N={N}: before and after differ by {agree:.3g} (relative)")
    if args.out:
        args.out.write_text(json.dumps({"command": "OPENBLAS_NUM_THREADS=1 python benchmarks/derivatives_speed.py "
                                        + " ".join(sys.argv[1:]), "passes": rows, "fits": fit_rows}, indent=1))


if __name__ == "__main__":
    main()
