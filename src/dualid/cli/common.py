"""Helpers shared by the command modules: printing errors and preparing output folders."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console

console = Console(stderr=True, soft_wrap=True)  # never hard-wrap messages: users grep them


def fail(message: str, code: int = 1) -> None:
    """Print an error in red and exit with ``code``."""
    console.print(f"[bold red]error:[/] {message}")
    raise typer.Exit(code)


def output_dir(path: Path, force: bool) -> Path:
    """Check --out against the output-directory policy before any work (dualid.report.outdir)."""
    from dualid.errors import OutputError
    from dualid.report.outdir import check_output_dir

    try:
        return check_output_dir(path, force)
    except OutputError as exc:
        fail(str(exc))
        raise  # unreachable: fail exits
