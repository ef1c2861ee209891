"""Preprocessing steps: closed-form derivatives, zero phase, recorded steps, consistent rates."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from dualid.data import Trajectory
from dualid.data.preprocessing import (
    differentiate,
    downsample,
    filter_lowpass,
    preprocess,
    resample,
    sample_rate,
    trim,
)
from dualid.errors import DataError

W = 2 * np.pi * 0.7  # [rad/s]


def sincos(rate=500.0, duration=4.0, noise=0.0, logged=("q", "tau"), seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, 1.0 / rate)
    q = np.stack([np.sin(W * t), np.cos(W * t)], axis=1) + noise * rng.standard_normal((t.size, 2))
    meta = {} if logged is None else {"logged": list(logged)}
    return Trajectory(t=t, q=q, v=np.zeros_like(q), tau=q.copy(), coordinates=("a1", "a2"), name="s", meta=meta)


def closed_form(t):
    v = W * np.stack([np.cos(W * t), -np.sin(W * t)], axis=1)
    a = -(W**2) * np.stack([np.sin(W * t), np.cos(W * t)], axis=1)
    return v, a


@pytest.mark.parametrize(
    "kwargs, tol_v, tol_a",
    [
        ({"method": "savgol", "window": 0.05}, 1e-6, 1e-3),
        ({"method": "central"}, 1e-4, 1e-4),
        ({"method": "central", "cutoff": 20.0}, 1e-3, 1e-2),
    ],
)
def test_derivatives_of_sin_cos_match_closed_forms(kwargs, tol_v, tol_a):
    traj = differentiate(sincos(), **kwargs)
    v, a = closed_form(traj.t)
    inner = slice(100, -100)  # away from the edges (filter transients)
    np.testing.assert_allclose(traj.v[inner], v[inner], atol=tol_v * W)
    np.testing.assert_allclose(traj.a[inner], a[inner], atol=tol_a * W**2)
    assert traj.meta["steps"][-1]["differentiate"]["method"] == kwargs["method"]


def test_differentiate_of_noisy_signal_is_close():
    traj = differentiate(sincos(noise=1e-3), method="savgol", window=0.1)
    v, a = closed_form(traj.t)
    inner = slice(50, -50)
    assert np.max(np.abs(traj.v[inner] - v[inner])) < 0.05 * W
    assert np.max(np.abs(traj.a[inner] - a[inner])) < 0.2 * W**2


def test_differentiate_replaces_v_only_when_not_logged_or_asked():
    not_logged = differentiate(sincos(logged=("q", "tau")))
    assert np.abs(not_logged.v).max() > 1.0 and not_logged.meta["steps"][-1]["differentiate"]["velocity"]
    logged = differentiate(sincos(logged=("q", "v", "tau")))
    assert np.all(logged.v == 0) and logged.a is not None
    simulated = differentiate(sincos(logged=None))  # no 'logged' key: v is trusted
    assert np.all(simulated.v == 0)
    asked = differentiate(sincos(logged=("q", "v", "tau")), velocity=True)
    assert np.abs(asked.v).max() > 1.0


def test_lowpass_is_zero_phase():
    rate = 500.0
    clean = sincos(rate)
    noisy = sincos(rate, noise=0.05, seed=1)
    out = filter_lowpass(noisy, cutoff=10.0, fields=("q",))
    x = clean.q[:, 0] - clean.q[:, 0].mean()
    y = out.q[:, 0] - out.q[:, 0].mean()
    xc = signal.correlate(y, x, mode="full")
    lags = signal.correlation_lags(y.size, x.size, mode="full")
    assert lags[np.argmax(xc)] == 0
    assert np.sqrt(np.mean((out.q[100:-100, 0] - clean.q[100:-100, 0]) ** 2)) < 0.015


def test_steps_are_recorded_in_order():
    config = [
        {"resample": {"rate": 250}},
        {"differentiate": {"method": "savgol", "window": 0.05}},
        {"filter_lowpass": {"cutoff": 20}},
        {"trim": {"start": 0.5, "stop": 3.5}},
        {"downsample": {"factor": 5}},
    ]
    out = preprocess(sincos(), config)
    steps = out.meta["steps"]
    assert [next(iter(s)) for s in steps] == [next(iter(c)) for c in config]
    assert steps[0]["resample"] == {"rate": 250.0, "method": "linear"}
    assert steps[2]["filter_lowpass"]["cutoff"] == 20.0
    assert steps[4]["downsample"]["factor"] == 5
    assert sample_rate(out.t) == pytest.approx(50.0)
    assert out.t[0] >= 0.5 and out.t[-1] <= 3.5


def test_preprocess_errors_name_known_steps_and_parameters():
    with pytest.raises(DataError, match=r"unknown preprocessing step 'smooth' \(step 0\); known steps: "
                       r"differentiate, downsample, filter_lowpass, resample, trim"):
        preprocess(sincos(), [{"smooth": {"cutoff": 3}}])
    with pytest.raises(DataError, match=r"preprocessing step 0 \(resample\): bad parameters \{'hz': 3\}"):
        preprocess(sincos(), [{"resample": {"hz": 3}}])
    with pytest.raises(DataError, match=r"preprocessing step 1 must be a one-key mapping"):
        preprocess(sincos(), [{"resample": {"rate": 100}}, {"trim": {}, "downsample": {}}])


@settings(max_examples=15, deadline=None)
@given(factor=st.integers(1, 9), rate=st.sampled_from([200.0, 500.0, 1000.0]))
def test_downsample_keeps_rate_consistent(factor, rate):
    traj = differentiate(sincos(rate=rate, duration=2.0))
    out = downsample(traj, factor)
    assert sample_rate(out.t) == pytest.approx(rate / factor, rel=1e-9)
    assert out.T == -(-traj.T // factor)
    np.testing.assert_array_equal(out.t, traj.t[::factor])
    assert out.a.shape == (out.T, 2)


def test_downsample_removes_content_above_new_nyquist():
    rate, factor = 500.0, 5  # new Nyquist 50 Hz
    t = np.arange(0, 2, 1 / rate)
    slow, fast = np.sin(2 * np.pi * 2 * t), 0.5 * np.sin(2 * np.pi * 80 * t)  # 80 Hz would alias to 20 Hz
    x = np.stack([slow + fast, slow], axis=1)
    traj = Trajectory(t=t, q=x, v=x, tau=x)
    out = downsample(traj, factor)
    np.testing.assert_allclose(out.tau[20:-20, 0], slow[::factor][20:-20], atol=0.02)
    with pytest.raises(DataError, match=r"downsample: factor must be a positive integer, got 2.5"):
        downsample(traj, 2.5)
    with pytest.raises(DataError, match=r"cutoff 60 Hz is not below the new Nyquist frequency 50 Hz"):
        downsample(traj, factor, cutoff=60)


def test_resample_irregular_stamps_onto_uniform_grid():
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.001, 0.003, 600))
    x = np.stack([2 * t + 1, -t], axis=1)  # linear: interpolated exactly
    traj = Trajectory(t=t, q=x, v=x, tau=x, a=x)
    with pytest.raises(DataError, match="time stamps are not uniform.*resample first"):
        differentiate(traj)
    for method in ("linear", "cubic"):
        out = resample(traj, 400.0, method=method)
        assert sample_rate(out.t, rtol=1e-6) == pytest.approx(400.0)
        assert out.t[0] == t[0] and out.t[-1] <= t[-1]
        np.testing.assert_allclose(out.q, np.stack([2 * out.t + 1, -out.t], axis=1), atol=1e-9)
        assert out.a is not None and out.meta["steps"] == [{"resample": {"rate": 400.0, "method": method}}]


def test_floating_base_is_processed_on_its_lie_group():
    """The refusals of quaternion configurations are lifted (dualid.data.lie; tests/test_floating.py checks
    the values): a resting base stays where it is, cubic interpolation of the group is refused."""
    T = 50
    t = np.arange(T) / 100.0
    q = np.tile([0, 0, 0, 0, 0, 0, 1.0], (T, 1))  # position + unit quaternion, nq = n + 1
    traj = Trajectory(t=t, q=q, v=np.zeros((T, 6)), tau=np.zeros((T, 6)))
    np.testing.assert_allclose(resample(traj, 50).q, q[::2][:resample(traj, 50).T], atol=1e-15)
    with pytest.raises(DataError, match=r"resample: method 'cubic' is not defined for a floating base"):
        resample(traj, 50, method="cubic")
    np.testing.assert_allclose(differentiate(traj).a, 0.0, atol=1e-12)
    np.testing.assert_allclose(filter_lowpass(traj, 10, fields=("q",)).q, q, atol=1e-15)
    out = downsample(traj, 2)
    assert out.meta["steps"][-1]["downsample"]["filtered"] == ["q", "v", "tau"]
    np.testing.assert_allclose(out.q, q[::2], atol=1e-15)


def test_trim_and_field_errors():
    traj = sincos()
    out = trim(traj, start=1.0, stop=2.0)
    assert out.t[0] == pytest.approx(1.0) and out.t[-1] <= 2.0 and out.t[-1] > 1.99
    assert out.meta["steps"] == [{"trim": {"start": 1.0, "stop": 2.0}}]
    with pytest.raises(DataError, match=r"trim: start must be before stop, got start=2, stop=1"):
        trim(traj, 2, 1)
    with pytest.raises(DataError, match=r"trim: \[10, 11\] s keeps 0 samples"):
        trim(traj, 10, 11)
    with pytest.raises(DataError, match=r"filter_lowpass: unknown fields \['x'\]"):
        filter_lowpass(traj, 10, fields=("x",))
    with pytest.raises(DataError, match=r"filter_lowpass: field 'a' requested but the trajectory has no acceleration"):
        filter_lowpass(traj, 10, fields=("a",))
    with pytest.raises(DataError, match=r"low-pass cutoff must be in \(0, 250\) Hz"):
        filter_lowpass(traj, 300)
    with pytest.raises(DataError, match=r"differentiate: method must be 'savgol' or 'central', got 'euler'"):
        differentiate(traj, method="euler")
