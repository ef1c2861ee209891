"""The faster kernels of the Newton fit against independent references."""

import numpy as np
import pytest
import scipy.linalg

from dualid import WLS, DualMetric
from dualid.bench.runner import base_samples, build_problem
from dualid.estimators.least_squares import wls_reference
from dualid.estimators.newton.objective import statistics
from dualid.metric_guard import guard_info
from dualid.model.consistency import feasible_set, max_step_blocks, max_step_psd_batched


@pytest.fixture(scope="module")
def arm7(tmp_path_factory):
    return build_problem(base_samples("arm7", tmp_path_factory.mktemp("bench"), 150), 150)


def _spd(rng, m):
    A = rng.standard_normal((m, m))
    return A @ A.T + 0.1 * np.eye(m)


def test_the_batched_max_step_is_the_generalised_eigenvalue_bound():
    rng = np.random.default_rng(0)
    X = np.stack([_spd(rng, 4) for _ in range(5)])
    dX = np.stack([0.5 * (A + A.T) for A in rng.standard_normal((5, 4, 4))])
    # reference: X + α dX ≻ 0 ⇔ α < −1/λ_min(dX, X), scipy's generalised symmetric eigenproblem per block
    lam = min(scipy.linalg.eigh(d, x, eigvals_only=True)[0] for x, d in zip(X, dX))
    assert max_step_psd_batched(X, dX) == pytest.approx(-1.0 / lam, rel=1e-10)
    assert max_step_blocks([X[2]], [dX[2]]) == pytest.approx(
        -1.0 / scipy.linalg.eigh(dX[2], X[2], eigvals_only=True)[0], rel=1e-10)
    # blocks of two sizes (a body's 4×4 beside a joint's 1×1: 1 − α > 0 ⇔ α < 1), one batched call per size
    assert max_step_blocks(list(X) + [np.eye(1)], list(dX) + [-np.eye(1)]) == pytest.approx(min(-1.0 / lam, 1.0),
                                                                                            rel=1e-10)
    assert max_step_psd_batched(X, np.abs(dX) * 0 + np.eye(4)) == np.inf  # a PSD direction never leaves the cone


def test_the_lmi_matrices_match_their_definitions(arm7):
    cons = feasible_set(arm7.parameters, True)
    rng = np.random.default_rng(1)
    theta = rng.standard_normal(arm7.p)
    for c in cons.lmis:
        expected = c.C0 + sum(t * V for t, V in zip(theta[c.idx], c.V))
        np.testing.assert_allclose(c.C(theta), expected, rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(c.dC(theta), expected - c.C0, rtol=1e-14, atol=1e-14)
        np.testing.assert_array_equal(c.C(theta), c.C0 + np.tensordot(theta[c.idx], c.V, axes=1))  # bit for bit


def test_the_guard_reference_solves_the_same_wls_problem_as_cvxpy(arm7):
    theta, how = wls_reference(arm7, True)
    assert how == "newton (tol 1e-06)"
    cvx = WLS(allow_unidentifiable=True).fit(arm7)
    W = np.linalg.inv(np.asarray(cvx.info["covariance_matrix"]))
    stats = statistics(arm7, 0.5 * (W + W.T))
    # the same optimum of Σ rᵀWr under the constraints (θ itself may differ along the unidentifiable directions)
    assert stats.objective(arm7, theta) == pytest.approx(cvx.objective, rel=1e-5)  # to the reference's TOL
    assert feasible_set(arm7.parameters, True).margin(theta) > 0
    # and the dual-metric fit's recorded guard is the one measured against the cvxpy reference
    fit = DualMetric(allow_unidentifiable=True).fit(arm7)
    assert fit.info["metric_guard_solver"] == "newton (tol 1e-06)" and fit.info["metric_guard_reference"] == "wls fit"
    expected = guard_info(arm7, fit.theta, cvx.theta)
    for k in ("metric_ratio_min", "metric_ratio_max"):  # the reference to 1e-6 in f moves the ratios by ~3e-4 here;
        assert fit.info[k] == pytest.approx(expected[k], rel=1e-2)  # the guard's bound is a factor 100
