"""``dualid simulate SYSTEM --out DIR``: write a simulated data set."""

from __future__ import annotations

from pathlib import Path

import typer

from dualid.cli.app import FLAG, app
from dualid.cli.common import console, fail, output_dir


@app.command()
def simulate(
    system: str = typer.Argument(..., help="crazyflie, landsalp or pan-tilt"),
    out: Path = typer.Option(..., "--out", help="directory to write the data set to"),
    seed: int = typer.Option(0, "--seed", help="random seed"),
    noise: str = typer.Option("realistic", "--noise", help="realistic, ideal or none"),
    size: str = typer.Option("default", "--size", help="default or small"),
    fmt: str = typer.Option("parquet", "--format", help="parquet or npz"),
    force: bool = typer.Option(False, "--force", metavar=FLAG, help="overwrite an existing output directory"),
) -> None:
    """Simulate a system's training and test runs and save them with a dataset.json manifest."""
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    from dualid.report.dataset import save_dataset
    from dualid.systems.base import make_system, system_names

    if system not in system_names():
        fail(f"unknown system {system!r}; expected one of {', '.join(system_names())}")
    from typing import get_args

    from dualid.systems.base import Noise, Size

    for flag, value, allowed in (("--noise", noise, get_args(Noise)), ("--size", size, get_args(Size)),
                                 ("--format", fmt, ("parquet", "npz"))):
        if value not in allowed:
            fail(f"{flag}: expected one of {', '.join(allowed)}, got {value!r}")
    if seed < 0:
        fail(f"--seed: expected an integer ≥ 0, got {seed}")
    output_dir(out, force)
    with Progress(SpinnerColumn(), TextColumn("{task.description}", markup=False), TimeElapsedColumn(), console=console) as bar:
        task = bar.add_task(f"simulating {system} (seed {seed}, noise {noise})", total=None)
        data = make_system(system, seed=seed, noise=noise, size=size)
        bar.update(task, description=f"writing {out}")
        info = {
            "system": data.name,
            "seed": seed,
            "noise": noise,
            "size": size,
            "parameter_names": list(data.model.parameters.names),
            "parameter_units": list(data.model.parameters.units),
            "theta_true": [float(x) for x in data.theta_true],
            "theta_nominal": [float(x) for x in data.theta_nominal],
            "description": data.description,
        }
        save_dataset(out, {"train": list(data.train), "test": list(data.test)}, info, fmt=fmt, overwrite=force)
    n_samples = sum(t.T for t in data.train + data.test)
    console.print(f"wrote {len(data.train)} training and {len(data.test)} test runs ({n_samples} samples) to {out}",
                  markup=False)
