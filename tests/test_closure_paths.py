"""Every path of dm's weighted fit is made on the closed feasible set (model.closure), and the closure
finds the unseen mass also where rounding leaves its regressor column not exactly zero.

- the weighted Newton fit whose cheap start fails (a bound the central point violates): before, ``quadratic_fit.fit_weighted``
  refitted the materialised constant metric without the closure (j0.m = 3.5·10⁹ kg where rounding left it);
- a cvxpy answer that the Newton polish certified within ``quadratic_newton.TOL``: before, it was returned as it was (j0.m =
  1.7·10⁷ kg where Clarabel stopped, no completion note);
- a tilted first joint with its link's parameters taken about a point of the axis (a link frame, not the joint
  frame): the mass column of Y is rounding (H_mm = 7e-38·c), the rule "row exactly 0" missed the ray and the fit
  stopped along it (j0.m = 1,323 kg; the two charts' objectives 6.7e-8 apart);
- dm's OLS/WLS pilot when both Newton fits fail: before, the library's OLS/WLS by cvxpy (original set).
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from dualid.estimators.methods import make_estimator
from dualid.estimators.quadratic_fit import fit_weighted
from dualid.model.closure import NOT_DETERMINED, ZERO_CURVATURE, close, complete
from dualid.model.consistency import feasible_set
from dualid.model.metric import AffineMetric

sys.path.insert(0, str(Path(__file__).parent))
from test_unattained_closure import EXTRA, A, _fit_data, _problem  # noqa: E402

F_INF = 2 * A**2 + 2 * EXTRA  # the infimum of the one-body problem (Izz → 0 as j0.m → ∞)


def _smallest(problem, theta, k) -> bool:
    """θ_k is the completed value: its block is consistent and on its boundary (smallest eigenvalue ≤ 1e-8 of the
    largest: closure.SLACK), and 1 % less of it is inconsistent."""
    block = feasible_set(problem.parameters, True).lmis[0]
    lam = np.linalg.eigvalsh(block.C(theta))
    lower = theta.copy()
    lower[k] *= 0.99
    return 0 < lam[0] <= 1e-8 * lam[-1] and np.linalg.eigvalsh(block.C(lower))[0] < 0


def test_the_weighted_fit_whose_cheap_start_fails_is_made_on_the_closed_set():
    problem, names = _problem()
    lower = np.full(problem.p, -np.inf)
    lower[names.index("j0.Iyy")] = 100.0  # Iyy ≫ Ixx + Izz at the central point: its block is indefinite there
    bounded = dataclasses.replace(problem, parameters=problem.parameters.with_bounds(lower, np.full(problem.p, np.inf)))
    common = dict(constrained=True, solver="newton", solver_options={}, allow_unidentifiable=True)
    result = fit_weighted(bounded, np.ones((1, 1, 1)), "dm", common, {})
    assert result.info["start"] == "phase-I" and result.solver == "newton"
    assert result.info["projected_parameters"].startswith("j0.m = ")  # before: none, j0.m = 3.5e9 kg
    assert bounded.parameters.is_consistent(result.theta)
    assert result.objective == pytest.approx(F_INF, rel=1e-9)


def test_close_counts_a_rounding_level_row_as_unseen_relative_to_f0():
    space, H, names = _fit_data()
    cons = feasible_set(space, True)
    m = names.index("j0.m")
    c = 1e6  # f(0) of the fit; H's seen diagonal is 1
    for h_mm, projected in ((0.0, True), (1e-34 * c, True), (0.5 * ZERO_CURVATURE * c, True),
                            (2 * ZERO_CURVATURE * c, False), (1e-12 * c, False)):
        H2 = H.copy()
        H2[m, m] = h_mm
        assert [names[p.k] for p in close(cons, H2, c)[1]] == (["j0.m"] if projected else []), h_mm
    # the scale is f(0): the same H is "seen" against a small c and "unseen" against a large one (units of f)
    H2 = H.copy()
    H2[m, m] = 1e-20
    assert close(cons, H2, 1.0)[1] == () and len(close(cons, H2, 1e6)[1]) == 1


def test_the_completed_value_is_said_to_be_not_determined_by_the_data():
    space, H, names = _fit_data()
    cons = feasible_set(space, True)
    _, projected = close(cons, H, 1.0)
    theta = np.zeros(space.p)
    theta[[names.index(n) for n in ("j0.Ixx", "j0.Iyy", "j0.Izz")]] = 1.0
    theta[names.index("j0.mc_x")] = 0.5
    _, info = complete(theta, cons, projected, names)
    assert info["projected_names"] == ["j0.m"]
    assert info["projected_parameters"].endswith(f"({NOT_DETERMINED})")
    assert NOT_DETERMINED == "not determined by the data: the smallest value consistent with the other parameters"
    assert info["projected_note"].startswith(f"{NOT_DETERMINED}, not an estimate")


# --- a tilted first joint, its link's parameters about a point of the axis ------------------------------------------
def _skew(x):
    return np.array([[0, -x[2], x[1]], [x[2], 0, -x[0]], [-x[1], x[0], 0]])


def _link_to_joint(R: np.ndarray, d: np.ndarray) -> np.ndarray:
    """T (10, 10), θ_joint = T θ_link, for parameters (m, mc, Ixx Ixy Iyy Ixz Iyz Izz) about a frame (R, d) of the
    joint frame: mc = R mc' + m d, I = R I' Rᵀ − m [d]ₓ² − [d]ₓ[R mc']ₓ − [R mc']ₓ[d]ₓ."""
    T = np.zeros((10, 10))
    for k in range(10):
        e = np.eye(10)[k]
        Ip = np.array([[e[4], e[5], e[7]], [e[5], e[6], e[8]], [e[7], e[8], e[9]]])
        mc = R @ e[1:4]
        I = R @ Ip @ R.T - e[0] * _skew(d) @ _skew(d) - _skew(d) @ _skew(mc) - _skew(mc) @ _skew(d)
        T[:, k] = [e[0], *(mc + e[0] * d), I[0, 0], I[0, 1], I[1, 1], I[0, 2], I[1, 2], I[2, 2]]
    return T


def _tilted(model: pin.Model, axis: np.ndarray) -> pin.Model:
    """The same arm with its first joint turning about ``axis`` (of its joint frame)."""
    out = pin.Model()
    out.gravity = model.gravity
    kinds = {"JointModelRX": pin.JointModelRX, "JointModelRY": pin.JointModelRY, "JointModelRZ": pin.JointModelRZ}
    for j in range(1, model.njoints):
        joint = pin.JointModelRevoluteUnaligned(axis) if j == 1 else kinds[model.joints[j].shortname()]()
        out.addJoint(model.parents[j], joint, model.jointPlacements[j], model.names[j])
        out.appendBodyToJoint(j, model.inertias[j], pin.SE3.Identity())
    return out


def test_dm_closes_the_ray_of_a_tilted_first_joint_whose_mass_column_is_rounding():
    """The statistical benchmark's sensor-case arm (5 DoF, seed 2, where j0.m runs off) with its first axis tilted
    and j0's parameters about a point 0.12 m up that axis in a rotated frame: analytically Y's j0.m column is 0
    (the mass's torques about the axis cancel), numerically 1e-19 of the torques."""
    from dualid.bench import arms as sb
    from dualid.model.joint_terms import with_joint_terms
    from dualid.model.rigid_body import RigidBodyModel
    from dualid.problem import build_problem

    seed, N = 2, 3000
    axis = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
    arm = sb.random_arm(np.random.default_rng([seed, 0]), 3 + seed % 5)
    ident = with_joint_terms(RigidBodyModel(_tilted(arm.ident.base.model, axis)), viscous=True, coulomb=True,
                             armature=True, coulomb_velocity=sb.COULOMB_VELOCITY)
    arm = sb.Arm(_tilted(arm.true_model, axis), arm.viscous, arm.coulomb, arm.armature, ident, arm.theta_true)
    kw = dict(case="sensor", case_seed=seed * 1000 + 7)
    runs = [sb.make_run(arm, np.random.default_rng([seed, 3, h]), N / 2 / sb.FS, 0.02, payload=h == 1, name=f"t{h}",
                        **kw) for h in range(2)]
    joint = build_problem(arm.ident, [r.measured for r in runs])
    T = _link_to_joint(sb._rotation(np.random.default_rng(5), 1.0), 0.12 * axis)
    Y = joint.Y.copy()
    Y[..., :10] = joint.Y[..., :10] @ T
    M0, Mk = joint.metric.basis()
    Mk[:, :10] = np.einsum("nkab,kl->nlab", Mk[:, :10], T)
    train = dataclasses.replace(joint, Y=Y, metric=AffineMetric.from_dense(Mk, M0))
    H, c = np.einsum("nap,naq->pq", train.Y, train.Y), float(np.sum(train.tau**2))
    assert 0 < H[0, 0] < 1e-30 * c  # rounding, not 0: the exact-zero rule did not project j0.m

    B = sb.rechart(np.random.default_rng([seed, 9]), np.concatenate([r.measured.q for r in runs]))
    est = make_estimator("dm", allow_unidentifiable=True)
    a, b = est.fit(train), est.fit(train.in_coordinates(B))
    assert a.info["projected_parameters"].startswith("j0.m = ")  # before the closure: 1,323 kg, a stopping point
    assert list(a.not_determined()) == ["j0.m"] and list(b.not_determined()) == ["j0.m"]
    assert b.objective == pytest.approx(a.objective, rel=1e-6)  # dm re-estimates its noise levels in each chart
    Yt = train.Y.reshape(-1, train.p)
    tau = Yt @ a.theta
    assert np.linalg.norm(Yt @ b.theta - tau) <= 1e-6 * np.linalg.norm(tau)
