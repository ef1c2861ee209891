"""The design problem: a fixed-base robot, its limits, its base parameters and the three criteria.

- Limits (lower/upper position, velocity, acceleration, effort) come from the Pinocchio model of the
  URDF; a URDF value that is absent, infinite or 0 (URDF's "not given" for effort and velocity) is
  read as "no limit" and noted; ``ExciteConfig.limits`` overrides per joint, ``acceleration`` gives
  the acceleration limit URDF cannot carry. Continuous joints have no position limit.
- The identification model is the one ``dualid fit`` uses: ``RigidBodyModel`` plus joint friction and
  armature (``with_joint_terms``), unless ``joint_terms`` is null. θ_nom: the URDF's inertials and its
  <dynamics damping friction> (armature 0 unless the Pinocchio model has one).
- Base parameters: dualid's regrouping (``dualid.identifiability.base_parameters``, QR with column
  pivoting of the column-scaled regressor) at random states within the limits, β = C θ.
- Criteria (all minimised), with W_i = Y_i[:, base] at the design samples i = 1..N:
    dm      −log det( Σ W_iᵀ M_i(θ_nom)⁻¹ W_i / N ): the dual-metric objective's Gauss–Newton information;
    logdet  −log det( Σ W_iᵀ W_i / N ): classic D-optimality;
    cond    log cond( W D ), W stacked, D scaling its columns to unit norm.
- The torque used for limits is the physical one of the URDF: rnea + damping·v + friction·tanh(v/v_c)
  + armature·a, with its exact Jacobian from ``pin.computeRNEADerivatives``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from dualid.errors import ConfigError, ModelError
from dualid.excite.config import ExciteConfig
from dualid.identifiability import BaseParameters, base_parameters
from dualid.model.joint_terms import JointTermsModel, with_joint_terms
from dualid.model.rigid_body import RigidBodyModel

LIMIT_KINDS = ("position", "velocity", "acceleration", "effort")
RANDOM_STATES = 300  # random samples for the base-parameter selection


@dataclass(frozen=True)
class Limits:
    """Per joint (n,) arrays; ±inf where there is no limit; ``notes`` say where each came from."""

    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    effort: np.ndarray
    notes: tuple[str, ...] = ()


def _finite(x: float) -> bool:
    return bool(np.isfinite(x) and abs(x) < 1e300)


def model_limits(rigid: RigidBodyModel, config: ExciteConfig) -> Limits:
    """The limits of the URDF's Pinocchio model with the config's overrides (see the module docstring)."""
    model, names = rigid.model, rigid.coordinates
    unknown = [j for j in config.limits if j not in names]
    if unknown:
        raise ConfigError(f"excite config: limits: unknown joints {unknown}; the model's joints are {list(names)}")
    n = len(names)
    lo, hi = np.full(n, -np.inf), np.full(n, np.inf)
    vel, acc, eff = np.full(n, np.inf), np.full(n, np.inf), np.full(n, np.inf)
    notes = []
    for j in range(1, model.njoints):
        joint, k = model.joints[j], model.joints[j].idx_v
        if joint.nq == 1 and _finite(model.lowerPositionLimit[joint.idx_q]) and _finite(model.upperPositionLimit[joint.idx_q]):
            lo[k], hi[k] = model.lowerPositionLimit[joint.idx_q], model.upperPositionLimit[joint.idx_q]
        for arr, src, what in ((vel, model.velocityLimit, "velocity"), (eff, model.effortLimit, "effort")):
            if _finite(src[k]) and src[k] > 0:
                arr[k] = src[k]
            elif src[k] == 0 and names[k] not in config.limits:
                notes.append(f"joint {names[k]!r}: the URDF's {what} limit is 0, read as 'not given'")
    for k, name in enumerate(names):
        override = config.limits.get(name)
        if override is not None:
            for key, arr in (("lower", lo), ("upper", hi), ("velocity", vel), ("acceleration", acc), ("effort", eff)):
                value = getattr(override, key)
                if value is not None:
                    arr[k] = value
        if not np.isfinite(acc[k]) and config.acceleration is not None:
            acc[k] = config.acceleration
        if lo[k] >= hi[k]:
            raise ConfigError(f"limits of joint {name!r}: lower {lo[k]} is not below upper {hi[k]}")
        missing = [kind for kind, arr in (("position", hi), ("velocity", vel), ("acceleration", acc), ("effort", eff))
                   if not np.isfinite(arr[k])]
        if missing:
            notes.append(f"joint {name!r}: no {', '.join(missing)} limit (none in the URDF or the config)")
    return Limits(lo, hi, vel, acc, eff, tuple(notes))


@dataclass(frozen=True, eq=False)
class Design:
    """Everything a criterion and the constraints need about one robot (see the module docstring)."""

    rigid: RigidBodyModel
    model: JointTermsModel | RigidBodyModel
    theta_nom: np.ndarray  # (p,)
    limits: Limits
    q_start: np.ndarray  # (n,)
    base: BaseParameters
    coulomb_velocity: float
    _pin: pin.Model = field(repr=False)  # the rigid model with armature 0 (joint terms are added here)
    _friction: tuple[np.ndarray, np.ndarray, np.ndarray] = field(repr=False)  # damping, friction, armature (n,)

    @property
    def n(self) -> int:
        return self.rigid.nv

    @property
    def joints(self) -> tuple[str, ...]:
        return self.rigid.coordinates

    # --- dynamics ---------------------------------------------------------------------------
    def regressor(self, q, v, a) -> np.ndarray:
        """Y (T, n, p) of the identification model."""
        return self.model.regressor(q, v, a)

    def mass_matrix(self, q) -> np.ndarray:
        """M_i(θ_nom) (T, n, n) from the model's affine metric."""
        return self.model.metric(q).evaluate(self.theta_nom)

    def torque(self, q, v, a, jacobian: bool = False):
        """Physical τ (T, n) [N m] (and ∂τ/∂q, ∂τ/∂v, ∂τ/∂a, each (T, n, n), when ``jacobian``)."""
        b, fc, Ia = self._friction
        qc = self.rigid.configuration(q)
        data = self._pin.createData()
        T = qc.shape[0]
        tau = np.empty((T, self.n))
        dq = dv = da = None
        if jacobian:
            dq, dv, da = (np.empty((T, self.n, self.n)) for _ in range(3))
        for t in range(T):
            if jacobian:
                dq[t], dv[t], da[t] = pin.computeRNEADerivatives(self._pin, data, qc[t], v[t], a[t])
                tau[t] = data.tau
            else:
                tau[t] = pin.rnea(self._pin, data, qc[t], v[t], a[t])
        sech2 = 1.0 - np.tanh(v / self.coulomb_velocity) ** 2
        tau += b * v + fc * np.tanh(v / self.coulomb_velocity) + Ia * a
        if not jacobian:
            return tau
        idx = np.arange(self.n)
        dv[:, idx, idx] += b + fc * sech2 / self.coulomb_velocity
        da[:, idx, idx] += Ia
        return tau, dq, dv, da

    # --- criteria ---------------------------------------------------------------------------
    def criterion(self, name: str, q, v, a) -> float:
        """The criterion (minimised) at the samples (q, v, a) (see the module docstring)."""
        W = self.base.regressor(self.regressor(q, v, a))  # (N, n, p_b)
        N = W.shape[0]
        if name == "cond":
            A = W.reshape(-1, W.shape[-1])
            s = np.linalg.svd(A / np.maximum(np.linalg.norm(A, axis=0), 1e-300), compute_uv=False)
            return float(np.log(s[0] / s[-1])) if s[-1] > 0 else float(np.inf)
        if name == "logdet":
            F = np.einsum("nap,naq->pq", W, W) / N
        elif name == "dm":
            L = np.linalg.cholesky(self.mass_matrix(q))
            Z = np.linalg.solve(L, W)  # L_i⁻¹ W_i
            F = np.einsum("nap,naq->pq", Z, Z) / N
        else:
            raise ConfigError(f"criterion: expected one of dm, logdet, cond, got {name!r}")
        sign, logdet = np.linalg.slogdet(F)
        return float(-logdet) if sign > 0 else float(np.inf)


def build_design(rigid: RigidBodyModel, config: ExciteConfig, seed: int = 0) -> Design:
    """The design problem of a fixed-base rigid-body model under ``config``."""
    if rigid.base_coordinates:
        raise ModelError("excite: the model has a floating base; excitation is designed for a fixed base only "
                         "(weld the base, or design the base motion yourself)")
    several = [rigid.model.names[j] for j in range(1, rigid.model.njoints) if rigid.model.joints[j].nv != 1]
    if several:
        raise ModelError(f"excite: joints {several} have more than one degree of freedom; only revolute, "
                         "prismatic and continuous joints are supported")
    limits = model_limits(rigid, config)
    names = rigid.coordinates
    unknown = [j for j in config.start if j not in names]
    if unknown:
        raise ConfigError(f"excite config: start: unknown joints {unknown}; the model's joints are {list(names)}")
    mid = np.where(np.isfinite(limits.lower) & np.isfinite(limits.upper), 0.5 * (limits.lower + limits.upper), 0.0)
    q_start = np.array([config.start.get(j, mid[k]) for k, j in enumerate(names)])
    outside = [j for k, j in enumerate(names) if not limits.lower[k] <= q_start[k] <= limits.upper[k]]
    if outside:
        raise ConfigError(f"excite config: start: joints {outside} are outside their position limits")
    model: JointTermsModel | RigidBodyModel = rigid
    pm = pin.Model(rigid.model)
    damping, friction, armature = (np.array(x, dtype=float) for x in (pm.damping, pm.friction, pm.armature))
    pm.armature[:] = 0.0
    theta = [rigid.nominal]
    vc = 0.01
    if config.joint_terms is not None:
        jt = config.joint_terms
        vc = jt.coulomb_velocity
        model = with_joint_terms(rigid, jt.viscous, jt.coulomb, jt.armature, coulomb_velocity=vc)
        theta += [x for flag, x in ((jt.viscous, damping), (jt.coulomb, friction), (jt.armature, armature)) if flag]
    theta_nom = np.concatenate(theta)
    rng = np.random.default_rng(seed)
    q, v, a = random_states(rng, limits, q_start, RANDOM_STATES)
    Y = model.regressor(q, v, a)  # (T, n, p)
    base = base_parameters(Y.reshape(-1, Y.shape[-1]), model.parameters)
    design = Design(rigid, model, theta_nom, limits, q_start, base, vc, pm, (damping, friction, armature))
    tau0 = design.torque(q_start[None], np.zeros((1, len(names))), np.zeros((1, len(names))))[0]
    over = [j for k, j in enumerate(names) if abs(tau0[k]) > limits.effort[k]]
    if over:
        raise ConfigError(f"excite: holding the start configuration needs more than the effort limit at joints {over} "
                          f"(τ = {np.round(tau0, 4).tolist()}); choose another 'start'")
    return design


def random_states(rng: np.random.Generator, limits: Limits, center: np.ndarray, T: int):
    """(q, v, a), each (T, n): uniform within the limits (±π around ``center``, ±1 where unlimited)."""
    lo = np.where(np.isfinite(limits.lower), limits.lower, center - np.pi)
    hi = np.where(np.isfinite(limits.upper), limits.upper, center + np.pi)
    vmax = np.where(np.isfinite(limits.velocity), limits.velocity, 1.0)
    amax = np.where(np.isfinite(limits.acceleration), limits.acceleration, 1.0)
    n = center.size
    return (rng.uniform(lo, hi, (T, n)), rng.uniform(-vmax, vmax, (T, n)), rng.uniform(-amax, amax, (T, n)))
