"""covariance_model.spd_inverse (the likelihood's batched Cholesky inverse) against numpy's LAPACK calls."""

import numpy as np
import pytest

from dualid.estimators.covariance_model import spd_inverse


@pytest.mark.parametrize("n", [1, 2, 3, 7, 12])
def test_matches_lapack_inverse_and_log_determinant(n):
    rng = np.random.default_rng(n)
    A = rng.normal(size=(200, n, n))
    C = A @ np.swapaxes(A, 1, 2) + 1e-3 * np.eye(n)  # condition numbers up to ~1e5
    logdet, Ci = spd_inverse(C)
    ref = np.linalg.inv(C)
    scale = np.abs(ref).max(axis=(1, 2))[:, None, None]
    assert np.max(np.abs(Ci - ref) / scale) < 1e-9
    assert np.allclose(logdet, np.linalg.slogdet(C)[1], rtol=0, atol=1e-10)
    assert np.array_equal(Ci, np.swapaxes(Ci, 1, 2))  # L⁻ᵀL⁻¹ is symmetric by construction


def test_reads_the_lower_triangle_and_refuses_a_matrix_that_is_not_positive_definite():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(5, 3, 3))
    C = A @ np.swapaxes(A, 1, 2) + np.eye(3)
    upper_garbage = C + np.triu(rng.normal(size=(5, 3, 3)), 1)
    assert np.allclose(spd_inverse(upper_garbage)[1], np.linalg.inv(C), rtol=1e-12)
    bad = C.copy()
    bad[3] = np.diag([1.0, -1e-12, 1.0])
    assert spd_inverse(bad) is None
    bad[3] = np.diag([1.0, np.nan, 1.0])
    assert spd_inverse(bad) is None
