"""Extra affine terms (models/extra_terms.py): linear base drag checked against Pinocchio's RNEA with fext."""

import numpy as np
import pinocchio as pin
import pytest

from dualid import OLS
from dualid.data.trajectory import Trajectory
from dualid.model.extra_terms import ExtraTermsModel, LinearBaseDrag, with_base_drag
from dualid.model.rigid_body import RigidBodyModel
from dualid.problem import build_problem
from tests.factories import arm


def states(model, T, rng):
    pin.seed(int(rng.integers(1 << 30)))
    q = np.stack([pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq)) for _ in range(T)])
    return q, rng.normal(size=(T, model.nv)), rng.normal(size=(T, model.nv))


def rnea_with_drag(model, q, v, a, d):
    """τ = RNEA with the drag force −d ⊙ v_lin on the free-flyer body (LOCAL frame)."""
    data = model.createData()
    out = []
    for qt, vt, at in zip(q, v, a):
        fext = pin.StdVec_Force()
        for j in range(model.njoints):
            fext.append(pin.Force.Zero())
        fext[1] = pin.Force(-d * vt[:3], np.zeros(3))
        out.append(pin.rnea(model, data, qt, vt, at, fext).copy())
    return np.array(out)


def test_base_drag_regressor_matches_rnea_with_the_drag_force():
    rng = np.random.default_rng(0)
    pm = arm(2, floating=True)
    model = with_base_drag(RigidBodyModel(pm))
    q, v, a = states(pm, 25, rng)
    d = np.array([0.3, 0.7, 1.1])
    theta = np.concatenate([RigidBodyModel(pm).nominal, d])
    np.testing.assert_allclose(model.regressor(q, v, a) @ theta, rnea_with_drag(pm, q, v, a, d), rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(model.bias_regressor(q, v) @ theta, rnea_with_drag(pm, q, v, 0 * a, d), rtol=1e-10, atol=1e-10)
    # the metric is the rigid body's: the drag parameters do not enter it
    M = model.metric(q).evaluate(theta)
    np.testing.assert_allclose(M, RigidBodyModel(pm).metric(q).evaluate(theta[:-3]), rtol=1e-12)
    assert model.parameters.names[-3:] == ("base_drag.d_vx", "base_drag.d_vy", "base_drag.d_vz")
    assert model.parameters.is_consistent(theta) and not model.parameters.is_consistent(np.concatenate([theta[:-3], [-1, 0, 0]]))


def test_base_drag_is_identified_from_exact_data():
    rng = np.random.default_rng(1)
    pm = arm(1, floating=True)
    model = with_base_drag(RigidBodyModel(pm))
    q, v, a = states(pm, 60, rng)
    d = np.array([0.05, 0.2, 0.4])
    tau = rnea_with_drag(pm, q, v, a, d)
    problem = build_problem(model, Trajectory(np.arange(60) * 0.01, q, v, tau, a=a, coordinates=model.coordinates,
                                              name="run"))
    fit = OLS(constrained=False, allow_unidentifiable=True).fit(problem)
    np.testing.assert_allclose(fit.theta[model.extra_indices], d, rtol=1e-8)


def test_base_drag_needs_a_floating_base():
    with pytest.raises(ValueError, match="floating-base"):
        with_base_drag(RigidBodyModel(arm(2)))
    with pytest.raises(ValueError, match="at least one"):
        ExtraTermsModel(RigidBodyModel(arm(1, floating=True)), ())
    assert LinearBaseDrag() == LinearBaseDrag()
