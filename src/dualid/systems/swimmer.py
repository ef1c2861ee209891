"""A simulated drag-dominated chain: a 4-link planar swimmer (snake-like robot) in a viscous medium,
the demonstration of the generic drag model (``dualid.model.drag``, docs/drag.md).

Kinematics: ``swimmer_urdf()`` (a URDF text: links link1 … link4 of length 0.25 m along x, revolute z
joints joint1 … joint3 at the link ends; link frames at the rear ends) with a planar base on link 1.
Model (``SPEC``): per link, drag in a frame at its centre — links 2–4 diagonal (vx, vy, wz), link 1
(the head, with an angled fin) a full PSD 3×3 matrix — plus damping of the three joints.

TRUE system (what the model lacks, all magnitudes invented):

    Σ_b J_bᵀ [C_b u_b + β ⊙ diag(C_b) ⊙ |u_b| ⊙ u_b / u_ref] + c ⊙ α̇ + f_c tanh(α̇ / ε) = τ,   u_b = J_b v

(quadratic drag β at |u| = u_ref, Coulomb joint friction f_c). The joints are driven by a
P position controller τ_j = K_p (α_ref,j(t) − α_j) (the base is passive: τ_base = 0); v is found
from τ by Newton's method at every instant and q̇ = v is integrated (v are world-frame rates of
x, y, theta and the joint rates: the model's chart).

Measured (``Measurement``): base pose by motion capture (Gaussian position and heading noise), joint
angles by 12-bit encoders (quantised), velocities by the sensors' own differentiation (noise), joint
torques from motor currents (white noise plus a per-run gain error of each joint's torque constant).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from dualid.errors import SimulationError
from dualid.model.drag import DragModel

N_LINKS = 4
LINK_LENGTH = 0.25  # [m]
JOINTS = tuple(f"joint{j}" for j in range(1, N_LINKS))
# the true drag (invented; roughly a slender 0.25 m link in a silicone-oil-like medium: lateral ≈ 2 × longitudinal,
# rotational ≈ lateral · L²/12), the head with a full matrix (a fin couples lateral and rotational drag)
HEAD = [[3.0, 0.4, 0.05], [0.4, 6.5, 0.12], [0.05, 0.12, 0.045]]
TRUE_DRAG = {
    "base": "planar",
    "bodies": {
        "link1": {"frame": "link1", "xyz": [LINK_LENGTH / 2, 0, 0], "full": HEAD},
        "link2": {"frame": "link2", "xyz": [LINK_LENGTH / 2, 0, 0], "diagonal": [2.0, 4.2, 0.022]},
        "link3": {"frame": "link3", "xyz": [LINK_LENGTH / 2, 0, 0], "diagonal": [2.2, 3.8, 0.020]},
        "link4": {"frame": "link4", "xyz": [LINK_LENGTH / 2, 0, 0], "diagonal": [1.6, 5.0, 0.026]},
    },
    "damping": {"joint1": 0.004, "joint2": 0.003, "joint3": 0.005},
}


def swimmer_urdf(n_links: int = N_LINKS, length: float = LINK_LENGTH) -> str:
    """The URDF text of the chain (massless links: a drag model needs only the kinematic tree)."""
    links = "\n".join(f'  <link name="link{i}"/>' for i in range(1, n_links + 1))
    joints = "\n".join(
        f'  <joint name="joint{i}" type="revolute">\n    <parent link="link{i}"/>\n    <child link="link{i + 1}"/>\n'
        f'    <origin xyz="{length:g} 0 0"/>\n    <axis xyz="0 0 1"/>\n'
        f'    <limit lower="-2" upper="2" effort="5" velocity="5"/>\n  </joint>'
        for i in range(1, n_links))
    return f'<?xml version="1.0"?>\n<robot name="swimmer">\n{links}\n{joints}\n</robot>\n'


@dataclass(frozen=True)
class TrueEffects:
    quadratic: float = 0.1  # β: relative quadratic drag at |u| = u_ref
    u_ref: tuple[float, float, float] = (0.15, 0.15, 1.5)  # [m/s, m/s, rad/s]
    joint_coulomb: float = 0.002  # f_c [N m]
    joint_epsilon: float = 0.05  # ε [rad/s]


@dataclass(frozen=True)
class Measurement:
    rate: float = 100.0  # [Hz]
    position_std: float = 5e-4  # [m] base position (motion capture)
    heading_std: float = np.deg2rad(0.3)  # [rad]
    encoder_counts: int = 4096  # per revolution (12 bit)
    velocity_std: tuple[float, float, float, float] = (0.004, 0.004, 0.03, 0.02)  # [m/s, m/s, rad/s, rad/s (joints)]
    torque_std: float = 0.002  # [N m] white torque noise
    torque_gain_std: float = 0.03  # relative torque-constant error per joint and run


KP = 0.5  # [N m/rad] joint position gain


class TrueSwimmer:
    """v from q and τ through the true (nonlinear) drag."""

    def __init__(self, model: DragModel, theta: np.ndarray, effects: TrueEffects):
        self.model, self.theta, self.effects = model, np.asarray(theta, float), effects
        self.C = model.drag_matrices(self.theta)
        self.damping = self.theta[-len(JOINTS):]

    def force(self, q, v) -> tuple[np.ndarray, np.ndarray]:
        """(f (n,) the true resistive generalized force at one state, its Jacobian ∂f/∂v (n, n))."""
        J = self.model.body_jacobians(q[None])
        e = self.effects
        f, K = np.zeros(self.model.n), np.zeros((self.model.n, self.model.n))
        for Jb, (name, C) in zip(J, self.C.items()):
            Jb = Jb[0]
            u = Jb @ v
            beta = e.quadratic * np.diag(C) / np.asarray(e.u_ref)
            f += Jb.T @ (C @ u + beta * np.abs(u) * u)
            K += Jb.T @ (C + np.diag(2 * beta * np.abs(u))) @ Jb
        a = v[-len(JOINTS):]
        th = np.tanh(a / e.joint_epsilon)
        f[-len(JOINTS):] += self.damping * a + e.joint_coulomb * th
        K[-len(JOINTS):, -len(JOINTS):] += np.diag(self.damping + e.joint_coulomb * (1 - th ** 2) / e.joint_epsilon)
        return f, K

    def velocity(self, q, tau, v0=None) -> np.ndarray:
        v = np.zeros(self.model.n) if v0 is None else v0.copy()
        for _ in range(30):
            f, K = self.force(q, v)
            step = np.linalg.solve(K, tau - f)
            v += step
            if np.linalg.norm(step) <= 1e-12 * max(1.0, np.linalg.norm(v)):
                return v
        raise SimulationError(f"swimmer: the true drag equations did not converge at q = {q}")


def joint_reference(t, amplitudes, frequencies, phases, offsets) -> np.ndarray:
    """α_ref (T, 3) [rad]: per joint a sum of sinusoids (amplitudes/frequencies/phases (3, k)) plus offsets (3,)."""
    t = np.atleast_1d(t)[:, None, None]
    return (np.asarray(amplitudes) * np.sin(2 * np.pi * np.asarray(frequencies) * t + np.asarray(phases))).sum(-1) \
        + np.asarray(offsets)


def excitation(rng) -> dict:
    """A training reference: three random sinusoids per joint, 0.1–0.8 Hz, 0.2–0.5 rad each (invented)."""
    return {"amplitudes": rng.uniform(0.1, 0.3, (3, 3)), "frequencies": rng.uniform(0.1, 0.8, (3, 3)),
            "phases": rng.uniform(0, 2 * np.pi, (3, 3)), "offsets": rng.uniform(-0.2, 0.2, 3)}


def gait(kind: str) -> dict:
    """Held-out references: a travelling wave ('swim', 0.5 Hz, 0.6 rad, phase lag 1 rad per joint),
    the same with a 0.3 rad offset ('turn'), and a faster, smaller wave ('fast')."""
    freq = {"swim": 0.5, "turn": 0.5, "fast": 0.9}[kind]
    amp = {"swim": 0.6, "turn": 0.5, "fast": 0.35}[kind]
    A = np.zeros((3, 3))
    A[:, 0] = amp
    F = np.full((3, 3), freq)
    P = np.zeros((3, 3))
    P[:, 0] = -np.arange(3) * 1.0
    return {"amplitudes": A, "frequencies": F, "phases": P, "offsets": np.full(3, 0.3 if kind == "turn" else 0.0)}


def simulate(true: TrueSwimmer, reference: dict, duration: float, rate: float = 100.0):
    """Exact (t, q, v, τ) at ``rate`` [Hz] of a run driven by the joint P controller."""
    n = true.model.n
    state = {"v": None}

    def tau_of(t, q):
        tau = np.zeros(n)
        tau[-3:] = KP * (joint_reference(t, **reference)[0] - q[-3:])
        return tau

    def rhs(t, q):
        v = true.velocity(q, tau_of(t, q), state["v"])
        state["v"] = v
        return v

    t = np.arange(0.0, duration, 1.0 / rate)
    q0 = np.zeros(n)
    q0[-3:] = joint_reference(0.0, **reference)[0]
    sol = solve_ivp(rhs, (0.0, t[-1]), q0, t_eval=t, method="RK45", rtol=1e-7, atol=1e-9)
    if not sol.success:
        raise SimulationError(f"swimmer: integration failed: {sol.message}")
    q = sol.y.T
    tau = np.array([tau_of(ti, qi) for ti, qi in zip(t, q)])
    v = np.array([true.velocity(qi, ti) for qi, ti in zip(q, tau)])
    return t, q, v, tau


def measure(t, q, v, tau, rng, m: Measurement = Measurement()) -> dict[str, np.ndarray]:
    """The sensor readings of an exact run (see the module docstring)."""
    qm = q.copy()
    qm[:, :2] += rng.normal(0, m.position_std, (len(t), 2))
    qm[:, 2] += rng.normal(0, m.heading_std, len(t))
    step = 2 * np.pi / m.encoder_counts
    qm[:, 3:] = np.round(q[:, 3:] / step) * step
    std = np.array(list(m.velocity_std[:3]) + [m.velocity_std[3]] * (q.shape[1] - 3))
    vm = v + rng.normal(0, 1, v.shape) * std
    gain = 1 + rng.normal(0, m.torque_gain_std, q.shape[1])
    gain[:3] = 1.0
    taum = tau * gain
    taum[:, 3:] += rng.normal(0, m.torque_std, (len(t), q.shape[1] - 3))
    return {"t": t, "q": qm, "v": vm, "tau": taum}
