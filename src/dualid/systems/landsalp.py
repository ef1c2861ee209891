"""Simulated LandSalp data: wheel-force-driven runs through a drag-dominated TRUE system that has
effects the model lacks, then motion capture, differentiation, filtering and force-sensor noise.

True system (per wheel frame b, wheel-frame velocity u_b = J_b(q) v):

    f_b(u) = D̃_b u + β ⊙ diag(D_b) ⊙ |u| ⊙ u / u_ref + c ⊙ tanh(u / ε)
    Σ_b J_bᵀ f_b(J_b v) + C v + c_j ⊙ tanh(α̇ / ε_j) = τ = Σ_b J_bᵀ [F_b, 0, 0]

D̃_b = D_b plus a small lateral/rotational coupling ρ √(D_lat D_rot) (not diagonal), a small quadratic
term (not linear), smooth Coulomb friction in every wheel frame and joint. v is found from τ by Newton's
method at every instant; the pose (x, y, heading) of the base frame is integrated on SE(2) with the
body velocity, ẋ_world = R(heading) [vx, vy]. With noise "ideal" or "none" the true system is exactly
the model with θ_true (v = M(q, θ_true)⁻¹ τ).

Every number below marked (invented) is ours, not the paper's; see docs/landsalp.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from dualid.data.preprocessing import lowpass
from dualid.data.trajectory import Trajectory
from dualid.errors import ConfigError, SimulationError
from dualid.model.landsalp import LandSalpModel, configuration

# published identified values (Yang & Hatton): link b (longitudinal, lateral, rotational), joint dampings
TRUE_THETA = np.array([55.94, 42.73, 0.6726, 73.66, 86.93, 0.7322, 57.76, 23.30, 0.2602, 0.01154, 0.01369])
# a "prior identification" guess, 20–40 % off the truth, all positive (invented)
NOMINAL_FACTORS = np.array([1.3, 0.7, 1.35, 0.75, 1.25, 0.65, 1.2, 1.4, 0.7, 1.3, 0.75])
NOMINAL_THETA = TRUE_THETA * NOMINAL_FACTORS

GAIT_FREQUENCY = 1.0 / 6.0  # ω [Hz] of the published gait form
# Test gaits u_b(t) = ū_b + A_s,b sin 2πωt + A_c,b cos 2πωt [N], wheels (1, 2, 3), ω = 1/6 Hz, 12 s (two
# cycles) from the start shape below. All coefficients are INVENTED: found by a random search followed by
# hill climbing on the simulated true system so that the chain moves in the named direction of the base
# (link 2) frame at t = 0 without folding a joint beyond ~1.3 rad. With passive joints a constant push
# along the chain axis buckles the chain, so forward/backward rely on the shape oscillation.
GAITS: dict[str, tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]] = {
    #              ū                      A_s                     A_c
    "forward": ((1.59, -0.59, 1.01), (0.61, -0.38, -1.67), (0.3, -2.13, -6.27)),
    "backward": ((-1.66, 4.38, -0.91), (-1.47, -0.03, -1.92), (-2.32, -0.2, 2.48)),
    "left": ((-3.96, -5.74, -4.3), (2.51, 2.39, 2.7), (-1.69, -1.0, 2.48)),
    "right": ((4.4, 5.98, 3.77), (1.91, 0.6, 0.04), (-0.71, 0.82, 2.6)),
    "turn": ((4.68, -1.52, -4.85), (-0.32, -0.32, -0.32), (-1.34, -1.11, -0.34)),
}
GAIT_START_SHAPES = {  # (alpha1, alpha2) [rad] at t = 0 (invented, part of each gait)
    "forward": (0.16, 0.4),
    "backward": (0.66, -0.55),
    "left": (0.53, -0.54),
    "right": (-0.62, 0.25),
    "turn": (-0.7, -0.32),
}
GAIT_DIRECTIONS = {  # intended net displacement, unit vector in the base frame at t = 0 ("turn": yaw, +z)
    "forward": (1.0, 0.0),
    "backward": (-1.0, 0.0),
    "left": (0.0, 1.0),
    "right": (0.0, -1.0),
    "turn": (0.0, 0.0),
}


@dataclass(frozen=True)
class TrueEffects:
    """What the real LandSalp does that the model does not (all invented magnitudes)."""

    coupling: float = 0.15  # ρ: lateral/rotational drag coupling, fraction of √(D_lat D_rot)
    quadratic: float = 0.1  # β: relative quadratic drag at |u| = u_ref
    u_ref: tuple[float, float, float] = (0.1, 0.1, 0.5)  # [m/s, m/s, rad/s]
    coulomb: tuple[float, float, float] = (0.15, 0.25, 0.002)  # wheel-frame Coulomb levels [N, N, N m]
    epsilon: tuple[float, float, float] = (0.005, 0.005, 0.02)  # tanh smoothing [m/s, m/s, rad/s]
    joint_coulomb: float = 0.001  # [N m]
    joint_epsilon: float = 0.02  # [rad/s]

    @staticmethod
    def none() -> "TrueEffects":
        return TrueEffects(0.0, 0.0, (0.1, 0.1, 0.5), (0.0, 0.0, 0.0), (0.005, 0.005, 0.02), 0.0, 0.02)

    @property
    def is_linear(self) -> bool:
        return self.coupling == 0 and self.quadratic == 0 and not any(self.coulomb) and self.joint_coulomb == 0


@dataclass(frozen=True)
class Measurement:
    """Motion capture of the link poses, differentiated and filtered; force sensors on the wheels."""

    rate: float = 100.0  # [Hz] motion-capture and force sample rate
    position_std: float = 5e-4  # [m] per link position coordinate
    angle_std: float = np.deg2rad(0.3)  # [rad] per link heading
    force_std: float = 0.05  # [N] white force-sensor noise per wheel
    force_gain_std: float = 0.03  # relative calibration error of each wheel's force sensor, per run
    cutoff: float = 2.0  # [Hz] zero-phase Butterworth low-pass on poses and forces
    exact_states: bool = False  # True: exact q and v (only force noise)


MAX_SHAPE = 1.3  # [rad] training segments that fold a joint further are redrawn (invented)
MAX_ATTEMPTS = 20
SIM_OPTIONS = {"method": "RK45", "rtol": 1e-6, "atol": 1e-8}


def wheel_forces(t: np.ndarray, mean, sin_amp, cos_amp, freq) -> np.ndarray:
    """F (T, 3) [N]: u_b(t) = ū_b + A_s,b sin 2πω_b t + A_c,b cos 2πω_b t (ω per wheel or shared)."""
    t = np.atleast_1d(np.asarray(t, dtype=float))[:, None]
    w = 2 * np.pi * np.broadcast_to(np.asarray(freq, dtype=float), (3,))
    return np.asarray(mean) + np.asarray(sin_amp) * np.sin(w * t) + np.asarray(cos_amp) * np.cos(w * t)


class TrueLandSalp:
    """Velocities of the true system from configuration and wheel forces."""

    def __init__(self, model: LandSalpModel, theta: np.ndarray, effects: TrueEffects):
        self.model, self.effects = model, effects
        theta = np.asarray(theta, dtype=float)
        d = theta[:9].reshape(3, 3)
        self.diag = d  # (3 wheels, 3)
        D = np.array([np.diag(db) for db in d])
        off = effects.coupling * np.sqrt(d[:, 1] * d[:, 2])
        D[:, 1, 2] = D[:, 2, 1] = off
        self.D = D  # (3, 3, 3) coupled drag matrices
        self.Dbig = np.zeros((9, 9))  # block-diagonal drag of the stacked wheel velocities
        for b in range(3):
            self.Dbig[3 * b : 3 * b + 3, 3 * b : 3 * b + 3] = D[b]
        self.C = np.diag([0, 0, 0, theta[9], theta[10]])

    def velocity(self, q: np.ndarray, F: np.ndarray, v0: np.ndarray | None = None) -> np.ndarray:
        """v (T, 5) solving Σ J_bᵀ f_b(J_b v) + joint terms = Σ J_bᵀ [F_b, 0, 0] (Newton per sample,
        started from v0 (T, 5) when given, else from the linear model's solution)."""
        J = self.model.wheel_jacobians(q)  # (T, 3, 3, 5)
        T = J.shape[0]
        A = J.reshape(T, 9, 5)  # stacked wheel-frame Jacobians: u = A v, u = (u_1, u_2, u_3)
        At = np.swapaxes(A, 1, 2)
        tau = At @ (F[:, :, None] * np.array([1.0, 0.0, 0.0])).reshape(T, 9, 1)  # (T, 5, 1)
        M = At @ self.Dbig @ A + self.C
        v = np.linalg.solve(M, tau)  # (T, 5, 1)
        if self.effects.is_linear:
            return v[..., 0]
        if v0 is not None:
            v = np.asarray(v0, dtype=float).reshape(T, 5, 1).copy()
        e = self.effects
        beta = (e.quadratic * self.diag / np.asarray(e.u_ref)).reshape(9, 1)
        c = np.tile(np.asarray(e.coulomb), 3).reshape(9, 1)
        eps = np.tile(np.asarray(e.epsilon), 3).reshape(9, 1)
        cj, ej = e.joint_coulomb, e.joint_epsilon
        for it in range(50):
            u = A @ v  # (T, 9, 1)
            th = np.tanh(u / eps)
            f = self.Dbig @ u + beta * np.abs(u) * u + c * th
            df = 2 * beta * np.abs(u) + c / eps * (1 - th**2)  # (T, 9, 1) extra diagonal slope
            tha = np.tanh(v[:, 3:] / ej)  # (T, 2, 1)
            R = At @ f + self.C @ v - tau
            R[:, 3:] += cj * tha
            K = M + At @ (df * A)
            K[:, 3, 3] += cj / ej * (1 - tha[:, 0, 0] ** 2)
            K[:, 4, 4] += cj / ej * (1 - tha[:, 1, 0] ** 2)
            step = np.linalg.solve(K, R)
            v = v - step
            if np.max(np.abs(step)) < 1e-12:
                break
        else:
            raise SimulationError("LandSalp true dynamics: Newton did not converge in 50 iterations")
        return v[..., 0]


def _rhs_state(state: np.ndarray) -> np.ndarray:
    """(x, y, heading, alpha1, alpha2) → Pinocchio configuration (1, 6)."""
    return configuration(*state)


def simulate_run(
    model: LandSalpModel,
    truth: TrueLandSalp,
    forces,  # callable t (T,) -> F (T, 3)
    duration: float,
    rng: np.random.Generator,
    measurement: Measurement | None,
    name: str = "",
    state0=(0.0, 0.0, 0.0, 0.0, 0.0),
    meta: dict | None = None,
) -> Trajectory:
    """One run at ``measurement.rate``; measurement None means exact data (no noise at all)."""
    rate = measurement.rate if measurement is not None else 100.0

    last = [None]  # warm start for Newton: the previous right-hand side's velocity

    def rhs(t, s):
        v = truth.velocity(_rhs_state(s), forces(np.array([t])), last[0])[0]
        last[0] = v
        c, sn = np.cos(s[2]), np.sin(s[2])
        return np.array([c * v[0] - sn * v[1], sn * v[0] + c * v[1], v[2], v[3], v[4]])

    t = np.arange(int(round(duration * rate))) / rate
    sol = solve_ivp(rhs, (0.0, t[-1]), np.asarray(state0, dtype=float), t_eval=t, **SIM_OPTIONS)
    if not sol.success:
        raise SimulationError(f"LandSalp simulation {name!r} failed: {sol.message}")
    state = sol.y.T  # (T, 5)
    q = configuration(*state.T)
    F = forces(t)
    v = truth.velocity(q, F)
    meta = dict(meta or {})
    meta.update({"wheel_forces_true": F, "state_true": state, "units": "m, rad, N, N m"})
    if measurement is None:
        return Trajectory(t, q, v, model.generalized_force(q, F), None, model.coordinates, name, meta)

    gain = 1.0 + measurement.force_gain_std * rng.standard_normal(3)
    F_meas = gain * F + measurement.force_std * rng.standard_normal(F.shape)
    if measurement.exact_states:
        tau = model.generalized_force(q, F_meas)
        meta["steps"] = [{"step": "force_noise", "gain": gain.tolist(), "std_N": measurement.force_std}]
        return Trajectory(t, q, v, tau, None, model.coordinates, name, meta)

    # motion capture: link poses with noise, shape from relative headings, base = link 2
    poses = model.link_poses(q)  # (T, 3, 3)
    noise = rng.standard_normal(poses.shape) * np.array([measurement.position_std] * 2 + [measurement.angle_std])
    poses = poses + noise
    head = np.unwrap(poses[:, :, 2], axis=0)  # (T, 3)
    raw = np.column_stack([poses[:, 1, 0], poses[:, 1, 1], head[:, 1], head[:, 0] - head[:, 1], head[:, 2] - head[:, 1]])
    fs = rate
    s = lowpass(raw, fs, measurement.cutoff)
    ds = np.gradient(s, 1.0 / fs, axis=0)
    c, sn = np.cos(s[:, 2]), np.sin(s[:, 2])
    v_meas = np.column_stack([c * ds[:, 0] + sn * ds[:, 1], -sn * ds[:, 0] + c * ds[:, 1], ds[:, 2:]])
    q_meas = configuration(*s.T)
    F_f = lowpass(F_meas, fs, measurement.cutoff)
    tau = model.generalized_force(q_meas, F_f)
    meta["steps"] = [
        {"step": "motion_capture", "position_std_m": measurement.position_std, "angle_std_rad": measurement.angle_std},
        {"step": "lowpass", "cutoff_hz": measurement.cutoff, "order": 4, "zero_phase": True, "signals": "poses, forces"},
        {"step": "differentiate", "method": "numpy.gradient", "frame": "body velocity of link 2"},
        {"step": "force_noise", "gain": gain.tolist(), "std_N": measurement.force_std},
    ]
    return Trajectory(t, q_meas, v_meas, tau, None, model.coordinates, name, meta)


def training_inputs(rng: np.random.Generator):
    """One excitation segment (invented): three wheels at DISTINCT frequencies in [1/6, 0.6] Hz."""
    grid = np.array([1 / 6, 0.21, 0.26, 0.31, 0.37, 0.43, 0.49, 0.55])
    freq = rng.choice(grid, size=3, replace=False)
    mean = rng.uniform(-1.5, 1.5, 3)  # ū [N]
    sin_amp = rng.uniform(-4.0, 4.0, 3)  # A_s [N]
    cos_amp = rng.uniform(-4.0, 4.0, 3)  # A_c [N]
    spec = {"mean": mean, "sin_amp": sin_amp, "cos_amp": cos_amp, "freq": freq}
    return (lambda t: wheel_forces(t, mean, sin_amp, cos_amp, freq)), spec


def gait_inputs(name: str):
    if name not in GAITS:
        raise ConfigError(f"unknown LandSalp gait {name!r}; expected one of {sorted(GAITS)}")
    mean, sin_amp, cos_amp = GAITS[name]
    spec = {"mean": mean, "sin_amp": sin_amp, "cos_amp": cos_amp, "freq": (GAIT_FREQUENCY,) * 3, "gait": name}
    return (lambda t: wheel_forces(t, mean, sin_amp, cos_amp, GAIT_FREQUENCY)), spec


def dataset(
    seed: int = 0,
    n_train: int = 8,
    train_duration: float = 22.5,
    gaits: tuple[str, ...] = tuple(GAITS),
    test_duration: float = 12.0,
    effects: TrueEffects = TrueEffects(),
    measurement: Measurement | None = Measurement(),
    theta: np.ndarray = TRUE_THETA,
    max_shape: float = MAX_SHAPE,
):
    """(model, train runs, test runs, true θ); 8 × 22.5 s = 3 min of training by default.

    Training inputs are redrawn (as an operator would) while a segment folds the chain beyond
    ±max_shape rad in either joint."""
    model = LandSalpModel()
    truth = TrueLandSalp(model, theta, effects)
    rng = np.random.default_rng(seed)
    train, test = [], []
    for k in range(n_train):
        for attempt in range(MAX_ATTEMPTS):
            forces, spec = training_inputs(rng)
            run = simulate_run(model, truth, forces, train_duration, rng, measurement, f"train_{k}",
                               meta={"input": spec, "attempt": attempt})
            if np.abs(run.meta["state_true"][:, 3:]).max() <= max_shape:
                break
        else:
            raise SimulationError(f"LandSalp: no training input kept the shape within ±{max_shape} rad")
        train.append(run)
    for g in gaits:
        forces, spec = gait_inputs(g)
        test.append(simulate_run(model, truth, forces, test_duration, rng, measurement, f"test_{g}",
                                 state0=(0.0, 0.0, 0.0, *GAIT_START_SHAPES[g]), meta={"input": spec}))
    return model, train, test, np.array(theta, dtype=float)


def make(seed: int = 0, noise: str = "realistic", size: str = "default"):
    """The LandSalp ``SystemData`` (see dualid.systems.base)."""
    from dualid.systems.base import SystemData

    levels = {
        "realistic": (TrueEffects(), Measurement()),
        "ideal": (TrueEffects.none(), Measurement(exact_states=True, force_gain_std=0.0)),
        "none": (TrueEffects.none(), None),
    }
    if noise not in levels:
        raise ConfigError(f"noise: expected one of {sorted(levels)}, got {noise!r}")
    sizes = {
        "default": dict(n_train=8, train_duration=22.5, gaits=tuple(GAITS), test_duration=12.0),
        "small": dict(n_train=2, train_duration=6.0, gaits=("forward", "turn"), test_duration=6.0),
    }
    if size not in sizes:
        raise ConfigError(f"size: expected one of {sorted(sizes)}, got {size!r}")
    effects, measurement = levels[noise]
    model, train, test, theta = dataset(seed, effects=effects, measurement=measurement, **sizes[size])
    return SystemData(
        name="landsalp",
        model=model,
        train=tuple(train),
        test=tuple(test),
        theta_true=theta,
        theta_nominal=NOMINAL_THETA.copy(),
        low_data_samples=40,
        slowest_period=1.0 / GAIT_FREQUENCY,
        shape_coordinates=("alpha1", "alpha2"),
        gamma=0.1,  # per equation: the prior counts as a tenth of the WLS data term
        description="LandSalp: three-link wheeled chain, drag-dominated (published drag values as truth)",
    )
