"""The fit and validation reports as one value (``document.Report``), built once from the outcome and
rendered by the Markdown and HTML writers alike.

A section is one function of ``FitReportData`` returning a ``Section``; ``FIT_SECTIONS`` lists them
in order, so a new section (e.g. base parameters with intervals) is one function and one line.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from dualid.evaluation.validation import Validation
from dualid.report.base_parameters import base_section
from dualid.report.document import (
    Bullets,
    Image,
    Pre,
    Report,
    Section,
    Table,
    Text,
    chunks,
    fmt,
    fmt_value,
    mean_cell,
    runs_phrase,
)
from dualid.report.metadata import metadata_items
from dualid.report.model_figures import body_section, friction_section
from dualid.report.model_files import ModelFiles, model_files_section, plausible_section
from dualid.report.render import table_markdown
from dualid.report.svgplot import score_svg, signal_svg
from dualid.robot.fit import FitOutcome

JOINTS_PER_TABLE = 7  # score tables of more joints are split into groups
SCORES = (("tau_rmse", "τ RMSE [N m]"), ("tau_ncc", "τ NCC"), ("a_ncc", "a NCC"))
SCORE_NOTE = ("τ: inverse dynamics τ̂ = Y(q, v, a)θ̂ from measured q, v and differentiated a, against the measured "
              "effort. a: forward dynamics â = M̂⁻¹(τ − ĥ) from measured q, v, τ, against the differentiated "
              "accelerations. NCC: normalized cross-correlation, maximum over shifts within ±{window} s.")
SOLVER_NOTES = ("fallback_reason", "solver_warnings", "fallback", "pilot", "projected_parameters", "projected_note",
                "diverging_direction")  # the last three: an
# infimum approached only as parameters grow (model.closure; dm-paper's optimum at infinity)


NOTE_LABELS = {  # SOLVER_NOTES keys in a reader's words
    "fallback_reason": "why the first solver was not used",
    "solver_warnings": "solver warnings",
    "pilot": "first fitted with",
    "diverging_direction": "the objective keeps improving along",
}
PROJECTED = ("set to the smallest value consistent with the other parameters: the data do not determine it, no "
             "prediction depends on it (details: parameters.yaml)")


def notes_once(notes: list[str]) -> list[str]:
    """'a: text', 'b: text' → 'a, b: text': a note several methods share is shown once."""
    grouped: dict[str, list[str]] = {}
    for note in notes:
        who, sep, text = note.partition(": ")
        grouped.setdefault(text if sep else note, []).append(who if sep else "")
    return [f"{', '.join(w for w in who if w)}: {text}" if any(who) else text for text, who in grouped.items()]


def noise_note(m: str, noise) -> str:
    """dm's noise model (estimators.noise_dm): the levels it estimated, the share of the residual each explains,
    and what it returned."""
    sd_tau = ", ".join(f"{x:.3g}" for x in np.sqrt(np.diag(noise.sigma_tau)))
    sd_a = ", ".join(f"{x:.3g}" for x in np.sqrt(np.diag(noise.sigma_a)))
    return (f"{m}: noise model ({noise.source}): torque noise sd [{sd_tau}], acceleration noise sd [{sd_a}] (sensor "
            f"chart); shares of the residual: torque {noise.torque_share:.2f}, acceleration "
            f"{noise.acceleration_share:.2f}; result: {noise.choice}")


def slug(s: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", s)


# --- shared tables ------------------------------------------------------------------------------
def score_tables(validations: dict[str, Validation], what: str = "held-out") -> list[Table]:
    """One table per score (rows: models, columns: joints in groups of JOINTS_PER_TABLE), each cell the mean
    ± std over runs (a single run: its value, said in the title)."""
    first = next(iter(validations.values()))
    coords = first.coordinates
    n_runs = {len(v.runs) for v in validations.values()}
    runs = runs_phrase(n_runs.pop()) if len(n_runs) == 1 else "mean ± std over runs"
    tables = []
    for key, name in SCORES:
        groups = chunks(list(range(len(coords))), JOINTS_PER_TABLE)
        for g, idx in enumerate(groups):
            part = f" (joints {g + 1}/{len(groups)})" if len(groups) > 1 else ""
            rows = [(label, *[mean_cell([getattr(r, key)[j] for r in v.runs]) for j in idx])
                    for label, v in validations.items()]
            title = f"{what} {name}, {runs}{part}".strip()
            tables.append(Table(("model", *[coords[j] for j in idx]), tuple(rows), title=title))
    return tables


def per_run_table(validations: dict[str, Validation], key: str = "tau_rmse", name: str = "τ RMSE [N m]") -> Table:
    """Per run and joint (rows: run × model); the spread behind the means."""
    first = next(iter(validations.values()))
    rows = []
    for i, r0 in enumerate(first.runs):
        for label, v in validations.items():
            rows.append((r0.run, label, *[mean_cell([x]) for x in getattr(v.runs[i], key)]))
    return Table(("run", "model", *first.coordinates), tuple(rows), title=f"held-out {name} per run")


def preprocessing_table(steps: list) -> Table:
    rows = []
    for k, step in enumerate(steps, 1):
        name, settings = next(iter(step.items())) if isinstance(step, dict) and len(step) == 1 else ("step", step)
        rows.append((str(k), name, fmt_value(settings)))
    return Table(("#", "step", "settings"), tuple(rows),
                 title="preprocessing (numbers rounded to 4 significant digits; exact values in parameters.yaml)")


def run_section(meta: dict) -> Section:
    inputs = Table(("role", "file", "SHA-256"), tuple((i["role"], i["path"], i["sha256"] or "(missing)")
                                                     for i in meta["inputs"]), title="input files")
    return Section("Run", (Table(("", ""), metadata_items(meta)), inputs))


# --- the fit report -------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class FitReportData:
    """Everything a fit report shows, computed once: the outcome, the URDF each method wrote, run metadata
    and the training/held-out validations (methods that succeeded, then references)."""

    outcome: FitOutcome
    urdfs: dict[str, str]
    meta: dict
    train: dict[str, Validation] = field(default_factory=dict)
    held_out: dict[str, Validation] = field(default_factory=dict)
    model_files: ModelFiles | None = None  # what report.model_files.write_model_files wrote, and why not


def report_data(outcome: FitOutcome, urdfs: dict[str, str], meta: dict,
                model_files: ModelFiles | None = None) -> FitReportData:
    """The held-out validations of the outcome and the same scores on the training runs (θ̂ of each
    method and reference predicting the data it was fitted on; computed by ``robot.fit``)."""
    held = {m: f.validation for m, f in outcome.fits.items() if f.ok and f.validation is not None}
    held.update({lab: v for lab, (_, v) in outcome.references.items() if v is not None})
    return FitReportData(outcome, urdfs, meta, dict(outcome.training), held, model_files)


def _summary(d: FitReportData) -> Section:
    o, cfg = d.outcome, d.outcome.config
    items = [
        f"training runs: {', '.join(p.name for p in cfg.train)}",
        f"held-out runs: {', '.join(p.name for p in cfg.test) or '(none: no validation)'}",
        f"samples after preprocessing: {o.problem.N} × {o.problem.n} joints; parameters: {o.problem.p}",
        f"joint terms: viscous={cfg.joint_terms.viscous}, coulomb={cfg.joint_terms.coulomb} "
        f"(v_c = {cfg.joint_terms.coulomb_velocity} rad/s), armature={cfg.joint_terms.armature}",
    ]
    if o.preprocessing_note:
        items.append(f"preprocessing {o.preprocessing_note} (no 'preprocessing' in the config)")
    if o.prior:
        weight = f"γ = {cfg.prior.gamma} per equation (γ·N·n)" if cfg.prior.per_equation else f"γ = {cfg.prior.gamma}"
        items.append(f"prior of logdet/pullback ({weight}): {o.prior}")
    return Section("Summary", (Bullets(tuple(items)), preprocessing_table(o.steps)))


def _warnings(d: FitReportData) -> Section:
    return Section("Warnings", (Bullets(tuple(d.outcome.warnings)),) if d.outcome.warnings else ())


def _identifiability(d: FitReportData) -> Section:
    return Section("Identifiability", (Pre(d.outcome.identifiability_text()),))


def guard_cell(info: dict) -> str:
    """The generalised-eigenvalue range of M(θ̂) against the URDF's M, flagged when it left [1/100, 100]."""
    if "metric_ratio_min" not in info:
        return info.get("metric_guard_error", "—")
    cell = f"[{info['metric_ratio_min']:.2g}, {info['metric_ratio_max']:.2g}]"
    return f"degenerate {cell}" if info.get("degenerate") else cell


def margin_note(method: str, info: dict) -> str:
    """The margin M(θ) ⪰ ε·M(θ_ref) a fit was constrained by (dualid.model.margin), flagged where it binds."""
    active = info.get("margin_active") or ""
    where = f"ACTIVE at {active} (the data pulled θ̂ onto the margin)" if active else "not active"
    enforced = "" if info.get("margin_enforced", True) else " — NOT enforced (unconstrained fit)"
    return (f"{method}: margin ε = {fmt_value(info['margin_epsilon'])} against the {info.get('margin_reference')}: "
            f"smallest ratio C_b(θ̂) : C_b(θ_ref) {fmt_value(info.get('margin_min_ratio'))}, {where}{enforced}")


def fit_notes(m: str, r) -> list[str]:
    """What a reader should know about how method m's fit r was obtained: a solver chain that was not a fallback,
    the SOLVER_NOTES keys it recorded, dm's noise model, a margin."""
    chain = str(r.info.get("solver_chain", r.solver))
    notes = [f"{m}: solver chain: {chain}"] if "→" in chain and not r.info.get("fallback_used") else []
    for k in SOLVER_NOTES:
        if k == "projected_note":
            continue  # said by PROJECTED with the values
        if k == "projected_parameters" and k in r.info:
            values = re.sub(r" \(not determined by the data[^)]*\)", "", str(r.info[k]))
            notes.append(f"{m}: {values}: {PROJECTED}")
        elif k in r.info:
            notes.append(f"{m}: {NOTE_LABELS.get(k, k.replace('_', ' '))}: {fmt_value(r.info[k])}")
    notes += [noise_note(m, r.noise)] if getattr(r, "noise", None) is not None else []
    return notes + ([margin_note(m, r.info)] if "margin_epsilon" in r.info else [])


def plausible_cell(f) -> str:
    """The fit table's word on the plausible-parameter step: what the model files carry."""
    if f.plausible_error:
        return "failed (files carry θ̂; see Plausible parameters)"
    if f.plausible is None:
        return "—"
    p = f.plausible
    return (f"{p.solver}, {p.form}" + (f", {p.level:g}" if p.form == "confidence" else "")
            + (" (outside the region: see Plausible parameters)" if p.status == "outside_region" else ""))


def _fits(d: FitReportData) -> Section:
    rows, notes = [], []
    for m, f in d.outcome.fits.items():
        if not f.ok:
            rows.append((m, "failed", "—", "—", "—", "—", "—", "—", "—", "—", "—"))
            notes.append(f"{m}: failed: {f.error}")
            continue
        r = f.result
        chain = str(r.info.get("solver_chain", r.solver))
        said = [w for w in str(r.info.get("solver_warnings", "")).split(" | ") if w]
        rows.append((m, r.status, r.solver, chain if r.info.get("fallback_used") else "no",
                     f"{r.solve_time:.2f}", fmt(r.iterations), str(r.is_consistent), guard_cell(r.info),
                     "; ".join(said) if said else "none", plausible_cell(f), d.urdfs.get(m, "")))
        notes += fit_notes(m, r)
    table = Table(("method", "status", "solver", "fallback", "time [s]", "iterations", "consistent",
                   "metric vs URDF", "solver warnings", "plausible parameters", "URDF"), tuple(rows),
                  note="fallback: when used, the solvers tried in order and the one that produced θ̂. "
                       "metric vs URDF: range of the generalized eigenvalues of the identified mass matrix against "
                       "the URDF's over the training samples ('degenerate' outside [1/100, 100]).")
    return Section("Fits", (table, *((Bullets(tuple(notes_once(notes))),) if notes else ())))


def _scores(d: FitReportData) -> Section:
    blocks: list = []
    if d.train:
        blocks += [Text("Training scores: each model predicting the runs it was fitted on (references: the "
                        "same runs).")] + score_tables(d.train, "training")
    if d.held_out:
        blocks += [Text("Held-out scores: the runs not used for fitting.")] + score_tables(d.held_out, "held-out")
        if len(next(iter(d.held_out.values())).runs) > 1:
            blocks.append(per_run_table(d.held_out))
    if blocks:
        blocks.append(Text(SCORE_NOTE.format(window=d.outcome.config.xcorr_window)))
    return Section("Scores", tuple(blocks))


def signal_images(validations: dict[str, Validation]) -> list[Image]:
    """Effort and acceleration figures for every held-out run."""
    images = []
    first = next(iter(validations.values()))
    for i, r in enumerate(first.runs):
        for signal, stem in (("tau", "effort"), ("a", "acceleration")):
            sf = signal_svg(validations, i, signal)
            images.append(Image(f"{stem}_{slug(r.run)}.svg", b"", sf.caption, svg=sf.svg))
    return images


def _figures(d: FitReportData) -> Section:
    if not d.held_out:
        return Section("Held-out signals")
    images = signal_images(d.held_out)
    if len(d.held_out) > 1:
        images.append(Image("scores.svg", b"", "Held-out scores per joint (bars: mean over runs; whiskers: std when "
                            "more than one run; pale, dashed outline: references).", svg=score_svg(d.held_out)))
    return Section("Held-out signals", tuple(images))


def parameter_tables(d: FitReportData) -> list[Table]:
    """One table per body/joint (parameter-name prefix): rows parameters, columns methods and references. A method with
    plausible parameters has two columns: the values its model files carry ("files", "(prior)" where the data do not
    determine them) and its raw θ̂ beside them."""
    o = d.outcome
    ok = [m for m, f in o.fits.items() if f.ok]
    P = o.problem.parameters
    unident = set(o.identifiability.unidentifiable)
    groups: dict[str, list[int]] = {}
    for k, n in enumerate(P.names):
        groups.setdefault(n.split(".", 1)[0] if "." in n else "other", []).append(k)
    heads, columns, marks = [], [], []  # per column: header, θ, {k: mark}
    for m in ok:
        f = o.fits[m]
        nd = f.result.not_determined()  # completed parameters, marked "(n.d.)"
        raw_marks = {k: " (n.d.)" for k, n in enumerate(P.names) if n in nd}
        if f.plausible is not None:
            heads.append(f"{m} (files)")
            columns.append(f.plausible.theta)
            marks.append({k: " (prior)" for k, x in enumerate(f.plausible.determined_by) if x == "prior"})
            heads.append(f"{m} θ̂")
        else:
            heads.append(m)
        columns.append(f.result.theta)
        marks.append(raw_marks)
    heads += list(o.references)
    columns += [th for th, _ in o.references.values()]
    marks += [{} for _ in o.references]
    tiny = [1e-10 * float(np.max(np.abs(th))) for th in columns]  # solver round-off, shown as 0
    se_of = {h: o.fits[m].uncertainty for m in ok for h in (m, f"{m} θ̂")}
    tables = []
    for group, idx in groups.items():
        rows = []
        for k in idx:
            cells = [P.names[k] + (" (n.i.)" if P.names[k] in unident else ""), P.units[k]]
            for h, th, eps, mk in zip(heads, columns, tiny, marks):
                value = "0" if abs(th[k]) <= eps else f"{th[k]:.5g}"
                se = se_of[h][k] if se_of.get(h) else None
                value += f" ± {se:.2g}" if isinstance(se, float) else ""
                cells.append(value + mk.get(k, ""))
            rows.append(tuple(cells))
        tables.append(Table(("parameter", "unit", *heads), tuple(rows), title=group))
    return tables


def _parameters(d: FitReportData) -> Section:
    return Section("Parameters", (Text("METHOD (files): the values the URDF/MJCF carry (the plausible parameters; "
                                       "(prior): not determined by the data, from the prior), METHOD θ̂: the fit's raw "
                                       "values; n.i.: not identifiable on its own; ± standard error (see the uncertainty note "
                                       "in parameters.yaml); 0: below 1e-10 × the largest value of its column "
                                       "(solver round-off; exact values in parameters.yaml); n.d.: not determined by "
                                       "the data, the smallest value consistent with the other parameters (its size "
                                       "reflects the solver's tolerance, not the data; no prediction depends on it; "
                                       "see the projected note under Fits)."), *parameter_tables(d)))


def _friction(d: FitReportData) -> Section:
    return friction_section(d.outcome)


def _bodies(d: FitReportData) -> Section:
    return body_section(d.outcome)


def _base(d: FitReportData) -> Section:
    return base_section(d.outcome)


def _plausible(d: FitReportData) -> Section:
    return plausible_section(d.outcome)


def _model_files(d: FitReportData) -> Section:
    return model_files_section(d.model_files)


FIT_SECTIONS: list[Callable[[FitReportData], Section]] = [
    _summary, _warnings, _identifiability, _fits, _scores, _figures, _friction, _bodies, _base, _plausible,
    _model_files, _parameters,
]


def fit_report(d: FitReportData) -> Report:
    o = d.outcome
    failed = [m for m, f in o.fits.items() if not f.ok]
    banner = (f"Incomplete: {len(failed)} of {len(o.fits)} requested methods failed ({', '.join(failed)}); see Fits."
              if failed else "")
    sections = [build(d) for build in FIT_SECTIONS] + [run_section(d.meta)]
    return Report(f"Identification of {o.config.model.urdf.name}", tuple(sections), banner)


# --- the validation report ----------------------------------------------------------------------
def validation_report(validation: Validation, model: str, meta: dict, xcorr_window: float | None = None) -> Report:
    vals = {validation.label: validation}
    blocks: list = [Bullets((f"model: {model}", f"runs: {', '.join(r.run for r in validation.runs)}")),
                    *score_tables(vals, "")]
    if xcorr_window is not None:
        blocks.append(Text(SCORE_NOTE.format(window=xcorr_window)))
    sections = [Section("Scores", tuple(blocks)), Section("Signals", tuple(signal_images(vals))), run_section(meta)]
    return Report(f"Validation of {model}", tuple(sections))


def score_table(validations: dict[str, Validation]) -> str:
    """The held-out score tables as Markdown (what the CLI prints)."""
    return "\n\n".join("\n".join(table_markdown(t)) for t in score_tables(validations))
