"""The chunk kernels (dualid.estimators.newton.objective) against AffineMetric.apply_quad, and
AffineMetric.evaluate (with and without its symmetrisation) against M_i = Σ_b J_bᵀ (Σ_k θ_k E_k) J_b + M0_i by loops."""

import pickle

import numpy as np
import pytest

import dualid.model.metric as metric_module
from dualid.estimators.newton.objective import residual_jacobian
from dualid.errors import ModelError
from dualid.model.metric import AffineMetric, MetricTerm
from dualid.model.rigid_body import spatial_inertia_basis


def _metric(kind: str, N=37, n=5, p=24, seed=0):
    rng = np.random.default_rng(seed)
    E = spatial_inertia_basis()
    shared = AffineMetric(p, (MetricTerm(tuple(range(0, 10)), E, rng.normal(size=(N, 6, n))),
                              MetricTerm(tuple(range(12, 22)), E, rng.normal(size=(N, 6, n)))))
    if kind == "shared":
        return shared
    if kind == "per_sample_M0":  # per-sample E on scattered indices, plus a constant part
        A = rng.normal(size=(N, 3, n, n))
        term = MetricTerm((23, 10, 5), A + np.swapaxes(A, -1, -2), np.broadcast_to(np.eye(n), (N, n, n)))
        B = rng.normal(size=(N, n, n))
        return AffineMetric(p, shared.terms + (term,), B @ np.swapaxes(B, 1, 2))
    if kind == "overlap":  # two terms on the same parameters: their contributions add
        return shared.plus(AffineMetric(p, (MetricTerm(tuple(range(5, 15)), E, rng.normal(size=(N, 6, n))),)))
    raise ValueError(kind)


@pytest.mark.parametrize("dense", [False, True])
@pytest.mark.parametrize("kind", ["shared", "per_sample_M0", "overlap"])
def test_kernels_match_affine_metric(kind, dense, monkeypatch):
    # both forms of the metric: the factored products, and the dense M_ik a small system keeps (``dense_rows``)
    monkeypatch.setattr(metric_module, "DENSE_MAX_N", 5 if dense else 0)
    monkeypatch.setattr(metric_module, "DENSE_AFTER", 0)
    metric = _metric(kind)
    assert (metric.dense_rows(slice(None)) is not None) == dense
    N, n = metric.shape
    p = metric.n_params
    rng = np.random.default_rng(1)
    theta, w, Y = rng.normal(size=p), rng.normal(size=(N, n)), rng.normal(size=(N, n, p))
    rows = slice(3, 30)
    ref, Mk = np.zeros((N, n, n)), np.zeros((N, p, n, n))  # by loops, sample by sample
    for i in range(N):
        for t in metric.terms:
            E = t.E[i] if t.per_sample else t.E
            for j, k in enumerate(t.indices):
                Mk[i, k] += t.J[i].T @ E[j] @ t.J[i]
            G = sum(theta[k] * E[j] for j, k in enumerate(t.indices))
            ref[i] += t.J[i].T @ G @ t.J[i]
        if metric.M0 is not None:
            ref[i] += metric.M0[i]
    ref = ref[rows]
    P_ref = np.einsum("ikab,ib->iak", Mk[rows], w[rows])  # [M_ik w_i]_k
    assert np.allclose(metric.apply(w[rows], rows), P_ref, rtol=1e-13, atol=1e-12 * np.abs(P_ref).max())
    quad_ref = np.einsum("ia,iak->ik", w[rows], P_ref)
    assert np.allclose(metric.quad(w[rows], rows), quad_ref, rtol=1e-12, atol=1e-12 * np.abs(quad_ref).max())
    M = metric.evaluate(theta, rows, symmetric=False)
    assert np.allclose(np.tril(M), np.tril(ref), rtol=1e-13, atol=1e-12 * np.abs(ref).max())
    Ms = metric.evaluate(theta, rows)
    assert np.array_equal(Ms, np.swapaxes(Ms, 1, 2))
    assert np.allclose(Ms, ref, rtol=1e-13, atol=1e-12 * np.abs(ref).max())
    Y_before = Y[rows].copy()
    D, wMw = residual_jacobian(metric, Y[rows], w[rows], rows)
    D_ref, wMw_ref = metric.apply_quad(w[rows], rows, out=Y[rows].copy())
    assert np.array_equal(Y[rows], Y_before)  # Y is not modified
    assert np.allclose(D, D_ref, rtol=1e-13, atol=1e-12 * np.abs(D_ref).max())
    assert np.allclose(wMw, wMw_ref, rtol=1e-12, atol=1e-12 * np.abs(wMw_ref).max())


def test_the_dense_form_is_built_only_for_a_metric_used_again(monkeypatch):
    """A metric used for one pass (a streamed block) keeps its factored products; one that has served DENSE_AFTER
    passes builds the dense form, and a subset taken from it keeps it. Both forms give the same M_i(θ)."""
    monkeypatch.setattr(metric_module, "DENSE_MAX_N", 5)
    metric = _metric("shared")
    N = metric.shape[0]
    theta = np.random.default_rng(2).normal(size=metric.n_params)
    first = metric.evaluate(theta)
    assert metric.dense is None
    for _ in range(metric_module.DENSE_AFTER - 1):  # passes in blocks of 10 samples
        for start in range(0, N, 10):
            metric.evaluate(theta, slice(start, start + 10))
    assert metric.dense is not None
    assert np.allclose(metric.evaluate(theta), first, rtol=1e-13, atol=1e-12 * np.abs(first).max())
    rows = np.array([3, 0, 7])
    assert np.array_equal(metric.take(rows).dense, metric.dense[rows])
    unused = theta.copy()
    unused[10] = np.nan  # a parameter no term uses (the terms use 0–9 and 12–21): the dense product must not read it
    assert np.allclose(metric.evaluate(unused), first, rtol=1e-13, atol=1e-12 * np.abs(first).max())
    assert pickle.loads(pickle.dumps(metric)).dense is None  # not shipped to a worker
    monkeypatch.setattr(metric_module, "DENSE_MAX_FLOATS", 2 * metric.dense.size)
    assert metric.take(np.tile(np.arange(N), 3)).dense is None  # a subset larger than the limit: factored
    monkeypatch.setattr(metric_module, "DENSE_MAX_N", 4)  # n = 5: too many coordinates, never dense
    large = _metric("shared")
    for _ in range(2 * metric_module.DENSE_AFTER):
        large.evaluate(theta)
    assert large.dense is None


def test_a_term_with_a_repeated_parameter_is_refused():
    with pytest.raises(ModelError, match="distinct"):
        MetricTerm((4, 4), np.ones((2, 1, 1)), np.ones((3, 1, 2)))
