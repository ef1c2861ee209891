"""Writing a real-robot fit or validation: parameters.yaml/json, <method>.urdf, report.md, report.html and SVG figures.

Files in the output folder of a fit:
- parameters.yaml, parameters.json: the run metadata (dualid version, git commit, UTC time, command
  line, SHA-256 of every input file), every method's parameters (name, unit, value, standard error or
  "not identifiable"), its base parameters with 95 % intervals, body physical quantities, solver status/time/fallback/guard, training and
  held-out scores, and the data files, column map and preprocessing steps used;
- <method>.urdf, <method>.xml: the URDF and MJCF with the identified parameters (the plausible ones when
  a prior exists; report/model_files.py);
- identifiability.txt; report.md with effort_<run>.svg / acceleration_<run>.svg for every held-out
  run, scores.svg and friction.svg; report.html: the same report (``report.fit_report``, one value rendered twice by
  ``report.render``) as one self-contained file with the figures embedded.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable


from dualid.estimators.methods import method as method_entry
from dualid.evaluation.validation import Validation
from dualid.report.base_parameters import UNCERTAINTY_NOTE, definitions, method_record
from dualid.report.fit_report import fit_report, report_data, score_table, validation_report
from dualid.report.io import jsonable, write_json, yaml_text
from dualid.report.metadata import run_metadata
from dualid.report.model_files import plausible_record, write_model_files
from dualid.report.outdir import write_output
from dualid.report.render import write_report
from dualid.robot.fit import FitOutcome

__all__ = ["parameters_record", "score_table", "write_fit", "write_validation"]


def method_entry_record(m: str, f, P) -> dict:
    """What parameters.yaml says of every fitted method, rigid-body or drag (``f``: a robot.fit.MethodFit, ``P``
    the parameter space): status, solver and fallback, objective, consistency, parameters with standard
    errors, base parameters with intervals and the held-out validation; for a failed fit, its error."""
    if not f.ok:
        return {"description": method_entry(m).description, "error": f.error}
    r = f.result
    return {
        "description": method_entry(m).description,
        "status": r.status,
        "solver": r.solver,
        "solver_chain": r.info.get("solver_chain", r.solver),
        "fallback_used": bool(r.info.get("fallback_used", False)),
        "solver_warnings": [w for w in str(r.info.get("solver_warnings", "")).split(" | ") if w],
        **({"noise_model": r.noise.as_dict()} if r.noise is not None else {}),
        "solve_time_s": r.solve_time,
        "objective": r.objective,
        "physically_consistent": bool(r.is_consistent),
        "parameters": r.parameter_records(f.uncertainty),  # the completed ones say so (model.closure)
        "base_parameters": method_record(f),
        "validation": None if f.validation is None else f.validation.as_dict(),
    }


def parameters_record(outcome: FitOutcome, urdfs: dict[str, str], meta: dict | None = None,
                      train: dict[str, Validation] | None = None, files: dict[str, dict] | None = None) -> dict:
    """The content of parameters.yaml / parameters.json; ``meta``: the run metadata
    (``report.metadata.run_metadata``), ``train``: the scores on the training runs per label, ``files``: the
    model files each method wrote (``report.model_files.write_model_files``)."""
    train = train or {}
    P = outcome.problem.parameters
    ident = outcome.identifiability
    methods = {}
    for m, f in outcome.fits.items():
        methods[m] = method_entry_record(m, f, P)
        if not f.ok:
            continue
        r = f.result
        methods[m].update({
            "metric_guard": {k: r.info[k] for k in ("metric_ratio_min", "metric_ratio_max", "degenerate",
                                                    "metric_guard_reference", "metric_guard_error") if k in r.info},
            **({"margin": {k.removeprefix("margin_"): v for k, v in r.info.items() if k.startswith("margin_")}}
               if "margin_epsilon" in r.info else {}),  # C_b(θ) ⪰ ε·C_b(θ_ref) (dualid.model.margin)
            **({"projected_parameters": {"values": r.info["projected_parameters"], "note": r.info.get("projected_note")}}
               if "projected_parameters" in r.info else {}),  # unseen masses completed (model.closure)
            "iterations": r.iterations,
            "urdf": urdfs.get(m),
            "mjcf": (files or {}).get(m, {}).get("mjcf"),
            "model_files_theta": (files or {}).get(m, {}).get("theta"),
            "mjcf_notes": (files or {}).get(m, {}).get("mjcf_notes"),
            "plausible": plausible_record(f),
            "bodies": r.body_records(),  # with not_determined_by_data on a body whose mass the fit completed
            "training_scores": None if m not in train else train[m].as_dict(),
        })
    return jsonable({
        "run": meta,
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
                    "training_scores": None if label not in train else train[label].as_dict(),
                    "validation": None if v is None else v.as_dict()}
            for label, (th, v) in outcome.references.items()
        },
    })


def input_files(outcome: FitOutcome, config_file: str | Path | None = None) -> dict[str, list]:
    """role → paths of every file the fit read (hashed in the run metadata)."""
    cfg = outcome.config
    files: dict[str, list] = {"config": [config_file] if config_file else [], "urdf": [cfg.model.urdf],
                              "train": list(cfg.train), "test": list(cfg.test),
                              "reference": [p for _, p in cfg.references]}
    if cfg.prior.source != "urdf":
        files["prior"] = [cfg.prior.source.partition("#")[0]]
    return {k: v for k, v in files.items() if v}


def write_fit(outcome: FitOutcome, out: str | Path, force: bool = False, command: str | None = None,
              config_file: str | Path | None = None, progress: Callable[[str], None] | None = None) -> dict[str, Path]:
    """parameters.yaml/json, <method>.urdf, identifiability.txt, report.md, report.html and figures in
    ``out`` (under the output-directory policy of dualid.report.outdir; force = --force). ``command``: the
    command line recorded in the run metadata (default: this process's argv); ``config_file``: hashed with
    the other inputs; ``progress(message)``: called before the model files and before the report."""
    meta = run_metadata(input_files(outcome, config_file), command)
    return write_output(out, force, lambda d: _write_fit(outcome, d, meta, progress or (lambda _: None)))


def _write_fit(outcome: FitOutcome, out: Path, meta: dict, progress: Callable[[str], None]) -> dict[str, Path]:
    progress(f"writing the model files and parameters.yaml to {out}")
    model_files = write_model_files(outcome, out)
    written, files = model_files.written, model_files.record()
    urdfs = {m: e["urdf"] for m, e in files.items()}
    data = report_data(outcome, urdfs, meta, model_files)
    record = parameters_record(outcome, urdfs, meta, data.train, files)
    (out / "parameters.yaml").write_text(yaml_text(record))
    write_json(out / "parameters.json", record)
    written["parameters.yaml"], written["parameters.json"] = out / "parameters.yaml", out / "parameters.json"
    (out / "identifiability.txt").write_text(outcome.identifiability_text() + "\n")
    written["identifiability.txt"] = out / "identifiability.txt"
    progress("drawing the report (report.md, report.html and their figures)")
    write_report(fit_report(data), out, written)
    return written


def write_validation(validation: Validation, out: str | Path, meta: dict, force: bool = False,
                     command: str | None = None, xcorr_window: float | None = None) -> dict[str, Path]:
    """validation.json, report.md, report.html and figures in ``out`` (under the output-directory policy).
    ``meta``: {"model": URDF path, "data": [log paths], …}; the run metadata (version, time, command,
    input hashes) is added."""
    files = {"urdf": [meta["model"]] if "model" in meta else [], "data": list(meta.get("data", []))}
    if meta.get("config"):
        files["config"] = [meta["config"]]
    run = run_metadata({k: v for k, v in files.items() if v}, command)
    return write_output(out, force, lambda d: _write_validation(validation, d, meta, run, xcorr_window))


def _write_validation(validation: Validation, out: Path, meta: dict, run: dict, xcorr_window) -> dict[str, Path]:
    record = jsonable({**meta, "run": run, "validation": validation.as_dict()})
    write_json(out / "validation.json", record)
    written = {"validation.json": out / "validation.json"}
    report = validation_report(validation, str(meta.get("model", validation.label)), run, xcorr_window)
    write_report(report, out, written)
    return written
