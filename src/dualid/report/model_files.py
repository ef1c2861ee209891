"""The model files of a real-robot fit, one pair per fitted method, and their record in parameters.yaml.

- <method>.urdf: the source URDF with the identified inertials and <dynamics damping friction>
  (armature as dualid's non-standard <dynamics armature>: no URDF loader keeps it);
- <method>.xml: MJCF through MuJoCo's MjSpec, with armature, damping and frictionloss.

Both carry θ_plausible (``robot.plausible_step``) when the fit has one, else the raw θ̂; the record
says which. A file that cannot be written (e.g. a fit on the consistency boundary) is a ``ModelFile``
without a path and with the reason, recorded as "not written: <why>"; the other files are still written.
The MJCF's joint ranges are checked against the logged motion (training and held-out runs), and its
``package://`` meshes are looked up in the config's ``model.package_path`` (``model.mjcf``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from dualid.errors import DualidError
from dualid.model.joint_terms import JointTermsModel
from dualid.report.document import Bullets, Section, Table, Text
from dualid.report.mjcf import write_mjcf
from dualid.report.urdf import write_urdf
from dualid.robot.fit import FitOutcome, MethodFit

RAW, PLAUSIBLE = "raw θ̂ (the fit's own values)", "θ_plausible (closest to the prior with θ̂'s predictions)"
PLAUSIBLE_REGION = "θ_plausible (closest to the prior with base parameters in the fit's {level:g} confidence region)"


def written_theta(fit: MethodFit) -> tuple[np.ndarray, str]:
    """(θ the files carry, which one it is)."""
    if fit.plausible is not None:
        p = fit.plausible
        return p.theta, (PLAUSIBLE_REGION.format(level=p.level) if p.form == "confidence" else PLAUSIBLE)
    return fit.result.theta, RAW


@dataclass(frozen=True)
class ModelFile:
    """One model file of one method: its path when written, else why not; what the writer dropped or changed."""

    method: str
    kind: Literal["urdf", "mjcf"]
    path: Path | None  # None: not written
    reason: str = ""  # why it was not written
    notes: tuple[str, ...] = ()

    @property
    def entry(self) -> str:
        """parameters.yaml's value: the file name or "not written: <why>"."""
        return self.path.name if self.path is not None else f"not written: {self.reason}"


@dataclass(frozen=True)
class ModelFiles:
    """The model files of a fit (two per method that fitted) and which θ each method's files carry."""

    files: tuple[ModelFile, ...]
    theta: tuple[tuple[str, str], ...]  # (method, which θ: RAW or a PLAUSIBLE form)

    @property
    def written(self) -> dict[str, Path]:
        """{file name: path} of the files written."""
        return {f.path.name: f.path for f in self.files if f.path is not None}

    @property
    def not_written(self) -> tuple[ModelFile, ...]:
        return tuple(f for f in self.files if f.path is None)

    def record(self) -> dict[str, dict[str, str]]:
        """{method: {"theta": …, "urdf": name or "not written: …", "mjcf": …, "mjcf_notes": …}} (parameters.yaml)."""
        out: dict[str, dict[str, str]] = {m: {"theta": which} for m, which in self.theta}
        for f in self.files:
            out[f.method][f.kind] = f.entry
            if f.kind == "mjcf" and f.path is not None:
                out[f.method]["mjcf_notes"] = "; ".join(f.notes)
        return out


def logged_ranges(outcome: FitOutcome) -> dict[str, tuple[float, float]]:
    """{joint: (lowest, highest) logged position} over the training and held-out runs (joints logged one column
    per coordinate; none for a floating base)."""
    runs = [r for r in (*outcome.train, *outcome.test) if r.q.shape[1] == len(r.coordinates)]
    if not runs or outcome.rigid.base_coordinates:
        return {}
    lo = np.min([r.q.min(axis=0) for r in runs], axis=0)
    hi = np.max([r.q.max(axis=0) for r in runs], axis=0)
    return {name: (float(a), float(b)) for name, a, b in zip(runs[0].coordinates, lo, hi)}


def write_model_files(outcome: FitOutcome, out: Path) -> ModelFiles:
    """Write <method>.urdf and <method>.xml for every method that fitted; returns what was written and why
    any file was not."""
    files: list[ModelFile] = []
    thetas: list[tuple[str, str]] = []
    p0 = outcome.rigid.parameters.p
    model = outcome.model
    urdf, ranges = outcome.config.model.urdf, logged_ranges(outcome)
    for m, f in outcome.fits.items():
        if not f.ok:
            continue
        theta, which = written_theta(f)
        thetas.append((m, which))
        if f.files_refused:  # a link no arm has (robot.plausible_step.refused_files): neither file is written
            files += [ModelFile(m, "urdf", None, f.files_refused), ModelFile(m, "mjcf", None, f.files_refused)]
            continue
        friction = model.friction(theta) if isinstance(model, JointTermsModel) else {}
        armature = model.armature_values(theta) if isinstance(model, JointTermsModel) else {}
        # a completed mass (not determined by the data) is said on its body when the files carry θ̂ itself
        nd = f.result.not_determined(outcome.rigid.parameters.names) if which == RAW else {}
        try:
            path = write_urdf(urdf, outcome.rigid, theta[:p0], out / f"{m}.urdf", overwrite=True,
                              friction=friction, armature=armature, not_determined=nd)
            files.append(ModelFile(m, "urdf", path))
        except (DualidError, ValueError) as exc:  # e.g. a fit on the consistency boundary the URDF writer refuses
            files.append(ModelFile(m, "urdf", None, " ".join(str(exc).split())))  # one line (MuJoCo's have several)
        try:
            path, mjcf = write_mjcf(urdf, outcome.rigid, theta[:p0], out / f"{m}.xml", overwrite=True,
                                    friction=friction, armature=armature, not_determined=nd, logged=ranges,
                                    package_path=outcome.config.model.package_path)
            files.append(ModelFile(m, "mjcf", path, notes=mjcf.notes))
        except (DualidError, ValueError) as exc:
            files.append(ModelFile(m, "mjcf", None, " ".join(str(exc).split())))
    return ModelFiles(tuple(files), tuple(thetas))


def plausible_record(fit: MethodFit) -> dict | None:
    """parameters.yaml's "plausible" entry of one method: how θ_plausible was chosen, and per parameter its
    value, the prior's and who determined it ("data" or "prior", with the prior's share)."""
    p = fit.plausible
    if p is None:
        return {"error": fit.plausible_error} if fit.plausible_error else None
    held_out = fit.plausible_validation
    return {
        **p.as_dict(),
        "held_out_tau_rmse": None if held_out is None else [float(x) for x in held_out.mean("tau_rmse")],
        "not_determined_by_data": list(p.by_prior()),  # their values come from the prior
        "parameters": [
            {"name": n, "value": float(x), "prior": float(x0), "determined_by": d, "prior_share": float(s)}
            for n, x, x0, d, s in zip(p.names, p.theta, p.theta0, p.determined_by, p.prior_share)
        ],
    }


def plausible_lines(outcome: FitOutcome) -> list[str]:
    """report.md: per method, how θ_plausible was chosen and the moving masses raw → plausible (prior)."""
    lines = []
    masses = [k for k, n in enumerate(outcome.rigid.parameters.names) if n.endswith(".m")]
    for m, f in outcome.fits.items():
        if not f.ok or (f.plausible is None and not f.plausible_error):
            continue
        if f.plausible is None:
            lines.append(f"- {m}: no plausible parameters ({f.plausible_error}); the model files carry θ̂")
            continue
        p = f.plausible
        cells = ", ".join(f"{p.names[k].removesuffix('.m')} {p.theta_hat[k]:.4g} → {p.theta[k]:.4g} "
                          f"({p.theta0[k]:.4g}, {p.determined_by[k]})" for k in masses)
        form = (f"{p.level:g} confidence region ((β − β̂)ᵀΣ⁻¹(β − β̂) = {p.statistic:.3g} ≤ {p.radius2:.3g})"
                if p.form == "confidence" else "same training predictions")
        rmse = (f"training τ RMSE {p.training_rmse_hat:.4g} → {p.training_rmse:.4g} "
                f"({100 * (p.training_rmse / p.training_rmse_hat - 1):+.2f} %)" if p.training_rmse_hat > 0 else "")
        if f.validation is not None and f.plausible_validation is not None:
            a, b = float(np.mean(f.validation.mean("tau_rmse"))), float(np.mean(f.plausible_validation.mean("tau_rmse")))
            rmse += f"{', ' if rmse else ''}held-out τ RMSE {a:.4g} → {b:.4g} ({100 * (b / a - 1):+.2f} %)"
        lines.append(f"- {m}: {form}{'; ' + p.note if p.note else ''}; {p.objective} divergence {p.divergence_hat:.4g} "
                     f"→ {p.divergence:.4g}, training predictions changed by {p.prediction_change:.1e} (relative)"
                     f"{', ' + rmse if rmse else ''}, {p.solver_chain}; "
                     f"masses [kg] raw → plausible (prior, determined by): {cells}; "
                     f"not determined by the data, from the prior ({len(p.by_prior())}): "
                     f"{', '.join(p.by_prior()) or 'none'}")
    return lines


PLAUSIBLE_INTRO = ("The model files carry, for each method, the parameters closest to the prior (log-det divergence "
                   "of the pseudo-inertias) among those the data do not reject: base parameters in the fit's "
                   "confidence region (every linear combination within its interval), or, with level 0 or without "
                   "uncertainty, the fit's own training predictions; parameters.yaml keeps the raw θ̂ and lists "
                   "θ_plausible with who determined each parameter.")


def plausible_section(outcome: FitOutcome) -> Section:
    """The report's 'Plausible parameters' section (empty, hence not shown, when no method has them)."""
    items = plausible_lines(outcome)
    return Section("Plausible parameters", (Text(PLAUSIBLE_INTRO), Bullets(tuple(i.removeprefix("- ") for i in items)))
                   if items else ())


MODEL_FILES_NOTE = ("Load the .xml in MuJoCo or in Pinocchio's MJCF reader (buildModelFromMJCF): it carries the armature, "
                    "damping and frictionloss. Every URDF reader (Pinocchio's, MuJoCo's, Gazebo's) loses the armature, "
                    "which URDF has no field for; dualid validate reads both files whole.")


def model_files_section(files: ModelFiles | None) -> Section:
    """The report's 'Model files' section: per method the files written (or why not), and what the MJCF writer
    dropped or changed (missing meshes, joint ranges the logs leave, …)."""
    if files is None or not files.files:
        return Section("Model files")
    cells: dict[str, dict[str, str]] = {m: {"theta": which} for m, which in files.theta}
    for f in files.files:
        cells[f.method][f.kind] = f.path.name if f.path is not None else "not written"
    rows = tuple((m, c.get("urdf", "—"), c.get("mjcf", "—"), c["theta"]) for m, c in cells.items())
    items = [f"{f.method}.{'urdf' if f.kind == 'urdf' else 'xml'} not written: {f.reason}" for f in files.not_written]
    items += list(dict.fromkeys(n for f in files.files for n in f.notes))
    return Section("Model files", (Table(("method", "URDF", "MJCF", "parameters carried"), rows), Text(MODEL_FILES_NOTE),
                                   *((Bullets(tuple(items)),) if items else ())))
