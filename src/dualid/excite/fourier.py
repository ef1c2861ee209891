"""Finite Fourier-series joint trajectories that start and end at rest at a given configuration.

Joint j, harmonics k = 1..K of the base frequency ω = 2π / period:

    q_j(t) = q0_j + Σ_k (a_jk / (kω)) sin(kωt) − (b_jk / (kω)) cos(kωt)
    v_j(t) = Σ_k a_jk cos(kωt) + b_jk sin(kωt)
    a_j(t) = Σ_k −a_jk kω sin(kωt) + b_jk kω cos(kωt)

The motion is periodic (it can be repeated and averaged). Rest at t = 0 (hence at every multiple of
the period) at q_start is imposed by *constraining the coefficients*, not by a polynomial correction:
v(0) = Σ_k a_jk = 0 and a(0) = ω Σ_k k b_jk = 0 fix the first harmonic, a_j1 = −Σ_{k≥2} a_jk and
b_j1 = −Σ_{k≥2} k b_jk, and q(0) = q_start fixes the offset q0_j = q_start_j + Σ_k b_jk / (kω). The
free design variables are x = (a_j2..a_jK, b_j2..b_jK) per joint [rad/s], 2(K − 1) per joint, and
q, v, a are affine in x, so their limits are linear constraints with exact Jacobians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dualid.errors import ConfigError


def _basis(t: np.ndarray, omega: float, K: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Φ_q, Φ_v, Φ_a), each (T, 2K): q, v, a of one joint = Φ @ [a_1..a_K, b_1..b_K] (q without q0)."""
    k = np.arange(1, K + 1)
    arg = np.asarray(t, dtype=float)[:, None] * (k * omega)[None, :]  # (T, K)
    s, c = np.sin(arg), np.cos(arg)
    kw = k * omega
    phi_q = np.hstack([s / kw, -c / kw])
    phi_v = np.hstack([c, s])
    phi_a = np.hstack([-s * kw, c * kw])
    return phi_q, phi_v, phi_a


def elimination(K: int) -> np.ndarray:
    """P (2K, 2(K − 1)): full coefficients [a_1..a_K, b_1..b_K] = P @ x of the free ones (rest at t = 0)."""
    if K < 2:
        raise ConfigError(f"harmonics: rest at start and end needs at least 2 harmonics, got {K}")
    m = K - 1
    P = np.zeros((2 * K, 2 * m))
    P[1:K, :m] = np.eye(m)
    P[0, :m] = -1.0
    P[K + 1:, m:] = np.eye(m)
    P[K, m:] = -np.arange(2, K + 1)
    return P


@dataclass(frozen=True)
class FourierTrajectory:
    """q(t), v(t), a(t) of a finite Fourier series per joint (see the module docstring)."""

    period: float  # [s]
    q0: np.ndarray  # (n,) offset [rad or m]
    a: np.ndarray  # (n, K) [rad/s]
    b: np.ndarray  # (n, K) [rad/s]

    def __post_init__(self) -> None:
        a, b = np.asarray(self.a, dtype=float), np.asarray(self.b, dtype=float)
        q0 = np.asarray(self.q0, dtype=float)
        if a.ndim != 2 or a.shape != b.shape or q0.shape != (a.shape[0],):
            raise ConfigError(f"FourierTrajectory: expected q0 (n,), a and b (n, K), got {q0.shape}, {a.shape}, {b.shape}")
        if not (np.isfinite(self.period) and self.period > 0):
            raise ConfigError(f"period: expected a positive number of seconds, got {self.period!r}")
        for name, arr in (("q0", q0), ("a", a), ("b", b)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def n(self) -> int:
        return self.a.shape[0]

    @property
    def harmonics(self) -> int:
        return self.a.shape[1]

    @property
    def omega(self) -> float:
        return 2 * np.pi / self.period

    @classmethod
    def at_rest(cls, period: float, q_start, x) -> "FourierTrajectory":
        """The trajectory of free coefficients x (n, 2(K − 1)) that is at rest at q_start at t = 0 and t = period."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        q_start = np.asarray(q_start, dtype=float)
        K = x.shape[1] // 2 + 1
        full = x @ elimination(K).T  # (n, 2K)
        a, b = full[:, :K], full[:, K:]
        omega = 2 * np.pi / period
        q0 = q_start + (b / (np.arange(1, K + 1) * omega)).sum(axis=1)
        return cls(period, q0, a, b)

    def free_coefficients(self) -> np.ndarray:
        """x (n, 2(K − 1)) such that ``at_rest(period, q(0), x)`` is this trajectory (if it is at rest at 0)."""
        return np.hstack([self.a[:, 1:], self.b[:, 1:]])

    def times(self, rate: float) -> np.ndarray:
        """Sample times [s] over one period at ``rate`` [Hz], both ends included."""
        if not (np.isfinite(rate) and rate > 0):
            raise ConfigError(f"rate: expected a positive number of samples per second, got {rate!r}")
        steps = max(int(round(self.period * rate)), 1)
        return np.linspace(0.0, self.period, steps + 1)

    def evaluate(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, v, a), each (T, n), at times t (T,) [s]."""
        phi_q, phi_v, phi_a = _basis(np.atleast_1d(t), self.omega, self.harmonics)
        c = np.hstack([self.a, self.b])  # (n, 2K)
        return self.q0 + phi_q @ c.T, phi_v @ c.T, phi_a @ c.T


def free_basis(t, period: float, K: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(B_q, B_v, B_a), each (T, 2(K − 1)): for every joint, q − q_start = B_q x_j, v = B_v x_j, a = B_a x_j."""
    omega = 2 * np.pi / period
    phi_q, phi_v, phi_a = _basis(np.atleast_1d(t), omega, K)
    phi_q0, _, _ = _basis(np.zeros(1), omega, K)
    P = elimination(K)
    return (phi_q - phi_q0) @ P, phi_v @ P, phi_a @ P
