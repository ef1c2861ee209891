"""Every estimator records the metric guard itself: against a given θ_ref, else its own pilot or prior."""

import numpy as np
import pytest

from dualid import OLS, WLS, DualMetric
from dualid.errors import ConfigError, DataError
from dualid.estimators.methods import METHODS, make_estimator
from dualid.metric_guard import guard_info
from tests.factories import drag_problem, random_chart

# what each method measures against when no guard_reference is given
REFERENCES = {
    "ols": None, "ols_unconstrained": None, "energy": None, "wls": "pilot (ols)", "logdet": "prior θ₀",
    "pullback": "prior θ₀", "dm": "pilot (unit-free least squares)", "dm-paper": "wls fit",
}


@pytest.fixture(scope="module")
def problem():
    return drag_problem(np.random.default_rng(3), N=80, n=3, noise=0.2)


def test_the_table_of_references_covers_every_method():
    assert set(REFERENCES) == set(METHODS) - {"truth"}


@pytest.mark.parametrize("key", sorted(REFERENCES))
def test_every_method_records_its_guard(problem, key):
    prob, theta = problem
    est = make_estimator(key, theta0=theta * 1.2 if METHODS[key].needs_prior else None)
    info = est.fit(prob).info
    ref = REFERENCES[key]
    if ref is None:  # nothing to measure against: said so, nothing flagged
        assert info["metric_guard_reference"].startswith("none") and "degenerate" not in info
        return
    assert info["metric_guard_reference"].startswith(ref)
    assert 1e-2 < info["metric_ratio_min"] <= info["metric_ratio_max"] < 1e2 and info["degenerate"] is False


@pytest.mark.parametrize("cls", [OLS, WLS, DualMetric])
def test_a_given_reference_is_used_and_a_blown_up_metric_is_flagged(problem, cls):
    prob, theta = problem
    small = cls(guard_reference=theta * 1e-3).fit(prob)  # against a metric 1000× smaller: the fit looks ×1000
    assert small.info["metric_guard_reference"] == "given guard_reference" and small.info["degenerate"] is True
    expected = guard_info(prob, small.theta, theta * 1e-3)
    assert small.info["metric_ratio_max"] == pytest.approx(expected["metric_ratio_max"], rel=1e-12)
    assert small.info["metric_ratio_min"] > 100
    # a wider bound accepts it
    assert cls(guard_reference=theta * 1e-3, guard_bound=1e4).fit(prob).info["degenerate"] is False


def test_the_recorded_guard_is_the_same_in_every_chart(problem):
    prob, theta = problem
    B = random_chart(np.random.default_rng(4), prob.N, prob.n, True)
    a = DualMetric(guard_reference=theta).fit(prob).info
    b = DualMetric(guard_reference=theta).fit(prob.in_coordinates(B)).info
    for k in ("metric_ratio_min", "metric_ratio_max"):
        assert b[k] == pytest.approx(a[k], rel=1e-6)


@pytest.mark.parametrize(
    "make, error, match",
    [
        (lambda: OLS(guard_bound=1.0), ConfigError, r"^OLS: guard_bound: expected a finite number > 1"),
        (lambda: WLS(guard_reference=[1.0, np.nan]), ConfigError, r"^WLS: guard_reference must be a finite vector"),
        (lambda: DualMetric(guard_bound="x"), ConfigError, r"^DualMetric: guard_bound: expected a finite number > 1"),
    ],
)
def test_guard_options_are_checked_in_the_constructor(make, error, match):
    with pytest.raises(error, match=match):
        make()


def test_a_reference_of_the_wrong_size_is_a_data_error(problem):
    prob, _ = problem
    with pytest.raises(DataError, match=r"^OLS: guard_reference has 2 entries, the problem has p = 9 parameters$"):
        OLS(guard_reference=[1.0, 2.0]).fit(prob)


def test_a_large_problem_is_guarded_on_evenly_strided_samples(problem, monkeypatch):
    """Above GUARD_SAMPLES the recorded guard is that of every k-th sample, and says how many it looked at."""
    import dualid.metric_guard as mg

    prob, theta = problem
    monkeypatch.setattr(mg.guard_sample, "__defaults__", (30,))  # 80 samples > 30: every 3rd, 27 samples
    info = DualMetric(guard_reference=theta * 1e-3).fit(prob).info
    expected = guard_info(prob.subset(slice(0, None, 3)), DualMetric().fit(prob).theta, theta * 1e-3)
    assert info["metric_guard_samples"] == 27
    assert info["metric_ratio_max"] == pytest.approx(expected["metric_ratio_max"], rel=1e-9)
    assert DualMetric().fit(prob).info["metric_guard_reference"] == "wls fit on 27 strided samples"
