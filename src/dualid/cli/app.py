"""The typer application; importing the command modules registers their commands.

Exit codes (docs/cli.md): 0 every requested computation succeeded; 1 a requested computation
failed (e.g. one fit method: the others' outputs are still written and the report says it is
incomplete); 2 bad input (usage, files, configs, logs, models, the output directory). A
``DualidError`` or a file-system error (``OSError``) never shows a traceback unless ``--debug``.
"""

from __future__ import annotations

import importlib

import typer
from typer.core import TyperGroup

from dualid.cli.common import error_exit_code, print_error

FLAG = ""  # metavar of boolean flags: help shows "--force", not "--force <bool>"


class DualidGroup(TyperGroup):
    """The command group: turns dualid's typed errors and file-system errors into a one-line message
    on stderr and a documented exit code (``--debug`` re-raises them with their traceback)."""

    def invoke(self, ctx):
        from dualid.errors import DualidError

        try:
            return super().invoke(ctx)
        except (DualidError, OSError) as exc:
            if ctx.params.get("debug"):
                raise
            print_error(exc)
            raise typer.Exit(error_exit_code(exc)) from None


app = typer.Typer(
    name="dualid",
    cls=DualidGroup,
    help="Coordinate-independent robot model identification (dual-metric least squares).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@app.callback()
def main(
    debug: bool = typer.Option(False, "--debug", metavar=FLAG, help="show the traceback of an error"),
) -> None:
    """dualid: identify robot models whose fit does not depend on coordinates, units or scaling.

    Exit codes: 0 success; 1 a requested fit or computation failed (other outputs written, report
    marked incomplete); 2 bad input (usage, files, config, logs, model, output directory)."""


# importing the command modules registers their commands on ``app``
@app.command()
def schema() -> None:
    """Print the JSON Schema of a fit config (docs/fit-config.schema.json; point your editor's YAML
    support at it for completion and checking)."""
    import json

    from dualid.robot.schema import json_schema

    typer.echo(json.dumps(json_schema(), indent=2, ensure_ascii=False))


for _module in ("simulate", "reproduce", "fit", "bench", "excite", "stream", "track", "inspect"):
    importlib.import_module(f"dualid.cli.{_module}")
