"""Where a user waits: `import dualid`, `dualid --help`, the DFKI example fit and the README's main job, measured
side by side in one run as child processes (wall time and CPU time of the process and its children), against
the targets. Writes benchmarks/speed.json and benchmarks/speed.md (quoted by docs/performance.md).

    python benchmarks/speed.py                 # everything (the main job: about 250 s of CPU over the cores)
    python benchmarks/speed.py --no-main-job   # the quick three only

Run it on a quiet machine: wall times of a loaded machine say little (the load average is recorded).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HERE = Path(__file__).resolve().parent
DFKI = ROOT / "examples" / "dfki"
ENV = {**os.environ, "PYTHONPATH": f"{ROOT / 'src'}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
DUALID = [sys.executable, "-m", "dualid.cli"]


def run(cmd: list[str], cwd: Path = ROOT) -> dict:
    """Wall and CPU (user + system, the process and every child it waited for) seconds of one command."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=cwd, env=ENV, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if proc.returncode != 0:
        sys.exit(f"{' '.join(cmd)} exited {proc.returncode}:\n{proc.stderr[-2000:]}")
    return {"wall_s": wall, "cpu_s": cpu, "stdout": proc.stdout, "stderr": proc.stderr}


def best_of(cmd: list[str], repeat: int) -> dict:
    runs = [run(cmd) for _ in range(repeat)]
    return {"wall_s": min(r["wall_s"] for r in runs), "cpu_s": min(r["cpu_s"] for r in runs), "repeat": repeat}


def import_time() -> float:
    """The cumulative import time of the dualid package by `python -X importtime` [s]."""
    err = run([sys.executable, "-X", "importtime", "-c", "import dualid"])["stderr"]
    line = [x for x in err.splitlines() if x.rstrip().endswith("| dualid")][-1]
    return int(line.split("|")[1]) / 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-main-job", action="store_true", help="skip `dualid reproduce crazyflie`")
    ap.add_argument("--repeat", type=int, default=5, help="repetitions of the quick commands (best kept)")
    args = ap.parse_args()
    rows = []
    imp = best_of([sys.executable, "-c", "import dualid"], args.repeat)
    imp["importtime_s"] = min(import_time() for _ in range(args.repeat))
    rows.append(("python -c 'import dualid'", imp, "wall ≤ 1 s", imp["wall_s"] <= 1.0))
    help_ = best_of([*DUALID, "--help"], args.repeat)
    rows.append(("dualid --help", help_, "wall ≤ 0.5 s", help_["wall_s"] <= 0.5))
    with tempfile.TemporaryDirectory() as tmp:
        fit = run([*DUALID, "fit", "--config", "fit.yaml", "--out", f"{tmp}/fit", "--verbose"], cwd=DFKI)
        stages = re.search(r"CPU time per stage \[s\]: (.*); total", fit["stderr"])
        fit["stages"] = dict((k.rsplit(" ", 1)[0], float(k.rsplit(" ", 1)[1])) for k in stages.group(1).split(", "))
        del fit["stdout"], fit["stderr"]
        rows.append(("dualid fit --config examples/dfki/fit.yaml", fit, "CPU ≤ 3 s", fit["cpu_s"] <= 3.0))
        if not args.no_main_job:
            job = run([*DUALID, "reproduce", "crazyflie", "--out", f"{tmp}/crazyflie"])
            job["progress_lines"] = sum(1 for line in job["stderr"].splitlines() if line.startswith("["))
            del job["stdout"], job["stderr"]
            rows.append(("dualid reproduce crazyflie", job, "wall ≤ 90 s", job["wall_s"] <= 90.0))
    for _, r, _, _ in rows:
        r.pop("stdout", None), r.pop("stderr", None)
    record = {"python": sys.version.split()[0], "cores": os.cpu_count(), "load_average": os.getloadavg(),
              "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
              "rows": [{"command": c, **r, "target": t, "met": m} for c, r, t, m in rows]}
    (HERE / "speed.json").write_text(json.dumps(record, indent=2) + "\n")
    lines = ["# Where a user waits", "", f"`python benchmarks/speed.py` ({record['time_utc']}, {record['cores']} cores, "
             f"load average {', '.join(f'{x:.1f}' for x in record['load_average'])} at the end).", "",
             "| command | wall [s] | CPU [s] | target | met |", "| --- | --- | --- | --- | --- |"]
    for c, r, t, m in rows:
        lines.append(f"| `{c}` | {r['wall_s']:.2f} | {r['cpu_s']:.2f} | {t} | {'yes' if m else '**no**'} |")
    lines += ["", f"`import dualid` by `-X importtime`: {imp['importtime_s']:.3f} s. Quick commands: best of "
              f"{args.repeat}.", "", "CPU seconds per stage of the DFKI fit (`--verbose`): "
              + ", ".join(f"{k} {v:.2f}" for k, v in fit["stages"].items()) + "."]
    (HERE / "speed.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
