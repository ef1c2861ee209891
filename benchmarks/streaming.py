"""A fit streamed from a Parquet file, chunk by chunk, against the materialised problem's size.

    OPENBLAS_NUM_THREADS=1 python benchmarks/streaming.py --n 1000000 --methods ols --out benchmarks/streaming.md

Writes N samples of a benchmark system (``--system``: the Crazyflie or the 7-joint arm of ``dualid bench``; q, v, a and
τ = Y θ + 5 % noise, the columns of a dualid data set
run; up to 20,000 distinct random states, repeated with fresh noise beyond) to a temporary Parquet file in row groups, then fits each method in its own process from a
``ChunkedProblem`` (the regressor and metric rebuilt chunk by chunk on every pass) and records wall time, passes
over the file and peak resident memory, next to the memory the materialised problem's Y and metric Jacobians
would take (N·n·p + bodies·N·6·n floats).
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

import numpy as np


def write_parquet(path: Path, N: int, system: str, chunk: int = 100_000) -> dict:
    import pinocchio as pin
    import pyarrow as pa
    import pyarrow.parquet as pq

    from dualid.bench.runner import pinocchio_model
    from dualid.model.rigid_body import RigidBodyModel

    rb = RigidBodyModel(pinocchio_model(system))
    theta = rb.nominal
    rng = np.random.default_rng(0)
    pin.seed(0)
    base = min(N, 20_000)  # distinct states (as dualid bench): larger N repeat them with fresh noise on τ
    q0 = np.stack([pin.randomConfiguration(rb.model, -np.ones(rb.nq), np.ones(rb.nq)) for _ in range(base)])
    v0, a0 = rng.normal(size=(base, rb.nv)), rng.normal(size=(base, rb.nv))
    tau0 = rb.regressor(q0, v0, a0) @ theta
    scale = 0.05 * np.abs(tau0).mean(axis=0)
    writer = None
    for start in range(0, N, chunk):
        idx = np.arange(start, min(start + chunk, N)) % base
        q, v, a = q0[idx], v0[idx], a0[idx]
        tau = tau0[idx] + scale * rng.normal(size=(len(idx), rb.nv))
        cols = {f"q_{j}": q[:, j] for j in range(rb.nq)}
        for name, x in (("v", v), ("a", a), ("tau", tau)):
            cols.update({f"{name}_{k}": x[:, i] for i, k in enumerate(rb.coordinates)})
        table = pa.table(cols)
        writer = writer or pq.ParquetWriter(path, table.schema)
        writer.write_table(table)
    writer.close()
    return {"n": rb.nv, "p": rb.parameters.p, "bodies": len(rb.bodies), "file_GB": path.stat().st_size / 1e9}


def run_one(path: Path, method: str, chunk: int, system: str) -> dict:
    from dualid.bench.runner import pinocchio_model
    from dualid.estimators.methods import make_estimator
    from dualid.model.rigid_body import RigidBodyModel
    from dualid.streaming import ChunkedProblem, ParquetSource

    rb = RigidBodyModel(pinocchio_model(system))
    problem = ChunkedProblem(rb, ParquetSource(path, rb.coordinates, rb.nq, chunk=chunk))
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    t0 = time.perf_counter()
    try:
        result = make_estimator(method, allow_unidentifiable=True).fit(problem)
    except Exception as exc:  # recorded
        return {"method": method, "error": f"{type(exc).__name__}: {str(exc)[:300]}"}
    return {"method": method, "N": problem.N, "wall_time_s": time.perf_counter() - t0, "passes": problem.passes,
            "rss_before_fit_GB": rss0, "peak_rss_GB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6,
            "status": result.status, "objective": result.objective, "iterations": result.iterations}


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        print(json.dumps(run_one(Path(sys.argv[2]), sys.argv[3], int(sys.argv[4]), sys.argv[5])), flush=True)
        return
    from dualid.bench.runner import PROBLEMS

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--methods", default="ols")
    ap.add_argument("--chunk", type=int, default=65536)
    ap.add_argument("--system", choices=PROBLEMS, default="crazyflie")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/streaming.md"))
    ap.add_argument("--force", action="store_true")
    args = ap.parse_args()
    if args.out.exists() and not args.force:
        sys.exit(f"{args.out} exists; pass --force to overwrite it")
    load0 = [round(x, 2) for x in os.getloadavg()]
    runs = []
    with tempfile.TemporaryDirectory(prefix="dualid-stream-") as tmp:
        path = Path(tmp) / f"{args.system}.parquet"
        t0 = time.perf_counter()
        shape = write_parquet(path, args.n, args.system)
        write_s = time.perf_counter() - t0
        for method in args.methods.split(","):
            out = subprocess.run([sys.executable, __file__, "--child", str(path), method, str(args.chunk), args.system],
                                 capture_output=True, text=True)
            try:
                row = json.loads(out.stdout.strip().splitlines()[-1])
            except (IndexError, json.JSONDecodeError):
                row = {"method": method, "error": out.stderr.strip()[-300:]}
            runs.append(row)
            print(row, flush=True)
    materialised = args.n * shape["n"] * (shape["p"] + 6 * shape["bodies"]) * 8 / 1e9
    lines = [
        f"# A fit streamed from Parquet (benchmark {'Crazyflie' if args.system == 'crazyflie' else '7-joint arm'})", "",
        f"Command: `OPENBLAS_NUM_THREADS=1 python {' '.join(sys.argv)}`", "",
        f"N = {args.n:,} samples in a {shape['file_GB']:.2f} GB Parquet file (written in {write_s:.0f} s); chunks of "
        f"{args.chunk:,} samples. The materialised problem would hold Y and the metric's body Jacobians: "
        f"**{materialised:.2f} GB**. Load average {load0} at the start, "
        f"{[round(x, 2) for x in os.getloadavg()]} at the end (shared machine).", "",
        "| method | time [s] | passes over the file | peak RSS [GB] | RSS before the fit [GB] | status | objective |",
        "| --- | ---: | ---: | ---: | ---: | --- | ---: |",
    ]
    for r in runs:
        if "error" in r:
            lines.append(f"| {r['method']} | — | — | — | — | error: {r['error'][:100]} | — |")
        else:
            lines.append(f"| {r['method']} | {r['wall_time_s']:.1f} | {r['passes']} | {r['peak_rss_GB']:.2f} | "
                         f"{r['rss_before_fit_GB']:.2f} | {r['status']} | {r['objective']:.10g} |")
    args.out.write_text("\n".join(lines) + "\n")
    args.out.with_suffix(".json").write_text(json.dumps({"runs": runs, "materialised_GB": materialised, **shape}, indent=1))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
