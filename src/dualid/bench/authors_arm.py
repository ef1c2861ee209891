"""The data of Yang and Hatton's public minimal example, re-implemented on dualid (driver: benchmarks/authors_example.py).

Re-implements the experiment of ``minimal_example.py`` in github.com/yanhaoy/coordinate_independent_robot_model_identification
(MIT License, Copyright (c) 2026 Yanhao Yang): the same arm, motion, noise, filters and sampling, so that every
dualid estimator can be scored on it. The authors' MuJoCo XML and hand-written body regressors are replaced by
dualid's own pieces: the arm is built through ``MjSpec`` (``mujoco_arms.mujoco_model``), the regressor and the
mass-matrix metric come from Pinocchio (``RigidBodyModel``), checked against MuJoCo's inverse dynamics.

The arm: three hinges (yaw about z at (0, 0, 0.2); pitch about y at (0.43, 0.12, 0.17); roll about x at
(0.34, 0.09, 0.16), each relative to its parent), massless links, one end-effector body of 1.15 kg whose 10
inertial parameters (Pinocchio's order, about the roll joint) are identified. Motion: q_j = A_j sin(ω_j t) with
ω = (2, 3, 5) rad/s, A = (0.65, 0.6, 0.5) rad, 45 s sampled at 100 Hz. Measurement: q + N(0, σ_q²) (σ_q = 1 mrad),
τ + N(0, (3 % of each joint's peak |τ|)²); v and a by np.gradient of q (twice), then q, v, a and τ filtered
forward and backward by an elliptic low-pass (cut-off 8 × the fastest joint frequency); N samples evenly spaced
after a 0.5 s margin at each end. The N = 100 set is every tenth-or-so sample of the N = 1000 set, as theirs.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from scipy.signal import iirdesign, sosfiltfilt

from dualid.bench.mujoco_arms import inverse_dynamics, mujoco_model
from dualid.errors import SimulationError
from dualid.model.metric import AffineMetric, MetricTerm
from dualid.model.parameters import rigid_body_space
from dualid.model.rigid_body import RigidBodyModel, spatial_inertia_basis
from dualid.problem import IdentificationProblem

RATE = 100  # [Hz] encoder rate
OMEGA = np.array([2.0, 3.0, 5.0])  # [rad/s] one frequency per joint
AMPLITUDE = np.array([0.65, 0.6, 0.5])  # [rad]
DURATION = 45.0  # [s]
MARGIN = 0.5  # [s] dropped at each end (filter transients)
ENCODER_NOISE = 1e-3  # [rad]
TORQUE_NOISE = 0.03  # fraction of each joint's peak |τ|
FULL, DOWN = 1000, 100  # samples of the two data sets
BODY = "end_effector"
JOINTS = (("yaw", pin.JointModelRZ, (0.0, 0.0, 0.2)), ("pitch", pin.JointModelRY, (0.43, 0.12, 0.17)),
          ("roll", pin.JointModelRX, (0.34, 0.09, 0.16)))
MASS, COM = 1.15, np.array([0.11, 0.045, -0.065])
CENTRAL_INERTIA = np.array([[0.055, 0.004, -0.003], [0.004, 0.062, 0.005], [-0.003, 0.005, 0.074]])


def true_parameters() -> np.ndarray:
    """The end effector's 10 parameters [m, mc, I about the roll joint] (Pinocchio's order)."""
    return pin.Inertia(MASS, COM, CENTRAL_INERTIA).toDynamicParameters()


def arm_model() -> pin.Model:
    """The arm with its true end effector (links massless)."""
    model = pin.Model()
    parent = 0
    for name, joint, offset in JOINTS:
        parent = model.addJoint(parent, joint(), pin.SE3(np.eye(3), np.array(offset)), name)
        model.appendBodyToJoint(parent, pin.Inertia.Zero(), pin.SE3.Identity())
    model.inertias[parent] = pin.Inertia(MASS, COM, CENTRAL_INERTIA)
    return model


def _lowpass():
    cutoff = 8.0 * OMEGA.max() / (2 * np.pi)  # [Hz]
    return iirdesign(wp=cutoff, ws=cutoff + (0.99 - 0.98 * 0.85) * (RATE / 2 - cutoff), gpass=0.1, gstop=60.0,
                     ftype="ellip", output="sos", fs=RATE)


def samples(seed: int, torque_noise: bool = True, encoder_noise: bool = True) -> tuple[np.ndarray, ...]:
    """(q, v, a, τ) (FULL, 3) each, measured as in the authors' example with the given noise sources on.
    The random draws are the same whichever sources are on (a source that is off is scaled by 0)."""
    rng = np.random.default_rng(seed)
    dense = int(round(DURATION * RATE))
    margin = int(round(MARGIN * RATE))
    t = np.linspace(0.0, DURATION, dense, endpoint=False)[:, None]
    q, v, a = AMPLITUDE * np.sin(OMEGA * t), AMPLITUDE * OMEGA * np.cos(OMEGA * t), -AMPLITUDE * OMEGA**2 * np.sin(OMEGA * t)
    tau = inverse_dynamics(mujoco_model(arm_model()), q, v, a)
    q_noisy = q + ENCODER_NOISE * float(encoder_noise) * rng.standard_normal(q.shape)
    tau_noisy = tau + TORQUE_NOISE * float(torque_noise) * np.abs(tau).max(axis=0) * rng.standard_normal(tau.shape)
    v_raw = np.gradient(q_noisy, 1 / RATE, axis=0)
    a_raw = np.gradient(v_raw, 1 / RATE, axis=0)
    sos = _lowpass()
    q_m, v_m, a_m, tau_m = (sosfiltfilt(sos, x, axis=0) for x in (q_noisy, v_raw, a_raw, tau_noisy))
    rows = np.linspace(margin, dense - margin - 1, FULL, dtype=int)
    return q_m[rows], v_m[rows], a_m[rows], tau_m[rows]


def down_rows() -> np.ndarray:
    """The rows of the N = DOWN set within the N = FULL set."""
    return np.linspace(0, FULL - 1, DOWN, dtype=int)


def problem(q: np.ndarray, v: np.ndarray, a: np.ndarray, tau: np.ndarray, check: bool = True) -> IdentificationProblem:
    """The identification problem of the end effector's 10 parameters: Y and M(q, θ) = Jᵀ G(θ) J from Pinocchio
    (the links are massless and known, so they add nothing). ``check``: Y θ_true must equal MuJoCo's inverse
    dynamics at the measured states (as the authors check their regressor)."""
    rb = RigidBodyModel(arm_model())
    Y = rb.regressor(q, v, a)[:, :, 20:30]
    if check:
        ref = inverse_dynamics(mujoco_model(arm_model()), q, v, a)
        err = np.abs(Y @ true_parameters() - ref).max()
        if err > 1e-8 * max(1.0, np.abs(ref).max()):
            raise SimulationError(f"authors' arm: Pinocchio's regressor and MuJoCo disagree by {err:.3g} N m")
    J = rb.jacobians(q)[:, 2]
    metric = AffineMetric(10, (MetricTerm(tuple(range(10)), spatial_inertia_basis(), J),))
    return IdentificationProblem(Y=Y, tau=tau, metric=metric, v=v, parameters=rigid_body_space([BODY]),
                                 coordinates=tuple(name for name, _, _ in JOINTS))
