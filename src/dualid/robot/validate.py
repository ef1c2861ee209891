"""Validation of a URDF as it stands (e.g. one written by ``dualid fit``) on logs; the scores are
``dualid.evaluation.validation``'s."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dualid.data.tables import reading_once
from dualid.errors import DataError, MissingFileError, ModelError
from dualid.evaluation.validation import Validation, validate
from dualid.model.joint_terms import JointTermsModel, with_joint_terms
from dualid.model.rigid_body import RigidBodyModel
from dualid.robot.fit import choose_preprocessing, column_map, load_runs, urdf_joint_terms


def _from_mjcf(path: Path, gravity, floating_base: bool) -> tuple[RigidBodyModel, dict[str, dict[str, float]]]:
    """An MJCF written by ``dualid fit`` (<method>.xml): Pinocchio's MJCF parser gives the inertials and each
    joint's damping, frictionloss (read as dualid's Coulomb level) and armature."""
    import pinocchio as pin

    if not path.is_file():
        raise MissingFileError(f"validate: no MJCF file at {path}")
    if floating_base:
        raise ModelError(f"validate: {path}: floating-base MJCF is not supported; validate the URDF instead")
    try:
        pm = pin.buildModelFromMJCF(str(path))
    except (RuntimeError, ValueError) as exc:
        raise ModelError(f"{path}: Pinocchio could not build a model from this MJCF: {exc}") from None
    terms = {}
    for j in range(1, pm.njoints):
        i = pm.joints[j].idx_v
        terms[pm.names[j]] = {"damping": float(pm.damping[i]), "friction": float(pm.friction[i]),
                              "armature": float(pm.armature[i])}
    pm.armature[:] = 0.0  # carried as dualid's joint term, not twice
    return RigidBodyModel(pm, gravity), terms


def validate_urdf(urdf, data, columns=None, preprocessing=None, xcorr_window: float = 0.02,
                  coulomb_velocity: float = 0.01, gravity=None, floating_base: bool = False,
                  label: str | None = None) -> tuple[JointTermsModel | RigidBodyModel, np.ndarray, Validation]:
    """Validate a URDF as it stands (e.g. one written by ``dualid fit``) on logs.

    θ: the URDF's inertials, plus per joint viscous damping and Coulomb friction from
    <dynamics damping friction> and armature from the non-standard <dynamics armature> that
    ``dualid fit`` writes (0 when absent). An .xml file is read as MJCF (``dualid fit``'s <method>.xml:
    damping, frictionloss and armature per joint). Returns (model, θ, Validation).
    """
    urdf = Path(urdf)
    data = [Path(p) for p in data]
    if not data:
        raise DataError("validate: no log files given")
    if urdf.suffix.lower() == ".xml":
        rigid, terms = _from_mjcf(urdf, gravity, floating_base)
    else:
        rigid = RigidBodyModel.from_urdf(urdf, floating_base, gravity)
    joints = tuple(j for j in rigid.coordinates if j not in rigid.base_coordinates)
    model = with_joint_terms(rigid, True, True, True, joints, coulomb_velocity) if joints else rigid  # no joint: a single body
    if urdf.suffix.lower() != ".xml":
        terms = urdf_joint_terms(urdf, joints)
    theta = np.concatenate([
        rigid.nominal,
        [terms[j]["damping"] for j in joints],
        [terms[j]["friction"] for j in joints],
        [terms[j]["armature"] for j in joints],
    ])
    with reading_once():  # the first log is checked, sampled and loaded: parsed once
        cmap = column_map(columns, tuple(rigid.coordinates), data[0])
        steps, _ = choose_preprocessing(preprocessing, data[0], cmap, tuple(rigid.coordinates))
        runs = load_runs(data, cmap, tuple(rigid.coordinates), steps, rigid)
    return model, theta, validate(model, theta, runs, label or urdf.stem, xcorr_window)
