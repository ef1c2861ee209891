"""dm's covariance structure chosen by time-blocked cross-validation (estimators/covariance_select.py,
FeasibleGLS(sigma_structure="auto")): folds, the choice on data with a known answer, invariance, record."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dualid.estimators.covariance_model import _gaussian_nll, full_likelihood_estimate
from dualid.estimators.covariance_select import SHRINK, blocked_folds, heldout_nll, select_structure, shrunk
from dualid.estimators.gls import FeasibleGLS
from tests.factories import drag_problem, random_chart
from tests.test_invariance import charts, rel

FIT = settings(max_examples=3, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def test_blocked_folds_are_contiguous_and_cover_every_sample_once():
    folds = blocked_folds(23, 5)
    assert [f.size for f in folds] == [5, 5, 5, 4, 4]
    np.testing.assert_array_equal(np.concatenate(folds), np.arange(23))
    assert all(np.all(np.diff(f) == 1) for f in folds)


def test_shrinkage_keeps_the_diagonal_and_scales_the_off_diagonal():
    S = np.array([[2.0, 0.8], [0.8, 1.0]])
    np.testing.assert_allclose(shrunk(S, 0.25), [[2.0, 0.6], [0.6, 1.0]])
    np.testing.assert_allclose(shrunk(S, 1.0), np.diag([2.0, 1.0]))


def test_heldout_nll_is_the_gaussian_negative_log_likelihood():
    rng = np.random.default_rng(0)
    r, M = rng.standard_normal((7, 2)), np.broadcast_to(np.diag([1.0, 3.0]), (7, 2, 2))
    S, k = np.array([[1.0, 0.3], [0.3, 2.0]]), 0.5
    C = S + k * M[0]
    ref = np.log(np.linalg.det(C)) + np.mean(np.einsum("na,ab,nb->n", r, np.linalg.inv(C), r))
    assert heldout_nll(S, k, r, M) == pytest.approx(ref, rel=1e-12)
    assert heldout_nll(-np.eye(2), 0.0, r, M) == np.inf and _gaussian_nll(-np.eye(2)[None] + 0 * M, r) is None


def _residuals(rng, N, L):
    n = L.shape[0]
    M = np.broadcast_to(np.eye(n), (N, n, n)) * rng.uniform(0.5, 2.0, (N, 1, 1))
    return rng.standard_normal((N, n)) @ L.T, M


def test_independent_coordinates_do_not_choose_the_full_model():
    """No correlation and few samples: the extra parameters of the full Σ only cost held-out likelihood."""
    rng = np.random.default_rng(1)
    r, M = _residuals(rng, 60, np.diag([1.0, 0.7, 1.3, 0.9, 1.1]))
    S, k, info = select_structure(r, M, 1e-9)
    crit = info["sigma_structure_criterion"]
    assert set(crit) == {"diagonal", "full", *(f"shrink {x:g}" for x in SHRINK)}
    assert crit["full"] > crit["diagonal"] and info["sigma_structure"] == min(crit, key=crit.get) == "shrink 0.75"
    S_full, k_full, _ = full_likelihood_estimate(r, M, 1e-9)  # refitted on all samples, then shrunk
    np.testing.assert_allclose(S, shrunk(S_full, 0.75))
    assert k == k_full


def test_strongly_correlated_coordinates_choose_the_full_model():
    rng = np.random.default_rng(2)
    L = np.array([[1.0, 0, 0], [0.95, 0.3, 0], [0.9, -0.2, 0.2]])
    r, M = _residuals(rng, 2000, L)
    S, k, info = select_structure(r, M, 1e-9)
    assert info["sigma_structure"] == "full" and info["sigma_structure_folds"] == 5
    np.testing.assert_allclose(S, full_likelihood_estimate(r, M, 1e-9)[0])
    crit = info["sigma_structure_criterion"]
    assert crit["full"] < crit["shrink 0.25"] < crit["shrink 0.75"] < crit["diagonal"]


def test_too_few_samples_fall_back_to_the_diagonal_model_and_say_so():
    rng = np.random.default_rng(3)
    r, M = _residuals(rng, 3, np.eye(2))
    _, _, info = select_structure(r, M, 1e-9)
    assert info["sigma_structure"] == "diagonal"
    assert info["sigma_structure_reason"] == "auto: 3 samples, too few to cross-validate; the diagonal model"


@FIT
@given(st.integers(0, 2**31 - 1))
def test_auto_fit_is_the_same_in_every_chart(seed):
    rng = np.random.default_rng(seed)
    problem, _ = drag_problem(rng, N=40, n=3, noise=0.3)
    est = FeasibleGLS(sigma_structure="auto", select="none")  # the GLS fit's own covariance record
    base = est.fit(problem)
    assert base.info["sigma_structure"] in base.info["sigma_structure_criterion"]
    cs = charts(rng, problem)
    cs["units_extreme"] = np.diag([1e-6, 1.0, 1e6])
    cs["composed"] = random_chart(rng, problem.N, 3, per_sample=True) @ np.diag([1e-6, 1.0, 1e6])
    for name, B in cs.items():
        fit = est.fit(problem.in_coordinates(B))
        assert fit.info["sigma_structure"] == base.info["sigma_structure"], name
        assert rel(fit.theta, base.theta) < 1e-6, name
        assert rel(fit.objective, base.objective) < 1e-6, name
