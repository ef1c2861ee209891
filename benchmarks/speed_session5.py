"""One pass of the dual-metric derivatives (f, ∇f, ∇²f over all samples), before and after the session-5 kernels,
side by side in one process, on the benchmark Crazyflie and arm7 (issue 12, point 6).

    OPENBLAS_NUM_THREADS=1 python benchmarks/speed_session5.py --sizes 20000,100000 --out benchmarks/speed_session5.json

"before" is the pass as it was on main 15bd74f (``AffineMetric.evaluate`` and ``apply_quad`` on a copy of Y,
4,096-sample chunks), re-stated here; "after" is ``dualid.estimators.newton.dual_metric_derivatives`` with its
default chunk. Both run alternately, ``--repeat`` times each, and the minimum is reported (the machine is
shared: the minimum is the least disturbed run). The two must agree: f, ∇f and ∇²f to 1e-10 relative.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from dualid.bench.runner import base_samples, build_problem
from dualid.estimators.newton.objective import _cholesky, _tri_inverse, dual_metric_derivatives
from dualid.problem import sample_blocks


def before(problem, theta, chunk=4096):
    """The pass of main 15bd74f (objective.dual_metric_derivatives, order 2)."""
    n, p = problem.n, problem.p
    f, grad, hess = 0.0, np.zeros(p), np.zeros((p, p))
    for block, rows, _ in sample_blocks(problem, chunk):
        Y = block.Y[rows]
        c = Y.shape[0]
        r = (Y.reshape(c * n, p) @ theta).reshape(c, n) - block.tau[rows]
        L = _cholesky(block.metric.evaluate(theta, rows))
        Li = _tri_inverse(L)
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problems", default="crazyflie,arm7")
    ap.add_argument("--sizes", default="20000,100000")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--out", type=Path, default=None, help="also write the rows as JSON here")
    args = ap.parse_args()
    cache = Path(tempfile.mkdtemp(prefix="dualid-speed-"))
    rows = []
    for name in args.problems.split(","):
        for N in [int(float(s)) for s in args.sizes.split(",")]:
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
        args.out.write_text(json.dumps({"command": "OPENBLAS_NUM_THREADS=1 python benchmarks/speed_session5.py "
                                        f"--problems {args.problems} --sizes {args.sizes} --repeat {args.repeat}",
                                        "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
