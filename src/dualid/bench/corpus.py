"""The stress corpus of identification problems; the driver is benchmarks/stress_corpus.py.

Every problem is built with Pinocchio from random states (configurations from ``pin.randomConfiguration``,
velocities and accelerations N(0, 1)), τ = Y θ_true + noise · rms(τ_j) · N(0, 1) per coordinate j, and the mass
matrix as the metric. Families:

- random serial chains of 2–12 joints mixing revolute (RX/RY/RZ), prismatic (PX/PY/PZ) and continuous
  (revolute unbounded, Pinocchio's RUBX/RUBY/RUBZ: nq = 2) joints, box-shaped links;
- the Crazyflie–pendulum (``systems.crazyflie_model``, floating base);
- rank-deficient data (N from 12 samples);
- constraints active at the truth: a point-mass link (pseudo-inertia of rank 1) and a nearly massless one;
- exact data and 0–20 % torque noise; one coordinate in units scaled by 1e-6 … 1e6 (a constant diagonal chart).

No file is written here; ``cases`` lists (name, builder) pairs and ``problem`` builds one by name.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from dualid.errors import ConfigError

JOINTS = {
    "R": (pin.JointModelRX, pin.JointModelRY, pin.JointModelRZ),
    "P": (pin.JointModelPX, pin.JointModelPY, pin.JointModelPZ),
    "C": (pin.JointModelRUBX, pin.JointModelRUBY, pin.JointModelRUBZ),
}


def random_chain(rng: np.random.Generator, kinds: str, point_mass: int | None = None,
                 massless: int | None = None) -> pin.Model:
    """A serial chain, one joint per letter of ``kinds`` ("R" revolute, "P" prismatic, "C" continuous), random
    axes and box links; link ``point_mass`` (index) is a point mass (rank-1 pseudo-inertia, on the consistency
    boundary), link ``massless`` weighs 1e-6 of the others."""
    if not kinds or any(k not in JOINTS for k in kinds):
        raise ConfigError(f"random_chain: kinds must be a non-empty string of R, P, C, got {kinds!r}")
    model, parent = pin.Model(), 0
    for j, kind in enumerate(kinds):
        joint = JOINTS[kind][int(rng.integers(3))]()
        w = rng.normal(size=3)
        R = pin.exp3(w / np.linalg.norm(w) * rng.uniform(0, 0.3))
        offset = np.array([*rng.uniform(-0.05, 0.05, 2), rng.uniform(0.1, 0.4) if j else 0.0])
        parent = model.addJoint(parent, joint, pin.SE3(R, offset), f"j{j}")
        mass = rng.uniform(0.3, 3.0)
        length = rng.uniform(0.1, 0.4)
        com = np.array([*rng.uniform(-0.03, 0.03, 2), rng.uniform(0.3, 0.7) * length])
        if j == point_mass:
            inertia = pin.Inertia(mass, com, np.zeros((3, 3)))
        else:
            a, b = rng.uniform(0.02, 0.1, 2)
            inertia = pin.Inertia(mass, com, mass / 12 * np.diag([b * b + length**2, a * a + length**2, a * a + b * b]))
        if j == massless:
            inertia = pin.Inertia(1e-6 * mass, com, 1e-6 * np.array(inertia.inertia))
        model.appendBodyToJoint(parent, inertia, pin.SE3.Identity())
    return model


def simulate(model: pin.Model, N: int, noise: float, seed: int, units: tuple[int, float] | None = None):
    """The identification problem of ``model`` (true inertias) at N random states (see the module doc);
    units = (coordinate k, factor): coordinate k re-expressed in units scaled by the factor (B = diag, B_kk = factor)."""
    from dualid.model.rigid_body import RigidBodyModel
    from dualid.problem import IdentificationProblem, owned

    rb = RigidBodyModel(model)
    pin.seed(seed)
    rng = np.random.default_rng(seed)
    lo, hi = -np.ones(model.nq), np.ones(model.nq)
    q = np.stack([pin.randomConfiguration(rb.model, lo, hi) for _ in range(N)])
    v, a = rng.normal(size=(2, N, model.nv))
    Y = rb.regressor(q, v, a)  # (N, n, p)
    tau = Y @ rb.nominal
    tau += noise * np.sqrt(np.mean(tau**2, axis=0)) * rng.normal(size=tau.shape)
    problem = IdentificationProblem(owned(Y), tau, rb.metric(q), v, rb.parameters, coordinates=rb.coordinates)
    if units is not None:
        B = np.eye(problem.n)
        B[units[0], units[0]] = units[1]
        problem = problem.in_coordinates(B, problem.coordinates)
    return problem, rb.nominal


def cad_prior(theta: np.ndarray, seed: int) -> np.ndarray:
    """A CAD-like prior: each body's mass, first moment and rotational inertia off by a factor in [0.7, 1.3]
    (physically consistent: a positive multiple of a consistent body's parts is re-assembled by Pinocchio)."""
    rng = np.random.default_rng([seed, 7])
    out = []
    for b in range(theta.size // 10):
        I = pin.Inertia.FromDynamicParameters(theta[10 * b:10 * b + 10])
        m = I.mass * rng.uniform(0.7, 1.3)
        Ic = np.array(I.inertia) * rng.uniform(0.7, 1.3) + 1e-6 * max(I.mass, 1e-9) * np.eye(3)
        out.append(pin.Inertia(m, np.array(I.lever) * rng.uniform(0.7, 1.3), Ic).toDynamicParameters())
    return np.concatenate(out)


@dataclass(frozen=True)
class Case:
    name: str
    family: str
    build: Callable[[], tuple]  # () -> (problem, θ_true) or (problem, θ_true or None, prior)
    sdp: bool = True  # the SDP reference is affordable (small N)
    quick: bool = False  # in the fast test subset
    methods: tuple[str, ...] | None = None  # None: every method; else only these (large N: no SDP, no prior fits)


def _chain(seed, kinds, N, noise, units=None, **kw):
    return lambda: simulate(random_chain(np.random.default_rng(seed), kinds, **kw), N, noise, seed, units)


def _crazyflie(N, noise, units=None):
    def build():
        from dualid.systems.crazyflie_model import build_model

        return simulate(build_model(), N, noise, 11, units)
    return build


def cases(large: bool = True) -> list[Case]:
    """The corpus (names are unique); ``large`` adds the N = 1e5 and 1e6 problems. Real DFKI data, the paper's
    systems and N = 1e6: ``corpus_extra``."""
    from dualid.bench.corpus_extra import (
        DEFAULT_PREPROCESSING,
        DFKI,
        EXAMPLE_PREPROCESSING,
        SCALABLE,
        chain_tiled,
        dfki,
        system,
    )

    out = [
        Case("chain RR, 2 dof, exact", "chain", _chain(1, "RR", 200, 0.0), quick=True),
        Case("chain RPR, 3 dof, 5 %", "chain", _chain(2, "RPR", 200, 0.05), quick=True),
        Case("chain CRP, 3 dof, 20 %", "chain", _chain(3, "CRP", 300, 0.20)),
        Case("chain RRPRC, 5 dof, 5 %", "chain", _chain(4, "RRPRC", 300, 0.05)),
        Case("chain 7 dof RRRRRRR, 10 %", "chain", _chain(5, "RRRRRRR", 300, 0.10)),
        Case("chain 8 dof mixed, 2 %", "chain", _chain(6, "RPRCRRPR", 300, 0.02)),
        Case("chain 12 dof mixed, 5 %", "chain", _chain(7, "RRPRRCRRPRRR", 300, 0.05)),
        Case("rank-deficient 4 dof, N = 12", "rank-deficient", _chain(8, "RRPR", 12, 0.05), quick=True),
        Case("rank-deficient 6 dof, N = 30", "rank-deficient", _chain(9, "RRRCRR", 30, 0.05)),
        Case("point-mass link, 3 dof, 5 %", "active constraint", _chain(10, "RRR", 200, 0.05, point_mass=2),
             quick=True),
        Case("nearly massless link, 4 dof, 5 %", "active constraint", _chain(11, "RRRR", 200, 0.05, massless=1)),
        Case("units 1e-6 on q1, 3 dof, 5 %", "units", _chain(12, "RPR", 200, 0.05, units=(0, 1e-6))),
        Case("units 1e6 on q1, 3 dof, 5 %", "units", _chain(12, "RPR", 200, 0.05, units=(0, 1e6)), quick=True),
        Case("crazyflie floating base, 5 %", "floating base", _crazyflie(300, 0.05)),
        Case("crazyflie, units 1e3 on q1, 5 %", "units", _crazyflie(300, 0.05, (0, 1e3))),
        Case("chain 5 dof, N = 5000, 5 %", "large N", _chain(13, "RRPRC", 5000, 0.05), sdp=False),
    ]
    if large:
        out.append(Case("crazyflie, N = 1e5, 5 %", "large N", _crazyflie(100_000, 0.05), sdp=False))
    if DFKI.is_dir():  # real logs, in the source tree only
        out += [Case("DFKI pendubot runs 00-03 tiled x10, default preprocessing", "real data",
                     dfki(DEFAULT_PREPROCESSING), sdp=False),
                Case("DFKI pendubot runs 00-03 tiled x10, example preprocessing", "real data",
                     dfki(EXAMPLE_PREPROCESSING), sdp=False)]
    out += [Case("crazyflie system (paper), realistic noise", "paper system", system("crazyflie")),
            Case("landsalp system (paper), realistic noise", "paper system", system("landsalp"))]
    if large:
        chain = lambda: random_chain(np.random.default_rng(14), "RP")  # noqa: E731
        out.append(Case("chain RP, 2 dof, N = 1e6, 5 %", "large N", chain_tiled(chain, 14, 10_000, 100, 0.05),
                        sdp=False, methods=SCALABLE))
    return out


def problem(name: str):
    """(problem, θ_true) of the corpus case ``name``."""
    for c in cases():
        if c.name == name:
            return c.build()
    raise ConfigError(f"unknown corpus case {name!r}; known: {', '.join(c.name for c in cases())}")


def with_mass_bounds(problem, bound: float = 10.0):
    """The problem with every mass ≤ bound (kg) and the first link's first moments in [−bound, bound] (kg m): the
    well-posed version of the corpus problems whose dual-metric infimum is not attained (j0.m → ∞)."""
    from dataclasses import replace

    P = problem.parameters
    lo = np.asarray(P.lower if P.lower is not None else [-np.inf] * problem.p, dtype=float).copy()
    hi = np.asarray(P.upper if P.upper is not None else [np.inf] * problem.p, dtype=float).copy()
    for i, n in enumerate(P.names):
        if n.endswith(".m"):
            hi[i] = min(hi[i], bound)
        if n.startswith("j0.mc"):
            lo[i], hi[i] = max(lo[i], -bound), min(hi[i], bound)
    return replace(problem, parameters=P.with_bounds(lo, hi))
