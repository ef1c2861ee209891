"""A simulated real-like arm from a public URDF: the truth, a CAD-like prior URDF and logs as a robot writes them.

The arm (default: the Franka Panda of the ``example-robot-data`` package, Apache-2.0) keeps the source
URDF's kinematics; its gripper joints are welded (``arm_urdf``: fixed, so the hand and fingers are part
of the last link, as on an arm whose gripper is not logged) and its meshes dropped. The truth is the source
URDF's inertials with joint friction (viscous and Coulomb, ``bench.arms.Arm.joint_torque``) and a
near-zero armature (torque sensors on the link side see little rotor inertia). The prior the user gives is
the same URDF with every link's mass, centre-of-mass offset and rotational inertia scaled by its own factor
in [1 − spread, 1 + spread] (a CAD model's error; ``prior_urdf``). The runs are ``bench.arms.make_run``'s:
sums of sinusoids about the middle of each joint's range, q quantised by a 16-bit encoder, τ with
Gaussian noise. Nothing here writes a file: the caller writes the URDF texts and the logs (``log_arrays``).
"""

from __future__ import annotations

import importlib.metadata
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin

from dualid.bench.arms import COULOMB_VELOCITY, Arm, Run, make_run
from dualid.errors import MissingFileError, ModelError
from dualid.model.joint_terms import with_joint_terms
from dualid.model.rigid_body import RigidBodyModel

PANDA = "panda_description/urdf/panda.urdf"  # inside example-robot-data's robots folder
ARMATURE = 1e-4  # [kg m²] the true armature's scale: near zero


def _num(x: float) -> str:
    return f"{float(x):.17g}"


def example_robot_urdf(relative: str = PANDA) -> Path:
    """The path of a URDF shipped by the ``example-robot-data`` PyPI package (its cmeel prefix)."""
    try:
        dist = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError:
        raise MissingFileError("example_robot_urdf: the example-robot-data package is not installed "
                               "(pip install example-robot-data)") from None
    path = Path(str(dist.locate_file(f"cmeel.prefix/share/example-robot-data/robots/{relative}")))
    if not path.is_file():
        raise MissingFileError(f"example_robot_urdf: no {relative} in example-robot-data ({path})")
    return path


def arm_urdf(source: str | Path) -> str:
    """The source URDF's text without <visual>/<collision> and with every joint that is not revolute
    (grippers, prismatic fingers) welded: type fixed, no <limit>, no <mimic>."""
    root = ET.parse(source).getroot()
    for link in root.findall("link"):
        for tag in ("visual", "collision"):
            for element in link.findall(tag):
                link.remove(element)
    for joint in root.findall("joint"):
        if joint.get("type") not in ("revolute", "fixed"):
            joint.set("type", "fixed")
            for tag in ("limit", "mimic", "dynamics", "axis", "safety_controller"):
                for element in joint.findall(tag):
                    joint.remove(element)
    return ET.tostring(root, encoding="unicode")


def prior_urdf(urdf: str, rng: np.random.Generator, spread: float = 0.3) -> str:
    """``urdf`` (text) with each link's mass, centre-of-mass offset and rotational inertia (about the centre of
    mass) scaled by its own factor in [1 − spread, 1 + spread]: physically consistent, as a CAD file is."""
    if not 0 <= spread < 1:
        raise ModelError(f"prior_urdf: spread must be in [0, 1), got {spread!r}")
    root = ET.fromstring(urdf)
    for link in root.findall("link"):
        inertial = link.find("inertial")
        if inertial is None or float(inertial.find("mass").get("value")) == 0.0:
            continue
        f_mass, f_com, f_inertia = rng.uniform(1 - spread, 1 + spread, 3)
        mass = inertial.find("mass")
        mass.set("value", _num(float(mass.get("value")) * f_mass))
        origin = inertial.find("origin")
        if origin is not None:
            xyz = np.array(origin.get("xyz", "0 0 0").split(), dtype=float) * f_com
            origin.set("xyz", " ".join(_num(x) for x in xyz))
        inertia = inertial.find("inertia")
        for key in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"):
            inertia.set(key, _num(float(inertia.get(key, "0")) * f_inertia))
    return ET.tostring(root, encoding="unicode")


def joint_ranges(urdf: str, joints: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) (n,) of the named joints' <limit> (±π where a joint has none)."""
    limits = {j.get("name"): j.find("limit") for j in ET.fromstring(urdf).findall("joint")}
    lo = np.array([float(limits[j].get("lower", -np.pi)) if limits.get(j) is not None else -np.pi for j in joints])
    hi = np.array([float(limits[j].get("upper", np.pi)) if limits.get(j) is not None else np.pi for j in joints])
    return lo, hi


def urdf_arm(truth: str, prior: str, rng: np.random.Generator) -> Arm:
    """The true arm of the URDF text ``truth`` with joint friction and a near-zero armature, identified with the
    kinematics and inertials of ``prior`` (module docstring)."""
    true_model = pin.buildModelFromXML(truth)
    ident = with_joint_terms(RigidBodyModel(pin.buildModelFromXML(prior)), viscous=True, coulomb=True, armature=True,
                             coulomb_velocity=COULOMB_VELOCITY)
    n = true_model.nv
    viscous = rng.uniform(0.05, 0.5, n)
    coulomb = rng.uniform(0.2, 1.0, n)
    armature = ARMATURE * rng.uniform(0.0, 1.0, n)
    theta_true = np.concatenate(
        [true_model.inertias[j].toDynamicParameters() for j in range(1, true_model.njoints)] + [viscous, coulomb, armature])
    return Arm(true_model, viscous, coulomb, armature, ident, theta_true)


def arm_runs(arm: Arm, urdf: str, rng: np.random.Generator, runs: int, seconds: float,
             noise: float = 0.02) -> list[Run]:
    """``runs`` simulated runs of ``seconds`` each (``make_run``), each about the middle of the joints' ranges
    with its own random offset of up to a sixth of the range (so the motion stays inside the URDF's limits)."""
    lo, hi = joint_ranges(urdf, arm.ident.coordinates)
    out = []
    for k in range(runs):
        centre = 0.5 * (lo + hi) + (hi - lo) / 6 * rng.uniform(-1, 1, lo.size)
        out.append(make_run(arm, rng, seconds, noise, name=f"run{k}", centre=centre))
    return out


def log_arrays(run: Run) -> dict[str, np.ndarray]:
    """What the robot logged in ``run``: {t (T,), q (T, n) encoder readings, tau (T, n) measured torques}."""
    m = run.measured
    return {"t": m.t, "q": m.q, "tau": m.tau}
