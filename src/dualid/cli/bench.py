"""``dualid bench``: time the dual-metric solvers (Newton, SDP) and constrained OLS against N."""

from __future__ import annotations

from pathlib import Path

import typer

from dualid.cli.app import FLAG, app
from dualid.cli.common import console, fail, output_dir


@app.command()
def bench(
    out: Path = typer.Option(Path("benchmarks/latest"), "--out", help="output directory"),
    quick: bool = typer.Option(False, "--quick", metavar=FLAG, help="smoke run: N ≤ 1,000 with the SDP (about a minute)"),
    max_n: int = typer.Option(None, "--max-n", help="largest N (default 1,000,000; 1,000 with --quick)"),
    problems: str = typer.Option("crazyflie,arm7", "--problems", help="comma-separated: crazyflie, arm7"),
    solvers: str = typer.Option(
        None, "--solvers",
        help="comma-separated: newton, sdp_clarabel, sdp_scs, ols_constrained (default all; --quick: no SCS)",
    ),
    sdp_max_n: int = typer.Option(None, "--sdp-max-n", help="largest N for the SDP solvers (default 10,000)"),
    cap: str = typer.Option("", "--cap", help="per-problem largest N, e.g. arm7=100000"),
    timeout: float = typer.Option(None, "--timeout", help="kill a single run after this many seconds"),
    budget: float = typer.Option(None, "--budget", help="skip a solver's larger N once one of its runs took longer [s]"),
    force: bool = typer.Option(False, "--force", metavar=FLAG, help="overwrite an existing non-empty output directory"),
) -> None:
    """Run every (problem, solver, N) in its own process and write results.json, results.md and
    scaling.png (log-log wall time and peak memory vs N) into the output directory."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from dualid.bench.runner import (
        PROBLEMS,
        SOLVERS,
        BenchConfig,
        parse_caps,
        parse_list,
        run_benchmark,
        time_ratios,
    )
    from dualid.report.bench import scaling_plot, to_markdown, write_results
    from dualid.report.figures import save_figure
    from dualid.report.outdir import write_output

    try:
        changes = {
            "problems": parse_list(problems, PROBLEMS, "problem"),
            "solvers": parse_list(solvers, SOLVERS, "solver") if solvers is not None else None,
            "max_n": max_n, "sdp_max_n": sdp_max_n, "timeout": timeout, "budget": budget, "caps": parse_caps(cap),
        }
        if quick:
            config = BenchConfig.quick(**changes)
        else:
            config = BenchConfig(**{k: v for k, v in changes.items() if v is not None})
    except ValueError as exc:
        fail(str(exc))
    out = output_dir(out, force)
    columns = (TextColumn("{task.description}", markup=False), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    with Progress(*columns, console=console) as progress:
        task = progress.add_task("benchmark runs", total=len(config.planned()))

        def report(done: int, total: int, row: dict | None) -> None:
            progress.update(task, completed=done, total=total)
            if row is not None:
                what = f"{row['problem']} {row['solver']} N={row['N']:,}"
                status = f"error: {row['error'][:60]}" if "error" in row else f"{row['wall_time_s']:.2f} s"
                progress.console.print(f"  {what}: {status}", markup=False)

        result = run_benchmark(config, progress=report)
    def write(d: Path) -> dict[str, Path]:
        js, md = write_results(result, d)
        return {"json": js, "md": md, "png": save_figure(scaling_plot(result), d / "scaling.png")}

    paths = write_output(out, force, write)
    json_path, md_path, png = paths["json"], paths["md"], paths["png"]
    typer.echo(to_markdown(result))
    for (problem, N), ratio in sorted(time_ratios(result, "newton", "sdp_clarabel").items()):
        typer.echo(f"{problem} N={N:,}: SDP (Clarabel) / Newton wall time = {ratio:.1f}×")
    console.print(f"wrote {json_path}, {md_path} and {png}", markup=False)
