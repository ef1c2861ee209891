"""Floating-base configurations on their Lie group: unit quaternions, velocities and accelerations,
resampling and filtering that respect the group (Pinocchio's ``liegroups``).

A Trajectory whose q has one column more than v (nq = n + 1, n ≥ 6) holds a free-flyer root first,
in Pinocchio's layout: q = [x, y, z, qx, qy, qz, qw, joint positions…] (position [m] of the base
frame in the world, unit quaternion (x, y, z, w) of world_R_base), and v = [vx, vy, vz, wx, wy, wz,
joint velocities…]: the base velocity in the LOCAL base frame (Pinocchio's free-flyer convention,
v_lin = Rᵀ ṗ, ω the body angular velocity). Its configuration space is SE(3) × Rᵏ with k joint
positions as angles or lengths: ``difference(q0, q1)`` = log(q0⁻¹ q1), ``integrate(q, ξ)`` = q·exp(ξ),
exactly the model's own ``pin.difference``/``pin.integrate`` for a free flyer followed by revolute
or prismatic joints (tests check it).

Differentiation and low-pass filtering work in the tangent space about each sample (a local chart):
ξ_kj = difference(q_k, q_j) for j in a window around k, then a linear filter (taps c) gives
q̂_k = integrate(q_k, Σ_j c⁰_j ξ_kj), v_k = Σ_j c¹_j ξ_kj and a_k = Σ_j c²_j ξ_kj. Because
d/dt log(q_k⁻¹ q(t)) = v(t_k) and d²/dt² … = v̇(t_k) at t = t_k (the exponential's Jacobian is I − ½ ad
at 0 and ad_ξ ξ = 0), these are the body velocity and its rate, and a constant twist (a screw
motion, ξ_kj = (t_j − t_k) v) is differentiated exactly. On the vector part the chart is the
identity, so joints are filtered exactly as by ``preprocessing.lowpass`` + Savitzky–Golay (up to the
edges, handled here by odd extension in the chart). The taps are the Savitzky–Golay taps convolved
with the impulse response of the same zero-phase Butterworth low-pass (truncated below 1e-5 of its
peak). A chart is valid for rotations below π about q_k: windows spanning more are refused.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from dualid.errors import DataError

BASE_COORDINATES = ("vx", "vy", "vz", "wx", "wy", "wz")  # the free-flyer root's velocity coordinates (LOCAL)
QUATERNION_TOL = 1e-3  # a logged quaternion whose norm is off 1 by more than this is refused (else normalized)
_TAP_FLOOR = 1e-5  # low-pass impulse response truncated below this fraction of its peak
_MAX_CHART_ANGLE = 0.9 * np.pi  # [rad] largest rotation a window may span about its centre sample


def is_floating(q: np.ndarray, v: np.ndarray) -> bool:
    """True when q holds a free-flyer root (nq = n + 1, n ≥ 6, unit quaternions in columns 3–6; see the
    module docstring)."""
    if not (q.shape[1] == v.shape[1] + 1 and v.shape[1] >= 6):
        return False
    return bool(np.all(np.abs(np.linalg.norm(q[:, 3:7], axis=1) - 1.0) <= QUATERNION_TOL))


def group(nq: int, nv: int):
    """The configuration space SE(3) × R^(nv − 6) of a floating-base trajectory (pin.liegroups)."""
    if nq != nv + 1 or nv < 6:
        raise DataError(f"a floating-base configuration has nq = nv + 1 with nv ≥ 6 (free flyer first); got nq={nq}, "
                        f"nv={nv}")
    G = pin.liegroups.SE3()
    return G if nv == 6 else G * pin.liegroups.Rn(nv - 6)


def unit_quaternions(quat: np.ndarray, where: str, columns) -> tuple[np.ndarray, int]:
    """(T, 4) quaternions (x, y, z, w) normalized and made sign-continuous (q and −q are the same
    rotation; each sample takes the sign nearer the previous one), and the number of sign flips undone.
    DataError naming the row and columns when a norm is off 1 by more than QUATERNION_TOL."""
    quat = np.asarray(quat, dtype=float)
    norm = np.linalg.norm(quat, axis=1)
    bad = np.abs(norm - 1.0) > QUATERNION_TOL
    if bad.any():
        k = int(np.argmax(bad))
        raise DataError(
            f"{where}: the quaternion columns {list(columns)} have norm {norm[k]:.6g} at row {k} (expected 1 within "
            f"{QUATERNION_TOL:g}; {int(bad.sum())} rows off); check the columns and their order "
            "(quaternion_order: xyzw or wxyz)")
    quat = quat / norm[:, None]
    dots = np.sum(quat[1:] * quat[:-1], axis=1)
    sign = np.concatenate([[1.0], np.cumprod(np.where(dots < 0, -1.0, 1.0))])
    return quat * sign[:, None], int(np.sum(dots < 0))


def _chart(G, q: np.ndarray, k: int, lo: int, hi: int) -> np.ndarray:
    """ξ (hi − lo + 1, nv): difference(q_k, q_j) for j = lo..hi."""
    return np.array([G.difference(q[k], q[j]) for j in range(lo, hi + 1)])


def filter_on_group(q: np.ndarray, nv: int, taps: list[np.ndarray | None]) -> list[np.ndarray | None]:
    """Apply symmetric taps (each of odd length 2L + 1, dot order) in the chart about every sample.

    taps[0] (if given) smooths the configuration (its taps sum to 1); the others return tangent
    vectors (T, nv), e.g. velocity and acceleration. Samples beyond the ends are the odd extension
    in the chart (2 ξ_end − ξ_mirror), which keeps a constant twist exact."""
    G = group(q.shape[1], nv)
    T = q.shape[0]
    L = max(len(c) for c in taps if c is not None) // 2
    if L >= T:
        raise DataError(f"a filter of {2 * L + 1} samples is longer than the run ({T} samples)")
    full = [None if c is None else np.pad(c, (L - len(c) // 2,) * 2) for c in taps]
    out = [None if c is None else np.empty((T, q.shape[1] if i == 0 else nv)) for i, c in enumerate(full)]
    for k in range(T):
        lo, hi = max(0, k - L), min(T - 1, k + L)
        xi = _chart(G, q, k, lo, hi)  # rows j = lo..hi
        angle = np.linalg.norm(xi[:, 3:6], axis=1)
        if angle.max() > _MAX_CHART_ANGLE:
            j = lo + int(np.argmax(angle))
            raise DataError(
                f"the base turns by {angle.max():.3g} rad between samples {k} and {j}, within the filter window "
                f"(±{L} samples): too far for the tangent space about one sample (valid below {_MAX_CHART_ANGLE:.3g} "
                "rad); shorten the window, raise the cutoff or log faster")
        if lo > k - L or hi < k + L:
            idx = np.arange(k - L, k + L + 1)
            ext = np.empty((idx.size, nv))
            inside = (idx >= 0) & (idx < T)
            ext[inside] = xi[idx[inside] - lo]
            left, right = idx < 0, idx >= T
            if left.any():
                ext[left] = 2 * xi[0 - lo] - xi[-idx[left] - lo]
            if right.any():
                ext[right] = 2 * xi[T - 1 - lo] - xi[2 * (T - 1) - idx[right] - lo]
            xi = ext
        for i, c in enumerate(full):
            if c is None:
                continue
            y = c @ xi
            out[i][k] = G.integrate(q[k], y) if i == 0 else y
    return out


def lowpass_taps(fs: float, cutoff: float, order: int = 4) -> np.ndarray:
    """The impulse response of the zero-phase Butterworth low-pass (``preprocessing.lowpass``), truncated
    below 1e-5 of its peak and normalized to unit sum: the same filter as a symmetric FIR."""
    if not 0 < cutoff < fs / 2:
        raise DataError(f"low-pass cutoff must be in (0, {fs / 2:.4g}) Hz (Nyquist at fs={fs:.4g} Hz), got {cutoff}")
    from scipy import signal  # here: scipy.signal costs ~0.7 s to import, and most fits filter nothing

    half = int(np.ceil(20 * fs / cutoff))
    x = np.zeros(2 * half + 1)
    x[half] = 1.0
    h = signal.sosfiltfilt(signal.butter(order, cutoff, btype="low", fs=fs, output="sos"), x)
    keep = np.nonzero(np.abs(h) > _TAP_FLOOR * np.abs(h).max())[0]
    L = max(half - keep[0], keep[-1] - half)
    h = h[half - L: half + L + 1]
    return h / h.sum()


def derivative_taps(fs: float, method: str, n: int, polyorder: int) -> list[np.ndarray]:
    """[smoothing, first, second derivative] dot-order taps: Savitzky–Golay over n samples, or central
    differences (second derivative = central difference of the central difference, as np.gradient twice)."""
    dt = 1.0 / fs
    if method == "savgol":
        from scipy import signal

        return [signal.savgol_coeffs(n, polyorder, deriv=d, delta=dt, use="dot") for d in range(3)]
    return [np.array([0.0, 1.0, 0.0]), np.array([-0.5, 0.0, 0.5]) / dt, np.array([0.25, 0.0, -0.5, 0.0, 0.25]) / dt**2]


def differentiate_on_group(q: np.ndarray, nv: int, fs: float, method: str, n: int, polyorder: int,
                           cutoff: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q smoothed, v, a) of a floating-base configuration (T, nq) sampled at fs [Hz] (module docstring)."""
    taps = derivative_taps(fs, method, n, polyorder)
    if cutoff is not None:
        h = lowpass_taps(fs, cutoff)
        taps = [np.convolve(h, c) for c in taps]
    qs, v, a = filter_on_group(q, nv, taps)
    return qs, v, a


def lowpass_on_group(q: np.ndarray, nv: int, fs: float, cutoff: float, order: int = 4) -> np.ndarray:
    """The configuration low-passed in the chart about each sample (zero-phase Butterworth as FIR taps)."""
    return filter_on_group(q, nv, [lowpass_taps(fs, cutoff, order)])[0]


def interpolate_on_group(t: np.ndarray, q: np.ndarray, nv: int, t_new: np.ndarray) -> np.ndarray:
    """q at t_new by geodesic interpolation between the bracketing samples (pin interpolate: a constant
    twist between samples), the group's counterpart of linear interpolation."""
    G = group(q.shape[1], nv)
    i = np.clip(np.searchsorted(t, t_new, side="right") - 1, 0, t.size - 2)
    u = np.clip((t_new - t[i]) / (t[i + 1] - t[i]), 0.0, 1.0)
    return np.array([G.interpolate(q[k], q[k + 1], float(s)) for k, s in zip(i, u)])


def gradient_on_group(t: np.ndarray, q: np.ndarray, nv: int) -> np.ndarray:
    """v (T, nv) by second-order differences in the chart about each sample on raw (irregular) time
    stamps, np.gradient's formula with edge_order=1: the placeholder velocity of a log without one."""
    G = group(q.shape[1], nv)
    T = t.size
    v = np.empty((T, nv))
    v[0] = G.difference(q[0], q[1]) / (t[1] - t[0])
    v[-1] = G.difference(q[-2], q[-1]) / (t[-1] - t[-2])
    for k in range(1, T - 1):
        h1, h2 = t[k] - t[k - 1], t[k + 1] - t[k]
        fwd, back = G.difference(q[k], q[k + 1]), G.difference(q[k], q[k - 1])
        v[k] = (h1 * h1 * fwd - h2 * h2 * back) / (h1 * h2 * (h1 + h2))
    return v
