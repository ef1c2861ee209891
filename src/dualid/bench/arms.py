"""The statistical-quality benchmark's data and metrics; the driver is benchmarks/statistical_quality.py.

Data (Pinocchio): a random serial arm of 3–7 revolute joints (random axes, link lengths, box-shaped links
with random mass, size, centre of mass and orientation, so every body is physically consistent), with
true viscous/Coulomb friction and armature. Commanded motion: a sum of sinusoids per joint. The true
torque is inverse dynamics on the true arm along the commanded (q, v, a):

    τ = rnea(q, v, a) + b v + fc tanh(v / v_c) + Ia a (+ the effects of a model-error case)

What the estimators get is what a robot logs: q quantised by a 16-bit encoder, v and a by
Savitzky–Golay differentiation of that q, τ with Gaussian noise (a fraction of each joint's τ rms)
and, in the model-error cases, effects the identification model lacks. The identification model is
``with_joint_terms(RigidBodyModel(arm), viscous, coulomb, armature)`` built from the arm's kinematics
with CAD-like (wrong) inertias: nothing the estimators see carries the true θ.

Metrics of a fit θ̂ on held-out runs (other random sinusoids, same arm):
- clean torque error: per joint RMSE of Y(q, v, a) θ̂ against the noise-free physical τ, both at the
  commanded (exact) states, divided by that joint's τ rms; aggregated as the rms over joints (NRMSE);
- forward dynamics: a = M̂⁻¹(τ − ĥ) from the *measured* q, v, τ against the measured (differentiated)
  a, scored by ``dualid.evaluation.scores.score_run`` (max normalised cross-correlation within ±T/72);
- metric guard: generalised eigenvalues of M(q, θ̂) against M(q, θ_true) on test states (chart-invariant).

No file is written here; the driver writes results.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from dualid.data.preprocessing import differentiate, trim
from dualid.data.trajectory import Trajectory
from dualid.errors import ConfigError, SimulationError
from dualid.model.joint_terms import JointTermsModel, with_joint_terms
from dualid.model.rigid_body import RigidBodyModel

FS = 200.0  # [Hz] sample rate of every run
PERIOD = 5.0  # [s] fundamental period of the excitation (harmonics 1..HARMONICS)
HARMONICS = 5
ENCODER_BITS = 16  # q quantised to 2π / 2^16 rad
SAVGOL_WINDOW = 0.1  # [s] differentiation window
COULOMB_VELOCITY = 0.01  # [rad/s] v_c of tanh(v / v_c), in the truth and in the identification model
TEST_RUNS = 2
TEST_SECONDS = 8.0
MODEL_ERROR_CASES = ("stribeck", "position_friction", "cogging", "sensor", "payload", "combined")


# --- the arm ------------------------------------------------------------------------------------
def _rotation(rng: np.random.Generator, scale: float = 1.0) -> np.ndarray:
    """A random rotation; scale < 1 gives one closer to the identity (axis-angle with angle·scale)."""
    w = rng.normal(size=3)
    w *= scale * rng.uniform(0, np.pi) / np.linalg.norm(w)
    return pin.exp3(w)


@dataclass(frozen=True, eq=False)
class Arm:
    """A true arm (Pinocchio model with true inertias, joint friction and armature) and the
    identification model the estimators get (same kinematics, CAD-like wrong inertias)."""

    true_model: pin.Model
    viscous: np.ndarray  # (n,) b [N m s/rad]
    coulomb: np.ndarray  # (n,) fc [N m]
    armature: np.ndarray  # (n,) Ia [kg m²]
    ident: JointTermsModel
    theta_true: np.ndarray  # (p,) in ident's parameter order

    @property
    def n(self) -> int:
        return self.true_model.nv

    def rnea(self, q: np.ndarray, v: np.ndarray, a: np.ndarray, model: pin.Model | None = None) -> np.ndarray:
        """Rigid-body inverse dynamics (T, n) of the true (or the given) model."""
        model = model or self.true_model
        data = model.createData()
        return np.stack([pin.rnea(model, data, q[t], v[t], a[t]) for t in range(q.shape[0])])

    def joint_torque(self, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """The modelled joint terms b v + fc tanh(v / v_c) + Ia a, (T, n)."""
        return self.viscous * v + self.coulomb * np.tanh(v / COULOMB_VELOCITY) + self.armature * a

    def torque(self, q, v, a) -> np.ndarray:
        """τ of the true arm without model error, (T, n) [N m]."""
        return self.rnea(q, v, a) + self.joint_torque(v, a)

    def inertial_torque(self, q, v, a) -> np.ndarray:
        """M(q) a including armature, (T, n): the torque that identifies the mass matrix."""
        return self.rnea(q, v, a) - self.rnea(q, v, np.zeros_like(a)) + self.armature * a


def random_arm(rng: np.random.Generator, dof: int) -> Arm:
    """A random revolute serial arm of ``dof`` joints (see the module doc) and its identification model."""
    if not 3 <= dof <= 7:
        raise ConfigError(f"random_arm: expected 3 to 7 joints, got {dof}")
    axes = {"X": pin.JointModelRX, "Y": pin.JointModelRY, "Z": pin.JointModelRZ}
    model, parent = pin.Model(), 0
    length = 0.1
    for j in range(dof):
        axis = "Z" if j == 0 else str(rng.choice(["X", "Y", "Z"], p=[0.35, 0.45, 0.2]))
        offset = np.array([*rng.uniform(-0.05, 0.05, 2), length])
        placement = pin.SE3(_rotation(rng, 0.15), offset)
        parent = model.addJoint(parent, axes[axis](), placement, f"j{j}")
        length = rng.uniform(0.15, 0.45) if j < dof - 1 else rng.uniform(0.05, 0.15)
        mass = rng.uniform(0.5, 4.0) * 0.8**j
        w, d = rng.uniform(0.04, 0.12, 2)
        I_box = mass / 12 * np.diag([d * d + length**2, w * w + length**2, w * w + d * d])
        R = _rotation(rng, 0.2)
        com = np.array([*rng.uniform(-0.03, 0.03, 2), rng.uniform(0.3, 0.7) * length])
        model.appendBodyToJoint(parent, pin.Inertia(mass, com, R @ I_box @ R.T), pin.SE3.Identity())
    scale = 0.8 ** np.arange(dof)
    viscous = rng.uniform(0.1, 1.0, dof) * scale
    coulomb = rng.uniform(0.2, 2.0, dof) * scale
    armature = rng.uniform(0.02, 0.2, dof) * scale
    # the identification model: same kinematics, inertias off by 20–50 % (what a CAD file would say)
    cad = pin.Model(model)
    for j in range(1, cad.njoints):
        I = cad.inertias[j]
        cad.inertias[j] = pin.Inertia(I.mass * rng.uniform(0.5, 1.5), I.lever * rng.uniform(0.5, 1.5), I.inertia * rng.uniform(0.5, 1.5))
    ident = with_joint_terms(RigidBodyModel(cad), viscous=True, coulomb=True, armature=True,
                             coulomb_velocity=COULOMB_VELOCITY)
    theta_true = np.concatenate(
        [model.inertias[j].toDynamicParameters() for j in range(1, model.njoints)] + [viscous, coulomb, armature]
    )
    return Arm(model, viscous, coulomb, armature, ident, theta_true)


# --- motion and measurement -------------------------------------------------------------------
def excitation(rng: np.random.Generator, n: int, seconds: float) -> tuple[np.ndarray, ...]:
    """(t, q, v, a) of a sum of HARMONICS sinusoids per joint (period PERIOD), sampled at FS."""
    t = np.arange(int(round(seconds * FS))) / FS
    w = 2 * np.pi * np.arange(1, HARMONICS + 1) / PERIOD  # (K,)
    amp = rng.uniform(0.1, 0.3, (n, HARMONICS)) / np.sqrt(np.arange(1, HARMONICS + 1))  # [rad]
    phase = rng.uniform(0, 2 * np.pi, (n, HARMONICS))
    q0 = rng.uniform(-0.6, 0.6, n)
    arg = t[:, None, None] * w[None, None, :] + phase[None]  # (T, n, K)
    q = q0 + np.sum(amp * np.sin(arg), axis=2)
    v = np.sum(amp * w * np.cos(arg), axis=2)
    a = -np.sum(amp * w**2 * np.sin(arg), axis=2)
    return t, q, v, a


@dataclass(frozen=True, eq=False)
class Run:
    """One run: the commanded (exact) states, the physical torque, and the logged (measured) trajectory.

    ``tau_phys``: the torque the actuators really produce (model error included, sensor error not);
    ``tau_clean``: what the logged τ would be without noise (sensor offset/gain included).
    ``measured``: q quantised, v and a differentiated, τ = tau_clean + noise, edges trimmed; ``keep``
    indexes the commanded samples that survive the trim.
    """

    q: np.ndarray
    v: np.ndarray
    a: np.ndarray
    tau_phys: np.ndarray
    tau_clean: np.ndarray
    inertial: np.ndarray
    unmodelled: np.ndarray  # tau_clean minus the modelled part Y θ_true at the commanded states
    measured: Trajectory
    keep: np.ndarray


def _model_error(arm: Arm, case: str | None, case_seed: int, q, v, a, payload: bool):
    """(extra physical torque (T, n), sensor gain (n,), sensor offset (n,)) of a model-error case.

    The case's random constants (phases, sensor gains and offsets) come from ``case_seed``: the same
    arm keeps the same defects in every run."""
    n = arm.n
    rng = np.random.default_rng(case_seed)
    extra = np.zeros_like(q)
    gain, offset = np.ones(n), np.zeros(n)
    if case is None:
        return extra, gain, offset
    cases = {"stribeck", "position_friction", "cogging", "sensor", "payload"} if case == "combined" else {case}
    fc = arm.coulomb
    if "stribeck" in cases:  # static friction 5× Coulomb, Stribeck velocity 0.15 rad/s
        extra += 4.0 * fc * np.exp(-((v / 0.15) ** 2)) * np.tanh(v / COULOMB_VELOCITY)
    if "position_friction" in cases:  # Coulomb level varies ±150 % with position (seals, gear eccentricity)
        extra += 1.5 * fc * np.sin(2 * q + rng.uniform(0, 2 * np.pi, n)) * np.tanh(v / COULOMB_VELOCITY)
    if "cogging" in cases:  # 8 ripples per revolution, amplitude 1.5× Coulomb
        extra += 1.5 * fc * np.sin(8 * q + rng.uniform(0, 2 * np.pi, n))
    if "sensor" in cases:  # torque-sensor gain error ±15 %, offset ±(1–2)·(fc + 0.3 N m)
        gain = 1 + rng.uniform(-0.15, 0.15, n)
        offset = rng.choice([-1, 1], n) * rng.uniform(1, 2, n) * (fc + 0.3)
    if "payload" in cases and payload:  # 1.5 kg held off-axis by the last link, not in the model
        heavy = pin.Model(arm.true_model)
        last = heavy.njoints - 1
        lever = np.array([0.05, -0.03, 0.12])
        heavy.inertias[last] = heavy.inertias[last] + pin.Inertia(1.5, lever, 1e-3 * np.eye(3))
        extra += arm.rnea(q, v, a, heavy) - arm.rnea(q, v, a)
    return extra, gain, offset


def make_run(arm: Arm, rng: np.random.Generator, seconds: float, noise: float, case: str | None = None,
             payload: bool = False, name: str = "", case_seed: int = 0) -> Run:
    """Simulate one run (see ``Run``). noise: torque noise std as a fraction of each joint's clean τ rms;
    case: one of MODEL_ERROR_CASES or None; payload: whether the run carries the unmodelled payload
    (payload and combined cases); case_seed: the seed of the case's constants (keep it per arm)."""
    if case is not None and case not in MODEL_ERROR_CASES:
        raise ConfigError(f"make_run: case must be None or one of {MODEL_ERROR_CASES}, got {case!r}")
    margin = SAVGOL_WINDOW  # trimmed at each end (Savitzky–Golay edge effects)
    t, q, v, a = excitation(rng, arm.n, seconds + 2 * margin)
    tau_model = arm.torque(q, v, a)
    extra, gain, offset = _model_error(arm, case, case_seed, q, v, a, payload)
    tau_phys = tau_model + extra
    tau_clean = gain * tau_phys + offset
    sigma = noise * np.sqrt(np.mean(tau_clean**2, axis=0))
    tau_meas = tau_clean + sigma * rng.normal(size=tau_clean.shape)
    step = 2 * np.pi / 2**ENCODER_BITS
    q_meas = np.round(q / step) * step
    traj = Trajectory(t, q_meas, np.zeros_like(q_meas), tau_meas, coordinates=arm.ident.coordinates, name=name,
                      meta={"logged": ["q", "tau"]})
    traj = differentiate(traj, "savgol", window=SAVGOL_WINDOW, polyorder=3, velocity=True)
    keep = np.flatnonzero((t >= t[0] + margin) & (t <= t[-1] - margin))
    traj = trim(traj, t[keep[0]], t[keep[-1]])
    if traj.t.shape[0] != keep.size:  # pragma: no cover - trim's bounds are inclusive
        raise SimulationError("make_run: trim kept an unexpected number of samples")
    sl = (keep,)
    inertial = arm.inertial_torque(q[sl], v[sl], a[sl])
    unmodelled = tau_clean[sl] - arm.ident.regressor(q[sl], v[sl], a[sl]) @ arm.theta_true
    return Run(q[sl], v[sl], a[sl], tau_phys[sl], tau_clean[sl], inertial, unmodelled, traj, keep)


# --- a configuration-dependent re-chart ---------------------------------------------------------
def rechart(rng: np.random.Generator, q: np.ndarray, spread: float = 2.0) -> np.ndarray:
    """B_i (N, n, n) = D (I + ½ K ⊙ sin(q_i 1ᵀ + Φ)), ‖K‖_F = 1, D = diag(10^U(−spread, spread)).

    Invertible at every sample (‖½ K ⊙ S‖₂ ≤ ½), smooth in q, so it is the Jacobian field of a
    configuration-dependent change of velocity coordinates with unit scalings over 10^±spread.
    """
    n = q.shape[1]
    K = rng.normal(size=(n, n))
    K /= np.linalg.norm(K)
    phase = rng.uniform(0, 2 * np.pi, (n, n))
    D = np.diag(10.0 ** rng.uniform(-spread, spread, n))
    S = np.sin(q[:, :, None] + phase[None])  # (N, n, n): entry (a, b) depends on q_a
    return D[None] @ (np.eye(n)[None] + 0.5 * K[None] * S)


# --- metrics ------------------------------------------------------------------------------------
def torque_nrmse(Y: np.ndarray, theta: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Per joint RMSE(Y θ − τ) / rms(τ), (n,)."""
    e = Y @ theta - tau
    return np.sqrt(np.mean(e**2, axis=0) / np.mean(tau**2, axis=0))


def aggregate(per_joint: np.ndarray) -> float:
    """rms over joints of per-joint NRMSEs."""
    return float(np.sqrt(np.mean(np.asarray(per_joint) ** 2)))


def metric_eigen_range(M_hat: np.ndarray, M_ref: np.ndarray) -> tuple[float, float]:
    """(min, max) generalised eigenvalue of M_hat against M_ref over samples: chart-invariant."""
    L = np.linalg.cholesky(M_ref)
    Li = np.linalg.inv(L)
    lam = np.linalg.eigvalsh(Li @ M_hat @ np.swapaxes(Li, 1, 2))
    return float(lam.min()), float(lam.max())
