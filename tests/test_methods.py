"""The method table is the one place that names methods: every entry's factory builds an estimator
whose fits carry the entry's result name, and every consumer resolves names through it."""

import numpy as np
import pytest

from dualid.errors import ConfigError
from dualid.estimators.methods import METHODS, label, make_estimator, method
from dualid.problem import build_problem
from dualid.systems import pan_tilt


@pytest.fixture(scope="module")
def problem_and_prior():
    model, train, _, theta_true = pan_tilt.dataset(seed=0, n_train=1, n_test=0, duration=2.0)
    return build_problem(model, train), np.asarray(theta_true) * 1.2


@pytest.mark.parametrize("key", list(METHODS))
def test_factory_result_name_matches_the_table(key, problem_and_prior):
    problem, theta0 = problem_and_prior
    result = make_estimator(key, theta0=theta0, gamma=0.1, per_equation=True).fit(problem)
    assert result.method == METHODS[key].result_name
    assert method(result.method) == METHODS[key] or METHODS[key].key == "ols_unconstrained"


def test_unknown_method_lists_the_table():
    with pytest.raises(ConfigError, match=r"^unknown method 'lasso'; known methods: ols, ols_unconstrained, wls, energy, "
                                          r"logdet, pullback, dm, dm-paper$"):
        make_estimator("lasso")
    assert label("my_estimator") == "my_estimator" and label("dual_metric") == "DM (paper)" and label("dm") == "DM"


@pytest.mark.parametrize("key", list(METHODS))
def test_every_estimator_is_a_hashable_value(key):
    options = {"dm-paper": {"solver_options": {"chunk": 512}}, "dm": {"max_iter": 50}}.get(key)
    a = make_estimator(key, theta0=np.ones(3), options=options)
    b = make_estimator(key, theta0=np.ones(3), options=options)
    assert a == b and hash(a) == hash(b) and len({a, b}) == 1
