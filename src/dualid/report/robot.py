"""Writing a real-robot fit: parameters.yaml/json, <method>.urdf, report.md and PNGs (matplotlib leaf).

Files in the output folder:
- parameters.yaml, parameters.json: every method's parameters (name, unit, value, standard error or
  "not identifiable"), its base parameters with 95 % intervals, body physical quantities, solver status/time, held-out scores, and the data
  files, column map and preprocessing steps used;
- <method>.urdf: the URDF with the identified inertials and <dynamics damping friction>;
- identifiability.txt; report.md; effort_<run>.png (predicted vs measured effort on a held-out
  run), acceleration_<run>.png (forward dynamics) and scores.png (per-joint RMSE/NCC per method).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import yaml
from matplotlib.figure import Figure

from dualid.errors import DualidError
from dualid.estimators.methods import color as method_color
from dualid.estimators.methods import method as method_entry
from dualid.evaluation.validation import Validation
from dualid.model.joint_terms import JointTermsModel
from dualid.report.base_parameters import UNCERTAINTY_NOTE, base_section, definitions, method_record
from dualid.report.figures import cycle_color, new_figure, save_figure
from dualid.report.io import jsonable, to_json, write_json
from dualid.report.outdir import write_output
from dualid.report.urdf import write_urdf
from dualid.robot.fit import FitOutcome


def _color(label: str, k: int) -> str:
    return method_color(label) or cycle_color(k)


def _friction(model, theta) -> dict[str, tuple[float, float]]:
    return model.friction(theta) if isinstance(model, JointTermsModel) else {}


def _armature(model, theta) -> dict[str, float]:
    return model.armature_values(theta) if isinstance(model, JointTermsModel) else {}


def _guard_cell(info: dict) -> str:
    """The generalised-eigenvalue range of M(θ̂) against the URDF's M, flagged when it left [1/100, 100]."""
    if "metric_ratio_min" not in info:
        return info.get("metric_guard_error", "—")
    cell = f"[{info['metric_ratio_min']:.2g}, {info['metric_ratio_max']:.2g}]"
    return f"**degenerate** {cell}" if info.get("degenerate") else cell


def _slug(s: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", s)


# --- figures ----------------------------------------------------------------------------------
def signal_plot(validations: dict[str, Validation], run: int, signal: str = "tau") -> Figure:
    """Measured vs predicted effort ("tau", inverse dynamics) or acceleration ("a", forward dynamics)
    on one held-out run, one panel per joint."""
    first = next(iter(validations.values()))
    coords = first.coordinates
    meas_run = first.runs[run]
    fig, axes = new_figure(len(coords), 1, figsize=(10, 2.6 * len(coords)), sharex=True)
    unit = "N m" if signal == "tau" else "rad/s²"
    what = "effort: inverse dynamics Y(q,v,a)θ̂" if signal == "tau" else "acceleration: forward dynamics M̂⁻¹(τ−ĥ)"
    for j, ax in enumerate(axes[:, 0]):
        measured = meas_run.tau if signal == "tau" else meas_run.a
        ax.plot(meas_run.t, measured[:, j], color="black", lw=1.2,
                label="measured" if signal == "tau" else "differentiated (measured q)")
        for k, (label, val) in enumerate(validations.items()):
            r = val.runs[run]
            pred = r.tau_pred if signal == "tau" else r.a_pred
            if pred is None:
                continue
            score = (r.tau_rmse if signal == "tau" else r.a_rmse)[j]
            ax.plot(r.t, pred[:, j], color=_color(label, k), lw=0.8, alpha=0.85, label=f"{label} (RMSE {score:.3g})")
        ax.set_ylabel(f"{coords[j]} [{unit}]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=4, loc="upper center", bbox_to_anchor=(0.5, -0.28),
                  frameon=False) if j == len(coords) - 1 else None
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(f"held-out run {meas_run.run}: {what}", fontsize=10)
    fig.tight_layout()
    return fig


def score_bars(validations: dict[str, Validation]) -> Figure:
    """Grouped bars per joint of held-out effort RMSE and NCC, and acceleration NCC (mean ± std over runs)."""
    first = next(iter(validations.values()))
    coords = first.coordinates
    panels = (("tau_rmse", "effort RMSE [N m] (lower is better)"), ("tau_ncc", "effort NCC (higher is better)"),
              ("a_ncc", "forward-dynamics acceleration NCC"))
    fig, axes = new_figure(1, 3, figsize=(13, 4))
    x = np.arange(len(coords))
    w = 0.8 / len(validations)
    for ax, (key, title) in zip(axes[0], panels):
        for k, (label, val) in enumerate(validations.items()):
            ax.bar(x - 0.4 + w * (k + 0.5), np.nan_to_num(val.mean(key)), w, yerr=np.nan_to_num(val.std(key)),
                   capsize=2, color=_color(label, k), label=label, error_kw={"elinewidth": 0.8})
        ax.set_xticks(x)
        ax.set_xticklabels(coords)
        ax.set_title(title, fontsize=9)
        ax.grid(axis="y", alpha=0.3)
        if key != "tau_rmse":
            lo = min([0.0] + [float(np.nanmin(v.mean(key))) for v in validations.values() if np.isfinite(v.mean(key)).any()])
            ax.set_ylim(min(lo - 0.05, 0.0) if lo < 0 else 0.0, 1.0)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 8), fontsize=8, frameon=False,
               bbox_to_anchor=(0.5, -0.04))
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    return fig


# --- tables -----------------------------------------------------------------------------------
def _fmt(x, digits=3) -> str:
    return "—" if x is None or not np.isfinite(x) else f"{x:.{digits}f}"


def score_table(validations: dict[str, Validation]) -> str:
    """Markdown: per label, held-out effort RMSE/NCC and acceleration NCC per joint (mean ± std over runs)."""
    coords = next(iter(validations.values())).coordinates
    head = ["model"] + [f"τ RMSE {c} [N m]" for c in coords] + [f"τ NCC {c}" for c in coords] + [f"a NCC {c}" for c in coords]
    lines = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for label, val in validations.items():
        cells = [label]
        for key in ("tau_rmse", "tau_ncc", "a_ncc"):
            m, s = val.mean(key), val.std(key)
            cells += [f"{_fmt(m[j])} ± {_fmt(s[j])}" if np.isfinite(m[j]) else "—" for j in range(len(coords))]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _param_table(outcome: FitOutcome) -> str:
    ok = [m for m, f in outcome.fits.items() if f.ok]
    names, units = outcome.problem.parameters.names, outcome.problem.parameters.units
    unident = set(outcome.identifiability.unidentifiable)
    head = ["parameter", "unit"] + ok + [lab for lab in outcome.references]
    lines = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for k, (n, u) in enumerate(zip(names, units)):
        cells = [n + (" (n.i.)" if n in unident else ""), u]
        for m in ok:
            f = outcome.fits[m]
            se = f.uncertainty[k] if f.uncertainty else None
            cells.append(f"{f.result.theta[k]:.5g}" + (f" ± {se:.2g}" if isinstance(se, float) else ""))
        cells += [f"{th[k]:.5g}" for th, _ in outcome.references.values()]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


# --- writers ----------------------------------------------------------------------------------
def parameters_record(outcome: FitOutcome, urdfs: dict[str, str]) -> dict:
    """The content of parameters.yaml / parameters.json."""
    P = outcome.problem.parameters
    ident = outcome.identifiability
    methods = {}
    for m, f in outcome.fits.items():
        if not f.ok:
            methods[m] = {"description": method_entry(m).description, "error": f.error}
            continue
        r = f.result
        methods[m] = {
            "description": method_entry(m).description,
            "status": r.status,
            "solver": r.solver,
            "solver_chain": r.info.get("solver_chain", r.solver),
            "fallback_used": bool(r.info.get("fallback_used", False)),
            "metric_guard": {k: r.info[k] for k in ("metric_ratio_min", "metric_ratio_max", "degenerate",
                                                    "metric_guard_reference", "metric_guard_error") if k in r.info},
            "solve_time_s": r.solve_time,
            "iterations": r.iterations,
            "objective": r.objective,
            "physically_consistent": bool(r.is_consistent),
            "urdf": urdfs.get(m),
            "parameters": [
                {"name": n, "unit": u, "value": float(x), "std_error": se}
                for n, u, x, se in zip(P.names, P.units, r.theta, f.uncertainty)
            ],
            "bodies": [b.as_dict() for b in r.bodies],
            "validation": None if f.validation is None else f.validation.as_dict(),
            "base_parameters": method_record(f),
        }
    return jsonable({
        "complete": outcome.complete,  # False when a requested method failed (its entry has "error")
        "warnings": list(outcome.warnings),
        "model": {"urdf": outcome.config.model.urdf, "floating_base": outcome.config.model.floating_base,
                  "gravity": list(outcome.rigid.gravity)},
        "data": {"train": list(outcome.config.train), "test": list(outcome.config.test),
                 "columns": outcome.columns.to_dict(), "preprocessing": outcome.steps,
                 "samples": outcome.problem.N},
        "identifiability": {"rank": ident.rank, "n_params": ident.n_params,
                            "condition_number": ident.condition_number,
                            "not_identifiable": list(ident.unidentifiable),
                            "base_parameters": definitions(ident.base) if ident.base is not None else [],
                            "no_effect": [P.names[j] for j in (ident.base.no_effect if ident.base else ())]},
        "prior": {"source": outcome.config.prior.source, "gamma": outcome.config.prior.gamma,
                  "per_equation": outcome.config.prior.per_equation, "theta0": outcome.prior},
        "uncertainty_note": UNCERTAINTY_NOTE,
        "methods": methods,
        "references": {
            label: {"parameters": [{"name": n, "value": float(x)} for n, x in zip(P.names, th)],
                    "validation": None if v is None else v.as_dict()}
            for label, (th, v) in outcome.references.items()
        },
    })


def write_fit(outcome: FitOutcome, out: str | Path, force: bool = False) -> dict[str, Path]:
    """parameters.yaml/json, <method>.urdf, identifiability.txt, report.md and figures in ``out``
    (under the output-directory policy of dualid.report.outdir; force = --force)."""
    return write_output(out, force, lambda d: _write_fit(outcome, d))


def _write_fit(outcome: FitOutcome, out: Path) -> dict[str, Path]:
    written: dict[str, Path] = {}
    urdfs: dict[str, str] = {}
    p0 = outcome.rigid.parameters.p
    for m, f in outcome.fits.items():
        if not f.ok:
            continue
        try:
            path = write_urdf(outcome.config.model.urdf, outcome.rigid, f.result.theta[:p0], out / f"{m}.urdf",
                              overwrite=True, friction=_friction(outcome.model, f.result.theta),
                              armature=_armature(outcome.model, f.result.theta))
        except (DualidError, ValueError) as exc:  # e.g. a fit on the consistency boundary the URDF writer refuses
            urdfs[m] = f"not written: {exc}"
            continue
        urdfs[m] = path.name
        written[f"{m}.urdf"] = path
    record = parameters_record(outcome, urdfs)
    (out / "parameters.yaml").write_text(yaml.safe_dump(record, sort_keys=False, allow_unicode=True))
    write_json(out / "parameters.json", record)
    written["parameters.yaml"], written["parameters.json"] = out / "parameters.yaml", out / "parameters.json"
    (out / "identifiability.txt").write_text(outcome.identifiability_text() + "\n")
    written["identifiability.txt"] = out / "identifiability.txt"

    validations = {m: f.validation for m, f in outcome.fits.items() if f.ok and f.validation is not None}
    validations.update({lab: v for lab, (_, v) in outcome.references.items() if v is not None})
    figures = []
    if validations:
        run = outcome.test[0].name
        for signal, stem in (("tau", "effort"), ("a", "acceleration")):
            p = save_figure(signal_plot(validations, 0, signal), out / f"{stem}_{_slug(run)}.png", bbox_inches="tight")
            written[p.name] = p
            figures.append(p.name)
        if len(validations) > 1:
            p = save_figure(score_bars(validations), out / "scores.png", bbox_inches="tight")
            written[p.name] = p
            figures.append(p.name)
    report = _report_md(outcome, validations, urdfs, figures)
    (out / "report.md").write_text(report)
    written["report.md"] = out / "report.md"
    return written


def _report_md(outcome: FitOutcome, validations, urdfs, figures) -> str:
    cfg = outcome.config
    failed = [m for m, f in outcome.fits.items() if not f.ok]
    lines = [f"# Identification of {cfg.model.urdf.name}", ""]
    if failed:
        lines += [f"**Incomplete: {len(failed)} of {len(outcome.fits)} requested methods failed "
                  f"({', '.join(failed)}); see Fits.**", ""]
    lines += [
        f"- training runs: {', '.join(p.name for p in cfg.train)}",
        f"- held-out runs: {', '.join(p.name for p in cfg.test) or '(none: no validation)'}",
        f"- samples after preprocessing: {outcome.problem.N} × {outcome.problem.n} joints; parameters: {outcome.problem.p}",
        f"- preprocessing: `{to_json(outcome.steps, indent=None)}`",
        *([f"- preprocessing {outcome.preprocessing_note} (no 'preprocessing' in the config)"]
          if outcome.preprocessing_note else []),
        f"- joint terms: viscous={cfg.joint_terms.viscous}, coulomb={cfg.joint_terms.coulomb} "
        f"(v_c = {cfg.joint_terms.coulomb_velocity} rad/s), armature={cfg.joint_terms.armature}",
        "",
    ]
    if outcome.warnings:
        lines += ["## Warnings", ""] + [f"- {w}" for w in outcome.warnings] + [""]
    lines += [
        "## Identifiability",
        "",
        "```",
        outcome.identifiability_text(),
        "```",
        "",
        "## Fits",
        "",
        "| method | status | solver | fallback | time [s] | consistent | metric vs URDF | URDF |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for m, f in outcome.fits.items():
        if f.ok:
            r = f.result
            fallback = r.info.get("solver_chain", "") if r.info.get("fallback_used") else "no"
            lines.append(f"| {m} | {r.status} | {r.solver} | {fallback} | {r.solve_time:.2f} | {r.is_consistent} | "
                         f"{_guard_cell(r.info)} | {urdfs.get(m, '')} |")
        else:
            lines.append(f"| {m} | failed: {f.error} | | | | | | |")
    if validations:
        lines += [
            "",
            "## Held-out validation",
            "",
            "τ: inverse dynamics τ̂ = Y(q, v, a)θ̂ from measured q, v and differentiated a, against the measured "
            "effort. a: forward dynamics â = M̂⁻¹(τ − ĥ) from measured q, v, τ, against the differentiated "
            f"accelerations. NCC: normalized cross-correlation, maximum over shifts within ±{cfg.xcorr_window} s. "
            "Mean ± std over the held-out runs.",
            "",
            score_table(validations),
            "",
        ]
        lines += [f"![{f}]({f})" for f in figures]
    if outcome.prior:
        weight = f"γ = {cfg.prior.gamma} per equation (γ·N·n)" if cfg.prior.per_equation else f"γ = {cfg.prior.gamma}"
        lines += ["", f"Prior of logdet/pullback ({weight}): {outcome.prior}."]
    lines += ["", *base_section(outcome)]
    lines += ["", "## Parameters", "", "(n.i.: not identifiable on its own; ± standard error, see parameters.yaml)", "",
              _param_table(outcome), ""]
    return "\n".join(lines)


def write_validation(validation: Validation, out: str | Path, meta: dict, force: bool = False) -> dict[str, Path]:
    """validation.json, report.md and figures in ``out`` (under the output-directory policy)."""
    return write_output(out, force, lambda d: _write_validation(validation, d, meta))


def _write_validation(validation: Validation, out: Path, meta: dict) -> dict[str, Path]:
    """``dualid validate`` outputs: validation.json, report.md and the effort/acceleration PNGs."""
    record = jsonable({**meta, "validation": validation.as_dict()})
    write_json(out / "validation.json", record)
    written = {"validation.json": out / "validation.json"}
    figures = []
    for signal, stem in (("tau", "effort"), ("a", "acceleration")):
        p = save_figure(signal_plot({validation.label: validation}, 0, signal), out / f"{stem}_{_slug(validation.runs[0].run)}.png",
                      bbox_inches="tight")
        written[p.name] = p
        figures.append(p.name)
    md = [f"# Validation of {meta.get('model', validation.label)}", "",
          f"runs: {', '.join(r.run for r in validation.runs)}", "", score_table({validation.label: validation}), ""]
    md += [f"![{f}]({f})" for f in figures]
    (out / "report.md").write_text("\n".join(md) + "\n")
    written["report.md"] = out / "report.md"
    return written
