"""``dualid reproduce SYSTEM``: the paper's comparison in simulation, with tables and figures."""

from __future__ import annotations

from pathlib import Path

import typer

from dualid.cli.app import FLAG, app
from dualid.cli.common import console, fail, output_dir


@app.command()
def reproduce(
    system: str = typer.Argument(..., help="crazyflie, landsalp or pan-tilt"),
    out: Path = typer.Option(None, "--out", help="output directory (default: results/SYSTEM)"),
    case: str = typer.Option("both", "--case", help="low, high or both"),
    seeds: int = typer.Option(5, "--seeds", help="random low-data subsamples"),
    data_seeds: int = typer.Option(5, "--data-seeds", help="simulated data sets (seeds 0..N-1), pooled"),
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
    results.json, results.md and the score and trajectory figures."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from dualid.report.study import reproduce as run
    from dualid.report.study import study_markdown
    from dualid.systems.base import system_names

    if system not in system_names():
        fail(f"unknown system {system!r}; expected one of {', '.join(system_names())}")
    from typing import get_args

    from dualid.systems.base import Noise, Size

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
    if seeds < 1:
        fail(f"--seeds: expected a positive number of seeds, got {seeds}")
    out = out or Path("results") / system
    output_dir(out, force)  # before the study, not after it
    columns = (TextColumn("{task.description}", markup=False), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    try:
        with Progress(*columns, console=console) as progress:
            result = run(system, out, case=case, seeds=seeds, noise=noise, size=size, ablation=ablation,
                         overwrite=force, progress=progress, data_seeds=data_seeds,
                         **({"base_drag": True} if base_drag else {}), **({} if margin is None else {"margin": margin}))
    except FileExistsError as exc:
        fail(f"{exc}; pass --force to overwrite it")
    console.print(study_markdown(result), markup=False)
    console.print(f"wrote {out}/results.json, results.md and figures", markup=False)
