"""The bounded fixed point (estimators/fixed_point.py): limits, invariance, errors."""

import numpy as np
import pytest

from dualid import WLS
from dualid.errors import ConfigError
from dualid.estimators.fixed_point import BoundedFixedPoint
from dualid.estimators.gls import FeasibleGLS
from tests.factories import drag_problem, random_chart
from tests.test_invariance import rel


def test_bound_one_is_the_frozen_pilot_metric_fit():
    rng = np.random.default_rng(0)
    problem, _ = drag_problem(rng, N=60, n=3, noise=0.3)
    pilot = WLS().fit(problem).theta
    frozen = FeasibleGLS(sigma=np.zeros(3), kappa=1.0, theta_ref=pilot).fit(problem)
    fit = BoundedFixedPoint(bound=1.0).fit(problem)
    assert rel(fit.theta, frozen.theta) < 1e-6
    assert fit.info["converged"]


def test_fixed_point_is_invariant_and_stays_inside_its_bound():
    rng = np.random.default_rng(1)
    problem, _ = drag_problem(rng, N=60, n=3, noise=0.3)
    est = BoundedFixedPoint(bound=3.0)
    base = est.fit(problem)
    for B in (random_chart(rng, problem.N, 3, True), np.diag([1e-6, 1.0, 1e6])):
        assert rel(est.fit(problem.in_coordinates(B)).theta, base.theta) < 1e-6
    assert base.info["feedback"] == "bounded" and not base.info["degenerate"]


@pytest.mark.parametrize("kwargs", [{"bound": 0.5}, {"damping": 0.0}, {"damping": 1.5}, {"max_iter": 0},
                                    {"max_iter": 2.5}, {"tol": -1.0}, {"pilot": "x"}])
def test_constructor_errors(kwargs):
    with pytest.raises(ConfigError):
        BoundedFixedPoint(**kwargs)
    assert BoundedFixedPoint() == BoundedFixedPoint() and hash(BoundedFixedPoint())
