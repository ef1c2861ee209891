import numpy as np

from dualid import OLS, DualMetric
from dualid.problem import build_problem
from dualid.systems import pan_tilt


def test_pan_tilt_chain_recovers_truth_from_noiseless_data():
    model, train, _, theta = pan_tilt.dataset(0, n_train=1, n_test=0, noise=pan_tilt.PanTiltNoise.noiseless(), duration=3)
    problem = build_problem(model, train)
    for est in (OLS(), DualMetric()):
        np.testing.assert_allclose(est.fit(problem.subset(slice(0, None, 5))).theta, theta, rtol=1e-4)


def test_build_problem_refuses_a_run_in_another_coordinate_order():
    import pytest

    from dualid.errors import DataError
    from dualid.systems import pan_tilt

    model, train, _, _ = pan_tilt.dataset(seed=0, n_train=1, n_test=0, duration=1.0)
    run = train[0]
    swapped = type(run)(run.t, run.q[:, ::-1], run.v[:, ::-1], run.tau[:, ::-1], run.a[:, ::-1],
                        run.coordinates[::-1], run.name)
    with pytest.raises(DataError, match=r"coordinates \['tilt', 'pan'\] do not match the model's \['pan', 'tilt'\]"):
        build_problem(model, swapped)
