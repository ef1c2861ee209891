"""Simulated Crazyflie–pendulum runs (docs/crazyflie.md): a geometric controller tracks sinusoidal
x, y, z, yaw references while the pendulum swings; motion capture, differentiation and the
firmware's thrust calibration turn the true motion into "measured" trajectories.

Simulation: Pinocchio's ``aba`` (aerodynamic drag as an external wrench on the base, applied as its
exact generalized-force equivalent; universal-joint friction as joint torque), fixed-step Lie-group
RK4 at 200 Hz (``pin.integrate`` on the configuration, so the quaternion stays on the unit sphere)
with the controller's PWM commands held between its 200 Hz updates; all runs of a data set advance
together so the controller is vectorised over runs. Samples are recorded at 100 Hz after a 2 s
warm-up. See docs/crazyflie.md for every number and its source.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.spatial.transform import Rotation

from dualid.data.preprocessing import lowpass, savgol_derivatives
from dualid.data.trajectory import Trajectory
from dualid.errors import ConfigError, SimulationError
from dualid.model.rigid_body import RigidBodyModel
from dualid.systems import crazyflie_model as cf
from dualid.systems.crazyflie_control import (
    REFERENCE_COMPONENTS,
    REFERENCE_PERIODS,
    V_CAL,
    Z_CENTRE,
    GeometricController,
    Reference,
    random_reference,
    rotation,
)
from dualid.systems.crazyflie_model import NOMINAL_THETA, TRUE_THETA, build_model

__all__ = [
    "CrazyflieNoise",
    "GeometricController",
    "Reference",
    "REFERENCE_COMPONENTS",
    "REFERENCE_PERIODS",
    "shape_angles",
    "measure_states",
    "measured_wrench",
    "TRUE_THETA",
    "NOMINAL_THETA",
    "build_model",
    "simulate",
    "dataset",
    "make",
]

RATE = 100.0  # [Hz] motion capture and logging
SIM_RATE = 200.0  # [Hz] controller update and RK4 step (zero-order hold in between); a multiple of RATE
WARMUP = 2.0  # [s] simulated before recording starts
# reference components: (axis, period [s]); axes x, y, z [m] and yaw [rad]; all periods mutually
# non-harmonic. The slow ones carry the motion (periods 3–9 s); the two short ones (1.15 s, 1.3 s,
# a few cm) keep the pendulum swinging, which the controller otherwise damps out within seconds
# (invented)
BATTERY_DROP = 0.004  # [V/s] voltage decay over a run (invented; ~7 min flight on 250 mAh)
COULOMB_WIDTH = 0.01  # [rad/s] smoothing of the Coulomb friction, tanh(α̇/width) (invented)


@dataclass(frozen=True)
class CrazyflieNoise:
    """What separates the measurements from the truth (all magnitudes invented unless noted)."""

    position_std: float = 5e-4  # [m] motion-capture position noise
    angle_std: float = float(np.deg2rad(0.3))  # [rad] motion-capture orientation noise (per axis)
    voltage_std: float = 0.005  # [V] battery-voltage measurement noise
    gain_error: tuple[float, float] = (0.02, 0.04)  # |δ| range of the common thrust-calibration gain error
    motor_spread: float = 0.005  # std of the motors' individual gain errors around the common one
    joint_viscous: float = 3e-6  # [N m s/rad] universal-joint viscous friction (unmodelled)
    joint_coulomb: float = 1e-5  # [N m] universal-joint Coulomb friction (unmodelled), smoothed by tanh
    drag: tuple[float, float, float] = (6.6e-3, 6.6e-3, 7.4e-3)  # [N s/m] body drag (Förster 2015 order)
    motor_lag: float = 0.025  # [s] first-order time constant of each motor's thrust (unmodelled: the
    # measured wrench comes from the commanded PWM); 20–30 ms for small brushed motors (invented)
    cutoff: float = 3.0  # [Hz] zero-phase Butterworth low-pass before differentiation (0: exact states)
    window: float = 0.07  # [s] Savitzky–Golay window for the derivatives
    force_std: tuple[float, ...] = ()  # (6,) i.i.d. noise on the base wrench [N, N m] (ideal data)

    @classmethod
    def realistic(cls) -> "CrazyflieNoise":
        return cls()

    @classmethod
    def ideal(cls) -> "CrazyflieNoise":
        """Exact states and accelerations, i.i.d. Gaussian force noise, no unmodelled effects."""
        return cls.none().with_force_noise((4e-3, 4e-3, 4e-3, 1e-5, 1e-5, 2e-6))

    @classmethod
    def none(cls) -> "CrazyflieNoise":
        """Exact data: true states, accelerations and forces."""
        return cls(
            position_std=0.0, angle_std=0.0, voltage_std=0.0, gain_error=(0.0, 0.0), motor_spread=0.0,
            joint_viscous=0.0, joint_coulomb=0.0, drag=(0.0, 0.0, 0.0), cutoff=0.0, window=0.0, motor_lag=0.0,
        )

    def with_force_noise(self, force_std) -> "CrazyflieNoise":
        """A copy with i.i.d. noise (6,) on the base wrench [N, N m]."""
        force_std = tuple(float(x) for x in force_std)
        if len(force_std) != 6 or min(force_std) < 0:
            raise ConfigError(f"force_std: expected 6 non-negative standard deviations, got {force_std}")
        return dataclasses.replace(self, force_std=force_std)

    def __post_init__(self) -> None:
        if not self.motor_lag >= 0:
            raise ConfigError(f"CrazyflieNoise: motor_lag must be ≥ 0 s, got {self.motor_lag}")
        if self.cutoff == 0.0:
            measured = {"position_std": self.position_std, "angle_std": self.angle_std,
                        "voltage_std": self.voltage_std, "gain_error": max(self.gain_error),
                        "motor_spread": self.motor_spread}
            bad = {k: v for k, v in measured.items() if v != 0}
            if bad:
                raise ConfigError(
                    f"CrazyflieNoise: cutoff = 0 means exact states and forces, but measurement errors {bad} "
                    "are set; give a low-pass cutoff [Hz] to simulate the measurement chain"
                )
        if self.force_std and self.cutoff != 0.0:
            raise ConfigError("CrazyflieNoise: force_std (i.i.d. force noise) applies to exact states only (cutoff = 0)")

    @property
    def exact_states(self) -> bool:
        return self.cutoff == 0.0


# --- simulation ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class RawRuns:
    """The true motion of B runs at 100 Hz and what the quadrotor logged."""

    t: np.ndarray  # (T,) [s]
    q: np.ndarray  # (B, T, 9) configuration
    v: np.ndarray  # (B, T, 8) velocity
    a: np.ndarray  # (B, T, 8) true acceleration (with the unmodelled effects)
    tau: np.ndarray  # (B, T, 8) true actuator generalized force (base wrench; 0 on the joints)
    pwm: np.ndarray  # (B, T, 4) commanded PWM
    V_true: np.ndarray  # (B, T) [V]
    V_meas: np.ndarray  # (B, T) [V]
    reference: np.ndarray  # (B, T, 4) x, y, z [m], yaw [rad]


class _Plant:
    """The true dynamics: aba with drag (fext on the base) and universal-joint friction."""

    def __init__(self, model: pin.Model, noise: CrazyflieNoise) -> None:
        self.model, self.data = model, model.createData()
        self.drag = np.asarray(noise.drag, dtype=float)
        self.viscous, self.coulomb = noise.joint_viscous, noise.joint_coulomb
        self.unmodelled = bool(np.any(self.drag) or self.viscous or self.coulomb)

    def accel(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """True acceleration (nv,). The drag wrench acts on the base body in its own frame; for the
        free-flyer root that is exactly fext[base] = (−D v_lin, 0) (its LOCAL Jacobian is [I₆ 0]), so it
        is added to τ[:6] directly (building a pin.Force per call costs more than the aba itself;
        tests check the equivalence with ``pin.aba(..., fext)``)."""
        if not self.unmodelled:
            return pin.aba(self.model, self.data, q, v, tau)
        tau = tau.copy()
        tau[:3] -= self.drag * v[:3]
        w1, w2 = float(v[6]), float(v[7])
        tau[6] -= self.viscous * w1 + self.coulomb * math.tanh(w1 / COULOMB_WIDTH)
        tau[7] -= self.viscous * w2 + self.coulomb * math.tanh(w2 / COULOMB_WIDTH)
        return pin.aba(self.model, self.data, q, v, tau)

    def external_force(self, v: np.ndarray) -> pin.StdVec_Force:
        """The drag as Pinocchio external forces (one per joint, in the joint's LOCAL frame)."""
        fext = pin.StdVec_Force()
        for _ in range(self.model.njoints):
            fext.append(pin.Force.Zero())
        fext[1] = pin.Force(-self.drag * v[:3], np.zeros(3))
        return fext

    def step(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray, dt: float):
        """One Lie-group RK4 step with τ held (zero-order hold)."""
        model, f = self.model, self.accel
        a1 = f(q, v, tau)
        v2 = v + 0.5 * dt * a1
        a2 = f(pin.integrate(model, q, 0.5 * dt * v), v2, tau)
        v3 = v + 0.5 * dt * a2
        a3 = f(pin.integrate(model, q, 0.5 * dt * v2), v3, tau)
        v4 = v + dt * a3
        a4 = f(pin.integrate(model, q, dt * v3), v4, tau)
        q_next = pin.integrate(model, q, dt / 6 * (v + 2 * v2 + 2 * v3 + v4))
        return q_next, v + dt / 6 * (a1 + 2 * a2 + 2 * a3 + a4)


def simulate(
    reference: Reference,
    duration: float,
    noise: CrazyflieNoise,
    rng: np.random.Generator,
    gains: np.ndarray | None = None,
    controller: GeometricController = GeometricController(),
) -> RawRuns:
    """Fly B runs (one per row of the reference) for ``duration`` s after a warm-up.

    ``gains`` (4,): true thrust / calibrated thrust per motor (1 = perfect calibration).
    """
    model = build_model()
    plant = _Plant(model, noise)
    B = reference.amplitude.shape[0]
    gains = np.ones(4) if gains is None else np.asarray(gains, dtype=float)
    dt, sub = 1.0 / SIM_RATE, int(round(SIM_RATE / RATE))
    if sub * RATE != SIM_RATE:
        raise ConfigError(f"simulate: SIM_RATE ({SIM_RATE} Hz) must be a multiple of RATE ({RATE} Hz)")
    T = int(round(duration * RATE))
    n_warm = int(round(WARMUP * SIM_RATE))
    n_steps = n_warm + T * sub
    t0 = -WARMUP

    # initial state: on the reference, level at the reference yaw, pendulum released from rest at an angle
    r, dr, _ = reference(t0)
    q = np.zeros((B, model.nq))
    v = np.zeros((B, model.nv))
    q[:, :3] = r[:, :3]
    q[:, 3:7] = np.column_stack([np.zeros((B, 2)), np.sin(r[:, 3] / 2), np.cos(r[:, 3] / 2)])
    v[:, :3] = np.einsum("bji,bj->bi", rotation(q[:, 3:7]), dr[:, :3])
    q[:, 7:9] = rng.uniform(-0.4, 0.4, size=(B, 2))  # [rad] initial swing (invented)
    V0 = rng.uniform(3.95, 4.1, size=B)  # [V] battery voltage at the start (invented)
    integral = np.zeros((B, 3))
    thrust = None  # (B, 4) [N] the motors' actual thrusts, lagging the commanded ones by noise.motor_lag
    lag = 1.0 - np.exp(-dt / noise.motor_lag) if noise.motor_lag > 0 else 1.0  # exact first-order step

    out = {k: [] for k in ("q", "v", "tau", "pwm", "V_true", "V_meas", "ref")}
    for k in range(n_steps):
        t = t0 + k * dt
        V_true = V0 - BATTERY_DROP * (t - t0)
        V_meas = V_true + noise.voltage_std * rng.standard_normal(B)
        pwm, integral = controller(reference, t, q, v, integral, V_meas, dt)
        f = cf.thrust_curve(pwm) * ((V_true / V_CAL) ** 2)[:, None] * gains  # (B, 4) commanded thrusts [N]
        thrust = f if thrust is None else thrust + lag * (f - thrust)
        tau = np.zeros((B, model.nv))
        tau[:, :6] = cf.body_wrench(thrust)
        if k >= n_warm and (k - n_warm) % sub == 0:
            for key, val in (("q", q), ("v", v), ("tau", tau), ("pwm", pwm), ("V_true", V_true),
                             ("V_meas", V_meas), ("ref", reference(t)[0])):
                out[key].append(val.copy())
        for b in range(B):
            q[b], v[b] = plant.step(q[b], v[b], tau[b], dt)
        if not np.all(np.isfinite(v)) or np.any(np.abs(q[:, 2] - Z_CENTRE) > 5.0):
            raise SimulationError(f"crazyflie simulation diverged at t = {t:.3f} s")

    arr = {key: np.swapaxes(np.array(val), 0, 1) for key, val in out.items()}  # (B, T, ...)
    a = np.array([[plant.accel(qi, vi, ui) for qi, vi, ui in zip(*x)] for x in zip(arr["q"], arr["v"], arr["tau"])])
    return RawRuns(np.arange(T) / RATE, arr["q"], arr["v"], a, arr["tau"], arr["pwm"], arr["V_true"],
                   arr["V_meas"], arr["ref"])


# --- measurement --------------------------------------------------------------------------------
def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (T, 4) quaternions stored (x, y, z, w)."""
    av, aw, bv, bw = a[:, :3], a[:, 3:], b[:, :3], b[:, 3:]
    return np.column_stack([aw * bv + bw * av + np.cross(av, bv), aw * bw - np.sum(av * bv, 1, keepdims=True)])


def shape_angles(R_base: np.ndarray, R_pendulum: np.ndarray) -> np.ndarray:
    """(α1, α2) (T, 2) from the orientations (T, 3, 3) of the quadrotor and the pendulum:
    R_baseᵀ R_pendulum = Rx(α1) Ry(α2)."""
    Rr = np.einsum("tji,tjk->tik", R_base, R_pendulum)
    return np.column_stack([np.arctan2(Rr[:, 2, 1], Rr[:, 1, 1]), np.arctan2(Rr[:, 0, 2], Rr[:, 0, 0])])


def measure_states(q: np.ndarray, noise: CrazyflieNoise, rng: np.random.Generator):
    """Motion capture of one run (q (T, 9) true) → (q, v, a) estimated: noisy poses of the quadrotor
    and the pendulum at 100 Hz, shape angles from their relative orientation, zero-phase low-pass,
    Savitzky–Golay derivatives, and body velocities from the quaternion and position derivatives."""
    T = q.shape[0]
    R = rotation(q[:, 3:7])
    R_pend = R @ Rotation.from_euler("XY", q[:, 7:9]).as_matrix()  # intrinsic x then y: Rx(α1) Ry(α2)
    p_m = q[:, :3] + noise.position_std * rng.standard_normal((T, 3))
    R_m = R @ Rotation.from_rotvec(noise.angle_std * rng.standard_normal((T, 3))).as_matrix()
    R_pend_m = R_pend @ Rotation.from_rotvec(noise.angle_std * rng.standard_normal((T, 3))).as_matrix()
    alpha_m = shape_angles(R_m, R_pend_m)
    quat = Rotation.from_matrix(R_m).as_quat()  # (x, y, z, w)
    flip = np.cumprod(np.where(np.sum(quat[1:] * quat[:-1], 1) < 0, -1.0, 1.0))
    quat[1:] *= flip[:, None]  # sign-continuous
    x = lowpass(np.column_stack([p_m, quat, alpha_m]), RATE, noise.cutoff)
    xs, dx, ddx = savgol_derivatives(x, RATE, noise.window)
    qs = xs[:, 3:7] / np.linalg.norm(xs[:, 3:7], axis=1, keepdims=True)
    Rs = rotation(qs)
    conj = qs * np.array([-1.0, -1.0, -1.0, 1.0])
    omega = 2 * _quat_mul(conj, dx[:, 3:7])[:, :3]  # body angular velocity [rad/s]
    omega_dot = 2 * _quat_mul(conj, ddx[:, 3:7])[:, :3]
    v_lin = np.einsum("tji,tj->ti", Rs, dx[:, :3])  # body linear velocity [m/s]
    a_lin = np.einsum("tji,tj->ti", Rs, ddx[:, :3]) - np.cross(omega, v_lin)  # d/dt of the body velocity
    q_out = np.column_stack([xs[:, :3], qs, xs[:, 7:9]])
    v_out = np.column_stack([v_lin, omega, dx[:, 7:9]])
    a_out = np.column_stack([a_lin, omega_dot, ddx[:, 7:9]])
    return q_out, v_out, a_out


def measured_wrench(pwm: np.ndarray, V_meas: np.ndarray) -> np.ndarray:
    """(T, 8) generalized force from commanded PWM (T, 4) and measured voltage (T,) through the
    firmware's thrust calibration; the passive joints' torques are recorded as zero."""
    tau = np.zeros((pwm.shape[0], 8))
    tau[:, :6] = cf.body_wrench(cf.thrust_curve(pwm) * ((V_meas / V_CAL) ** 2)[:, None])
    return tau


def _trajectories(raw: RawRuns, noise: CrazyflieNoise, rng: np.random.Generator, names, coordinates):
    runs = []
    for b, name in enumerate(names):
        meta = {"system": "crazyflie", "reference": raw.reference[b], "V_meas": raw.V_meas[b],
                "pwm": raw.pwm[b], "true": {"q": raw.q[b], "v": raw.v[b], "a": raw.a[b], "tau": raw.tau[b]}}
        if noise.exact_states:
            tau = raw.tau[b].copy()
            if noise.force_std:
                tau[:, :6] += np.asarray(noise.force_std) * rng.standard_normal((tau.shape[0], 6))
            runs.append(Trajectory(raw.t, raw.q[b], raw.v[b], tau, raw.a[b], coordinates, name, meta))
            continue
        q, v, a = measure_states(raw.q[b], noise, rng)
        tau = lowpass(measured_wrench(raw.pwm[b], raw.V_meas[b]), RATE, noise.cutoff)
        tau[:, 6:] = 0.0
        meta["steps"] = [
            {"step": "motion_capture", "position_std_m": noise.position_std, "angle_std_rad": noise.angle_std},
            {"step": "lowpass", "cutoff_hz": noise.cutoff, "order": 4, "applied_to": "poses, angles, tau"},
            {"step": "savgol_derivatives", "window_s": noise.window, "polyorder": 3},
        ]
        runs.append(Trajectory(raw.t, q, v, tau, a, coordinates, name, meta))
    return runs


def noise_preset(noise: str | CrazyflieNoise) -> CrazyflieNoise:
    """A CrazyflieNoise by preset name ("realistic", "ideal", "none"), or the one given."""
    if isinstance(noise, CrazyflieNoise):
        return noise
    presets = {"realistic": CrazyflieNoise.realistic, "ideal": CrazyflieNoise.ideal, "none": CrazyflieNoise.none}
    if noise not in presets:
        raise ConfigError(f"noise: expected one of {sorted(presets)}, got {noise!r}")
    return presets[noise]()


def dataset(seed: int = 0, n_train: int = 6, n_test: int = 6, duration: float = 35.0,
            noise: str | CrazyflieNoise = "realistic"):
    """(model, training runs, test runs, true θ): all runs flown together, test runs at other phases."""
    noise = noise_preset(noise)
    if n_train < 1 or n_test < 0:
        raise ConfigError(f"dataset: expected n_train ≥ 1 and n_test ≥ 0, got {n_train} and {n_test}")
    if duration < 1.0:
        raise ConfigError(f"dataset: duration must be at least 1 s (derivative filters), got {duration}")
    rng = np.random.default_rng(seed)
    lo, hi = noise.gain_error
    # true thrust / calibrated thrust: one calibration error for the batch of motors plus a small spread
    gains = 1.0 + rng.choice([-1.0, 1.0]) * rng.uniform(lo, hi) + noise.motor_spread * rng.standard_normal(4)
    reference = random_reference(rng, n_train + n_test)
    raw = simulate(reference, duration, noise, rng, gains=gains)
    model = RigidBodyModel(build_model())
    names = [f"train_{k}" for k in range(n_train)] + [f"test_{k}" for k in range(n_test)]
    runs = _trajectories(raw, noise, rng, names, model.coordinates)
    return model, runs[:n_train], runs[n_train:], np.array(TRUE_THETA)


NOMINAL_DRAG = (3e-3, 3e-3, 3e-3)  # [N s/m] a prior for the base drag: of the literature's order, not the truth


def make(seed: int = 0, noise: str = "realistic", size: str = "default", base_drag: bool = False):
    """The Crazyflie–pendulum ``SystemData`` (see dualid.systems.base). ``base_drag``: the identification
    model also has the base's linear drag (3 parameters d ≥ 0, ``dualid.model.extra_terms``), the
    unmodelled rotor drag that otherwise leaves residual the rigid model cannot fit."""
    from dualid.model.extra_terms import with_base_drag
    from dualid.systems.base import SystemData

    sizes = {"default": (6, 6, 35.0), "small": (2, 2, 8.0)}
    if size not in sizes:
        raise ConfigError(f"size: expected one of {sorted(sizes)}, got {size!r}")
    n_train, n_test, duration = sizes[size]
    model, train, test, theta = dataset(seed, n_train, n_test, duration, noise)
    alpha = np.concatenate([run.meta["true"]["q"][:, 7:9] for run in train])  # [rad] true shape angles
    swing = np.degrees(np.sqrt(np.mean((alpha - alpha.mean(0)) ** 2, axis=0)))
    nominal = np.array(NOMINAL_THETA)
    if base_drag:
        model = with_base_drag(model)
        theta = np.concatenate([theta, noise_preset(noise).drag])
        nominal = np.concatenate([nominal, NOMINAL_DRAG])
    return SystemData(
        name="crazyflie",
        model=model,
        train=tuple(train),
        test=tuple(test),
        theta_true=theta,
        theta_nominal=nominal,
        low_data_samples=20,
        slowest_period=max(REFERENCE_PERIODS),  # the yaw period
        shape_coordinates=("alpha1", "alpha2"),
        gamma=0.1,  # per equation: the prior counts as a tenth of the WLS data term
        description="Crazyflie 2.0 with a universal-joint pendulum (floating base, 30 inertial parameters); "
        f"pendulum swing rms {swing[0]:.1f}° (alpha1), {swing[1]:.1f}° (alpha2) over the training runs; "
        f"motor lag {noise_preset(noise).motor_lag * 1e3:.0f} ms"
        + ("; identification model with linear base drag (3 parameters)" if base_drag else ""),
    )
