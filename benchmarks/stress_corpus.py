"""Stress corpus of identification problems: every method and solver on every problem.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python benchmarks/stress_corpus.py \
        [--out benchmarks/stress_corpus] [--quick] [--no-large]

Problems: ``dualid.bench.corpus`` (random chains 2–12 DoF with revolute, prismatic and continuous joints, the
floating-base Crazyflie, rank-deficient data from N = 12, a point-mass and a nearly massless link, exact data and
0–20 % torque noise, one coordinate in units ×1e-6 / ×1e3 / ×1e6, N up to 1e5). Runs and references:
``dualid.bench.corpus_run``. Writes OUT/results.json (every run) and OUT/results.md (counts and every run).
Failures are rows; nothing is dropped.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from dualid.report.outdir import check_output_files
from dualid.bench.corpus import cases
from dualid.bench.corpus_run import fits

QUAD = ("ols", "wls", "energy", "logdet", "pullback")


def _fmt(x, spec=".3g"):
    return "" if x is None or (isinstance(x, float) and not np.isfinite(x)) else format(x, spec)


def summary(rows: list[dict]) -> list[str]:
    """The count table per (method, variant, solver) and the three summary counts."""
    keys = []
    for r in rows:
        k = (r["method"], r["variant"], r["solver_choice"])
        if k not in keys:
            keys.append(k)
    out = ["| method | variant | solver | runs | optimal | optimal_inaccurate | failed | first solver failed (in chain) "
           "| inaccurate in chain | iterations median / max | time median / max [s] | max \\|rel. gap\\| | max pred. diff |",
           "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for k in keys:
        rs = [r for r in rows if (r["method"], r["variant"], r["solver_choice"]) == k]
        its = [r["iterations"] for r in rs if isinstance(r.get("iterations"), int)]
        ts = [r["time_s"] for r in rs]
        gaps = [abs(r["rel_gap"]) for r in rs if r.get("rel_gap") is not None]
        pds = [r["pred_diff"] for r in rs if r.get("pred_diff") is not None]
        out.append(
            f"| {k[0]} | {k[1]} | {k[2]} | {len(rs)} | {sum(r['status'] == 'optimal' for r in rs)} | "
            f"{sum(r['status'] == 'optimal_inaccurate' for r in rs)} | {sum(r['status'] == 'FAILED' for r in rs)} | "
            f"{sum(_first_failed(r) for r in rs)} | "
            f"{sum('optimal_inaccurate' in r.get('chain', '') for r in rs)} | "
            f"{(str(int(np.median(its))) + ' / ' + str(max(its))) if its else ''} | "
            f"{np.median(ts):.2f} / {max(ts):.2f} | {_fmt(max(gaps) if gaps else None, '.1e')} | "
            f"{_fmt(max(pds) if pds else None, '.1e')} |")
    return out


def _first_failed(row: dict) -> bool:
    """Did the run's first solver fail (its chain starts "newton failed" or "CLARABEL failed"), or the run?"""
    text = row.get("chain", "") + row.get("error", "")
    return text.startswith(("newton failed", "CLARABEL failed")) or "CLARABEL failed" in row.get("error", "")


def counts(rows: list[dict]) -> dict:
    by_case = {}
    for r in rows:
        by_case.setdefault(r["case"], []).append(r)
    newton_fail_sdp_ok = 0
    for rs in by_case.values():
        sdp = [r for r in rs if r["method"] == "dm-paper" and r["solver_choice"] == "sdp_clarabel"]
        new = [r for r in rs if r["method"] == "dm-paper" and r["solver_choice"] == "newton"]
        if sdp and new and sdp[0]["status"] == "optimal" and new[0]["status"] != "optimal":
            newton_fail_sdp_ok += 1
    quad = [r for r in rows if r["method"] in QUAD and "floor off" not in r["variant"]]
    quad_off = [r for r in rows if "floor off" in r["variant"]]
    return {
        "runs": len(rows),
        "dm-paper Newton not optimal where the SDP is optimal": newton_fail_sdp_ok,
        "quadratic/regularized fits whose interior point failed, Clarabel took over (default)":
            sum(_first_failed(r) for r in quad),
        "quadratic/regularized fits FAILED (default)": sum(r["status"] == "FAILED" for r in quad),
        "boundary-prior fits FAILED with the floor off (before)": sum(r["status"] == "FAILED" for r in quad_off),
        "boundary-prior fits whose interior point failed, floor off (before)": sum(_first_failed(r) for r in quad_off),
        "results with status optimal_inaccurate (reported in status)":
            sum(r["status"] == "optimal_inaccurate" for r in rows),
        "results whose chain records an optimal_inaccurate first solve (reported in info)":
            sum("optimal_inaccurate" in r.get("chain", "") for r in rows),
        "runs with a raw warning reaching the caller": sum(r.get("raw_warnings", 0) > 0 for r in rows),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "stress_corpus")
    ap.add_argument("--quick", action="store_true", help="only the cases of the fast test subset")
    ap.add_argument("--no-large", action="store_true", help="without the N = 1e5 and 1e6 problems")
    ap.add_argument("--case", default="", help="only the cases whose name contains this text")
    ap.add_argument("--force", action="store_true", help="replace existing output files")
    args = ap.parse_args()
    # before the work: an existing result is not replaced without --force
    check_output_files([args.out / "results.json", args.out / "results.md"], args.force, ap)
    t_start, load0 = time.time(), os.getloadavg()
    rows = []
    for c in cases(large=not args.no_large):
        if args.quick and not c.quick:
            continue
        if args.case and args.case not in c.name:
            continue
        t0 = time.perf_counter()
        problem, theta, prior = (*c.build(), None)[:3]
        for row in fits(problem, theta, sdp=c.sdp, prior=prior, methods=c.methods):
            rows.append({"case": c.name, "family": c.family, **row})
            print(f"{c.name} | {row['method']} {row['variant']} {row['solver_choice']} | {row['status']} "
                  f"| {_fmt(row.get('rel_gap'), '.1e')} | {row.get('error', '')[:100]}", flush=True)
        print(f"  ({time.perf_counter() - t0:.1f} s)", file=sys.stderr, flush=True)
    meta = {"command": "python benchmarks/stress_corpus.py " + " ".join(sys.argv[1:]),
            "wall_time_s": time.time() - t_start, "load_average_start": load0, "load_average_end": os.getloadavg(),
            "python": platform.python_version(), "numpy": np.__version__,
            "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS", "(default)")}
    total = counts(rows)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.json").write_text(json.dumps({"meta": meta, "counts": total, "runs": rows}, indent=1,
                                                      default=float))
    lines = ["# Stress corpus", "", f"`{meta['command']}` — {meta['wall_time_s']:.0f} s, load average "
             f"{load0[0]:.1f} → {meta['load_average_end'][0]:.1f} on 2 shared cores (times are under load).", "",
             "## Counts", "", "| count | value |", "| --- | ---: |"]
    lines += [f"| {k} | {v} |" for k, v in total.items()]
    lines += ["", "## Per method, variant and solver", ""] + summary(rows)
    lines += ["", "## Every run", "", "| case | N | method | variant | solver | status | it. | time [s] | f | rel. gap "
              "| pred. diff | chain / error |", "| --- | ---: | --- | --- | --- | --- | ---: | ---: | ---: | ---: | ---: | --- |"]
    for r in rows:
        note = (r.get("error") or r.get("chain") or "").replace("|", "/")[:160]
        if r.get("prior_lifted"):
            note = f"prior lifted: {', '.join(r['prior_lifted'])}; " + note
        lines.append(f"| {r['case']} | {r['N']} | {r['method']} | {r['variant']} | {r['solver_choice']} | {r['status']} | "
                     f"{r.get('iterations') if r.get('iterations') is not None else ''} | {r['time_s']:.2f} | "
                     f"{_fmt(r.get('objective'), '.8g')} | {_fmt(r.get('rel_gap'), '.1e')} | "
                     f"{_fmt(r.get('pred_diff'), '.1e')} | {note} |")
    (args.out / "results.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
