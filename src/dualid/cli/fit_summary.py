"""What ``dualid fit`` prints after a rigid-body fit: each method's plausible parameters (and the parameters the data
do not determine), a failed plausible step, and the files written (and, for any not written, why)."""

from __future__ import annotations

from pathlib import Path

from dualid.cli.common import console, print_error

FIGURE_SUFFIXES = (".png", ".svg")


def print_plausible(outcome) -> list[str]:
    """One line per method with plausible parameters: how they were chosen and every parameter the prior set (the
    data do not determine it). Returns the methods whose plausible step failed (printed as errors)."""
    failed = []
    for m, f in outcome.fits.items():
        if not f.ok:
            continue
        if f.plausible_error:
            print_error(f"{m}: plausible parameters failed: {f.plausible_error}; its model files carry the raw fit θ̂")
            failed.append(m)
            continue
        p = f.plausible
        if p is None:
            continue
        inside = "≤" if p.status != "outside_region" else "> the radius"
        where = (f"in the {p.level:g} confidence region (statistic {p.statistic:.3g} {inside} {p.radius2:.3g})"
                 if p.form == "confidence" else "with the training predictions of θ̂")
        by_prior = p.by_prior()
        console.print(f"{m}: the model files carry the parameters closest to the prior {where}; "
                      f"{len(by_prior)} parameters the data do not determine come from the prior"
                      + (f": {', '.join(by_prior)}" if by_prior else ""), markup=False, highlight=False)
    return failed


def files_line(written: dict[str, Path], out: Path, outcome) -> str:
    """'wrote A, B, … and N figures to OUT; not written: X (why), …' from write_fit's {name: path} and the model
    files each method should have (the reasons come from the parameters.json just written)."""
    import json

    names = [n for n in written if not n.endswith(FIGURE_SUFFIXES)]
    figures = len(written) - len(names)
    order = {"parameters.yaml": 0, "parameters.json": 1}
    names.sort(key=lambda n: order.get(n, 2 if n.endswith((".urdf", ".xml")) else 3))  # stable within a group
    text = f"wrote {', '.join(names)}" + (f" and {figures} figures" if figures else "") + f" to {out}"
    missing = []
    record = {}
    if (out / "parameters.json").is_file():
        record = json.loads((out / "parameters.json").read_text()).get("methods", {})
    for m, f in outcome.fits.items():
        if not f.ok:
            missing.append(f"{m}.urdf and {m}.xml (the fit failed)")
            continue
        whys = {name: str(record.get(m, {}).get(key) or "unknown").removeprefix("not written: ")
                for key, name in (("urdf", f"{m}.urdf"), ("mjcf", f"{m}.xml")) if name not in written}
        if len(whys) == 2 and len(set(whys.values())) == 1:  # one reason for both files: said once
            missing.append(f"{m}.urdf and {m}.xml ({whys[f'{m}.urdf']})")
        else:
            missing += [f"{name} ({why})" for name, why in whys.items()]
    return text + (f"; not written: {'; '.join(missing)}" if missing else "")


def print_summary(outcome, written: dict[str, Path], out: Path) -> list[str]:
    """What ``dualid fit`` prints after a rigid-body fit; returns the methods that failed (a fit or its plausible
    step), which make the exit code 1."""
    import typer

    from dualid.report.robot import score_table

    console.print(outcome.identifiability.describe(max_items=0), markup=False)
    for m, f in outcome.fits.items():
        if f.ok:
            chain = f.result.info.get("solver_chain")
            used = f" — fallback: {chain}" if f.result.info.get("fallback_used") else ""
            console.print(f"{m}: {f.result.status} in {f.result.solve_time:.2f} s ({f.result.solver}){used}", markup=False)
    validations = {m: f.validation for m, f in outcome.fits.items() if f.validation is not None}
    validations.update({k: v for k, (_, v) in outcome.references.items() if v is not None})
    if validations:
        typer.echo(score_table(validations))
    failed = [m for m, f in outcome.fits.items() if not f.ok]
    for m in failed:
        print_error(f"{m}: failed: {outcome.fits[m].error}")
    failed += print_plausible(outcome)
    failed += [m for m, f in outcome.fits.items() if f.ok and f.files_refused and m not in failed]
    console.print(files_line(written, out, outcome) + (" (incomplete: see report.html)" if failed else ""),
                  markup=False, highlight=False)
    return failed
