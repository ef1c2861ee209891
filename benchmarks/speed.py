"""Where a user waits: `import dualid`, `dualid --help`, the DFKI example fit (with and without its `dm`) and the
README's main job, measured as child processes (wall time and CPU time of the process and its children), against
the targets. Writes benchmarks/speed.json and benchmarks/speed.md (quoted by docs/performance.md).

    python benchmarks/speed.py                                  # everything (the main job: ~250 s of CPU)
    python benchmarks/speed.py --no-main-job                    # the quick rows only
    python benchmarks/speed.py --no-main-job --baseline-src OLD/src   # and the same rows from another source
                                                                      # tree, interleaved run by run (before/after)

Quick rows are repeated (--repeat) and the best kept. Run it on a quiet machine: wall times of a loaded machine say
little (the load average is recorded); CPU times are the numbers to compare.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import resource
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from dualid.report.outdir import check_output_files
from dualid.report.metadata import git_commit

ROOT = Path(__file__).resolve().parents[1]
HERE = Path(__file__).resolve().parent
DFKI = ROOT / "examples" / "dfki"
DUALID = [sys.executable, "-m", "dualid.cli"]
NO_DM = [a for m in ("ols", "wls", "energy", "logdet", "pullback") for a in ("--method", m)]
ROWS = (  # (label, command after `dualid` or python, cwd, target, limit [s], measure)
    ("python -c 'import dualid'", [sys.executable, "-c", "import dualid"], ROOT, "wall ≤ 1 s", 1.0, "wall_s"),
    ("dualid --help", [*DUALID, "--help"], ROOT, "wall ≤ 0.5 s", 0.5, "wall_s"),
    ("dualid fit --config examples/dfki/fit.yaml", [*DUALID, "fit", "--config", "fit.yaml", "--verbose"], DFKI,
     "CPU ≤ 3 s", 3.0, "cpu_s"),
    ("dualid fit --config examples/dfki/fit.yaml " + " ".join(NO_DM),
     [*DUALID, "fit", "--config", "fit.yaml", "--verbose", *NO_DM], DFKI, "(without dm)", None, "cpu_s"),
)


def env_for(src: Path) -> dict:
    """This environment with ``src`` first on PYTHONPATH and no BLAS thread count set (the command chooses)."""
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    return {**env, "PYTHONPATH": f"{src}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}


def run(cmd: list[str], cwd: Path, src: Path) -> dict:
    """Wall and CPU (user + system, the process and every child it waited for) seconds of one command."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=cwd, env=env_for(src), capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if proc.returncode not in (0, 1):  # 1: a method failed, the other outputs were written (still timed)
        sys.exit(f"{' '.join(cmd)} exited {proc.returncode}:\n{proc.stderr[-2000:]}")
    return {"wall_s": wall, "cpu_s": cpu, "stderr": proc.stderr}


def stages(stderr: str) -> dict[str, float]:
    """The CPU seconds per stage of `dualid fit --verbose`."""
    m = re.search(r"CPU time per stage \[s\]: (.*); total", stderr)
    return {} if m is None else {k.rsplit(" ", 1)[0]: float(k.rsplit(" ", 1)[1]) for k in m.group(1).split(", ")}


def import_time(src: Path) -> float:
    """The cumulative import time of the dualid package by `python -X importtime` [s]."""
    err = run([sys.executable, "-X", "importtime", "-c", "import dualid"], ROOT, src)["stderr"]
    line = [x for x in err.splitlines() if x.rstrip().endswith("| dualid")][-1]
    return int(line.split("|")[1]) / 1e6


def measure(sources: dict[str, Path], repeat: int) -> list[dict]:
    """Each quick row from every source tree, interleaved (row by row, source by source), best of ``repeat``."""
    best: dict[tuple[int, str], dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(repeat):
            for i, (_, cmd, cwd, *_rest) in enumerate(ROWS):
                for name, src in sources.items():
                    out = ["--out", f"{tmp}/{name}{i}{r}"] if "fit" in cmd else []
                    got = run(cmd + out, cwd, src)
                    b = best.setdefault((i, name), {"wall_s": got["wall_s"], "cpu_s": got["cpu_s"], "stages": {}})
                    b["wall_s"], b["cpu_s"] = min(b["wall_s"], got["wall_s"]), min(b["cpu_s"], got["cpu_s"])
                    if got["cpu_s"] <= b["cpu_s"]:
                        b["stages"] = stages(got["stderr"])
    rows = []
    for i, (label, _, _, target, limit, key) in enumerate(ROWS):
        now = best[(i, "now")]
        row = {"command": label, **now, "repeat": repeat, "target": target,
               "met": None if limit is None else now[key] <= limit}
        if "before" in sources:
            row["before"] = best[(i, "before")]
        rows.append(row)
    rows[0]["importtime_s"] = min(import_time(sources["now"]) for _ in range(repeat))
    if "before" in sources:
        rows[0]["before"]["importtime_s"] = min(import_time(sources["before"]) for _ in range(repeat))
    return rows


def main_job() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        job = run([*DUALID, "reproduce", "crazyflie", "--out", f"{tmp}/crazyflie"], ROOT, ROOT / "src")
    job["progress_lines"] = sum(1 for line in job.pop("stderr").splitlines() if line.startswith("["))
    return {"command": "dualid reproduce crazyflie", **job, "repeat": 1, "target": "wall ≤ 90 s",
            "met": job["wall_s"] <= 90.0}


def machine() -> str:
    cpu = next((x.split(":", 1)[1].strip() for x in Path("/proc/cpuinfo").read_text().splitlines()
                if x.startswith("model name")), platform.processor()) if Path("/proc/cpuinfo").exists() else platform.processor()
    import numpy

    return (f"{cpu}, {os.cpu_count()} cores, {platform.system()} {platform.release()}, Python "
            f"{platform.python_version()}, numpy {numpy.__version__}")


def markdown(record: dict) -> str:
    before = any("before" in r for r in record["rows"])
    lines = ["# Where a user waits", "", f"Command: `{record['command']}`", "",
             f"Commit: {record['commit']}" + (f"; before: {record['baseline']}" if before else ""), "",
             f"Machine: {record['machine']}; load average {', '.join(f'{x:.1f}' for x in record['load_average'])} "
             f"at the end ({record['time_utc']}).", ""]
    head = "| command | wall [s] | CPU [s] |" + (" before: CPU [s] |" if before else "") + " target | met |"
    lines += [head, "|" + " --- |" * (head.count("|") - 1)]
    for r in record["rows"]:
        met = "" if r["met"] is None else "yes" if r["met"] else "**no**"
        old = f" {r['before']['cpu_s']:.2f} |" if before and "before" in r else (" |" if before else "")
        lines.append(f"| `{r['command']}` | {r['wall_s']:.2f} | {r['cpu_s']:.2f} |{old} {r['target']} | {met} |")
    imp = record["rows"][0]
    lines += ["", f"`import dualid` by `-X importtime`: {imp['importtime_s']:.3f} s"
              + (f" (before: {imp['before']['importtime_s']:.3f} s)" if before else "")
              + f". Quick rows: best of {imp['repeat']}" + (", the two source trees interleaved." if before else ".")]
    for r in record["rows"][2:4]:
        for who, s in [("now", r["stages"])] + ([("before", r["before"]["stages"])] if before else []):
            lines += ["", f"CPU seconds per stage of `{r['command']}` ({who}, `--verbose`): "
                      + ", ".join(f"{k} {v:.2f}" for k, v in s.items()) + "."]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-main-job", action="store_true", help="skip `dualid reproduce crazyflie`")
    ap.add_argument("--repeat", type=int, default=5, help="repetitions of the quick rows (best kept)")
    ap.add_argument("--baseline-src", type=Path, help="another source tree (its src folder): its quick rows "
                    "are measured too, interleaved with this tree's")
    ap.add_argument("--force", action="store_true", help="replace existing output files")
    args = ap.parse_args()
    # before the work: an existing result is not replaced without --force
    check_output_files([HERE / "speed.json", HERE / "speed.md"], args.force, ap)
    sources = {"now": ROOT / "src"} | ({"before": args.baseline_src.resolve()} if args.baseline_src else {})
    rows = measure(sources, args.repeat)
    if not args.no_main_job:
        rows.append(main_job())
    record = {"command": shlex.join(["python", "benchmarks/speed.py", *sys.argv[1:]]),
              "commit": git_commit(ROOT / "src" / "dualid") or "(no git)",
              "baseline": str(args.baseline_src) if args.baseline_src else None, "machine": machine(),
              "load_average": os.getloadavg(), "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
              "rows": rows}
    (HERE / "speed.json").write_text(json.dumps(record, indent=2) + "\n")
    text = markdown(record)
    (HERE / "speed.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
