"""Times the dual-metric solvers: Newton (interior point) vs the SDP (Clarabel, SCS), and constrained OLS.

    python benchmarks/bench_solvers.py [--max-n 1000000] [--sdp-max-n 10000] [--budget 300] [--cap arm7=100000]

A thin wrapper around ``dualid.bench.runner`` (problems, timing in one subprocess per run, writers;
see that module's doc) that writes benchmarks/results.json and benchmarks/results.md. The same
benchmark with a scaling plot: ``dualid bench --out DIR``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from dualid.bench.runner import (
    PROBLEMS,
    BenchConfig,
    parse_caps,
    parse_list,
    run_benchmark,
    run_one,
)
from dualid.report.bench import to_markdown, write_results

HERE = Path(__file__).resolve().parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-n", type=int, default=1_000_000)
    ap.add_argument("--sdp-max-n", type=int, default=10_000)
    ap.add_argument("--budget", type=float, default=300.0, help="skip larger N for a solver once a run took longer [s]")
    ap.add_argument("--timeout", type=float, default=900.0, help="kill a single run after this many seconds")
    ap.add_argument("--problems", default="crazyflie,arm7")
    ap.add_argument("--cap", default="", help="per-problem largest N, e.g. arm7=100000 (memory: Y is N·n·p·8 bytes)")
    ap.add_argument("--single", nargs=3, metavar=("PROBLEM", "SOLVER", "N"), help=argparse.SUPPRESS)
    ap.add_argument("--cache", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.single:  # one run in this process (as run_benchmark does in each subprocess)
        name, solver, N = args.single
        if args.cache is None:
            sys.exit("--single needs --cache DIR (where the base samples are kept)")
        print(json.dumps(run_one(name, solver, int(N), Path(args.cache))))
        return
    try:
        config = BenchConfig(problems=parse_list(args.problems, PROBLEMS, "problem"), max_n=args.max_n,
                             sdp_max_n=args.sdp_max_n, budget=args.budget, timeout=args.timeout,
                             caps=parse_caps(args.cap))
    except ValueError as exc:
        sys.exit(f"error: {exc}")
    result = run_benchmark(config, Path(args.cache) if args.cache else None,
                           progress=lambda done, total, row: row and print(json.dumps(row), flush=True))
    write_results(result, HERE)
    print(to_markdown(result))


if __name__ == "__main__":
    main()
