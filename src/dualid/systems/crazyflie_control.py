"""The Crazyflie's flight: the excitation reference (sinusoids of x, y, z, yaw) and the geometric
controller that tracks it, as the simulator runs them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dualid.systems import crazyflie_model as cf

REFERENCE_COMPONENTS = ((0, 4.3), (1, 3.1), (2, 5.9), (3, 8.3), (0, 1.3), (1, 1.15))
REFERENCE_PERIODS = tuple(period for _, period in REFERENCE_COMPONENTS)
Z_CENTRE = 1.0  # [m] reference height (invented)
V_CAL = 4.0  # [V] battery voltage at which the thrust curve holds (invented)


_OMEGA_REF = 2 * np.pi / np.asarray(REFERENCE_PERIODS)  # (K,) [rad/s]
_AXIS_OF = np.eye(4)[[axis for axis, _ in REFERENCE_COMPONENTS]]  # (K, 4) component → axis


@dataclass(frozen=True)
class Reference:
    """Sinusoidal x, y, z, yaw references of B runs: r(t) = centre + Σ_k A_k sin(2πt/T_k + φ_k)."""

    amplitude: np.ndarray  # (B, K) [m or rad] per component of REFERENCE_COMPONENTS
    phase: np.ndarray  # (B, K) [rad]

    def __call__(self, t: float):
        """(r, ṙ, r̈) each (B, 4): position x, y, z [m] and yaw [rad] with their derivatives."""
        w = _OMEGA_REF
        arg = w * t + self.phase
        sin, cos = self.amplitude * np.sin(arg), self.amplitude * np.cos(arg)
        r = sin @ _AXIS_OF
        r[:, 2] += Z_CENTRE
        return r, (w * cos) @ _AXIS_OF, -(w * w * sin) @ _AXIS_OF


def random_reference(rng: np.random.Generator, B: int) -> Reference:
    lo = np.array([0.35, 0.3, 0.15, 0.6, 0.08, 0.08])  # [m, m, m, rad, m, m] (invented; the two short
    # components swing the pendulum by about 5–8° rms, 0.1–0.2 rad at the peaks)
    hi = np.array([0.5, 0.45, 0.25, 1.0, 0.12, 0.12])
    K = len(REFERENCE_COMPONENTS)
    return Reference(rng.uniform(lo, hi, size=(B, K)), rng.uniform(0, 2 * np.pi, size=(B, K)))


def rotation(quat: np.ndarray) -> np.ndarray:
    """R (B, 3, 3) from Pinocchio quaternions (B, 4) stored (x, y, z, w)."""
    x, y, z, w = quat.T
    R = np.empty((quat.shape[0], 3, 3))
    R[:, 0, 0] = 1 - 2 * (y * y + z * z)
    R[:, 0, 1] = 2 * (x * y - z * w)
    R[:, 0, 2] = 2 * (x * z + y * w)
    R[:, 1, 0] = 2 * (x * y + z * w)
    R[:, 1, 1] = 1 - 2 * (x * x + z * z)
    R[:, 1, 2] = 2 * (y * z - x * w)
    R[:, 2, 0] = 2 * (x * z - y * w)
    R[:, 2, 1] = 2 * (y * z + x * w)
    R[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return R


@dataclass(frozen=True)
class GeometricController:
    """Lee, Leok & McClamroch (2010) SE(3) tracking with a position integral; the pendulum is a
    disturbance. Desired collective thrust and body torques are mixed to motor thrusts and mapped
    through the inverse thrust curve (battery-compensated with the measured voltage) to PWM."""

    mass: float = 0.04  # [kg] the controller's total-mass guess (invented)
    kp: float = 6.0  # [1/s²] position gain (per unit mass)
    kd: float = 4.5  # [1/s]
    ki: float = 1.5  # [1/s³]
    omega_att: float = 25.0  # [rad/s] attitude loop natural frequency
    zeta_att: float = 0.8

    def __call__(self, ref: Reference, t: float, q: np.ndarray, v: np.ndarray, integral: np.ndarray,
                 V_meas: np.ndarray, dt: float):
        """(PWM (B, 4) integers as float, updated integral (B, 3))."""
        r, dr, ddr = ref(t)
        R = rotation(q[:, 3:7])
        p, pdot = q[:, :3], (R @ v[:, :3, None])[..., 0]
        e_p, e_v = p - r[:, :3], pdot - dr[:, :3]
        integral = integral + dt * e_p
        F = self.mass * (ddr[:, :3] - self.kp * e_p - self.kd * e_v - self.ki * integral)
        F[:, 2] += self.mass * cf.GRAVITY
        b3 = F / np.sqrt(np.sum(F * F, axis=1, keepdims=True))
        yaw = r[:, 3]
        c, s = np.cos(yaw), np.sin(yaw)
        b2 = np.column_stack([-b3[:, 2] * s, b3[:, 2] * c, b3[:, 0] * s - b3[:, 1] * c])  # b3 × (c, s, 0)
        b2 /= np.sqrt(np.sum(b2 * b2, axis=1, keepdims=True))
        Rd = np.empty_like(R)  # columns b1 = b2 × b3, b2, b3
        Rd[:, :, 0], Rd[:, :, 1], Rd[:, :, 2] = _cross(b2, b3), b2, b3
        E = np.swapaxes(Rd, 1, 2) @ R  # R_dᵀ R
        e_R = 0.5 * np.column_stack([E[:, 2, 1] - E[:, 1, 2], E[:, 0, 2] - E[:, 2, 0], E[:, 1, 0] - E[:, 0, 1]])
        omega = v[:, 3:6]
        omega_d = (np.swapaxes(R, 1, 2) @ Rd[:, :, 2:3])[..., 0] * dr[:, 3:4]  # Rᵀ R_d (0, 0, ψ̇_d)
        J = _J_DIAG
        torque = -J * self.omega_att**2 * e_R - 2 * self.zeta_att * self.omega_att * J * (omega - omega_d)
        torque += _cross(omega, omega * J)
        thrust = np.maximum(np.sum(F * R[:, :, 2], axis=1), 0.0)
        f = np.column_stack([thrust, torque]) @ _MIXER_INV.T  # (B, 4) [N]
        kappa = (V_meas / V_CAL) ** 2
        return cf.inverse_thrust_curve(f / kappa[:, None]), integral


_J_DIAG = np.diag(cf.CF_INERTIA).copy()
_MIXER_INV = np.linalg.inv(cf.mixer_matrix())


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise a × b for (B, 3) arrays (np.cross is slow on small arrays)."""
    c = np.empty_like(a)
    c[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    c[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    c[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return c


