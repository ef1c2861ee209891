"""Small synthetic identification problems with known truth, for specification tests."""

from __future__ import annotations

import numpy as np

from dualid.model.metric import AffineMetric, MetricTerm
from dualid.model.parameters import ParameterBlock, ParameterSpace
from dualid.problem import IdentificationProblem


def drag_problem(rng: np.random.Generator, N: int = 60, n: int = 3, bodies: int = 3, noise: float = 0.0,
                 theta: np.ndarray | None = None):
    """τ_i = M_i(θ) v_i with M_i = Σ_b J_ibᵀ diag(θ_b) J_ib, random J_ib (3×n) and v_i; (problem, θ_true)."""
    p = 3 * bodies
    J = rng.standard_normal((bodies, N, 3, n))
    E = np.zeros((3, 3, 3))
    E[np.arange(3), np.arange(3), np.arange(3)] = 1.0
    terms = tuple(MetricTerm(tuple(range(3 * b, 3 * b + 3)), E, J[b]) for b in range(bodies))
    metric = AffineMetric(p, terms)
    if theta is None:
        theta = rng.uniform(0.5, 2.0, p)
    v = rng.standard_normal((N, n))
    Y = metric.apply(v)
    tau = Y @ theta + noise * rng.standard_normal((N, n))
    names = tuple(f"body{b}.{k}" for b in range(bodies) for k in ("d_long", "d_lat", "d_rot"))
    space = ParameterSpace(
        names, ("N s/m",) * p, tuple(ParameterBlock(f"body{b}", "drag_diagonal", (3 * b, 3 * b + 1, 3 * b + 2)) for b in range(bodies))
    )
    return IdentificationProblem(Y, tau, metric, v, space, "drag"), theta


def random_chart(rng: np.random.Generator, N: int, n: int, per_sample: bool, cond: float = 10.0) -> np.ndarray:
    """Invertible B ((n, n) or (N, n, n)) with singular values in [1/√cond, √cond]."""
    shape = (N, n, n) if per_sample else (n, n)
    U, _, Vt = np.linalg.svd(rng.standard_normal(shape))
    s = np.exp(rng.uniform(-0.5, 0.5, shape[:-1]) * np.log(cond))
    return U @ (s[..., None] * Vt)


def box_inertia(rng: np.random.Generator):
    """A physically consistent pin.Inertia: a solid box with random size, mass, offset and orientation."""
    import pinocchio as pin

    m = rng.uniform(0.1, 2.0)
    a, b, c = rng.uniform(0.05, 0.5, 3)
    I_box = m / 12 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    R = _rotation(rng)
    return pin.Inertia(m, rng.uniform(-0.2, 0.2, 3), R @ I_box @ R.T)


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def arm(n_joints: int = 3, floating: bool = False):
    """A Pinocchio chain of thin rods (nearly singular pseudo-inertias), revolute about alternating axes."""
    import pinocchio as pin

    model = pin.Model()
    parent = 0
    if floating:
        parent = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base")
        model.appendBodyToJoint(parent, pin.Inertia.FromBox(1.0, 0.2, 0.2, 0.1), pin.SE3.Identity())
    axes = [pin.JointModelRY(), pin.JointModelRX(), pin.JointModelRZ()]
    for j in range(n_joints):
        placement = pin.SE3(np.eye(3), np.array([0.0, 0.0, 0.3 if j else 0.1]))
        parent = model.addJoint(parent, axes[j % 3], placement, f"joint{j + 1}")
        rod = pin.Inertia.FromCylinder(0.5 - 0.1 * j, 0.005, 0.3)  # thin: near the consistency boundary
        model.appendBodyToJoint(parent, rod, pin.SE3(np.eye(3), np.array([0.0, 0.0, 0.15])))
    return model
