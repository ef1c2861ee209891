"""Sufficient statistics of the quadratic objectives, in one pass over the samples:
H = Σ Y_iᵀ W Y_i, g = Σ Y_iᵀ W τ_i, c = Σ τ_iᵀ W τ_i (or the energy residual's, v_iᵀ r_i)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dualid.problem import IdentificationProblem


@dataclass(frozen=True)
class Statistics:
    """Sufficient statistics of Σ r_iᵀ W_i r_i = θᵀHθ − 2gᵀθ + c, and the weight they came from."""

    H: np.ndarray  # (p, p)
    g: np.ndarray  # (p,)
    c: float
    W: np.ndarray | None = None  # (n, n) constant weight; None: identity (or energy if energy=True)
    energy: bool = False

    def objective(self, problem: IdentificationProblem, theta: np.ndarray) -> float:
        """Σ r_iᵀ W_i r_i from the residuals (no cancellation, unlike θᵀHθ − 2gᵀθ + c)."""
        r = problem.residual(theta)
        if self.energy:
            return float(np.sum(np.einsum("na,na->n", problem.v, r) ** 2))
        if self.W is None:
            return float(np.sum(r * r))
        return float(np.einsum("na,ab,nb->", r, self.W, r))


def statistics(problem: IdentificationProblem, W: np.ndarray | None = None, chunk: int = 65536) -> Statistics:
    """H, g, c for a constant weight W (n, n) (None: identity), accumulated in chunks of samples."""
    p = problem.p
    H, g, c = np.zeros((p, p)), np.zeros(p), 0.0
    for start in range(0, problem.N, chunk):
        Y = problem.Y[start : start + chunk].reshape(-1, p) if W is None else None
        tau = problem.tau[start : start + chunk]
        if W is None:
            t = tau.reshape(-1)
            H += Y.T @ Y
            g += Y.T @ t
            c += float(t @ t)
        else:
            Yc = problem.Y[start : start + chunk]
            WY = np.einsum("ab,nbp->nap", W, Yc)
            H += np.einsum("nap,naq->pq", Yc, WY)
            g += np.einsum("nap,na->p", WY, tau)
            c += float(np.einsum("na,ab,nb->", tau, W, tau))
    return Statistics(0.5 * (H + H.T), g, c, W)


def energy_statistics(problem: IdentificationProblem, chunk: int = 65536) -> Statistics:
    """W_i = v_i v_iᵀ: the rows e_i = Y_iᵀ v_i and targets v_iᵀ τ_i, accumulated in chunks of samples."""
    p = problem.p
    H, g, c = np.zeros((p, p)), np.zeros(p), 0.0
    for start in range(0, problem.N, chunk):
        rows = slice(start, start + chunk)
        e = np.einsum("nap,na->np", problem.Y[rows], problem.v[rows])
        y = np.einsum("na,na->n", problem.tau[rows], problem.v[rows])
        H += e.T @ e
        g += e.T @ y
        c += float(y @ y)
    return Statistics(H, g, c, energy=True)
