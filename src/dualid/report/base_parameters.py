"""Base parameters and their intervals in a fit's report.md and parameters.yaml (dualid.robot.fit outcome)."""

from __future__ import annotations

from dualid.identifiability import BaseParameters
from dualid.report.document import Bullets, Section, Table, Text

UNCERTAINTY_NOTE = (
    "Base parameters: the combinations of parameters the data determine (QR with column pivoting of the "
    "column-scaled regressor); lower/upper: 95 % intervals from the sandwich covariance H⁻¹BH⁻¹ of each "
    "method's own objective (H its Hessian in base coordinates, B the outer products of its gradients summed "
    "over segments of the training runs), Student-t with (segments − base parameters) degrees of freedom. "
    "Constraints active at the estimate are listed, not used: the intervals are those of the unconstrained "
    "local fit, so an interval may reach past a bound (below 0 for a friction fitted at 0). They cover "
    "sampling noise only: model error and a biased objective (dm-paper) are not in them. "
    "std_error of a parameter: its base parameter's, when it is a base parameter on its own; otherwise "
    "'not identifiable'; null: no uncertainty (see the method's base_parameters.error)."
)


def definitions(base: BaseParameters) -> list[dict]:
    """[{name, unit, definition}] of every base parameter, and the parameters with no effect."""
    return [{"name": b.name, "unit": b.unit, "definition": b.expression(6)} for b in base.items]


def method_record(fit) -> dict:
    """parameters.yaml's base_parameters entry of one method's fit (a dualid.robot.fit.MethodFit)."""
    if fit.base is None:
        return {"error": fit.base_error or "not computed"}
    u = fit.base
    return {
        "uncertainty": u.summary(),
        "active_constraints": list(u.active),
        "values": [{k: r[k] for k in ("name", "unit", "value", "std_error", "lower", "upper")} for r in u.records()],
    }


def _cell(fit, k: int) -> str:
    if fit.base is None:
        return "—"
    u = fit.base
    return f"{u.values[k]:.4g} [{u.lower[k]:.4g}, {u.upper[k]:.4g}]"


def base_section(outcome) -> Section:
    """The report's 'Base parameters' section: their definitions and, per fitted method, value [95 % interval]
    (empty, hence not shown, without base parameters)."""
    base = outcome.identifiability.base
    if base is None:
        return Section("Base parameters")
    ok = {m: f for m, f in outcome.fits.items() if f.ok}
    rows = tuple((f"β{k + 1}", b.unit, b.expression(), *(_cell(f, k) for f in ok.values()))
                 for k, b in enumerate(base.items))
    blocks: list = [
        Text(f"{base.rank} combinations of the {base.parameters.p} parameters are determined by the data; each is "
             "named after its lead parameter and absorbs the dependent ones with the coefficients shown. "
             "Value [95 % interval] per method (see parameters.yaml's uncertainty_note)."),
        Table(("β", "unit", "definition", *ok), rows),
    ]
    if base.no_effect:
        names = base.parameters.names
        blocks.append(Text(f"No effect on these data ({len(base.no_effect)}): "
                           + ", ".join(names[j] for j in base.no_effect)))
    notes = [f"{m}: {f.base.summary()}" for m, f in ok.items() if f.base is not None]
    notes += [f"{m}: no intervals ({f.base_error})" for m, f in ok.items() if f.base is None]
    if notes:
        blocks.append(Bullets(tuple(notes)))
    return Section("Base parameters", tuple(blocks))
