"""``dualid excite --model ROBOT.urdf --out DIR``: design an optimal excitation trajectory."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from dualid.cli.app import FLAG, app
from dualid.cli.common import console, output_dir


@app.command()
def excite(
    model: Path = typer.Option(..., "--model", help="the robot's URDF (fixed base)"),
    out: Path = typer.Option(..., "--out", help="output directory"),
    config: Optional[Path] = typer.Option(None, "--config", help="excite.yaml (limits, period, harmonics, criterion, ...)"),
    criterion: Optional[str] = typer.Option(None, "--criterion", help="dm (default), logdet or cond"),
    seed: Optional[int] = typer.Option(None, "--seed", help="seed of the random restarts (default 0)"),
    restarts: Optional[int] = typer.Option(None, "--restarts", help="number of SLSQP restarts (default 4)"),
    force: bool = typer.Option(False, "--force", metavar=FLAG, help="write into an existing non-empty output directory"),
) -> None:
    """Optimise a periodic Fourier-series trajectory (at rest at both ends) for identification under the
    URDF's joint limits; write trajectory.csv, coefficients.yaml, trajectory.png and identifiability.md/json."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from dualid.excite import ExciteConfig, build_design, optimize
    from dualid.excite.collision import link_distance
    from dualid.excite.predict import predict
    from dualid.model.rigid_body import RigidBodyModel
    from dualid.report.excite import write_excite

    cfg = ExciteConfig.from_yaml(config) if config is not None else ExciteConfig()
    cfg = cfg.with_overrides(criterion=criterion, seed=seed, restarts=restarts)
    output_dir(out, force)
    rigid = RigidBodyModel.from_urdf(model)
    design = build_design(rigid, cfg, seed=cfg.seed)
    notes = list(design.limits.notes)
    distance = None
    if cfg.min_distance is not None:
        distance, note = link_distance(model, rigid)
        notes.append(note)
    else:
        notes.append("min_distance not set: link distances were not constrained")
    columns = (TextColumn("{task.description}", markup=False), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    with Progress(*columns, console=console) as bar:
        task = bar.add_task(f"optimising ({cfg.criterion}, {cfg.restarts} restarts)", total=cfg.restarts)

        def report(done: int, total: int, best: float | None) -> None:
            bar.update(task, completed=done, description=f"optimising ({cfg.criterion}); best {best:.4g}")

        result = optimize(design, cfg, report, distance)
    if result.scaled:
        notes.append(f"the optimum exceeded a limit between grid samples; it was scaled by "
                     f"{result.restarts[result.best].scale:.4f} to hold every limit at {cfg.check_rate:g} Hz")
    prediction = predict(design, result.trajectory, cfg.rate, cfg.torque_noise)
    paths = write_excite(result, prediction, out, force, notes)
    ident = prediction.identifiability
    typer.echo(f"criterion {cfg.criterion}: {result.value:.4g}; rank {ident.rank} of {ident.n_params}, "
               f"{len(prediction.base_names)} base parameters, condition number {prediction.cond:.4g} (column-scaled)")
    for note in notes:
        typer.echo(f"note: {note}")
    console.print(f"wrote {', '.join(str(p) for p in paths.values())}", markup=False)
