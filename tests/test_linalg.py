"""dualid's own small linear algebra against numpy/LAPACK on the stacked matrices."""

import numpy as np

import pytest

from dualid.linalg import cholesky_batch, cholesky_inverse, forward_substitute, triangular_factor


def test_the_blockwise_qr_is_the_qr_of_the_stacked_matrix():
    """TSQR over uneven row blocks (one shorter than the width): the R of the whole matrix, up to each row's sign."""
    rng = np.random.default_rng(3)
    A = rng.standard_normal((1000, 7)) * np.logspace(-6, 6, 7)  # columns on scales 1e±6
    cuts = [0, 300, 304, 700, 1000]
    R = triangular_factor((A[a:b] for a, b in zip(cuts[:-1], cuts[1:])), 7)
    R_ref = np.linalg.qr(A, mode="r")
    assert R.shape == (7, 7) and np.allclose(np.abs(R), np.abs(R_ref), rtol=1e-10, atol=1e-12 * np.abs(R_ref).max())
    assert np.allclose(R.T @ R, A.T @ A, rtol=1e-10, atol=1e-10 * np.abs(A.T @ A).max())


@pytest.mark.parametrize("n", [1, 2, 7])
def test_the_batched_kernels_are_lapacks_per_matrix(n):
    """Cholesky inverse and forward substitution over a batch of SPD matrices on scales 1e±3 (well conditioned
    once scaled): numpy's inverse and solve, entry by entry."""
    rng = np.random.default_rng(n)
    A = rng.standard_normal((50, n, n))
    D = np.logspace(-3, 3, n)
    C = D[:, None] * (A @ np.swapaxes(A, 1, 2) + n * np.eye(n)) * D
    L = cholesky_batch(C)
    assert np.allclose(cholesky_inverse(L), np.linalg.inv(C), rtol=1e-8, atol=0)
    r = rng.standard_normal((50, n))
    assert np.allclose(forward_substitute(L, r), np.linalg.solve(L, r[..., None])[..., 0], rtol=1e-10, atol=1e-12)
