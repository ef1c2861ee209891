"""``dualid reproduce SYSTEM``: the paper's comparison in simulation, with tables and figures."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from dualid.cli.app import FLAG, app
from dualid.cli.common import console, fail, output_dir

QUICK = {"data_seeds": 1, "seeds": 6}  # the default: one data set, its fits spread over the cores
FULL = {"data_seeds": 5, "seeds": 5}  # --full: the study of docs/results.md


def _cores() -> int:
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


@app.command()
def reproduce(
    system: str = typer.Argument(..., help="crazyflie, landsalp or pan-tilt"),
    out: Path = typer.Option(None, "--out", help="output directory (default: results/SYSTEM)"),
    case: str = typer.Option("both", "--case", help="low, high or both"),
    full: bool = typer.Option(False, "--full", metavar=FLAG,
                              help=f"the full study of docs/results.md: {FULL['data_seeds']} data sets × "
                                   f"{FULL['seeds']} low-data subsets (default: {QUICK['data_seeds']} × "
                                   f"{QUICK['seeds']})"),
    seeds: Optional[int] = typer.Option(None, "--seeds", help="random low-data subsets per data set "
                                        f"(default {QUICK['seeds']}; {FULL['seeds']} with --full)"),
    data_seeds: Optional[int] = typer.Option(None, "--data-seeds", help="simulated data sets (seeds 0..N-1), pooled "
                                             f"(default {QUICK['data_seeds']}; {FULL['data_seeds']} with --full)"),
    workers: Optional[int] = typer.Option(None, "--workers", help="processes, one fit each at a time "
                                          "(default: the usable cores)"),
    base_drag: bool = typer.Option(False, "--base-drag", metavar=FLAG,
                                   help="crazyflie: identify the base's linear (rotor) drag too"),
    noise: str = typer.Option("realistic", "--noise", help="realistic, ideal (Gaussian force noise only) or none"),
    size: str = typer.Option("default", "--size", help="default or small (a quick smoke run)"),
    ablation: str = typer.Option(None, "--ablation", help="'units': fit in re-charted coordinates (mm, degrees)"),
    force: bool = typer.Option(False, "--force", metavar=FLAG, help="overwrite an existing output directory"),
    margin: float = typer.Option(None, "--margin", metavar="EPS", help="every method under M(θ) ⪰ EPS·M(θ_WLS), a "
                                 "constrained WLS pilot per training set (docs/margin.md); 0 ≤ EPS < 1"),
) -> None:
    """Simulate SYSTEM, fit every estimator in the low- and high-data cases and write
    results.json, results.md and the score and trajectory figures. Progress: one line per fit on stderr."""
    from dualid.cli.common import one_blas_thread

    one_blas_thread()  # before numpy loads; the pool's workers inherit it (one process per core, small products)
    import time
    from functools import partial
    from typing import get_args

    from dualid.cli.common import count_progress, progress_line
    from dualid.report.study import reproduce as run
    from dualid.report.study import study_markdown
    from dualid.systems.base import Noise, Size, system_names

    if system not in system_names():
        fail(f"unknown system {system!r}; expected one of {', '.join(system_names())}")
    for flag, value, allowed in (("--case", case, ("low", "high", "both")), ("--noise", noise, get_args(Noise)),
                                 ("--size", size, get_args(Size))):
        if value not in allowed:
            fail(f"{flag}: expected one of {', '.join(allowed)}, got {value!r}")
    if base_drag and system != "crazyflie":
        fail(f"--base-drag: only the crazyflie has a floating base to put drag on, got {system!r}")
    if ablation is not None and ablation != "units":
        fail(f"--ablation: expected units, got {ablation!r}")
    if margin is not None and not 0.0 <= margin < 1.0:
        fail(f"--margin: expected a number in [0, 1), got {margin!r}")
    plan = FULL if full else QUICK
    seeds = plan["seeds"] if seeds is None else seeds
    data_seeds = plan["data_seeds"] if data_seeds is None else data_seeds
    for flag, value, what in (("--seeds", seeds, "seeds"), ("--data-seeds", data_seeds, "data sets"),
                              ("--workers", workers, "processes")):
        if value is not None and value < 1:
            fail(f"{flag}: expected a positive number of {what}, got {value}")
    workers = workers or _cores()
    out = out or Path("results") / system
    output_dir(out, force)  # before the study, not after it
    start = time.perf_counter()
    progress_line(f"{system}: {data_seeds} data set(s) × ({seeds} low-data subsets + all samples) × every method, "
                  f"{workers} process(es){'' if full else '; the full study: --full'}", start)
    try:
        result = run(system, out, case=case, seeds=seeds, noise=noise, size=size, ablation=ablation,
                     overwrite=force, progress=partial(count_progress, start), data_seeds=data_seeds,
                     workers=workers, **({"base_drag": True} if base_drag else {}),
                     **({} if margin is None else {"margin": margin}))
    except FileExistsError as exc:
        fail(f"{exc}; pass --force to overwrite it")
    progress_line(f"done in {time.perf_counter() - start:.0f} s", start)
    console.print(study_markdown(result), markup=False)
    console.print(f"wrote {out}/results.json, results.md and figures", markup=False)
