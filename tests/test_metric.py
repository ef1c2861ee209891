import numpy as np
import pytest

from dualid.model.metric import AffineMetric, MetricTerm
from tests.factories import drag_problem, random_chart


def test_factored_operations_agree_with_the_dense_basis():
    rng = np.random.default_rng(0)
    problem, theta = drag_problem(rng, N=20, n=4)
    metric = problem.metric
    M0, Mk = metric.basis()
    np.testing.assert_allclose(metric.evaluate(theta), M0 + np.einsum("k,nkij->nij", theta, Mk), atol=1e-12)
    w = rng.standard_normal((20, 4))
    np.testing.assert_allclose(metric.quad(w), np.einsum("ni,nkij,nj->nk", w, Mk, w), atol=1e-12)
    np.testing.assert_allclose(metric.apply(w), np.einsum("nkij,nj->nik", Mk, w), atol=1e-12)
    dense = AffineMetric.from_dense(Mk, M0)
    np.testing.assert_allclose(dense.evaluate(theta), metric.evaluate(theta), atol=1e-12)
    np.testing.assert_allclose(dense.apply(w), metric.apply(w), atol=1e-12)


def test_pullback_take_and_concatenate():
    rng = np.random.default_rng(1)
    problem, theta = drag_problem(rng, N=10, n=3)
    B = random_chart(rng, 10, 3, per_sample=True)
    M = problem.metric.evaluate(theta)
    np.testing.assert_allclose(problem.metric.pullback(B).evaluate(theta), np.swapaxes(B, 1, 2) @ M @ B, atol=1e-10)
    np.testing.assert_allclose(problem.metric.take([2, 5]).evaluate(theta), M[[2, 5]])
    both = AffineMetric.concatenate([problem.metric.take([0, 1]), problem.metric.take([2])])
    np.testing.assert_allclose(both.evaluate(theta), M[:3])


def test_metric_term_shape_errors():
    with pytest.raises(ValueError, match=r"J must have shape \(N, d, n\), got \(3, 3\)"):
        MetricTerm((0,), np.eye(3)[None], np.eye(3))
    with pytest.raises(ValueError, match=r"E must have shape \(1, 2, 2\) or \(4, 1, 2, 2\), got \(1, 3, 3\)"):
        MetricTerm((0,), np.eye(3)[None], np.zeros((4, 2, 5)))
    with pytest.raises(ValueError, match="every E_k must be symmetric"):
        MetricTerm((0,), np.array([[[0.0, 1.0], [0.0, 0.0]]]), np.zeros((4, 2, 5)))
    with pytest.raises(ValueError, match=r"term indices \[3\] outside 0..1"):
        AffineMetric(2, (MetricTerm((3,), np.eye(2)[None], np.zeros((4, 2, 5))),))
