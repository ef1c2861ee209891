"""A fit over many Parquet files on a local Dask cluster of 1 and 2 workers, against the streamed fit on one machine.

    OPENBLAS_NUM_THREADS=1 python benchmarks/distributed_fit.py --n 100000 --files 20 --methods ols,wls,dm-paper,dm \
        --out benchmarks/distributed_fit.md
    OPENBLAS_NUM_THREADS=1 python benchmarks/distributed_fit.py --n 10000000 --files 20 --methods ols --workers 2 \
        --out benchmarks/distributed_fit_1e7.md

Writes N samples of the benchmark Crazyflie (as benchmarks/streaming.py: q, v, a and τ = Y θ + 5 % noise) to one
Parquet file and splits it into ``--files`` files. Fits each method (1) streamed from the one file in this process
(``ChunkedProblem``), (2) over the files on a ``LocalCluster`` of 1 worker process and (3) of 2 (``DaskProblem``,
one task per file and pass, one thread per worker, a Dask memory limit per worker), and records wall time (the cluster started and warmed up
beforehand), passes, the largest relative difference of θ from the streamed fit, and the workers' peak RSS.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from streaming import write_parquet  # noqa: E402  (the same data as the streaming benchmark)


def split(path: Path, files: int, folder: Path) -> list[Path]:
    import pyarrow.parquet as pq

    source = pq.ParquetFile(path)
    size = -(-source.metadata.num_rows // files)
    out = []
    for k, batch in enumerate(source.iter_batches(batch_size=size)):
        out.append(folder / f"part{k:03d}.parquet")
        pq.write_table(__import__("pyarrow").Table.from_batches([batch]), out[-1])
    return out


def peak_rss_gb() -> float:
    """This process's peak resident memory (VmHWM: its own, unlike ru_maxrss, which Linux keeps across exec and so
    would report a spawned worker's parent)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1e6
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6


def fit(method: str, problem) -> tuple[np.ndarray, float, str]:
    from dualid.estimators.methods import make_estimator

    t0 = time.perf_counter()
    result = make_estimator(method, allow_unidentifiable=True).fit(problem)
    return result.theta, time.perf_counter() - t0, result.status


def run(path: Path, parts: list[Path], methods: list[str], chunk: int, workers_list: list[int],
        memory_limit: str) -> list[dict]:
    from distributed import Client, LocalCluster

    from dualid.distributed import DaskProblem
    from dualid.model.rigid_body import RigidBodyModel
    from dualid.problem import sample_blocks
    from dualid.streaming import ChunkedProblem, ParquetSource
    from dualid.systems.crazyflie_model import build_model

    rb = RigidBodyModel(build_model())
    rows, reference = [], {}
    block, first, _ = next(iter(sample_blocks(ChunkedProblem(rb, ParquetSource(path, rb.coordinates, rb.nq)), 20_000)))
    Y = block.Y[first].reshape(-1, rb.parameters.p)  # predictions Yθ compared on the first 20,000 samples
    for method in methods:
        problem = ChunkedProblem(rb, ParquetSource(path, rb.coordinates, rb.nq, chunk=chunk))
        theta, wall, status = fit(method, problem)
        reference[method] = theta
        rows.append({"method": method, "where": "one process, streamed", "wall_time_s": wall, "passes": problem.passes,
                     "status": status, "max_rel_dtheta": 0.0, "rel_dprediction": 0.0,
                     "peak_rss_GB": peak_rss_gb()})
        print(rows[-1], flush=True)
    for workers in workers_list:
        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                          memory_limit=memory_limit) as cluster, \
                Client(cluster) as client:
            client.run(lambda: __import__("dualid.estimators.methods"))
            for method in methods:
                problem = DaskProblem.from_files(rb, parts, client, chunk=chunk)
                theta, wall, status = fit(method, problem)
                dtheta = float(np.max(np.abs(theta - reference[method])) / np.max(np.abs(reference[method])))
                dpred = float(np.linalg.norm(Y @ (theta - reference[method])) / np.linalg.norm(Y @ reference[method]))
                rss = max(client.run(peak_rss_gb).values())
                rows.append({"method": method, "where": f"Dask, {workers} worker{'s' * (workers > 1)}",
                             "wall_time_s": wall, "passes": problem.passes, "status": status,
                             "max_rel_dtheta": dtheta, "rel_dprediction": dpred, "peak_rss_GB": rss})
                print(rows[-1], flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200_000)
    ap.add_argument("--files", type=int, default=8)
    ap.add_argument("--methods", default="ols,dm-paper")
    ap.add_argument("--chunk", type=int, default=65536)
    ap.add_argument("--workers", default="1,2", help="cluster sizes to run, e.g. 2")
    ap.add_argument("--memory-limit", default="2GB", help="each worker's Dask memory limit")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/distributed_fit.md"))
    ap.add_argument("--force", action="store_true")
    args = ap.parse_args()
    if args.out.exists() and not args.force:
        sys.exit(f"{args.out} exists; pass --force to overwrite it")
    load0 = [round(x, 2) for x in os.getloadavg()]
    with tempfile.TemporaryDirectory(prefix="dualid-dask-") as tmp:
        path = Path(tmp) / "all.parquet"
        shape = write_parquet(path, args.n, "crazyflie")
        (Path(tmp) / "parts").mkdir()
        parts = split(path, args.files, Path(tmp) / "parts")
        rows = run(path, parts, args.methods.split(","), args.chunk, [int(w) for w in args.workers.split(",")],
                   args.memory_limit)
    lines = [
        "# A fit over many Parquet files on a local Dask cluster (benchmark Crazyflie)", "",
        f"Command: `OPENBLAS_NUM_THREADS=1 python {' '.join(sys.argv)}`", "",
        f"N = {args.n:,} samples (n = {shape['n']}, p = {shape['p']}), {shape['file_GB']:.3f} GB of Parquet split into "
        f"{len(parts)} files; chunks of {args.chunk:,} samples; one thread per worker, memory limit {args.memory_limit} "
        f"per worker. Wall time of the fit alone "
        f"(cluster started and warmed up). Load average {load0} at the start, "
        f"{[round(x, 2) for x in os.getloadavg()]} at the end (a shared 2-core machine).", "",
        "| method | where | time [s] | passes | max rel. Δθ vs streamed | rel. Δ(Yθ) vs streamed | peak RSS per process [GB] "
        "| status |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    for r in rows:
        lines.append(f"| {r['method']} | {r['where']} | {r['wall_time_s']:.1f} | {r['passes']} | "
                     f"{r['max_rel_dtheta']:.1e} | {r['rel_dprediction']:.1e} | {r['peak_rss_GB']:.2f} | {r['status']} |")
    args.out.write_text("\n".join(lines) + "\n")
    args.out.with_suffix(".json").write_text(json.dumps({"runs": rows, **shape}, indent=1))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
