"""Signal processing for trajectories: zero-phase low-pass filtering and numerical differentiation.

Every step applied to a ``Trajectory`` is appended to ``trajectory.meta['steps']`` so the output of
a fit records how its data were made.
"""

from __future__ import annotations

import inspect
import warnings
from dataclasses import replace

import numpy as np

from dualid.data import lie
from dualid.data.checks import check_gaps, check_upsampling
from dualid.data.trajectory import Trajectory
from dualid.errors import DataError, DualidWarning


def sample_rate(t: np.ndarray, rtol: float = 0.05) -> float:
    """The (uniform) sample rate of t [Hz]; DataError when the spacing varies by more than rtol."""
    dt = np.diff(np.asarray(t, dtype=float))
    med = float(np.median(dt))
    if med <= 0:
        raise DataError(f"time stamps must increase; median step is {med}")
    spread = float(np.max(np.abs(dt - med))) / med
    if spread > rtol:
        raise DataError(
            f"time stamps are not uniform: step varies by {spread:.0%} of the median {med:.4g} s "
            f"(tolerance {rtol:.0%}); resample first"
        )
    return 1.0 / med


def _is_number(x) -> bool:
    """A real number (not a bool, not text such as 'fast' from a config)."""
    return not isinstance(x, bool) and isinstance(x, (int, float, np.integer, np.floating))


def lowpass(x: np.ndarray, fs: float, cutoff: float, order: int = 4) -> np.ndarray:
    """Zero-phase Butterworth low-pass along axis 0 (filtfilt, second-order sections)."""
    if not _is_number(cutoff) or not 0 < cutoff < fs / 2:
        raise DataError(f"low-pass cutoff must be in (0, {fs / 2:.4g}) Hz (Nyquist at fs={fs:.4g} Hz), got {cutoff!r}")
    from scipy import signal  # here: scipy.signal costs ~0.7 s to import, and many logs need no filter

    sos = signal.butter(order, cutoff, btype="low", fs=fs, output="sos")
    padlen = 3 * (2 * len(sos) + 1)  # scipy's default for sosfiltfilt
    if np.shape(x)[0] <= padlen:
        raise DataError(f"low-pass: a signal of {np.shape(x)[0]} samples is too short for an order-{order} zero-phase "
                        f"filter (needs more than {padlen})")
    return signal.sosfiltfilt(sos, np.asarray(x, dtype=float), axis=0)


def _savgol_samples(window: float, fs: float, polyorder: int) -> int:
    """The odd number of samples of a Savitzky–Golay window of ``window`` s (at least polyorder + 2)."""
    n = int(round(window * fs)) | 1
    return max(n, polyorder + 2 + (polyorder % 2 == 0))


def savgol_derivatives(x: np.ndarray, fs: float, window: float, polyorder: int = 3):
    """Smoothed x and its first two time derivatives by a Savitzky–Golay fit over ``window`` seconds."""
    n = _savgol_samples(window, fs, polyorder)
    if n > x.shape[0]:
        raise DataError(f"Savitzky–Golay window of {n} samples is longer than the signal ({x.shape[0]} samples)")
    from scipy import signal

    dt = 1.0 / fs
    x = np.asarray(x, dtype=float)
    xs = signal.savgol_filter(x, n, polyorder, deriv=0, axis=0, mode="interp")
    dx = signal.savgol_filter(x, n, polyorder, deriv=1, delta=dt, axis=0, mode="interp")
    ddx = signal.savgol_filter(x, n, polyorder, deriv=2, delta=dt, axis=0, mode="interp")
    return xs, dx, ddx


# --------------------------------------------------------------------------------------------------
# Trajectory -> Trajectory steps. Each returns a new Trajectory and appends {name: parameters} to
# meta["steps"]. All but ``resample`` and ``trim`` need uniform time stamps (see ``sample_rate``).
# --------------------------------------------------------------------------------------------------

_FIELDS = ("q", "v", "tau", "a", "wrench")


def _has_quaternion(traj: Trajectory) -> bool:
    """True when q is not a plain vector of the velocity coordinates (floating base: nq = n + 1)."""
    return traj.q.shape[1] != traj.v.shape[1]


def _floating(traj: Trajectory) -> bool:
    """True when q holds a free-flyer root (dualid.data.lie): processed on its Lie group."""
    return lie.is_floating(traj.q, traj.v)


def _velocity_logged(traj: Trajectory) -> bool:
    """Whether v holds measured data. Loaders list measured quantities in meta['logged']; a trajectory
    without that key (e.g. a simulated one) is taken to carry a meaningful v."""
    logged = traj.meta.get("logged")
    return True if logged is None else "v" in logged


def interpolate(t: np.ndarray, x: np.ndarray, t_new: np.ndarray, method: str = "linear") -> np.ndarray:
    """The columns of x (T, k), sampled at t, at the times t_new: "linear" or "cubic" (not-a-knot spline)."""
    if method == "linear":
        return np.stack([np.interp(t_new, t, x[:, j]) for j in range(x.shape[1])], axis=1)
    from scipy.interpolate import CubicSpline

    return CubicSpline(t, x, axis=0)(t_new)


def resample(traj: Trajectory, rate: float, method: str = "linear") -> Trajectory:
    """Interpolate every channel onto the uniform grid t0, t0 + 1/rate, ... ≤ t_end [Hz].

    method: "linear" (no overshoot) or "cubic" (not-a-knot cubic spline, smooth derivatives).
    A floating-base q (with a unit quaternion) is interpolated on its Lie group ("linear" only: along
    the geodesic between samples, ``lie.interpolate_on_group``); the other channels as vectors.
    """
    if not (_is_number(rate) and np.isfinite(rate) and rate > 0):
        raise DataError(f"resample: rate must be a positive number of Hz, got {rate!r}")
    if method not in ("linear", "cubic"):
        raise DataError(f"resample: method must be 'linear' or 'cubic', got {method!r}")
    floating = _floating(traj)
    if floating and method != "linear":
        raise DataError("resample: method 'cubic' is not defined for a floating base's configuration (a Lie group); "
                        "use method 'linear' (geodesic interpolation between samples)")
    if _has_quaternion(traj) and not floating:
        raise DataError(f"resample: q has {traj.q.shape[1]} columns for {traj.n} velocity coordinates; only a "
                        "floating base (free flyer first, nq = n + 1) is supported")
    t = traj.t
    check_gaps(t)
    check_upsampling(t, rate)
    T_new = int(np.floor((t[-1] - t[0]) * rate * (1 + 1e-12))) + 1
    if T_new < 2:
        raise DataError(f"resample: a {t[-1] - t[0]:.4g} s run gives fewer than 2 samples at {rate} Hz")
    t_new = t[0] + np.arange(T_new) / rate
    t_new[-1] = min(t_new[-1], t[-1])  # guard round-off past the end

    changes = {key: None if getattr(traj, key) is None else interpolate(t, getattr(traj, key), t_new, method)
               for key in _FIELDS if not (key == "q" and floating)}
    if floating:
        changes["q"] = lie.interpolate_on_group(t, traj.q, traj.n, t_new)
    step = {"resample": {"rate": float(rate), "method": method}}
    return traj.with_step(step, t=t_new, **changes)


def filter_lowpass(traj: Trajectory, cutoff: float, fields=("q", "v", "tau"), order: int = 4) -> Trajectory:
    """Zero-phase Butterworth low-pass (``lowpass``) of the named fields at ``cutoff`` Hz. A floating-base
    q is filtered in the tangent space about each sample (``lie.lowpass_on_group``); "tau" also filters
    the external wrenches (``wrench``), measured forces alike."""
    fields = (fields,) if isinstance(fields, str) else tuple(fields)
    if "tau" in fields and "wrench" not in fields and traj.wrench is not None:
        fields += ("wrench",)
    unknown = [f for f in fields if f not in _FIELDS]
    if unknown:
        raise DataError(f"filter_lowpass: unknown fields {unknown}; allowed: {list(_FIELDS)}")
    if "a" in fields and traj.a is None:
        raise DataError("filter_lowpass: field 'a' requested but the trajectory has no acceleration")
    if "wrench" in fields and traj.wrench is None:
        raise DataError("filter_lowpass: field 'wrench' requested but the trajectory has no external wrenches")
    floating = _floating(traj)
    if "q" in fields and _has_quaternion(traj) and not floating:
        raise DataError(f"filter_lowpass: q has {traj.q.shape[1]} columns for {traj.n} velocity coordinates; only a "
                        "floating base (free flyer first, nq = n + 1) is supported")
    fs = sample_rate(traj.t)
    changes = {f: lowpass(getattr(traj, f), fs, cutoff, order) for f in fields if not (f == "q" and floating)}
    if "q" in fields and floating:
        changes["q"] = lie.lowpass_on_group(traj.q, traj.n, fs, cutoff, order)
    step = {"filter_lowpass": {"cutoff": float(cutoff), "fields": list(fields), "order": int(order)}}
    return traj.with_step(step, **changes)


def differentiate(
    traj: Trajectory,
    method: str = "savgol",
    window: float = 0.05,
    cutoff: float | None = None,
    polyorder: int = 3,
    velocity: bool | None = None,
) -> Trajectory:
    """Velocity and acceleration from q by numerical differentiation.

    method "savgol": Savitzky–Golay first and second derivatives over ``window`` seconds;
    method "central": second-order central differences (np.gradient), best of a low-passed q.
    cutoff: if given, q is first low-passed (zero-phase) at this frequency [Hz].
    velocity: replace v by dq/dt? None (default) = only when v was not logged (meta['logged']
    from the loader lacks "v"); True = always; False = keep v. ``a`` is always computed from q.
    q itself is left unchanged. A floating-base q is differentiated on its Lie group, in the tangent
    space about each sample with the same filters (``lie.differentiate_on_group``): v is the body
    velocity (LOCAL) and a its rate, as Pinocchio's free flyer expects.
    """
    if method not in ("savgol", "central"):
        raise DataError(f"differentiate: method must be 'savgol' or 'central', got {method!r}")
    floating = _floating(traj)
    if _has_quaternion(traj) and not floating:
        raise DataError(f"differentiate: q has {traj.q.shape[1]} columns for {traj.n} velocity coordinates; only a "
                        "floating base (free flyer first, nq = n + 1) is supported")
    if method == "savgol" and not (_is_number(window) and np.isfinite(window) and window > 0):
        raise DataError(f"differentiate: window must be a positive number of seconds, got {window!r}")
    if isinstance(polyorder, bool) or not isinstance(polyorder, (int, np.integer)) or polyorder < 2:
        raise DataError(f"differentiate: polyorder must be an integer ≥ 2 (accelerations need it), got {polyorder!r}")
    fs = sample_rate(traj.t)
    if method == "savgol" and window * fs < polyorder + 1:
        warnings.warn(f"differentiate: a {window:g} s window is {window * fs:.2g} samples at {fs:.4g} Hz, fewer than "
                      f"polyorder + 1 = {polyorder + 1}; it was widened to {_savgol_samples(window, fs, polyorder)} samples",
                      DualidWarning, stacklevel=2)
    if floating:
        n_win = _savgol_samples(window, fs, polyorder) if method == "savgol" else 3
        if n_win > traj.T:
            raise DataError(f"Savitzky–Golay window of {n_win} samples is longer than the signal ({traj.T} samples)")
        _, dq, ddq = lie.differentiate_on_group(traj.q, traj.n, fs, method, n_win, polyorder, cutoff)
    elif method == "savgol":
        q = traj.q if cutoff is None else lowpass(traj.q, fs, cutoff)
        _, dq, ddq = savgol_derivatives(q, fs, window, polyorder)
    else:
        q = traj.q if cutoff is None else lowpass(traj.q, fs, cutoff)
        dt = 1.0 / fs
        dq = np.gradient(q, dt, axis=0, edge_order=2)
        ddq = np.gradient(dq, dt, axis=0, edge_order=2)
    replace_v = (not _velocity_logged(traj)) if velocity is None else bool(velocity)
    changes = {"a": ddq}
    if replace_v:
        changes["v"] = dq
    params = {"method": method, "cutoff": None if cutoff is None else float(cutoff), "velocity": replace_v}
    if floating:
        params["on"] = "Lie group (tangent space about each sample)"
    if method == "savgol":
        params.update(window=float(window), polyorder=int(polyorder))
    return traj.with_step({"differentiate": params}, **changes)


def trim(traj: Trajectory, start: float | None = None, stop: float | None = None) -> Trajectory:
    """The samples with start ≤ t ≤ stop (times in seconds on the trajectory's own clock, traj.t)."""
    for name, x in (("start", start), ("stop", stop)):
        if x is not None and (isinstance(x, bool) or not isinstance(x, (int, float)) or not np.isfinite(x)):
            raise DataError(f"trim: {name} must be a number of seconds or null, got {x!r}")
    lo = -np.inf if start is None else float(start)
    hi = np.inf if stop is None else float(stop)
    if lo >= hi:
        raise DataError(f"trim: start must be before stop, got start={start}, stop={stop}")
    mask = (traj.t >= lo) & (traj.t <= hi)
    if mask.sum() < 2:
        raise DataError(
            f"trim: [{start}, {stop}] s keeps {int(mask.sum())} samples of a run spanning "
            f"[{traj.t[0]:.6g}, {traj.t[-1]:.6g}] s; need at least 2"
        )
    out = traj.take(mask)
    return out.with_step({"trim": {"start": start, "stop": stop}})


def downsample(traj: Trajectory, factor: int, cutoff: float | None = None, order: int = 4) -> Trajectory:
    """Keep every ``factor``-th sample after a zero-phase anti-aliasing low-pass.

    cutoff defaults to 0.8 × the new Nyquist frequency (0.4 · fs / factor). Every channel is filtered;
    a floating-base q on its Lie group (``lie.lowpass_on_group``).
    """
    if isinstance(factor, bool) or not isinstance(factor, (int, np.integer)) or factor < 1:
        raise DataError(f"downsample: factor must be a positive integer, got {factor!r}")
    factor = int(factor)
    fs = sample_rate(traj.t)
    if cutoff is None:
        cutoff = 0.4 * fs / factor
    if not (_is_number(cutoff) and np.isfinite(cutoff) and cutoff > 0):
        raise DataError(f"downsample: cutoff must be a positive number of Hz, got {cutoff!r}")
    if factor > 1 and cutoff >= fs / (2 * factor):
        raise DataError(
            f"downsample: cutoff {cutoff} Hz is not below the new Nyquist frequency {fs / (2 * factor):.4g} Hz "
            f"(fs={fs:.4g} Hz, factor={factor}); aliasing would follow"
        )
    floating = _floating(traj)
    fields = [f for f in _FIELDS if getattr(traj, f) is not None and not (f == "q" and _has_quaternion(traj)
                                                                           and not floating)]
    if factor > 1:
        changes = {f: lowpass(getattr(traj, f), fs, cutoff, order) for f in fields if not (f == "q" and floating)}
        if floating:
            changes["q"] = lie.lowpass_on_group(traj.q, traj.n, fs, cutoff, order)
        traj = replace(traj, **changes)
    step = {"downsample": {"factor": factor, "cutoff": float(cutoff), "order": int(order), "filtered": fields}}
    return traj.take(slice(0, None, factor)).with_step(step)


STEPS = {
    "resample": resample,
    "filter_lowpass": filter_lowpass,
    "differentiate": differentiate,
    "trim": trim,
    "downsample": downsample,
}


def preprocess(traj: Trajectory, steps: list[dict]) -> Trajectory:
    """Apply a pipeline given as config, e.g.
    [{"resample": {"rate": 500}}, {"differentiate": {"method": "savgol", "window": 0.05}},
     {"filter_lowpass": {"cutoff": 20}}, {"downsample": {"factor": 5}}].
    Each step is a one-key mapping {name: parameters}; parameters may be omitted (None or {})."""
    known = ", ".join(sorted(STEPS))
    for k, step in enumerate(steps):
        if not isinstance(step, dict) or len(step) != 1:
            raise DataError(f"preprocessing step {k} must be a one-key mapping {{name: parameters}}, got {step!r}")
        (name, params), = step.items()
        if name not in STEPS:
            raise DataError(f"unknown preprocessing step {name!r} (step {k}); known steps: {known}")
        params = {} if params is None else params
        if not isinstance(params, dict):
            raise DataError(f"preprocessing step {k} ({name}): parameters must be a mapping, got {params!r}")
        fn = STEPS[name]
        try:
            inspect.signature(fn).bind(traj, **params)
        except TypeError as err:
            accepted = [p for p in inspect.signature(fn).parameters if p != "traj"]
            raise DataError(
                f"preprocessing step {k} ({name}): bad parameters {params} ({err}); accepted: {accepted}"
            ) from err
        traj = fn(traj, **params)
    return traj
