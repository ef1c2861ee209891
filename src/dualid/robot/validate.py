"""Validation of a URDF as it stands (e.g. one written by ``dualid fit``) on logs; the scores are
``dualid.evaluation.validation``'s."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dualid.errors import DataError
from dualid.evaluation.validation import Validation, validate
from dualid.model.joint_terms import JointTermsModel, with_joint_terms
from dualid.model.rigid_body import RigidBodyModel
from dualid.robot.fit import choose_preprocessing, column_map, load_runs, urdf_joint_terms


def validate_urdf(urdf, data, columns=None, preprocessing=None, xcorr_window: float = 0.02,
                  coulomb_velocity: float = 0.01, gravity=None, floating_base: bool = False,
                  label: str | None = None) -> tuple[JointTermsModel | RigidBodyModel, np.ndarray, Validation]:
    """Validate a URDF as it stands (e.g. one written by ``dualid fit``) on logs.

    θ: the URDF's inertials, plus per joint viscous damping and Coulomb friction from
    <dynamics damping friction> and armature from the non-standard <dynamics armature> that
    ``dualid fit`` writes (0 when absent). Returns (model, θ, Validation).
    """
    urdf = Path(urdf)
    data = [Path(p) for p in data]
    if not data:
        raise DataError("validate: no log files given")
    rigid = RigidBodyModel.from_urdf(urdf, floating_base, gravity)
    joints = tuple(j for j in rigid.coordinates if j not in rigid.base_coordinates)
    terms = urdf_joint_terms(urdf, joints)
    model = with_joint_terms(rigid, True, True, True, joints, coulomb_velocity) if joints else rigid  # no joint: a single body
    theta = np.concatenate([
        rigid.nominal,
        [terms[j]["damping"] for j in joints],
        [terms[j]["friction"] for j in joints],
        [terms[j]["armature"] for j in joints],
    ])
    cmap = column_map(columns, tuple(rigid.coordinates), data[0])
    steps, _ = choose_preprocessing(preprocessing, data[0], cmap, tuple(rigid.coordinates))
    runs = load_runs(data, cmap, tuple(rigid.coordinates), steps, rigid)
    return model, theta, validate(model, theta, runs, label or urdf.stem, xcorr_window)
