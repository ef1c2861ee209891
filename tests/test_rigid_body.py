"""RigidBodyModel against Pinocchio's rnea/crba (the independent reference), fixed and floating base."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dualid.errors import DataError
from dualid.model.base import Model
from dualid.model.rigid_body import RigidBodyModel, spatial_inertia_basis


def random_valid_theta(rng: np.random.Generator) -> np.ndarray:
    """Dynamic parameters of a physically valid random body (mass > 0, inertia about CoM ≻ 0)."""
    m = rng.uniform(0.1, 3.0)
    c = rng.normal(size=3) * 0.3
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    # principal moments satisfying the triangle inequality
    d = rng.uniform(0.5, 1.0, size=3)
    Ic = R @ np.diag([d[1] + d[2], d[0] + d[2], d[0] + d[1]]) @ R.T * 0.1
    return pin.Inertia(m, c, Ic).toDynamicParameters()


def manipulator() -> RigidBodyModel:
    return RigidBodyModel(pin.buildSampleModelManipulator())


def humanoid() -> RigidBodyModel:
    """A free-flyer humanoid whose random inertias are replaced by physically valid ones
    (pin.Inertia.Random need not satisfy the triangle inequality)."""
    pin.seed(3)
    model = pin.buildSampleModelHumanoidRandom()
    rng = np.random.default_rng(3)
    for j in range(1, model.njoints):
        model.inertias[j] = pin.Inertia.FromDynamicParameters(random_valid_theta(rng))
    return RigidBodyModel(model)


def random_states(rbm: RigidBodyModel, T: int, seed: int):
    rng = np.random.default_rng(seed)
    model = rbm.model
    lower = np.where(np.isfinite(model.lowerPositionLimit), model.lowerPositionLimit, -1.0)
    upper = np.where(np.isfinite(model.upperPositionLimit), model.upperPositionLimit, 1.0)
    lower, upper = np.maximum(lower, -3.0), np.minimum(upper, 3.0)
    q = np.stack([pin.randomConfiguration(model, lower, upper) for _ in range(T)])
    v = rng.normal(size=(T, rbm.nv))
    a = rng.normal(size=(T, rbm.nv))
    return q, v, a


@pytest.fixture(params=["manipulator", "humanoid"], scope="module")
def rbm(request) -> RigidBodyModel:
    return manipulator() if request.param == "manipulator" else humanoid()


def test_satisfies_model_protocol(rbm):
    assert isinstance(rbm, Model)
    assert rbm.kind == "inertia"
    assert len(rbm.coordinates) == rbm.nv == len(set(rbm.coordinates))


def test_regressor_matches_rnea(rbm):
    q, v, a = random_states(rbm, 5, 0)
    theta = rbm.nominal
    Y = rbm.regressor(q, v, a)
    assert Y.shape == (5, rbm.nv, 10 * (rbm.model.njoints - 1))
    data = rbm.model.createData()
    for t in range(5):
        tau = pin.rnea(rbm.model, data, q[t], v[t], a[t])
        np.testing.assert_allclose(Y[t] @ theta, tau, atol=1e-10, rtol=0)


def test_regressor_matches_rnea_for_other_parameters(rbm):
    """Y is the same for every θ: rnea on a model with other (random, valid) inertias."""
    rng = np.random.default_rng(1)
    thetas = [random_valid_theta(rng) for _ in range(rbm.model.njoints - 1)]
    other = pin.Model(rbm.model)
    for j, th in enumerate(thetas, start=1):
        other.inertias[j] = pin.Inertia.FromDynamicParameters(th)
    q, v, a = random_states(rbm, 4, 2)
    Y = rbm.regressor(q, v, a)
    data = other.createData()
    for t in range(4):
        np.testing.assert_allclose(Y[t] @ np.concatenate(thetas), pin.rnea(other, data, q[t], v[t], a[t]), atol=1e-10)


def test_bias_regressor_is_regressor_at_zero_acceleration(rbm):
    q, v, _ = random_states(rbm, 3, 4)
    data = rbm.model.createData()
    h = rbm.bias_regressor(q, v) @ rbm.nominal
    for t in range(3):
        np.testing.assert_allclose(h[t], pin.nonLinearEffects(rbm.model, data, q[t], v[t]), atol=1e-10)


def test_metric_matches_crba(rbm):
    q, _, _ = random_states(rbm, 4, 5)
    M = rbm.metric(q).evaluate(rbm.nominal)
    data = rbm.model.createData()
    for t in range(4):
        Mref = pin.crba(rbm.model, data, q[t])
        Mref = np.triu(Mref) + np.triu(Mref, 1).T
        np.testing.assert_allclose(M[t], Mref, atol=1e-10)


def test_metric_quad_and_apply_consistent_with_evaluate(rbm):
    q, w, _ = random_states(rbm, 3, 6)
    metric = rbm.metric(q)
    p = rbm.parameters.p
    _, Mk = metric.basis()
    np.testing.assert_allclose(metric.quad(w), np.einsum("ni,nkij,nj->nk", w, Mk, w), atol=1e-10)
    np.testing.assert_allclose(metric.apply(w), np.einsum("nkij,nj->nik", Mk, w), atol=1e-10)
    theta = np.random.default_rng(0).normal(size=p)
    np.testing.assert_allclose(np.einsum("nkij,k->nij", Mk, theta), metric.evaluate(theta), atol=1e-10)


def test_single_sample_inputs():
    rbm = manipulator()
    q, v, a = random_states(rbm, 1, 7)
    np.testing.assert_array_equal(rbm.regressor(q[0], v[0], a[0]), rbm.regressor(q, v, a))
    assert rbm.metric(q[0]).shape == (1, rbm.nv)


def test_bad_shapes_are_named():
    rbm = manipulator()
    with pytest.raises(DataError, match=r"q: expected shape \(T, 6\) or \(6,\), got \(2, 5\)"):
        rbm.regressor(np.zeros((2, 5)), np.zeros((2, 6)), np.zeros((2, 6)))
    with pytest.raises(DataError, match="accelerations a are required"):
        rbm.regressor(np.zeros(6), np.zeros(6), None)
    with pytest.raises(DataError, match="q, v, a have 2, 1, 1 samples"):
        rbm.regressor(np.zeros((2, 6)), np.zeros(6), np.zeros(6))


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_spatial_inertia_basis_is_pinocchio_matrix(seed):
    theta = random_valid_theta(np.random.default_rng(seed))
    G = np.tensordot(theta, spatial_inertia_basis(), axes=1)
    np.testing.assert_allclose(G, pin.Inertia.FromDynamicParameters(theta).matrix(), atol=1e-12)


def test_parameter_names_blocks_and_coordinates():
    rbm = manipulator()
    joints = ("shoulder1_joint", "shoulder2_joint", "shoulder3_joint", "elbow_joint", "wrist1_joint", "wrist2_joint")
    assert rbm.coordinates == joints
    assert rbm.base_coordinates == ()
    assert rbm.parameters.names[:3] == ("shoulder1_joint.m", "shoulder1_joint.mc_x", "shoulder1_joint.mc_y")
    assert rbm.parameters.names[-1] == "wrist2_joint.Izz"
    assert [b.name for b in rbm.parameters.blocks] == list(joints)
    assert all(b.kind == "rigid_body" for b in rbm.parameters.blocks)
    assert rbm.parameters.blocks[2].indices == tuple(range(20, 30))

    hum = humanoid()
    assert hum.coordinates[:7] == ("vx", "vy", "vz", "wx", "wy", "wz", "lleg1_joint")
    assert hum.base_coordinates == ("vx", "vy", "vz", "wx", "wy", "wz")
    assert hum.parameters.blocks[0].name == "root_joint"


def test_multi_dof_joint_names():
    model = pin.Model()
    j = model.addJoint(0, pin.JointModelSpherical(), pin.SE3.Identity(), "ball")
    model.appendBodyToJoint(j, pin.Inertia.Random(), pin.SE3.Identity())
    assert RigidBodyModel(model).coordinates == ("ball_0", "ball_1", "ball_2")


def test_nominal_is_physically_consistent(rbm):
    assert rbm.parameters.is_consistent(rbm.nominal)


def test_gravity_override_and_copy():
    base = pin.buildSampleModelManipulator()
    rbm = RigidBodyModel(base, gravity=(0.0, 0.0, -1.62))
    assert rbm.gravity == (0.0, 0.0, -1.62)
    assert np.allclose(base.gravity.linear, [0, 0, -9.81])  # the caller's model is untouched
    assert RigidBodyModel(base).gravity == (0.0, 0.0, -9.81)
    q = pin.neutral(rbm.model)
    z = np.zeros(rbm.nv)
    g = rbm.regressor(q, z, z)[0] @ rbm.nominal
    np.testing.assert_allclose(g, pin.rnea(rbm.model, rbm.model.createData(), q, z, z), atol=1e-12)
    earth = rbm.with_gravity((0, 0, -9.81)).regressor(q, z, z)[0] @ rbm.nominal
    np.testing.assert_allclose(earth, g * 9.81 / 1.62, atol=1e-10)
    with pytest.raises(ValueError, match="gravity must be 3 finite numbers"):
        RigidBodyModel(base, gravity=(0, 1))


def test_floating_base_from_urdf(tmp_path):
    urdf = tmp_path / "chain.urdf"
    urdf.write_text(
        """<robot name="chain">
  <link name="a"><inertial><origin xyz="0.1 0 0"/><mass value="1"/>
    <inertia ixx="0.1" ixy="0" ixz="0" iyy="0.2" iyz="0" izz="0.2"/></inertial></link>
  <link name="b"><inertial><origin xyz="0 0.1 0"/><mass value="0.5"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.02"/></inertial></link>
  <link name="c"><inertial><origin xyz="0 0 0.2"/><mass value="0.2"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.005"/></inertial></link>
  <joint name="j1" type="revolute"><parent link="a"/><child link="b"/><origin xyz="0.2 0 0"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="j2" type="continuous"><parent link="b"/><child link="c"/><origin xyz="0 0.2 0"/>
    <axis xyz="1 0 0"/></joint>
</robot>"""
    )
    rbm = RigidBodyModel.from_urdf(urdf, floating_base=True)
    assert rbm.coordinates == ("vx", "vy", "vz", "wx", "wy", "wz", "j1", "j2")  # continuous: nq 2, nv 1
    assert rbm.bodies[:2] == ("root_joint", "j1")
    q, v, a = random_states(rbm, 3, 8)
    data = rbm.model.createData()
    Y = rbm.regressor(q, v, a)
    M = rbm.metric(q).evaluate(rbm.nominal)
    for t in range(3):
        np.testing.assert_allclose(Y[t] @ rbm.nominal, pin.rnea(rbm.model, data, q[t], v[t], a[t]), atol=1e-10)
        Mref = pin.crba(rbm.model, data, q[t])
        np.testing.assert_allclose(M[t], np.triu(Mref) + np.triu(Mref, 1).T, atol=1e-10)
    with pytest.raises(FileNotFoundError, match="no URDF file at"):
        RigidBodyModel.from_urdf(tmp_path / "missing.urdf")


# --- joint friction and armature (dualid.model.joint_terms) ---------------------------------------
from dualid.model.joint_terms import with_joint_terms  # noqa: E402
from dualid.model.pan_tilt import PanTilt, jacobian  # noqa: E402


def test_joint_terms_closed_form_on_pan_tilt():
    """τ = τ_pan_tilt + b v + fc tanh(v / v_c) + Ia a and M = m JᵀJ + diag(Ia), by hand."""
    base = PanTilt()
    model = with_joint_terms(base, armature=True, coulomb_velocity=0.05)
    assert isinstance(model, Model)
    assert model.parameters.names[3:] == (
        "pan.b", "tilt.b", "pan.fc", "tilt.fc", "pan.Ia", "tilt.Ia",
    )
    assert model.parameters.units[3:] == ("N m s/rad",) * 2 + ("N m",) * 2 + ("kg m^2",) * 2
    assert [(b.name, b.kind, b.indices) for b in model.parameters.blocks[2:]] == [
        ("viscous", "nonnegative", (3, 4)),
        ("coulomb", "nonnegative", (5, 6)),
        ("armature", "nonnegative", (7, 8)),
    ]
    rng = np.random.default_rng(0)
    q, v, a = rng.normal(size=(3, 6, 2))
    m, b, fc, Ia = 0.7, np.array([0.1, 0.2]), np.array([0.03, 0.05]), np.array([0.004, 0.006])
    theta = np.concatenate([[m, 0.0, 0.0], b, fc, Ia])
    tau_base = base.regressor(q, v, a) @ np.array([m, 0.0, 0.0])
    expected = tau_base + b * v + fc * np.tanh(v / 0.05) + Ia * a
    np.testing.assert_allclose(model.regressor(q, v, a) @ theta, expected, atol=1e-12)
    h_expected = base.bias_regressor(q, v) @ np.array([m, 0, 0]) + b * v + fc * np.tanh(v / 0.05)
    np.testing.assert_allclose(model.bias_regressor(q, v) @ theta, h_expected, atol=1e-12)
    J = jacobian(q, base.length)
    M_expected = m * np.swapaxes(J, 1, 2) @ J + np.diag(Ia)
    np.testing.assert_allclose(model.metric(q).evaluate(theta), M_expected, atol=1e-12)


def test_joint_terms_selection_and_errors():
    base = PanTilt()
    model = with_joint_terms(base, coulomb=False, armature=False, joints=["tilt"])
    assert model.parameters.names[3:] == ("tilt.b",)
    v = np.array([[1.0, 2.0]])
    Y = model.regressor(np.zeros((1, 2)), v, np.zeros((1, 2)))
    np.testing.assert_array_equal(Y[0, :, 3], [0.0, 2.0])
    assert len(model.metric(np.zeros((1, 2))).terms) == 1  # no armature: the base metric only
    with pytest.raises(ValueError, match=r"unknown joints \['elbow'\]; valid joints are \['pan', 'tilt'\]"):
        with_joint_terms(base, joints=["elbow"])
    with pytest.raises(ValueError, match="choose at least one of viscous, coulomb, armature"):
        with_joint_terms(base, viscous=False, coulomb=False, armature=False)
    with pytest.raises(ValueError, match="coulomb_velocity must be > 0"):
        with_joint_terms(base, coulomb_velocity=0.0)


def test_joint_terms_skip_free_flyer_root_and_match_pinocchio():
    hum = humanoid()
    model = with_joint_terms(hum, armature=True)
    assert len(model.dofs) == hum.nv - 6 and model.dofs[0] == 6
    assert model.parameters.names[hum.parameters.p] == "lleg1_joint.b"
    q, v, a = random_states(hum, 2, 9)
    rng = np.random.default_rng(1)
    extra = rng.uniform(0.01, 0.1, size=3 * len(model.dofs))
    theta = np.concatenate([hum.nominal, extra])
    Ia = extra[2 * len(model.dofs):]
    # Pinocchio's own armature (model.armature) as the reference for the mass matrix
    ref = pin.Model(hum.model)
    arm = np.zeros(hum.nv)
    arm[6:] = Ia
    ref.armature = arm
    data = ref.createData()
    M = model.metric(q).evaluate(theta)
    for t in range(2):
        Mref = pin.crba(ref, data, q[t])
        np.testing.assert_allclose(M[t], np.triu(Mref) + np.triu(Mref, 1).T, atol=1e-10)


def test_undeclared_world_root_link_is_declared(tmp_path):
    """Gazebo-style URDFs weld to a "world" link they never declare; urdfdom rejects them as is."""
    urdf = tmp_path / "welded.urdf"
    urdf.write_text(
        """<robot name="welded">
  <joint name="weld" type="fixed"><parent link="world"/><child link="base"/></joint>
  <link name="base"/>
  <link name="arm"><inertial><origin xyz="0 0 -0.3"/><mass value="0.5"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.001"/></inertial></link>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="arm"/>
    <axis xyz="1 0 0"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
</robot>"""
    )
    rbm = RigidBodyModel.from_urdf(urdf)
    assert rbm.coordinates == ("shoulder",)
    np.testing.assert_allclose(rbm.nominal[:4], [0.5, 0.0, 0.0, -0.15])
    assert RigidBodyModel.from_urdf(urdf, floating_base=True).coordinates[-1] == "shoulder"


def test_joint_terms_refuse_drag_models():
    class Drag:
        kind = "drag"
        coordinates = ("x",)
        parameters = PanTilt.parameters

    with pytest.raises(ValueError, match="expected an inertia-dominated model, got kind 'drag'"):
        with_joint_terms(Drag())
