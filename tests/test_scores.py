"""Specifications of the scores: known answers, invariances, errors."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dualid.errors import DataError
from dualid.evaluation.scores import max_normalized_xcorr, metric_rmse, rmse, score_run, shift_window

T = 400
t = np.linspace(0.0, 4.0, T, endpoint=False)
rng = np.random.default_rng(0)
# a broadband, non-periodic signal so that only the right shift aligns it
base = np.convolve(rng.standard_normal(T + 40), np.ones(20) / 20, mode="same")[20:-20] + np.sin(2 * np.pi * 0.7 * t)


def delayed(x, d):
    """x delayed by d samples (edge-padded), i.e. y[t] = x[t − d]."""
    return np.concatenate([np.full(d, x[0]), x[:-d]]) if d > 0 else x.copy()


def test_identical_signals_score_one():
    assert max_normalized_xcorr(base, base, 0) == pytest.approx(1.0, abs=1e-12)


def test_shift_inside_the_window_is_found():
    y = delayed(base, 7)
    assert max_normalized_xcorr(y, base, 10) > 0.999
    assert max_normalized_xcorr(base, y, 10) > 0.999  # either direction


def test_shift_outside_the_window_is_not_found():
    y = delayed(base, 40)
    inside = max_normalized_xcorr(y, base, 45)
    outside = max_normalized_xcorr(y, base, 10)
    assert inside > 0.999
    assert outside < 0.95


def test_sign_flip_scores_minus_one():
    assert max_normalized_xcorr(-base, base, 0) == pytest.approx(-1.0, abs=1e-12)


def test_orthogonal_signals_score_near_zero():
    s, c = np.sin(2 * np.pi * t), np.cos(2 * np.pi * 3 * t)
    assert abs(max_normalized_xcorr(s, c, 0)) < 1e-10


def test_scale_and_offset_do_not_matter():
    assert max_normalized_xcorr(1e-4 * base + 3.0, 250.0 * base - 1.0, 5) == pytest.approx(1.0, abs=1e-12)


def test_constant_signal_is_an_error():
    with pytest.raises(ValueError, match=r"max_normalized_xcorr: pred is constant \(value 2\); the correlation"):
        max_normalized_xcorr(np.full(T, 2.0), base, 3)
    with pytest.raises(ValueError, match="meas is constant"):
        max_normalized_xcorr(base, np.zeros(T), 3)


def test_input_errors():
    with pytest.raises(ValueError, match=r"signals must have the same length, got 400 and 399"):
        max_normalized_xcorr(base, base[:-1], 1)
    with pytest.raises(ValueError, match=r"expected two 1-D signals, got shapes \(400, 1\) and \(400,\)"):
        max_normalized_xcorr(base[:, None], base, 1)
    with pytest.raises(ValueError, match=r"max_shift: expected an integer in \[0, 398\] for signals of 400 samples"):
        max_normalized_xcorr(base, base, 399)
    with pytest.raises(DataError, match=r"^max_shift: expected an integer number of samples, got 1.5$"):
        max_normalized_xcorr(base, base, 1.5)
    with pytest.raises(ValueError, match=r"pred has non-finite values"):
        max_normalized_xcorr(np.where(t > 1, np.nan, base), base, 1)
    with pytest.raises(ValueError, match=r"score_run: pred and meas must both have shape \(T, n\) and agree, "
                       r"got \(400, 2\) and \(400, 3\)"):
        score_run(np.zeros((T, 2)), np.zeros((T, 3)), 1)
    with pytest.raises(ValueError, match=r"rmse: pred and meas must both have shape \(T, n\) and agree"):
        rmse(np.zeros(T), np.zeros(T))
    with pytest.raises(ValueError, match=r"metric_rmse: expected M of shape \(400, 2, 2\), got \(400, 2\)"):
        metric_rmse(np.zeros((T, 2)), np.ones((T, 2)), np.ones((T, 2)))
    with pytest.raises(ValueError, match=r"shift_window: dt must be a positive finite number of seconds, got 0"):
        shift_window(1.0, 0)


def test_shift_window_is_five_degrees_of_the_slowest_period():
    assert shift_window(7.2, 0.01) == 10  # 7.2 s / 72 = 0.1 s = 10 samples
    assert shift_window(6.0, 0.01) == 8  # 0.0833 s → 8
    assert shift_window(0.1, 0.01) == 0


def test_score_run_per_coordinate():
    meas = np.stack([base, np.sin(2 * np.pi * t)], axis=1)
    pred = np.stack([3 * base, -np.sin(2 * np.pi * t)], axis=1)
    np.testing.assert_allclose(score_run(pred, meas, 0), [1.0, -1.0], atol=1e-12)
    assert score_run(pred, meas, 2)[1] > -1.0  # a shift moves the flipped sine off exact anti-phase


def test_rmse_and_metric_rmse_closed_forms():
    meas = np.zeros((T, 2))
    pred = np.tile([3.0, 4.0], (T, 1))
    np.testing.assert_allclose(rmse(pred, meas), [3.0, 4.0])
    M = np.tile(np.diag([2.0, 0.5]), (T, 1, 1))
    assert metric_rmse(pred, meas, M) == pytest.approx(np.sqrt(2 * 9 + 0.5 * 16))


def test_metric_rmse_is_chart_invariant():
    """Under a change of chart v = B ṽ: ẽ = B⁻¹e, M̃ = BᵀMB, so ẽᵀM̃ẽ = eᵀMe; RMSE is not invariant."""
    r = np.random.default_rng(3)
    e_pred, e_meas = r.standard_normal((50, 3)), r.standard_normal((50, 3))
    A = r.standard_normal((50, 3, 3))
    M = A @ np.swapaxes(A, 1, 2) + np.eye(3)
    B = r.standard_normal((50, 3, 3)) + 3 * np.eye(3)
    to_new = lambda x: np.linalg.solve(B, x[..., None])[..., 0]
    Mt = np.swapaxes(B, 1, 2) @ M @ B
    assert metric_rmse(to_new(e_pred), to_new(e_meas), Mt) == pytest.approx(metric_rmse(e_pred, e_meas, M), rel=1e-10)
    assert not np.allclose(rmse(to_new(e_pred), to_new(e_meas)), rmse(e_pred, e_meas))


@settings(max_examples=60, deadline=None)
@given(
    a=st.floats(1e-3, 1e3),
    b=st.floats(-1e3, 1e3),
    which=st.sampled_from(["pred", "meas"]),
    shift=st.integers(0, 20),
    seed=st.integers(0, 2**16),
)
def test_score_is_invariant_to_positive_affine_rescaling(a, b, which, shift, seed):
    r = np.random.default_rng(seed)
    x = np.cumsum(r.standard_normal(200))
    y = x + 5 * r.standard_normal(200)
    ref = max_normalized_xcorr(x, y, shift)
    got = max_normalized_xcorr(a * x + b, y, shift) if which == "pred" else max_normalized_xcorr(x, a * y + b, shift)
    assert got == pytest.approx(ref, abs=1e-9)
