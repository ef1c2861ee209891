"""Joint friction and armature read back from θ: rounding below zero reads as zero, a real negative
value is kept (so the URDF writer refuses it) instead of being clamped away."""

import numpy as np

from dualid.model import RigidBodyModel, with_joint_terms
from tests.factories import arm


def test_friction_and_armature_from_theta():
    rigid = RigidBodyModel(arm(2))
    model = with_joint_terms(rigid, viscous=True, coulomb=True, armature=True)
    theta = np.concatenate([rigid.nominal, [0.1, -1e-13], [0.2, -0.05], [1e-3, 2e-3]])
    j1, j2 = model.coordinates
    assert model.friction(theta) == {j1: (0.1, 0.2), j2: (0.0, -0.05)}
    assert model.armature_values(theta) == {j1: 1e-3, j2: 2e-3}
    assert with_joint_terms(rigid, viscous=True, coulomb=False, armature=False).armature_values(rigid.nominal) == {}
