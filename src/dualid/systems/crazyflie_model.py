"""The Crazyflie 2.0 + universal-joint pendulum as a Pinocchio model, and its actuator numbers.

Bodies (3 × 10 inertial parameters = 30), each named after the joint that moves it:

- ``base``   free flyer (JointModelFreeFlyer): the quadrotor with its pendulum mount;
- ``alpha1`` revolute about the body x axis: the small universal-joint core;
- ``alpha2`` revolute about the core's y axis: the pendulum (rod + tip mass), hanging along −z.

Body frame: x forward, y left, z up (rotor plane at z = 0); gravity (0, 0, −9.81) m/s².
Numbers marked "invented" were not published for the paper's rig (see docs/crazyflie.md).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

# --- Crazyflie 2.0 (published) ---------------------------------------------------------------
CF_MASS = 0.027  # [kg] stock Crazyflie 2.0 (Bitcraze datasheet)
# [kg m²] inertia about the CoM, Förster 2015 (ETH bachelor thesis, "System identification of the
# Crazyflie 2.0 nano quadrocopter"), Table 4.2
CF_INERTIA = np.array(
    [
        [1.657171e-5, 0.830806e-6, 0.718277e-6],
        [0.830806e-6, 1.6655602e-5, 1.800197e-6],
        [0.718277e-6, 1.800197e-6, 2.9261652e-5],
    ]
)
ARM = 0.046  # [m] centre to motor axis (Bitcraze)
THRUST_COEFFS = (2.130295e-11, 1.032633e-6, 5.484560e-4)  # thrust per motor [N] = a c² + b c + d (Förster 2015)
PWM_MAX = 65535  # PWM command range [0, 65535]
YAW_PER_THRUST = 0.005964552  # [m] rotor drag torque per thrust (Förster 2015)
# motors M1..M4 in the X configuration: M1 front-right, M2 back-right, M3 back-left, M4 front-left
MOTOR_XY = ARM / np.sqrt(2.0) * np.array([[1.0, -1.0], [-1.0, -1.0], [-1.0, 1.0], [1.0, 1.0]])  # (4, 2) [m]
# yaw reaction torque sign per motor: M1, M3 spin counter-clockwise seen from above (torque −z on
# the body), M2, M4 clockwise (Bitcraze motor layout)
SPIN = np.array([-1.0, 1.0, -1.0, 1.0])

# --- mount, universal joint and pendulum (invented) --------------------------------------------
MOUNT_MASS = 0.003  # [kg] invented: pendulum mount under the body
MOUNT_OFFSET = np.array([0.0, 0.0, -0.012])  # [m] invented: mount CoM and universal-joint centre
CORE_MASS = 0.001  # [kg] invented: universal-joint core (cross piece)
CORE_SIZE = 0.006  # [m] invented: edge of the core (a cube for its inertia)
ROD_LENGTH = 0.15  # [m] invented: pivot to tip mass
ROD_MASS = 0.002  # [kg] invented: thin rod
TIP_MASS = 0.006  # [kg] invented: tip mass (pendulum total 8 g)
TIP_RADIUS = 0.006  # [m] invented: tip mass as a solid sphere
GRAVITY = 9.81  # [m/s²]


def thrust_curve(c: np.ndarray) -> np.ndarray:
    """Thrust per motor [N] of PWM command(s) c ∈ [0, 65535] (firmware calibration, Förster 2015)."""
    a, b, d = THRUST_COEFFS
    c = np.asarray(c, dtype=float)
    return (a * c + b) * c + d


def inverse_thrust_curve(f: np.ndarray) -> np.ndarray:
    """The PWM command(s) (integers in [0, 65535], as float) giving thrust(s) f [N], clamped to the range."""
    a, b, d = THRUST_COEFFS
    f = np.asarray(f, dtype=float)
    disc = np.maximum(b * b - 4.0 * a * (d - f), 0.0)
    c = (-b + np.sqrt(disc)) / (2.0 * a)  # the non-negative root (c = 0 at f = d)
    return np.clip(np.rint(c), 0, PWM_MAX)


def mixer_matrix() -> np.ndarray:
    """A (4, 4): [collective thrust [N], torque x, y, z [N m]] = A @ motor thrusts [N] (body frame)."""
    x, y = MOTOR_XY[:, 0], MOTOR_XY[:, 1]
    return np.stack([np.ones(4), y, -x, YAW_PER_THRUST * SPIN])


def body_wrench(f: np.ndarray) -> np.ndarray:
    """(..., 6) body wrench [force; torque] at the body-frame origin from motor thrusts f (..., 4) [N]."""
    f = np.asarray(f, dtype=float)
    ftm = f @ mixer_matrix().T  # (..., 4) collective thrust, torques
    w = np.zeros(f.shape[:-1] + (6,))
    w[..., 2] = ftm[..., 0]
    w[..., 3:] = ftm[..., 1:]
    return w


def _base_inertia(mass, com, inertia_c, mount_mass, mount_offset) -> pin.Inertia:
    body = pin.Inertia(mass, np.asarray(com, dtype=float), np.asarray(inertia_c, dtype=float))
    return body + pin.Inertia(mount_mass, np.asarray(mount_offset, dtype=float), np.zeros((3, 3)))


def _core_inertia(mass, size, com=(0.0, 0.0, 0.0)) -> pin.Inertia:
    return pin.Inertia(mass, np.asarray(com, dtype=float), mass * size**2 / 6.0 * np.eye(3))


def _pendulum_inertia(rod_mass, tip_mass, length, tip_radius, com_xy=(0.0, 0.0)) -> pin.Inertia:
    """Thin rod from the pivot to −length along z, plus a solid sphere at its end (frame at the pivot)."""
    cx, cy = com_xy
    rod_I = rod_mass * length**2 / 12.0 * np.diag([1.0, 1.0, 0.0])
    rod = pin.Inertia(rod_mass, np.array([cx, cy, -length / 2]), rod_I)
    tip = pin.Inertia(tip_mass, np.array([cx, cy, -length]), 0.4 * tip_mass * tip_radius**2 * np.eye(3))
    return rod + tip


def _assemble(base: pin.Inertia, core: pin.Inertia, pendulum: pin.Inertia, pivot: np.ndarray) -> pin.Model:
    model = pin.Model()
    model.name = "crazyflie_pendulum"
    model.gravity = pin.Motion(np.array([0.0, 0.0, -GRAVITY]), np.zeros(3))
    j0 = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base")
    model.appendBodyToJoint(j0, base, pin.SE3.Identity())
    j1 = model.addJoint(j0, pin.JointModelRX(), pin.SE3(np.eye(3), np.asarray(pivot, dtype=float)), "alpha1")
    model.appendBodyToJoint(j1, core, pin.SE3.Identity())
    j2 = model.addJoint(j1, pin.JointModelRY(), pin.SE3.Identity(), "alpha2")
    model.appendBodyToJoint(j2, pendulum, pin.SE3.Identity())
    return model


def build_model() -> pin.Model:
    """The true Crazyflie–pendulum model (free flyer, universal joint alpha1 (x) then alpha2 (y))."""
    base = _base_inertia(CF_MASS, np.zeros(3), CF_INERTIA, MOUNT_MASS, MOUNT_OFFSET)
    core = _core_inertia(CORE_MASS, CORE_SIZE)
    pendulum = _pendulum_inertia(ROD_MASS, TIP_MASS, ROD_LENGTH, TIP_RADIUS)
    return _assemble(base, core, pendulum, MOUNT_OFFSET)


def _theta(model: pin.Model) -> np.ndarray:
    return np.concatenate([model.inertias[j].toDynamicParameters() for j in range(1, model.njoints)])


def _nominal_model() -> pin.Model:
    """A CAD-like prior, deliberately off the truth (all invented): the stock mass without the mount,
    a diagonal inertia 25–30 % low, a CoM 2 mm off, a heavier core (+30 %), and a pendulum 'drawn'
    15 % too light, 1 cm too short and with a 2 mm lateral CoM error (first moment −21 %, inertia
    about the pivot −27 %)."""
    base = _base_inertia(
        CF_MASS, np.array([0.002, -0.001, -0.002]), np.diag([1.2e-5, 1.2e-5, 2.1e-5]), 0.0, np.zeros(3)
    )
    core = _core_inertia(1.3e-3, 0.008, com=(0.0, 0.0, -0.001))
    pendulum = _pendulum_inertia(0.0018, 0.005, 0.14, 0.007, com_xy=(0.002, 0.0))
    return _assemble(base, core, pendulum, MOUNT_OFFSET)


TRUE_THETA = _theta(build_model())  # (30,) [kg, kg m, kg m²] Pinocchio order, per body in its joint frame
NOMINAL_THETA = _theta(_nominal_model())  # (30,) CAD-like prior, physically consistent, off the truth
TRUE_THETA.setflags(write=False)
NOMINAL_THETA.setflags(write=False)
TOTAL_MASS = float(TRUE_THETA[0] + TRUE_THETA[10] + TRUE_THETA[20])  # [kg] 0.039
