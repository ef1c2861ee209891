"""``dualid fit-stream``: fit one method to logs streamed in chunks (data larger than memory), a progress bar
per pass over the data."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Optional

import typer
from rich.text import Text

from dualid.cli.app import FLAG, app
from dualid.cli.common import EXIT_FAILED, console, fail, print_warning

EXPLAINED = 0.5  # warn when the fit explains less than this share of the effort's variance (R²)


@app.command("fit-stream")
def fit_stream(
    model: Path = typer.Option(..., "--model", help="URDF of the robot"),
    data: list[Path] = typer.Option(..., "--data", help="Parquet file (columns q_0.., v_/a_/tau_<joint>), a directory "
                                    "of q.npy, v.npy, a.npy, tau.npy (memory-mapped), or a log read as dualid fit reads "
                                    "it: a ROS bag, or any log with --config; with --workers/--scheduler one or more "
                                    "Parquet files (repeat --data), one task per file"),
    config: Optional[Path] = typer.Option(None, "--config", help="fit.yaml whose columns (or columns.topics) and "
                                          "preprocessing read --data as a log; the log is read whole"),
    method: str = typer.Option("ols", "--method", help="ols, ols_unconstrained, wls, energy, dm, dm-paper"),
    floating_base: bool = typer.Option(False, "--floating-base", metavar=FLAG, help="the URDF's root is free"),
    chunk: int = typer.Option(65536, "--chunk", help="samples per chunk (memory: chunk·n·p floats for Y)"),
    strict: bool = typer.Option(False, "--strict", metavar=FLAG,
                                help="fail when the data do not determine every parameter (by default, as dualid "
                                     "fit does, the fit returns one minimiser on the closed feasible set and says "
                                     "which parameters the data leave open)"),
    workers: int = typer.Option(0, "--workers", help="run the passes on a local Dask cluster of this many worker "
                                "processes (needs dualid[distributed])"),
    scheduler: Optional[str] = typer.Option(None, "--scheduler", help="run the passes on the Dask cluster whose "
                                            "scheduler is at this address (e.g. tcp://host:8786)"),
) -> None:
    """Fit without loading the data: every pass reads the file chunk by chunk and builds the regressor on the
    fly, so memory holds one chunk. Prints the identified parameters, the objective and the passes made. With
    --workers or --scheduler the passes run on a Dask cluster, one task per file, and only sums travel."""
    from dualid.model.rigid_body import RigidBodyModel
    from dualid.streaming import ChunkedProblem

    if method in ("logdet", "pullback"):
        fail(f"--method {method}: not available for streamed data (needs a prior θ₀ or a weight per sample); "
             "use ols, ols_unconstrained, wls, energy, dm or dm-paper")
    if chunk < 1:
        fail(f"--chunk: expected a positive number of samples, got {chunk}")
    rb = RigidBodyModel.from_urdf(model, floating_base=floating_base)
    if workers or scheduler:
        _fit_spread(rb, data, method, chunk, strict, workers, scheduler, config)
        return
    if len(data) != 1:
        fail(f"--data: {len(data)} files given; several files are read by a Dask cluster (--workers N or --scheduler)")
    data = data[0]
    source = open_source(rb, data, config, chunk)
    if source.N < 2 or source.N * rb.nv < rb.parameters.p:
        fail(f"--data {data}: {source.N} sample{'s' * (source.N != 1)} × {rb.nv} coordinates = {source.N * rb.nv} "
             f"equations for {rb.parameters.p} parameters; a fit needs more samples")
    _fit_and_print(rb, method, strict, lambda report: ChunkedProblem(rb, source, report))


def open_source(rb, data: Path, config: Optional[Path], chunk: int, log_suffixes: tuple[str, ...] = ()):
    """The samples of ``data`` for ``rb``: a log read as ``dualid fit`` reads it (with ``config``, a bag, or a file
    whose suffix is in ``log_suffixes``), a directory of .npy arrays, or a Parquet file of q_/v_/a_/tau_ columns."""
    from dualid.data.bags import is_bag
    from dualid.robot.config import FitConfig
    from dualid.robot.stream_source import log_source
    from dualid.streaming import ArraySource, ParquetSource

    if config is not None or is_bag(data) or data.suffix.lower() in log_suffixes:
        cfg = None if config is None else FitConfig.from_yaml(config)
        return log_source(rb, [data], None if cfg is None else cfg.columns, None if cfg is None else cfg.preprocessing,
                          chunk=chunk)
    if data.is_dir():
        return ArraySource.from_npy(data, chunk=chunk)
    return ParquetSource(data, rb.coordinates, rb.nq, chunk=chunk)


def _fit_spread(rb, data: list[Path], method: str, chunk: int, strict: bool, workers: int,
                scheduler: Optional[str], config: Optional[Path]) -> None:
    """The fit's passes as one task per Parquet file on a Dask cluster (local, or at ``scheduler``)."""
    try:
        from distributed import Client
    except ImportError:
        fail("--workers/--scheduler need dask.distributed: pip install 'dualid[distributed]'")
    from dualid.distributed import DaskProblem, local_client

    if workers and scheduler:
        fail("--workers and --scheduler: give one (a local cluster of N workers, or a running cluster's address)")
    if workers < 0:
        fail(f"--workers: expected a positive number of worker processes, got {workers}")
    if config is not None or any(p.is_dir() for p in data):
        fail("--workers/--scheduler read Parquet files (columns q_0.., v_/a_/tau_<joint>), not --config logs or .npy "
             "directories")
    try:
        client = local_client(workers) if workers else Client(scheduler, timeout=5)
    except OSError as exc:
        fail(f"--scheduler {scheduler}: no Dask scheduler reached ({exc})")
    try:
        typer.echo(f"Dask cluster: {len(client.scheduler_info()['workers'])} workers "
                   f"({'local' if workers else scheduler}), {len(data)} file{'s' * (len(data) != 1)}")
        _fit_and_print(rb, method, strict,
                       lambda report: DaskProblem.from_files(rb, data, client, chunk=chunk, progress=report))
    finally:
        cluster = client.cluster if workers else None
        client.close()
        if cluster is not None:
            cluster.close()


def _fit_and_print(rb, method: str, strict: bool, make_problem) -> None:
    """Fit ``make_problem(progress)`` with one progress bar per pass; print θ̂, the objective, the passes, R²."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from dualid.estimators.methods import make_estimator

    estimator = make_estimator(method, allow_unidentifiable=True)
    columns = (TextColumn("{task.description}", markup=False), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    with Progress(*columns, console=console) as progress:
        tasks: dict[int, int] = {}

        def report(k: int, done: int, total: int) -> None:  # one bar per pass over the data
            if k not in tasks:
                tasks[k] = progress.add_task(f"pass {k}", total=total)
            progress.update(tasks[k], completed=done)

        problem = make_problem(report)
        ident = problem.identifiability()
        unseen = ", ".join(ident.unidentifiable) or "(combinations only)"
        if ident.rank < problem.p and strict:
            progress.stop()
            fail(f"--strict: the data determine {ident.rank} of {problem.p} parameter combinations, not θ; "
                 f"not identifiable on these data: {unseen}", EXIT_FAILED)
        t0 = time.perf_counter()
        result = estimator.fit(problem)
        wall = time.perf_counter() - t0
    if ident.rank < problem.p:
        console.print(Text(f"note: the data determine {ident.rank} of {problem.p} parameter combinations (base "
                           f"parameters); θ̂ is one minimiser on the closed feasible set. Not identifiable on these data: "
                           f"{unseen}. dualid fit makes such "
                           "parameters plausible against the URDF's inertials; --strict fails here instead."),
                      highlight=False)
    typer.echo(f"{method}: {result.status} ({result.solver}), objective {result.objective:.10g}, "
               f"N = {problem.N:,}, {problem.passes} passes over the data, {wall:.1f} s")
    for name, value in result.named().items():
        typer.echo(f"  {name:32s} {value: .6g}")
    r2 = problem.explained(result.theta)
    if not r2 >= EXPLAINED:
        print_warning(f"the fitted model explains {100 * r2:.1f} % of the logged effort's variance (R² = {r2:.3g}): "
                      f"are these logs of this robot, with q, v, a, tau in the model's order ({', '.join(rb.coordinates)}) "
                      "and SI units?")
