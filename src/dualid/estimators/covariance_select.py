"""Choosing the structure of dm's covariance model C_i = Σ + κ M_i from the data (``sigma_structure="auto"``).

Candidates, all fitted by Gaussian maximum likelihood on the pilot's residuals (``covariance_model``):
- ``diagonal``: Σ diagonal (n numbers + κ);
- ``full``: Σ a full symmetric matrix (n(n+1)/2 numbers + κ);
- ``shrink λ`` (λ ∈ SHRINK): the full fit's Σ shrunk toward its own diagonal, (1 − λ) Σ + λ diag Σ, κ kept
  (a Ledoit–Wolf-type compromise; positive definite as a convex combination of two such matrices).

Criterion: the held-out Gaussian negative log-likelihood (mean over samples of log det C_i + r_iᵀ C_i⁻¹ r_i)
under K-fold cross-validation with contiguous blocks of samples as folds (the residuals are correlated in
time, so shuffled folds would leak). The lowest mean held-out value wins; every candidate's value is
recorded (info["sigma_structure_criterion"]). Each fit is done in the scaled sensor chart (every
coordinate's residual rms 1), so the choice is the same under any re-chart that the problem records and
under unit changes: the criterion's differences between candidates do not depend on the chart (a change
of coordinates adds the same log-det term to every candidate).
"""

from __future__ import annotations

import numpy as np

from dualid.estimators.covariance_model import _gaussian_nll, full_likelihood_estimate, likelihood_estimate

SHRINK = (0.25, 0.5, 0.75)  # shrinkage intensities of the full Σ toward its diagonal
FOLDS = 5  # time-blocked folds
MIN_FOLD = 2  # samples per held-out block; fewer samples: no cross-validation, the diagonal model (recorded)


def blocked_folds(N: int, K: int) -> list[np.ndarray]:
    """K contiguous, nearly equal blocks of 0..N−1 (the held-out sets)."""
    return [b for b in np.array_split(np.arange(N), K) if b.size]


def shrunk(S: np.ndarray, lam: float) -> np.ndarray:
    """(1 − λ) Σ + λ diag(Σ)."""
    return (1.0 - lam) * S + lam * np.diag(np.diag(S))


def _candidates(r: np.ndarray, M: np.ndarray, floor: float) -> dict[str, tuple[np.ndarray, float]]:
    """name → (Σ (n, n), κ) fitted on (r, M), every candidate."""
    sig, k_d, _ = likelihood_estimate(r, M, floor)
    S, k_f, _ = full_likelihood_estimate(r, M, floor)
    out = {"diagonal": (np.diag(sig), k_d), "full": (S, k_f)}
    out.update({f"shrink {lam:g}": (shrunk(S, lam), k_f) for lam in SHRINK})
    return out


def heldout_nll(S: np.ndarray, kappa: float, r: np.ndarray, M: np.ndarray) -> float:
    """Mean of log det C_i + r_iᵀ C_i⁻¹ r_i over the given samples, C_i = Σ + κ M_i (inf if some C_i ⊁ 0)."""
    value = _gaussian_nll(S[None] + kappa * M, r)
    return np.inf if value is None else value[0]


def select_structure(r: np.ndarray, M: np.ndarray, floor: float, folds: int = FOLDS) -> tuple[np.ndarray, float, dict]:
    """(Σ (n, n), κ, info): the candidate with the lowest time-blocked cross-validated held-out likelihood,
    refitted on all samples (r (N, n), M (N, n, n) pre-scaled as in ``covariance_model``)."""
    N = r.shape[0]
    K = min(folds, N // MIN_FOLD)
    if K < 2:
        sig, kappa, info = likelihood_estimate(r, M, floor)
        info.update(sigma_structure="diagonal", sigma_structure_selected="diagonal",
                    sigma_structure_reason=f"auto: {N} samples, too few to cross-validate; the diagonal model")
        return np.diag(sig), kappa, info
    totals: dict[str, float] = {}
    for held in blocked_folds(N, K):
        train = np.setdiff1d(np.arange(N), held)
        for name, (S, kappa) in _candidates(r[train], M[train], floor).items():
            totals[name] = totals.get(name, 0.0) + held.size * heldout_nll(S, kappa, r[held], M[held])
    criterion = {name: float(v / N) for name, v in totals.items()}
    best = min(criterion, key=lambda k: (criterion[k], k != "full"))  # ties: the full model
    if best == "diagonal":
        sig, kappa, info = likelihood_estimate(r, M, floor)
        S = np.diag(sig)
    else:
        S, kappa, info = full_likelihood_estimate(r, M, floor)
        if best != "full":
            S = shrunk(S, float(best.split()[1]))
    info.update(sigma_structure=best, sigma_structure_selected=best, sigma_structure_criterion=criterion,
                sigma_structure_folds=int(K))
    return S, float(kappa), info
