"""Arms simulated in MuJoCo for the noise benchmarks (benchmarks/noise_sources.py, benchmarks/authors_example.py).

The kinematic tree comes from a Pinocchio model (any URDF, e.g. the public arms of the
``example-robot-data`` package); ``mujoco_model`` rebuilds it body by body through MuJoCo's ``MjSpec``
with the true inertias, joint armature (reflected rotor inertia) and viscous damping. The physical
torque of a commanded motion (q, v, a) is MuJoCo's inverse dynamics (``mj_inverse``: M(q) a + bias −
passive forces) plus Coulomb friction fc·tanh(v / v_c), the smooth sign dualid's joint model uses.
Pinocchio's regressor, used by the estimators, is an independent computation of the same torque.

What an estimator gets is what a robot logs (``measure``): q from an encoder (Gaussian noise, then
quantisation), v and a from dualid's own preprocessing (``dualid.data.preprocessing.differentiate``,
Savitzky–Golay), τ with Gaussian noise of a given fraction of each joint's clean τ rms.

No file is written here.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin

from dualid.data.preprocessing import differentiate, trim
from dualid.data.trajectory import Trajectory
from dualid.bench.urdf_arm import example_robot_urdf
from dualid.errors import ConfigError, ModelError
from dualid.model.joint_terms import JointTermsModel, with_joint_terms
from dualid.model.rigid_body import RigidBodyModel

COULOMB_VELOCITY = 0.01  # [rad/s] v_c of the smooth Coulomb sign, in the truth and in the identification model
# public arms of the example-robot-data package: (URDF inside its robots folder, joints to lock)
ROBOTS = {
    "panda": ("panda_description/urdf/panda.urdf", ("panda_finger_joint1", "panda_finger_joint2")),
    "xarm7": ("xarm_description/urdf/xarm7.urdf", ()),
    "ur5": ("ur_description/urdf/ur5_robot.urdf", ()),
}


def robot_urdf(name: str) -> Path:
    """The URDF file of a ``ROBOTS`` arm inside the installed example-robot-data package."""
    if name not in ROBOTS:
        raise ConfigError(f"robot: expected one of {sorted(ROBOTS)}, got {name!r}")
    return example_robot_urdf(ROBOTS[name][0])


def robot_model(name: str) -> pin.Model:
    """The Pinocchio model of a ``ROBOTS`` arm, its gripper joints locked at 0."""
    model = pin.buildModelFromUrdf(str(robot_urdf(name)))
    lock = [model.getJointId(j) for j in ROBOTS[name][1]]
    if lock:
        model = pin.buildReducedModel(model, lock, pin.neutral(model))
    return model


def _hinge_axis(joint) -> np.ndarray:
    short = joint.shortname()
    if short in ("JointModelRX", "JointModelRY", "JointModelRZ"):
        return np.eye(3)["XYZ".index(short[-1])]
    if short == "JointModelRevoluteUnaligned":
        return np.asarray(joint.axis, dtype=float)
    raise ModelError(f"mujoco_model: only revolute joints are simulated, got {short}")


def mujoco_model(model: pin.Model, armature=None, damping=None) -> mujoco.MjModel:
    """The Pinocchio tree as a MuJoCo model: same placements, hinge axes and inertias (a body without mass
    is compiled with a negligible one, then set massless); ``armature``/``damping`` (nv,) per joint."""
    nv = model.nv
    armature = np.zeros(nv) if armature is None else np.asarray(armature, dtype=float)
    damping = np.zeros(nv) if damping is None else np.asarray(damping, dtype=float)
    spec = mujoco.MjSpec()
    spec.option.gravity = np.asarray(model.gravity.linear, dtype=float)
    bodies = {0: spec.worldbody}
    massless = []
    for j in range(1, model.njoints):
        placement = model.jointPlacements[j]
        body = bodies[model.parents[j]].add_body(
            name=model.names[j], pos=placement.translation, quat=pin.Quaternion(placement.rotation).coeffs()[[3, 0, 1, 2]])
        k = model.joints[j].idx_v
        body.add_joint(name=model.names[j], type=mujoco.mjtJoint.mjJNT_HINGE, axis=_hinge_axis(model.joints[j]),
                       armature=float(armature[k]), damping=[float(damping[k]), 0.0, 0.0])
        inertia = model.inertias[j]
        body.explicitinertial = True
        if inertia.mass > 0:
            I = inertia.inertia
            body.mass, body.ipos = float(inertia.mass), np.asarray(inertia.lever)
            body.fullinertia = [I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]
        else:
            body.mass, body.ipos, body.fullinertia = 1e-8, np.zeros(3), [1e-8, 1e-8, 1e-8, 0.0, 0.0, 0.0]
            massless.append(j)
        bodies[j] = body
    mj = spec.compile()
    if massless:  # MuJoCo wants positive inertias while compiling; the bodies are massless
        mj.body_mass[massless] = 0.0
        mj.body_inertia[massless] = 0.0
        mujoco.mj_setConst(mj, mujoco.MjData(mj))
    return mj


def inverse_dynamics(mj: mujoco.MjModel, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
    """MuJoCo's inverse dynamics (T, nv): M(q) a + c(q, v) + g(q) + damping·v (armature inside M)."""
    data = mujoco.MjData(mj)
    tau = np.empty_like(np.asarray(q, dtype=float))
    for t in range(q.shape[0]):
        data.qpos[:], data.qvel[:], data.qacc[:] = q[t], v[t], a[t]
        mujoco.mj_inverse(mj, data)
        tau[t] = data.qfrc_inverse
    return tau


@dataclass(frozen=True, eq=False)
class SimArm:
    """A true arm in MuJoCo and the identification model the estimators get (its kinematics, joint friction
    and armature; no inertias)."""

    name: str
    mj: mujoco.MjModel
    coulomb: np.ndarray  # (n,) fc [N m]
    ident: JointTermsModel
    theta_true: np.ndarray  # (p,) in ident's parameter order

    @property
    def n(self) -> int:
        return self.mj.nv

    def torque(self, q, v, a) -> np.ndarray:
        """The physical joint torque (T, n) of a commanded motion."""
        return inverse_dynamics(self.mj, q, v, a) + self.coulomb * np.tanh(v / COULOMB_VELOCITY)


def sim_arm(name: str, rng: np.random.Generator) -> SimArm:
    """A ``ROBOTS`` arm with its URDF inertias, and random joint armature, viscous and Coulomb friction of a
    real arm's size (armature 0.05–0.3 kg m², viscous 0.2–1 N m s/rad, Coulomb 0.3–2 N m, smaller towards the
    tool)."""
    model = robot_model(name)
    n = model.nv
    scale = 0.8 ** np.arange(n)
    armature = rng.uniform(0.05, 0.3, n) * scale
    viscous = rng.uniform(0.2, 1.0, n) * scale
    coulomb = rng.uniform(0.3, 2.0, n) * scale
    ident = with_joint_terms(RigidBodyModel(model), viscous=True, coulomb=True, armature=True,
                             coulomb_velocity=COULOMB_VELOCITY)
    theta = np.concatenate([RigidBodyModel(model).nominal, viscous, coulomb, armature])
    return SimArm(name, mujoco_model(model, armature, viscous), coulomb, ident, theta)


# --- motion and measurement ---------------------------------------------------------------------
def excitation(rng: np.random.Generator, n: int, seconds: float, fs: float, period: float = 5.0,
               harmonics: int = 5, amplitude: float = 0.5) -> tuple[np.ndarray, ...]:
    """(t, q, v, a) of a sum of ``harmonics`` sinusoids per joint (fundamental ``period``), sampled at fs;
    the joint's total amplitude is at most ``amplitude`` rad around a random centre within ±0.5 rad."""
    t = np.arange(int(round(seconds * fs))) / fs
    k = np.arange(1, harmonics + 1)
    w = 2 * np.pi * k / period
    amp = rng.uniform(0.5, 1.0, (n, harmonics)) / k
    amp *= amplitude / amp.sum(axis=1, keepdims=True)
    phase = rng.uniform(0, 2 * np.pi, (n, harmonics))
    arg = t[:, None, None] * w + phase[None]
    q = rng.uniform(-0.5, 0.5, n) + np.sum(amp * np.sin(arg), axis=2)
    v = np.sum(amp * w * np.cos(arg), axis=2)
    a = -np.sum(amp * w**2 * np.sin(arg), axis=2)
    return t, q, v, a


@dataclass(frozen=True, eq=False)
class Run:
    """The commanded (exact) states and clean torque of one run, and the trajectory a robot would log."""

    q: np.ndarray
    v: np.ndarray
    a: np.ndarray
    tau_clean: np.ndarray
    measured: Trajectory


def measure(arm: SimArm, rng: np.random.Generator, seconds: float, fs: float, torque_noise: float,
            encoder_noise: float, encoder_bits: int, window: float, name: str = "") -> Run:
    """One logged run: q + N(0, encoder_noise²) quantised to 2π/2^encoder_bits (no quantisation when
    encoder_bits is 0), v and a by Savitzky–Golay differentiation over ``window`` s (cubic), τ + noise of
    ``torque_noise`` × each joint's clean τ rms; ``window`` is trimmed at each end."""
    t, q, v, a = excitation(rng, arm.n, seconds + 2 * window, fs)
    tau = arm.torque(q, v, a)
    noise_q = encoder_noise * rng.normal(size=q.shape)
    noise_tau = torque_noise * np.sqrt(np.mean(tau**2, axis=0)) * rng.normal(size=tau.shape)
    q_meas = q + noise_q
    if encoder_bits:
        step = 2 * np.pi / 2**encoder_bits
        q_meas = np.round(q_meas / step) * step
    traj = Trajectory(t, q_meas, np.zeros_like(q_meas), tau + noise_tau, coordinates=arm.ident.coordinates,
                      name=name, meta={"logged": ["q", "tau"]})
    traj = trim(differentiate(traj, "savgol", window=window, polyorder=3, velocity=True), t[0] + window, t[-1] - window)
    keep = np.searchsorted(t, traj.t)
    return Run(q[keep], v[keep], a[keep], tau[keep], traj)
