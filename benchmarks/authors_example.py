"""The paper authors' minimal example as a benchmark: pseudo-inertia geodesic error of every method.

Re-implements the experiment of ``minimal_example.py`` from Yang and Hatton's public repository
github.com/yanhaoy/coordinate_independent_robot_model_identification (MIT License, Copyright (c) 2026 Yanhao
Yang); the data are made by ``dualid.bench.authors_arm`` (same arm, motion, noise, filters and sampling as theirs;
arm built through MuJoCo's MjSpec, regressor and metric from Pinocchio). A 3-DoF arm with massless links
identifies its end effector's 10 inertial parameters from q (1 mrad encoder noise; v and a by differentiating
and filtering q) and τ (3 % torque noise). Score: the geodesic distance between the estimated and the true
pseudo-inertia (``dualid.evaluation.parameter_error``, their half-trace convention; +inf if inconsistent).

Cases: both noises (theirs), torque noise only, encoder noise only; N = 1000 and N = 100 (a subset of the
1000); seeds 42, 0, 1, 2, 3 (their default seed first). Methods are keys of dualid's method table
(``dualid.estimators.methods.make_estimator``): point PYTHONPATH at another worktree's src to score its
estimators. Per fit: geodesic error, CPU time (process time of ``fit``), status, physical consistency;
a fit that raises is counted as a failure with its error.

    PYTHONPATH=src python -W ignore benchmarks/authors_example.py --method ols --method wls --method dm-paper --method dm
    PYTHONPATH=src python -W ignore benchmarks/authors_example.py --quick --out /tmp/authors_quick.json

Writes OUT (JSON) and OUT with suffix .md (default benchmarks/authors_example.{json,md}); refuses to replace an
existing file without --force.
"""

from __future__ import annotations

import argparse
import os
import platform
import shlex
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import dualid  # noqa: E402
from dualid.bench import authors_arm  # noqa: E402
from dualid.bench.runner import machine  # noqa: E402
from dualid.errors import DualidError  # noqa: E402
from dualid.estimators.methods import make_estimator  # noqa: E402
from dualid.evaluation.parameter_error import geodesic_distance  # noqa: E402
from dualid.report.io import markdown_table, write_json  # noqa: E402
from dualid.report.metadata import git_commit  # noqa: E402

CASES = {"both": (True, True), "torque": (True, False), "encoder": (False, True)}
SEEDS = (42, 0, 1, 2, 3)
SIZES = (authors_arm.FULL, authors_arm.DOWN)
DEFAULT_METHODS = ("ols", "wls", "dm-paper", "dm")
HERE = Path(__file__).resolve().parent


def fit_one(key: str, problem, truth: np.ndarray) -> dict:
    """One fit of method ``key``: geodesic error, CPU time, status, consistency (or the error it raised)."""
    estimator = make_estimator(key)
    start = time.process_time()
    try:
        result = estimator.fit(problem)
    except (DualidError, ArithmeticError, np.linalg.LinAlgError) as exc:
        return {"method": key, "failed": True, "error": f"{type(exc).__name__}: {exc}",
                "cpu_s": time.process_time() - start}
    cpu = time.process_time() - start
    return {"method": key, "failed": False, "geodesic": geodesic_distance(truth, result.theta), "cpu_s": cpu,
            "status": result.status, "consistent": bool(result.is_consistent), "theta": result.theta}


def run_seed(seed: int, case: str, methods, sizes=SIZES) -> list[dict]:
    """Every method on one seed and noise case, at each N."""
    torque, encoder = CASES[case]
    q, v, a, tau = authors_arm.samples(seed, torque_noise=torque, encoder_noise=encoder)
    full = authors_arm.problem(q, v, a, tau)
    truth = authors_arm.true_parameters()
    rows = []
    for N in sizes:
        problem = full if N == authors_arm.FULL else full.subset(authors_arm.down_rows())
        for key in methods:
            rows.append({"case": case, "N": problem.N, "seed": seed, **fit_one(key, problem, truth)})
    return rows


def summarise(rows: list[dict], methods) -> list[dict]:
    """Per case, N and method: mean, min, max of the geodesic error over seeds; failures; median CPU."""
    out = []
    for case in CASES:
        for N in sorted({r["N"] for r in rows}, reverse=True):
            for key in methods:
                sel = [r for r in rows if r["case"] == case and r["N"] == N and r["method"] == key]
                if not sel:
                    continue
                g = np.array([r["geodesic"] for r in sel if not r["failed"]], dtype=float)
                out.append({"case": case, "N": N, "method": key, "fits": len(sel),
                            "failures": sum(r["failed"] for r in sel),
                            "inconsistent": sum(not r.get("consistent", True) for r in sel),
                            "mean": float(g.mean()) if g.size else None, "min": float(g.min()) if g.size else None,
                            "max": float(g.max()) if g.size else None,
                            "median_cpu_s": float(np.median([r["cpu_s"] for r in sel]))})
    return out


def fmt(x, digits=3) -> str:
    return "–" if x is None else ("inf" if not np.isfinite(x) else f"{x:.{digits}f}")


def to_markdown(result: dict) -> str:
    methods, summary = result["methods"], result["summary"]
    lines = ["# The authors' minimal example: pseudo-inertia geodesic error to the truth", "",
             header(result), "",
             f"Seeds {', '.join(map(str, result['seeds']))}. Cell: mean (min–max) over seeds; "
             "lower is better; a failed or inconsistent fit is counted in the last columns.", ""]
    rows = []
    for case in CASES:
        for N in sorted({s["N"] for s in summary}, reverse=True):
            cells = {s["method"]: s for s in summary if s["case"] == case and s["N"] == N}
            if not cells:
                continue
            rows.append([case, N] + [f"{fmt(cells[m]['mean'])} ({fmt(cells[m]['min'])}–{fmt(cells[m]['max'])})"
                                     if m in cells else "–" for m in methods]
                        + [sum(c["failures"] for c in cells.values()), sum(c["inconsistent"] for c in cells.values())])
    lines += markdown_table(["noise", "N", *methods, "failures", "inconsistent"], rows)
    n_max = max(s["N"] for s in summary)
    lines += ["", f"Median CPU time per fit [s] (N = {n_max}, all cases):", ""]
    full = [r for r in result["rows"] if r["N"] == n_max]
    lines += markdown_table(methods, [[fmt(float(np.median([r["cpu_s"] for r in full if r["method"] == m])), 3)
                                       for m in methods]])
    lines += ["", f"Wall time {result['wall_time_s']:.0f} s (the machine may be shared)."]
    return "\n".join(lines) + "\n"


def provenance() -> dict:
    """dualid's source directory and commit (``report.metadata.git_commit``: "-dirty" with uncommitted changes)."""
    src = Path(dualid.__file__).resolve().parent
    return {"dualid": str(src), "commit": git_commit(src) or "unknown", "python": platform.python_version(),
            "machine": machine()}


def header(result: dict) -> str:
    """The result's first line: its command, the dualid commit and the machine."""
    prov = result["provenance"]
    where = ""
    if "machine" in prov:
        m = prov["machine"]
        where = f", {m['cpu']}, {m['cores']} cores, load average {m['load_average_at_start'][0]:.1f} at start"
    return f"Command: `{result['command']}` (dualid {prov['commit'][:10] + prov['commit'][40:]} from `{prov['dualid']}`{where})."


def output_paths(out: str, force: bool, parser) -> tuple[Path, Path]:
    """(json, md) paths of OUT; the parser's usage error (exit 2) when one exists and --force is not given."""
    from dualid.report.outdir import check_output_files

    json_path = Path(out)
    if json_path.suffix != ".json":  # else the .md would be written over the .json
        parser.error(f"--out: expected the result's .json path (its .md goes beside it), got {out}")
    return tuple(check_output_files([json_path, json_path.with_suffix(".md")], force, parser))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--method", action="append", help=f"a key of dualid's method table (repeatable; default "
                    f"{' '.join(DEFAULT_METHODS)})")
    ap.add_argument("--seeds", type=int, nargs="+", default=list(SEEDS))
    ap.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES))
    ap.add_argument("--quick", action="store_true", help="smoke run: seed 42, N = 100 only")
    ap.add_argument("--out", default=str(HERE / "authors_example.json"))
    ap.add_argument("--force", action="store_true", help="replace existing output files")
    args = ap.parse_args(argv)
    methods = list(args.method or DEFAULT_METHODS)
    for key in methods:  # fail early on an unknown key
        try:
            make_estimator(key)
        except DualidError as exc:
            print(f"error: --method {key}: {exc}", file=sys.stderr)
            return 2
    json_path, md_path = output_paths(args.out, args.force, ap)
    seeds = [42] if args.quick else args.seeds
    sizes = (authors_arm.DOWN,) if args.quick else SIZES
    t0 = time.time()
    rows = []
    for case in args.cases:
        for seed in seeds:
            rows += run_seed(seed, case, methods, sizes)
            print(f"[{time.time() - t0:5.0f} s] {case} seed {seed}: " + ", ".join(
                f"{r['method']}@{r['N']} {fmt(r.get('geodesic'))}" for r in rows[-len(methods) * len(sizes):]), flush=True)
    cmd = "python benchmarks/authors_example.py " + shlex.join(sys.argv[1:] if argv is None else argv)
    result = {"command": cmd, "methods": methods, "seeds": seeds, "cases": args.cases,
              "truth": authors_arm.true_parameters(), "wall_time_s": time.time() - t0, "provenance": provenance(),
              "summary": summarise(rows, methods), "rows": rows}
    write_json(json_path, result)
    md_path.write_text(to_markdown(result))
    print(f"wrote {json_path} and {md_path} ({time.time() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
