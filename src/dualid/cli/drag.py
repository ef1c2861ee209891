"""``dualid fit`` for a drag model (``model.kind: drag`` in the config): fit, write, print the scores."""

from __future__ import annotations

import typer

from dualid.cli.common import EXIT_FAILED, console, print_error, progress_status, show_warnings


def fit_drag_command(cfg, force: bool, config_file=None, command: str | None = None) -> None:
    """Run ``robot.drag_fit.fit_drag`` with a progress line and write ``report.drag`` into cfg.out."""
    import warnings

    from dualid.report.drag import score_table, write_drag_fit
    from dualid.robot.drag_fit import fit_drag

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            with progress_status() as say:
                outcome = fit_drag(cfg, progress=say)
                say(f"writing {cfg.out}")
                write_drag_fit(outcome, cfg.out, force, command=command, config_file=config_file)
        finally:
            show_warnings(caught)
    console.print(outcome.identifiability.describe(max_items=0), markup=False)
    for m, f in outcome.fits.items():
        if f.ok:
            used = f" — fallback: {f.result.info.get('solver_chain')}" if f.result.info.get("fallback_used") else ""
            console.print(f"{m}: {f.result.status} in {f.result.solve_time:.2f} s ({f.result.solver}){used}", markup=False)
    validations = {m: f.validation for m, f in outcome.fits.items() if f.validation is not None}
    if validations:
        typer.echo("held-out velocity NCC (v̂ = D̂⁻¹τ vs measured v):")
        typer.echo("\n".join(score_table(validations, "a_ncc")))
    failed = [m for m, f in outcome.fits.items() if not f.ok]
    console.print(f"wrote parameters, report.md and report.html to {cfg.out}"
                  + (" (incomplete: see report.html)" if failed else ""),
                  markup=False)
    for m in failed:
        print_error(f"{m}: failed: {outcome.fits[m].error}")
    if failed:
        raise typer.Exit(EXIT_FAILED)
