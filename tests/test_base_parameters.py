"""Base parameters (QR with column pivoting) against the classic regrouping of a planar 2R arm."""

import numpy as np
import pinocchio as pin
import pytest

from dualid import BaseParameters, RigidBodyModel, with_joint_terms
from dualid.errors import DataError
from dualid.identifiability import base_parameters, readable_unit, unit_ratio

L1 = 0.4  # [m] link-1 length: joint 2 sits at x = L1 in link 1's frame


def planar_2r(l1: float = L1) -> pin.Model:
    """Two revolute z-joints in the x–y plane; gravity is set in the plane by the caller."""
    m = pin.Model()
    j1 = m.addJoint(0, pin.JointModelRZ(), pin.SE3.Identity(), "j1")
    m.appendBodyToJoint(j1, pin.Inertia.FromBox(2.0, l1, 0.05, 0.05), pin.SE3(np.eye(3), np.array([l1 / 2, 0.01, 0])))
    j2 = m.addJoint(j1, pin.JointModelRZ(), pin.SE3(np.eye(3), np.array([l1, 0, 0])), "j2")
    m.appendBodyToJoint(j2, pin.Inertia.FromBox(1.0, 0.3, 0.05, 0.05), pin.SE3(np.eye(3), np.array([0.15, 0.02, 0])))
    return m


def _regressor(model, T=300, seed=0):
    rng = np.random.default_rng(seed)
    q, v, a = rng.uniform(-3, 3, (T, 2)), rng.normal(size=(T, 2)), rng.normal(size=(T, 2))
    return model.regressor(q, v, a)


@pytest.fixture(scope="module")
def vertical():
    model = RigidBodyModel(planar_2r(), gravity=(0.0, -9.81, 0.0))
    Y = _regressor(model)
    return model, Y, base_parameters(Y.reshape(-1, Y.shape[2]), model.parameters)


def test_planar_arm_has_the_classic_six_base_parameters(vertical):
    model, _, base = vertical
    names = model.parameters.names
    assert base.rank == 6
    # the z-axis torques never see these (planar motion about parallel z axes, joint 1 on the fixed axis)
    assert {names[j] for j in base.no_effect} == {
        "j1.m", "j1.mc_z", "j1.Ixx", "j1.Ixy", "j1.Iyy", "j1.Ixz", "j1.Iyz",
        "j2.mc_z", "j2.Ixx", "j2.Ixy", "j2.Iyy", "j2.Ixz", "j2.Iyz"}
    assert {"j1.mc_y", "j2.mc_x", "j2.mc_y", "j2.Izz"} <= set(base.names)  # alone, as in the textbook
    # one linear relation: the column of j2.m is L1² (j1.Izz) + L1 (j1.mc_x) (the elbow mass lumped into
    # link 1: ZZ1R = ZZ1 + m2 L1², MX1R = MX1 + m2 L1), i.e. the null vector z below; whichever of the three
    # the pivoting calls dependent (d), every other one k absorbs it with c_kd = −z_k / z_d
    z = {"j1.Izz": L1**2, "j1.mc_x": L1, "j2.m": -1.0}
    (d,) = [names[j] for j in base.dependent]
    assert d == "j2.m"  # the classic choice: the mass is lumped onto the inertia and first moment (lead_preference)
    for k in set(z) - {d}:
        row = base.names.index(k)
        assert base.C[row, names.index(d)] == pytest.approx(-z[k] / z[d], rel=1e-10)
    assert np.count_nonzero(base.C) == 6 + 2


def test_armature_regroups_with_the_axial_inertia():
    model = with_joint_terms(RigidBodyModel(planar_2r(), gravity=(0.0, 0.0, -9.81)), True, True, True)
    Y = _regressor(model)
    base = base_parameters(Y.reshape(-1, Y.shape[2]), model.parameters)
    names = model.parameters.names
    # horizontal arm: ZZ1R = ZZ1 + Ia1 + m2 L1² (j1.Izz, j1.Ia and j2.m have proportional columns, w below:
    # column_x = w_x u), ZZ2, MX2, MY2, viscous and Coulomb of both joints (4) and the joint-2 armature, which
    # acts on joint 2 alone (Izz2 acts on both): 9. The group's lead k absorbs the others with c_kd = w_d / w_k.
    assert base.rank == 9
    w = {"j1.Izz": 1.0, "j1.Ia": 1.0, "j2.m": L1**2}
    (lead,) = set(w) & set(base.names)
    assert lead == "j1.Izz"
    for d in set(w) - {lead}:
        assert base.C[base.names.index(lead), names.index(d)] == pytest.approx(w[d] / w[lead], rel=1e-10)
    assert {"j2.Ia", "j2.Izz", "j2.mc_x", "j2.mc_y", "j1.b", "j2.b", "j1.fc", "j2.fc"} <= set(base.names)


def test_predictions_from_base_parameters_equal_those_from_theta(vertical):
    model, Y, base = vertical
    rng = np.random.default_rng(3)
    for _ in range(3):
        theta = rng.normal(size=model.parameters.p)
        tau = Y @ theta
        tau_base = base.regressor(Y) @ base.values(theta)
        assert np.max(np.abs(tau_base - tau)) <= 1e-10 * np.max(np.abs(tau))


def test_the_value_is_immutable_and_named(vertical):
    _, _, base = vertical
    assert isinstance(base, BaseParameters)
    with pytest.raises(ValueError):
        base.C[0, 0] = 2.0
    text = base.describe(theta=np.ones(base.parameters.p))
    assert text.count("β") == 6 and "no effect on these data (13)" in text
    assert "… and 4 more" in base.describe(max_items=2)
    with pytest.raises(DataError, match=r"^base parameters: expected θ of shape \(20,\), got \(3,\)$"):
        base.values(np.ones(3))


def test_units_are_readable():
    assert readable_unit("kg m^2") == "kg m²"
    assert unit_ratio("kg m^2", "kg") == "m²"
    assert unit_ratio("kg", "kg m") == "m⁻¹"
    assert unit_ratio("kg m^2", "kg m^2") == ""
    assert unit_ratio("N m s/rad", "kg m^2") == "N s/(kg m rad)"


def test_identifiability_report_is_complete():
    model = RigidBodyModel(planar_2r(), gravity=(0.0, -9.81, 0.0))
    from dualid.identifiability import identifiability

    Y = _regressor(model)
    ident = identifiability(Y.reshape(-1, Y.shape[2]), model.parameters)
    text = ident.describe()
    assert "6 base parameters" in text and text.count("  β") == 6 and "more" not in text
    assert "… and 3 more" in ident.describe(max_items=3)
    assert ident.describe(max_items=0).splitlines()[1] == (
        "6 base parameters, 13 parameters with no effect (listed in full by describe(); in a fit: identifiability.txt)")
