"""Sufficient statistics of the quadratic objectives, in one pass over the samples:
H = Σ Y_iᵀ W Y_i, g = Σ Y_iᵀ W τ_i, c = Σ τ_iᵀ W τ_i (or the energy residual's, v_iᵀ r_i)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dualid.problem import IdentificationProblem, additive, sample_blocks


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
        return _residual_sum(problem, theta, self.W, self.energy)


@additive
def _residual_sum(problem, theta: np.ndarray, W: np.ndarray | None, energy: bool) -> float:
    f = 0.0
    for block, rows, _ in sample_blocks(problem, 16384):
        r = block.Y[rows] @ theta - block.tau[rows]
        if energy:
            f += float(np.sum(np.einsum("na,na->n", block.v[rows], r) ** 2))
        elif W is None:
            f += float(np.sum(r * r))
        else:
            f += float(np.einsum("na,ab,nb->", r, W, r))
    return f


def statistics(problem: IdentificationProblem, W: np.ndarray | None = None, chunk: int = 16384) -> Statistics:
    """H, g, c for a constant weight W (n, n) (None: identity), accumulated in chunks of samples."""
    F = None
    if W is not None:  # W = F Fᵀ (eigen-factor, W ⪰ 0): Σ Y_iᵀ W Y_i = Σ (Fᵀ Y_i)ᵀ (Fᵀ Y_i), one GEMM per chunk
        lam, U = np.linalg.eigh(0.5 * (np.asarray(W, dtype=float) + np.asarray(W, dtype=float).T))
        F = U * np.sqrt(np.clip(lam, 0.0, None))
    H, g, c = _sums(problem, F, chunk)
    return Statistics(0.5 * (H + H.T), g, c, W)


@additive
def _sums(problem, F: np.ndarray | None, chunk: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Σ A_iᵀA_i, Σ A_iᵀt_i, Σ t_iᵀt_i with A_i = FᵀY_i, t_i = Fᵀτ_i (F None: the identity)."""
    p = problem.p
    H, g, c = np.zeros((p, p)), np.zeros(p), 0.0
    for block, rows, _ in sample_blocks(problem, chunk):
        Yc, tau = block.Y[rows], block.tau[rows]
        if F is not None:
            Yc, tau = np.matmul(F.T, Yc), tau @ F
        A, t = Yc.reshape(-1, p), tau.reshape(-1)
        H += A.T @ A
        g += A.T @ t
        c += float(t @ t)
    return H, g, c


def energy_statistics(problem: IdentificationProblem, chunk: int = 16384) -> Statistics:
    """W_i = v_i v_iᵀ: the rows e_i = Y_iᵀ v_i and targets v_iᵀ τ_i, accumulated in chunks of samples."""
    return Statistics(*_energy_sums(problem, chunk), energy=True)


@additive
def _energy_sums(problem, chunk: int) -> tuple[np.ndarray, np.ndarray, float]:
    p = problem.p
    H, g, c = np.zeros((p, p)), np.zeros(p), 0.0
    for block, rows, _ in sample_blocks(problem, chunk):
        e = np.einsum("nap,na->np", block.Y[rows], block.v[rows])
        y = np.einsum("na,na->n", block.tau[rows], block.v[rows])
        H += e.T @ e
        g += e.T @ y
        c += float(y @ y)
    return H, g, c
