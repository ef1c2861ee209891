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
    """Refuse an existing non-empty directory unless --force was given."""
    if path.exists() and (not path.is_dir() or any(path.iterdir())) and not force:
        fail(f"{path} already exists and is not empty; pass --force to overwrite it")
    path.mkdir(parents=True, exist_ok=True)
    return path
