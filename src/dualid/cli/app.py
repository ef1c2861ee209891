"""The typer application; importing the command modules registers their commands."""

from __future__ import annotations

import importlib

import typer

app = typer.Typer(
    name="dualid",
    help="Coordinate-independent robot model identification (dual-metric least squares).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)




@app.callback()
def main() -> None:
    """dualid: identify robot models whose fit does not depend on coordinates, units or scaling."""


# importing the command modules registers their commands on ``app``
for _module in ("simulate", "reproduce", "fit", "bench"):
    importlib.import_module(f"dualid.cli.{_module}")
