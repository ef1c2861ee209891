"""Writing a drag-model fit (``model.kind: drag``): parameters.yaml/json, identifiability.txt, report.md
and PNGs, under the output-directory policy (``report.outdir``).

- parameters.yaml/json: the drag spec, data and preprocessing, identifiability, and per method its
  status, solver, parameters (name, unit, value, standard error), per-body drag matrices with their
  eigenvalues (physical consistency: all ≥ 0) and held-out scores;
- report.md (with velocity_<run>.png, the forward prediction v̂ against measured v, for every held-out run)
  and report.html (the same report, one value rendered twice, figures embedded): summary and
  preprocessing, identifiability, fits, held-out scores (effort τ̂ = D̂v and velocity v̂ = D̂⁻¹τ per
  coordinate), base parameters with intervals, parameters, run metadata (also under run: in parameters.yaml).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from dualid.estimators.methods import color as method_color
from dualid.evaluation.validation import Validation
from dualid.report.base_parameters import base_section
from dualid.report.document import Bullets, Image, Pre, Report, Section, Table, Text, runs_phrase
from dualid.report.figures import cycle_color, new_figure, png
from dualid.report.fit_report import fit_notes, preprocessing_table, run_section
from dualid.report.io import jsonable, markdown_table, write_json, yaml_text
from dualid.report.metadata import run_metadata
from dualid.report.outdir import write_output
from dualid.report.render import write_report
from dualid.report.robot import method_entry_record
from dualid.robot.drag_fit import DragFitOutcome


def _color(label: str, k: int):
    return method_color(label) or cycle_color(k)


def _cell(m: float, s: float, digits: int = 3) -> str:
    return "—" if not np.isfinite(m) else f"{m:.{digits}g} ± {s:.1g}" if np.isfinite(s) and s > 0 else f"{m:.{digits}g}"


def velocity_plot(validations: dict[str, Validation], run: int, units: tuple[str, ...]) -> Figure:
    """Measured vs predicted velocity v̂ = D̂⁻¹τ on one held-out run, one panel per coordinate."""
    first = next(iter(validations.values()))
    meas = first.runs[run]
    n = len(first.coordinates)
    fig, axes = new_figure(n, 1, figsize=(10, 2.0 * n), sharex=True)
    for j, ax in enumerate(axes[:, 0]):
        ax.plot(meas.t, meas.a[:, j], color="black", lw=1.2, label="measured")
        for k, (label, val) in enumerate(validations.items()):
            r = val.runs[run]
            if r.a_pred is not None:
                ax.plot(r.t, r.a_pred[:, j], color=_color(label, k), lw=0.8, alpha=0.85,
                        label=f"{label} (NCC {r.a_ncc[j]:.3f})")
        lo, hi = np.percentile(meas.a[:, j], [0.5, 99.5])  # axes follow the measured signal
        pad = 0.25 * max(hi - lo, 1e-12)
        ax.set_ylim(lo - pad, hi + pad)
        ax.set_ylabel(f"{first.coordinates[j]} [{units[j]}]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6, ncol=4, loc="upper right")
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(f"held-out run {meas.run}: velocity v̂ = D̂(q)⁻¹τ from measured q, τ", fontsize=10)
    fig.tight_layout()
    return fig


def parameters_record(outcome: DragFitOutcome) -> dict:
    P = outcome.problem.parameters
    methods = {}
    for m, f in outcome.fits.items():
        methods[m] = method_entry_record(m, f, P)
        if f.ok:
            methods[m]["drag_matrices"] = {name: {"matrix": C, "eigenvalues": np.linalg.eigvalsh(C)}
                                           for name, C in outcome.model.drag_matrices(f.result.theta).items()}
    cfg = outcome.config
    ident = outcome.identifiability
    return jsonable({
        "complete": outcome.complete,
        "warnings": list(outcome.warnings),
        "model": {"kind": "drag", "urdf": cfg.model.urdf, "coordinates": list(outcome.model.coordinates),
                  "drag": cfg.model.drag.as_dict()},
        "data": {"train": list(cfg.train), "test": list(cfg.test), "columns": outcome.columns.to_dict(),
                 "preprocessing": outcome.steps, "samples": outcome.problem.N},
        "identifiability": {"rank": ident.rank, "n_params": ident.n_params,
                            "condition_number": ident.condition_number,
                            "not_identifiable": list(ident.unidentifiable)},
        "prior": {"theta0": outcome.prior or None, "gamma": cfg.prior.gamma, "per_equation": cfg.prior.per_equation},
        "validation_note": "a_rmse/a_ncc: the forward prediction v̂ = D̂⁻¹τ against the measured velocity",
        "methods": methods,
    })


def write_drag_fit(outcome: DragFitOutcome, out: str | Path, force: bool = False, command: str | None = None,
                   config_file: str | Path | None = None) -> dict[str, Path]:
    """parameters.yaml/json, identifiability.txt, report.md with its PNGs and report.html in ``out`` (under the
    output-directory policy); ``command`` and ``config_file`` go into the run metadata as for ``write_fit``."""
    cfg = outcome.config
    files = {"config": [config_file] if config_file else [], "urdf": [cfg.model.urdf] if cfg.model.urdf else [],
             "train": list(cfg.train), "test": list(cfg.test)}
    meta = run_metadata({k: v for k, v in files.items() if v}, command)
    return write_output(out, force, lambda d: _write(outcome, d, meta))


def _write(outcome: DragFitOutcome, out: Path, meta: dict) -> dict[str, Path]:
    written: dict[str, Path] = {}
    record = {"run": meta, **parameters_record(outcome)}
    (out / "parameters.yaml").write_text(yaml_text(jsonable(record)))
    written["parameters.yaml"] = out / "parameters.yaml"
    written["parameters.json"] = write_json(out / "parameters.json", record)
    (out / "identifiability.txt").write_text(outcome.identifiability.describe() + "\n")
    written["identifiability.txt"] = out / "identifiability.txt"
    write_report(drag_report(outcome, meta), out, written)
    return written


def _score_rows(validations: dict[str, Validation], key: str) -> tuple[tuple[str, ...], ...]:
    return tuple((label, *(_cell(m, s) for m, s in zip(v.mean(key), v.std(key)))) for label, v in validations.items())


def drag_report(outcome: DragFitOutcome, meta: dict) -> Report:
    """The drag fit's report as one value (rendered to report.md and report.html)."""
    cfg, P = outcome.config, outcome.problem.parameters
    source = cfg.model.urdf.name if cfg.model.urdf is not None else f"chain {list(cfg.model.drag.chain)}"
    failed = [m for m, f in outcome.fits.items() if not f.ok]
    banner = (f"Incomplete: {len(failed)} of {len(outcome.fits)} requested methods failed ({', '.join(failed)})."
              if failed else "")
    summary = Section("Summary", (
        Bullets((
            f"model: τ = D(q, θ)v, coordinates {', '.join(outcome.model.coordinates)}, base {cfg.model.drag.base}; "
            f"{len(cfg.model.drag.bodies)} drag bodies, {len(cfg.model.drag.damping)} damped joints; p = {P.p}",
            f"training runs: {', '.join(p.name for p in cfg.train)}; "
            f"held-out: {', '.join(p.name for p in cfg.test) or '(none)'}",
            f"samples: {outcome.problem.N} × {outcome.problem.n} coordinates",
            *([f"preprocessing {outcome.preprocessing_note}"] if outcome.preprocessing_note else []),
            *([f"prior of logdet/pullback: {outcome.prior}"] if outcome.prior else []),
        )),
        preprocessing_table(outcome.steps),
    ))
    warnings = Section("Warnings", (Bullets(tuple(outcome.warnings)),) if outcome.warnings else ())
    ident = Section("Identifiability", (Pre(outcome.identifiability.describe()),))
    rows, notes = [], []
    for m, f in outcome.fits.items():
        if f.ok:
            r = f.result
            notes += fit_notes(m, r)
            fallback = r.info.get("solver_chain", "") if r.info.get("fallback_used") else "no"
            mins = min(float(np.linalg.eigvalsh(C)[0]) for C in outcome.model.drag_matrices(r.theta).values())
            rows.append((m, r.status, r.solver, fallback, f"{r.solve_time:.2f}", r.is_consistent, f"{mins:.3g}"))
        else:
            rows.append((m, f"failed: {f.error}", "", "", "", "", ""))
    fits = Section("Fits", (Table(("method", "status", "solver", "fallback", "time [s]", "consistent",
                                   "min eig(C_b)"), tuple(rows)), *((Bullets(tuple(notes)),) if notes else ())))
    validations = {m: f.validation for m, f in outcome.fits.items() if f.ok and f.validation is not None}
    blocks: list = []
    if validations:
        coords = ("method", *next(iter(validations.values())).coordinates)
        units = tuple(outcome.columns.unit("velocity", c) for c in outcome.model.coordinates)
        blocks = [
            Text(f"Over {runs_phrase(len(outcome.test))}. NCC: normalized cross-correlation, maximum over "
                 f"shifts within ±{cfg.xcorr_window} s (NaN where a signal is constant, e.g. a passive coordinate's "
                 "zero effort)."),
            Table(coords, _score_rows(validations, "a_ncc"),
                  title="Velocity NCC (forward prediction v̂ = D̂(q)⁻¹τ vs measured v)"),
            Table(coords, _score_rows(validations, "a_rmse"), title="Velocity RMSE"),
            Table(coords, _score_rows(validations, "tau_rmse"), title="Effort RMSE (τ̂ = D̂(q)v vs measured τ)"),
        ]
        for k, run in enumerate(outcome.test):
            fig = velocity_plot(validations, k, units)
            blocks.append(Image(f"velocity_{run.name}.png", png(fig),
                                f"Held-out run {run.name}: velocity v̂ = D̂(q)⁻¹τ from measured q, τ."))
    held_out = Section("Held-out validation", tuple(blocks))
    ok = [m for m, f in outcome.fits.items() if f.ok]
    prows = []
    for k, (n, u) in enumerate(zip(P.names, P.units)):
        cells = [n, u]
        for m in ok:
            se = outcome.fits[m].uncertainty[k] if outcome.fits[m].uncertainty else None
            cells.append(f"{outcome.fits[m].result.theta[k]:.4g}" + (f" ± {se:.2g}" if isinstance(se, float) else ""))
        prows.append(tuple(cells))
    params = Section("Parameters", (Text("± standard error of a parameter that is a base parameter on its own "
                                         "(sandwich covariance; see parameters.yaml)"),
                                    Table(("parameter", "unit", *ok), tuple(prows))))
    sections = (summary, warnings, ident, fits, held_out, base_section(outcome), params, run_section(meta))
    return Report(f"Drag-model identification ({source})", sections, banner)


def score_table(validations: dict[str, Validation], key: str) -> list[str]:
    """Markdown rows: per method, a held-out score per coordinate (mean ± std over runs)."""
    coords = next(iter(validations.values())).coordinates
    rows = [[label] + [_cell(m, s) for m, s in zip(v.mean(key), v.std(key))] for label, v in validations.items()]
    return markdown_table(["method", *coords], rows)
