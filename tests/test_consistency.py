"""Body quantities from the parameters agree with the parallel-axis theorem computed by hand."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from dualid.model.consistency import body_at_com, body_properties
from dualid.model.parameters import rigid_body_space


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_body_at_com_is_the_parallel_axis_theorem(seed):
    rng = np.random.default_rng(seed)
    m = rng.uniform(0.1, 5.0)
    c = rng.normal(size=3) * 0.3
    A = rng.normal(size=(3, 3)) * 0.1
    S = A @ A.T * m + np.eye(3) * 1e-4  # second moment of a mass distribution about its centre
    I_c = np.trace(S) * np.eye(3) - S  # a physically realizable inertia (triangle inequality holds)
    I_o = I_c + m * (c @ c * np.eye(3) - np.outer(c, c))  # about the body frame's origin
    theta = np.array([m, *(m * c), I_o[0, 0], I_o[0, 1], I_o[1, 1], I_o[0, 2], I_o[1, 2], I_o[2, 2]])
    m2, c2, I2 = body_at_com(theta)
    np.testing.assert_allclose([m2, *c2], [m, *c], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(I2, I_c, atol=1e-12)
    (body,) = body_properties(rigid_body_space(["b"]), theta)
    np.testing.assert_allclose(body.principal_moments, np.linalg.eigvalsh(I_c), atol=1e-12)
    assert body.margin > 0 and body.mass == m2


def test_massless_body_reports_the_origin_inertia():
    theta = np.zeros(10)
    theta[4] = theta[6] = theta[9] = 1e-3
    (body,) = body_properties(rigid_body_space(["b"]), theta)
    assert body.mass == 0.0 and np.all(np.isnan(body.com))
    np.testing.assert_allclose(np.diag(body.inertia_com), [1e-3] * 3)
