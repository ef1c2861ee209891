"""Simulated pan–tilt data: torque-driven runs with encoder noise, numerical differentiation,
torque-sensor noise and an unmodelled Coulomb friction."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from dualid.data.preprocessing import savgol_derivatives
from dualid.data.trajectory import Trajectory
from dualid.errors import ConfigError, SimulationError
from dualid.model.pan_tilt import PanTilt, jacobian

TRUE_THETA = np.array([0.5, 0.02, 0.03])  # m [kg], b_pan, b_tilt [N m s/rad] (invented)
NOMINAL_THETA = np.array([0.6, 0.01, 0.01])  # a "CAD" guess, deliberately off


@dataclass(frozen=True)
class PanTiltNoise:
    angle_std: float = 2e-4  # encoder noise [rad]
    torque_std: float = 0.02  # torque-sensor noise [N m]
    coulomb: tuple[float, float] = (0.02, 0.03)  # unmodelled Coulomb friction [N m]
    filter_window: float = 0.06  # Savitzky–Golay window for v and a [s]

    @staticmethod
    def noiseless() -> "PanTiltNoise":
        return PanTiltNoise(0.0, 0.0, (0.0, 0.0), 0.0)


def _reference(rng: np.random.Generator):
    """Sums of sinusoids for pan and tilt (tilt kept within ±1.2 rad, away from the pole)."""
    freqs = rng.uniform(0.15, 1.2, size=(2, 3))
    amps = np.array([[0.6], [0.25]]) * rng.uniform(0.5, 1.0, size=(2, 3)) / 1.0
    phases = rng.uniform(0, 2 * np.pi, size=(2, 3))
    offset = np.array([0.0, rng.uniform(-0.3, 0.3)])

    def ref(t):
        w = 2 * np.pi * freqs
        arg = w * t + phases
        q = offset + np.sum(amps * np.sin(arg), axis=1)
        v = np.sum(amps * w * np.cos(arg), axis=1)
        a = -np.sum(amps * w**2 * np.sin(arg), axis=1)
        return q, v, a

    return ref


def simulate_run(
    model: PanTilt,
    theta: np.ndarray,
    rng: np.random.Generator,
    duration: float = 10.0,
    rate: float = 200.0,
    noise: PanTiltNoise = PanTiltNoise(),
    name: str = "",
) -> Trajectory:
    """One run at ``rate`` Hz: a PD + feed-forward controller tracks random sinusoids through the true
    dynamics (with unmodelled Coulomb friction); then the measurement model is applied."""
    ref = _reference(rng)
    coulomb = np.asarray(noise.coulomb)
    kp, kd = np.array([8.0, 8.0]), np.array([1.0, 1.0])

    def control(t, q, v):
        qr, vr, ar = ref(t)
        ff = model.regressor(qr[None], vr[None], ar[None])[0] @ theta
        return ff + kp * (qr - q) + kd * (vr - v)

    def accel(q, v, tau):
        J = jacobian(q[None], model.length)[0]
        M = theta[0] * J.T @ J
        h = model.bias_regressor(q[None], v[None])[0] @ theta
        return np.linalg.solve(M, tau - h - coulomb * np.tanh(v / 0.05))

    def rhs(t, x):
        q, v = x[:2], x[2:]
        return np.concatenate([v, accel(q, v, control(t, q, v))])

    t = np.arange(0.0, duration, 1.0 / rate)
    q0, v0, _ = ref(0.0)
    sol = solve_ivp(rhs, (0, t[-1]), np.concatenate([q0, v0]), t_eval=t, rtol=1e-8, atol=1e-9, method="DOP853")
    if not sol.success:
        raise SimulationError(f"pan-tilt simulation failed: {sol.message}")
    q_true, v_true = sol.y[:2].T, sol.y[2:].T
    tau_true = np.array([control(ti, qi, vi) for ti, qi, vi in zip(t, q_true, v_true)])
    if noise.filter_window == 0.0:  # exact states and accelerations; force noise only
        a_true = np.array([accel(qi, vi, ui) for qi, vi, ui in zip(q_true, v_true, tau_true)])
        tau_meas = tau_true + noise.torque_std * rng.standard_normal(tau_true.shape)
        return Trajectory(t, q_true, v_true, tau_meas, a_true, model.coordinates, name)
    q_meas = q_true + noise.angle_std * rng.standard_normal(q_true.shape)
    q_s, v_s, a_s = savgol_derivatives(q_meas, rate, noise.filter_window)
    tau_meas = tau_true + noise.torque_std * rng.standard_normal(tau_true.shape)
    return Trajectory(
        t, q_s, v_s, tau_meas, a_s, model.coordinates, name,
        meta={"steps": [{"step": "savgol_derivatives", "window_s": noise.filter_window, "polyorder": 3}]},
    )


def dataset(seed: int = 0, n_train: int = 3, n_test: int = 3, noise: PanTiltNoise = PanTiltNoise(), **kw):
    """(model, train runs, test runs, true θ)."""
    model = PanTilt()
    rng = np.random.default_rng(seed)
    train = [simulate_run(model, TRUE_THETA, rng, noise=noise, name=f"train_{k}", **kw) for k in range(n_train)]
    test = [simulate_run(model, TRUE_THETA, rng, noise=noise, name=f"test_{k}", **kw) for k in range(n_test)]
    return model, train, test, TRUE_THETA.copy()


def make(seed: int = 0, noise: str = "realistic", size: str = "default"):
    """The pan–tilt ``SystemData`` (see dualid.systems.base)."""
    from dualid.systems.base import SystemData

    levels = {
        "realistic": PanTiltNoise(),
        "ideal": PanTiltNoise(angle_std=0.0, torque_std=0.02, coulomb=(0.0, 0.0), filter_window=0.0),
        "none": PanTiltNoise.noiseless(),
    }
    if noise not in levels:
        raise ConfigError(f"noise: expected one of {sorted(levels)}, got {noise!r}")
    sizes = {"default": (3, 3, 10.0), "small": (1, 2, 3.0)}
    if size not in sizes:
        raise ConfigError(f"size: expected one of {sorted(sizes)}, got {size!r}")
    n_train, n_test, duration = sizes[size]
    model, train, test, theta = dataset(seed, n_train, n_test, noise=levels[noise], duration=duration)
    return SystemData(
        name="pan-tilt",
        model=model,
        train=tuple(train),
        test=tuple(test),
        theta_true=theta,
        theta_nominal=NOMINAL_THETA.copy(),
        low_data_samples=10,
        slowest_period=1 / 0.15,
        shape_coordinates=("tilt",),
        gamma=0.1,  # per equation: the prior counts as a tenth of the WLS data term
        description="point mass on a pan–tilt link (teaching example)",
    )
