"""Every estimator fits both simulated robots' data with physically consistent parameters."""

import pytest

from dualid.paper.study import DEFAULT_METHODS, make_estimator
from dualid.problem import build_problem
from dualid.systems.base import make_system


@pytest.mark.parametrize("name", ["crazyflie", "landsalp"])
def test_every_constrained_estimator_is_physically_consistent_on_simulated_data(name):
    system = make_system(name, size="small")
    problem = build_problem(system.model, list(system.train))
    for method in DEFAULT_METHODS:
        if method == "ols_unconstrained":
            continue
        result = make_estimator(method, system).fit(problem)
        assert result.status in ("optimal", "optimal_inaccurate"), (method, result.status)
        margins = result.parameters.consistency_margins(result.theta)
        assert min(margins.values()) >= -1e-7, (name, method, margins)
