"""``dualid fit-stream``: fit one method to logs streamed in chunks (data larger than memory), a progress bar
per pass over the data."""

from __future__ import annotations

import time
from pathlib import Path

import typer

from dualid.cli.app import FLAG, app
from dualid.cli.common import console, fail, print_warning

EXPLAINED = 0.5  # warn when the fit explains less than this share of the effort's variance (R²)


@app.command("fit-stream")
def fit_stream(
    model: Path = typer.Option(..., "--model", help="URDF of the robot"),
    data: Path = typer.Option(..., "--data", help="Parquet file (columns q_0.., v_/a_/tau_<joint>) or a directory "
                                                  "of q.npy, v.npy, a.npy, tau.npy (memory-mapped)"),
    method: str = typer.Option("ols", "--method", help="ols, ols_unconstrained, wls, energy, dm, dm-paper"),
    floating_base: bool = typer.Option(False, "--floating-base", metavar=FLAG, help="the URDF's root is free"),
    chunk: int = typer.Option(65536, "--chunk", help="samples per chunk (memory: chunk·n·p floats for Y)"),
    allow_unidentifiable: bool = typer.Option(False, "--allow-unidentifiable", metavar=FLAG,
                                              help="accept one minimiser when the data do not determine θ"),
) -> None:
    """Fit without loading the data: every pass reads the file chunk by chunk and builds the regressor on the
    fly, so memory holds one chunk. Prints the identified parameters, the objective and the passes made."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from dualid.estimators.methods import make_estimator
    from dualid.model.rigid_body import RigidBodyModel
    from dualid.streaming import ArraySource, ChunkedProblem, ParquetSource

    if method in ("logdet", "pullback", "dm-bfp"):
        fail(f"--method {method}: not available for streamed data (needs a prior θ₀ or a weight per sample); "
             "use ols, ols_unconstrained, wls, energy, dm or dm-paper")
    if chunk < 1:
        fail(f"--chunk: expected a positive number of samples, got {chunk}")
    rb = RigidBodyModel.from_urdf(model, floating_base=floating_base)
    if data.is_dir():
        source = ArraySource.from_npy(data, chunk=chunk)
    else:
        source = ParquetSource(data, rb.coordinates, rb.nq, chunk=chunk)
    if source.N < 2 or source.N * rb.nv < rb.parameters.p:
        fail(f"--data {data}: {source.N} sample{'s' * (source.N != 1)} × {rb.nv} coordinates = {source.N * rb.nv} "
             f"equations for {rb.parameters.p} parameters; a fit needs more samples")
    estimator = make_estimator(method, allow_unidentifiable=allow_unidentifiable)
    columns = (TextColumn("{task.description}", markup=False), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    with Progress(*columns, console=console) as progress:
        tasks: dict[int, int] = {}

        def report(k: int, done: int, total: int) -> None:  # one bar per pass over the data
            if k not in tasks:
                tasks[k] = progress.add_task(f"pass {k}", total=total)
            progress.update(tasks[k], completed=done)

        problem = ChunkedProblem(rb, source, report)
        t0 = time.perf_counter()
        result = estimator.fit(problem)
        wall = time.perf_counter() - t0
    typer.echo(f"{method}: {result.status} ({result.solver}), objective {result.objective:.10g}, "
               f"N = {problem.N:,}, {problem.passes} passes over the data, {wall:.1f} s")
    for name, value in result.named().items():
        typer.echo(f"  {name:32s} {value: .6g}")
    r2 = problem.explained(result.theta)
    if not r2 >= EXPLAINED:
        print_warning(f"the fitted model explains {100 * r2:.1f} % of the logged effort's variance (R² = {r2:.3g}): "
                      f"are these logs of this robot, with q, v, a, tau in the model's order ({', '.join(rb.coordinates)}) "
                      "and SI units?")
