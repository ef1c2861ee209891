import numpy as np

from dualid import OLS, DualMetric
from dualid.problem import build_problem
from dualid.systems import pan_tilt


def test_pan_tilt_chain_recovers_truth_from_noiseless_data():
    model, train, _, theta = pan_tilt.dataset(0, n_train=1, n_test=0, noise=pan_tilt.PanTiltNoise.noiseless(), duration=3)
    problem = build_problem(model, train)
    for est in (OLS(), DualMetric()):
        np.testing.assert_allclose(est.fit(problem.subset(slice(0, None, 5))).theta, theta, rtol=1e-4)
