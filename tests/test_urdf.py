"""write_urdf: identified inertials round-trip through Pinocchio's URDF parser."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from dualid.errors import ConsistencyError, OutputError
from dualid.model.rigid_body import RigidBodyModel
from dualid.report.urdf import write_urdf

PENDUBOT = Path(__file__).resolve().parents[1] / "examples" / "dfki" / "data" / "pendubot_model_2.1.urdf"  # shipped with the repository

CHAIN = """<robot name="chain">
  <link name="a"><inertial><origin xyz="0.1 0 0"/><mass value="1"/>
    <inertia ixx="0.1" ixy="0" ixz="0" iyy="0.2" iyz="0" izz="0.2"/></inertial></link>
  <link name="b"><inertial><origin xyz="0 0.1 0" rpy="0.3 0.2 0.1"/><mass value="0.5"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.02"/></inertial></link>
  <link name="tool"><inertial><origin xyz="0 0 0.1"/><mass value="0.1"/>
    <inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/></inertial></link>
  <joint name="j1" type="revolute"><parent link="a"/><child link="b"/><origin xyz="0.2 0 0" rpy="0 0.5 0"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="weld" type="fixed"><parent link="b"/><child link="tool"/><origin xyz="0 0.2 0" rpy="0.1 0 0"/></joint>
</robot>"""


def perturbed(theta: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A physically consistent θ near theta: each body's mass, CoM and inertia changed a little."""
    out = []
    for k in range(0, len(theta), 10):
        body = pin.Inertia.FromDynamicParameters(theta[k : k + 10])
        R = pin.rpy.rpyToMatrix(*rng.normal(scale=0.2, size=3))
        Ic = R @ (body.inertia * rng.uniform(0.8, 1.2)) @ R.T
        new = pin.Inertia(body.mass * rng.uniform(0.8, 1.2), body.lever + rng.normal(scale=0.01, size=3), Ic)
        out.append(new.toDynamicParameters())
    return np.concatenate(out)


def test_pendubot_round_trip(tmp_path):
    model = RigidBodyModel.from_urdf(PENDUBOT)
    assert model.bodies == ("Joint1", "Joint2")
    theta = perturbed(model.nominal, np.random.default_rng(0))
    assert model.parameters.is_consistent(theta)
    out = write_urdf(PENDUBOT, model, theta, tmp_path / "identified.urdf", friction={"Joint1": (0.01, 0.05)})
    back = RigidBodyModel.from_urdf(out)
    np.testing.assert_allclose(back.nominal, theta, atol=1e-9, rtol=0)
    np.testing.assert_allclose(back.model.jointPlacements[2].rotation, model.model.jointPlacements[2].rotation)
    root = ET.parse(out).getroot()
    dyn = root.find("joint[@name='Joint1']/dynamics")
    assert (float(dyn.get("damping")), float(dyn.get("friction"))) == (0.01, 0.05)
    weight = root.find("link[@name='Weight']/inertial/mass")
    assert float(weight.get("value")) == 0.0
    assert "zeroed" in out.read_text() and "dualid: identified inertia" in out.read_text()
    assert root.find("transmission") is not None  # everything else is copied
    mesh = root.find("link[@name='Link1']/visual/geometry/mesh").get("filename")
    assert (out.parent / mesh).resolve() == (PENDUBOT.parent / "meshes" / "Link1.obj").resolve()


def test_fixed_links_are_not_double_counted(tmp_path):
    src = tmp_path / "chain.urdf"
    src.write_text(CHAIN)
    model = RigidBodyModel.from_urdf(src, floating_base=True)
    assert model.bodies == ("root_joint", "j1")
    theta = perturbed(model.nominal, np.random.default_rng(1))
    out = write_urdf(src, model, theta, tmp_path / "out.urdf")
    np.testing.assert_allclose(RigidBodyModel.from_urdf(out, floating_base=True).nominal, theta, atol=1e-12)
    root = ET.parse(out).getroot()
    assert float(root.find("link[@name='tool']/inertial/mass").get("value")) == 0.0
    assert float(root.find("link[@name='b']/inertial/mass").get("value")) == pytest.approx(theta[10])


def test_overwrite_refused(tmp_path):
    src = tmp_path / "chain.urdf"
    src.write_text(CHAIN)
    model = RigidBodyModel.from_urdf(src)
    target = tmp_path / "out.urdf"
    target.write_text("keep me")
    with pytest.raises(OutputError, match=r"out\.urdf already exists; pass overwrite=True to replace it"):
        write_urdf(src, model, model.nominal, target)
    assert target.read_text() == "keep me"
    write_urdf(src, model, model.nominal, target, overwrite=True)
    np.testing.assert_allclose(RigidBodyModel.from_urdf(target).nominal, model.nominal, atol=1e-12)


def test_inconsistent_theta_refused(tmp_path):
    src = tmp_path / "chain.urdf"
    src.write_text(CHAIN)
    model = RigidBodyModel.from_urdf(src)
    theta = model.nominal.copy()
    theta[0] = -0.1
    with pytest.raises(ConsistencyError, match=r"body 'j1' has mass -0.1 kg \(expected > 0\)"):
        write_urdf(src, model, theta, tmp_path / "bad.urdf")
    theta = model.nominal.copy()
    theta[4] = -1.0  # Ixx about the joint origin far below m (c_y² + c_z²): not PSD about the CoM
    with pytest.raises(ConsistencyError, match="inertia about its centre of mass with eigenvalues"):
        write_urdf(src, model, theta, tmp_path / "bad.urdf")
    assert not (tmp_path / "bad.urdf").exists()
    with pytest.raises(ValueError, match=r"θ must have shape \(10,\)"):
        write_urdf(src, model, np.zeros(12), tmp_path / "bad.urdf")
    with pytest.raises(ValueError, match=r"friction for unknown joint 'weld'; moving joints are \['j1'\]"):
        write_urdf(src, model, model.nominal, tmp_path / "bad.urdf", friction={"weld": (0.1, 0.1)})


def test_armature_is_written_as_a_dynamics_attribute(tmp_path):
    src = tmp_path / "chain.urdf"
    src.write_text(CHAIN)
    model = RigidBodyModel.from_urdf(src)
    out = write_urdf(src, model, model.nominal, tmp_path / "out.urdf", friction={"j1": (0.2, 0.05)}, armature={"j1": 3e-4})
    dynamics = ET.parse(out).getroot().find("joint[@name='j1']/dynamics")
    assert float(dynamics.get("armature")) == 3e-4 and float(dynamics.get("damping")) == 0.2
    with pytest.raises(ConsistencyError, match=r"joint 'j1' armature must be ≥ 0, got -1.0"):
        write_urdf(src, model, model.nominal, tmp_path / "bad.urdf", armature={"j1": -1.0})
    with pytest.raises(ValueError, match=r"armature for unknown joint 'weld'; moving joints are \['j1'\]"):
        write_urdf(src, model, model.nominal, tmp_path / "bad.urdf", armature={"weld": 1.0})
