"""The scale-aware prior of the plausible parameters and its interior-point solve (evaluation.plausible_newton).

Specifications: (1) rounding a prior body keeps its mass and centre of mass, keeps it consistent and bounds the
ratio of its principal moments; (2) a massless prior body becomes the documented regularised body; (3) the joint-term
weights follow a parameter's unit (w × 1/s² when θ_k is written s times larger); (4) armatures at their bound in θ̂
and a prior floored relative to the torque — what made the Cholesky of the old metric fail — give a consistent θ in
the region, and the exact choice (level 0) no longer fails with a LinAlgError.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from dualid.evaluation.plausible_newton import MASSLESS_SHARE, ROUNDING, rounded_body, rounded_prior, torque_weights
from dualid.evaluation.plausible_region import plausible_in_region

sys.path.insert(0, str(Path(__file__).parent))
from test_plausible_region import _fit, _pendubot_problem  # noqa: E402 - its small pendubot problems


def test_rounding_keeps_mass_and_centre_and_bounds_the_moments():
    thin = pin.Inertia(0.7, np.array([0.01, -0.03, 0.1]), np.diag([1e-2, 1e-2, 1e-7]))  # a rod
    out = pin.Inertia.FromDynamicParameters(rounded_body(thin.toDynamicParameters()))
    assert out.mass == pytest.approx(0.7) and np.allclose(out.lever, thin.lever)
    moments = np.linalg.eigvalsh(out.inertia)
    assert moments.min() >= ROUNDING * np.trace(thin.inertia) / 3 * (1 - 1e-9)
    assert np.trace(out.inertia) == pytest.approx(np.trace(thin.inertia))


def test_a_massless_prior_body_becomes_the_regularised_body():
    problem, theta_true = _pendubot_problem(1)
    P = problem.parameters
    theta0 = theta_true.copy()
    theta0[10:20] = 0.0  # Link2 without inertial
    out = rounded_prior(P, theta0)
    assert P.is_consistent(out, tol=0.0)
    assert out[10] == pytest.approx(MASSLESS_SHARE * theta_true[0])  # a share of the other bodies' mean mass
    np.testing.assert_array_equal(out[11:14], 0.0)  # at the frame's origin
    np.testing.assert_array_equal(out[20:], theta0[20:])  # joint terms untouched


def test_joint_term_weights_follow_the_unit():
    problem, _ = _pendubot_problem(3)
    k, s = problem.parameters.index("Joint1.b"), 1000.0
    Y = np.array(problem.Y)
    Y[:, :, k] /= s
    w, w_s = torque_weights(problem), torque_weights(dataclasses.replace(problem, Y=Y))
    assert w_s[k] == pytest.approx(w[k] / s**2, rel=1e-12)
    np.testing.assert_allclose(np.delete(w_s, k), np.delete(w, k), rtol=1e-12)


def test_armatures_at_their_bound_do_not_break_the_step():
    problem, theta_true = _pendubot_problem(2)
    theta_hat, unc = _fit(problem)
    P = problem.parameters
    arm = [P.index("Joint1.Ia"), P.index("Joint2.Ia")]
    theta0 = theta_true.copy()
    theta0[:20] *= np.repeat([1.25, 0.8], 10)
    theta0[arm] = 1e-3 / np.sqrt(torque_weights(problem)[arm])  # the fit's floor (robot.prior.prior_theta)
    hat = theta_hat.copy()
    hat[arm] = 1e-11  # where the constrained fits put them
    region = plausible_in_region(problem, hat, theta0, unc, 0.95)
    assert region.consistent and region.statistic <= region.radius2 * (1 + 1e-4)
    exact = plausible_in_region(problem, hat, theta0, unc, 0.0)  # used to raise LinAlgError (Cholesky of N'GN)
    assert exact.form == "exact"
