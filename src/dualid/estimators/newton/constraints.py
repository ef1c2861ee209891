"""The feasible set of the Newton solver: small LMIs C_b(θ) ⪰ 0 and linear rows Gθ + h ≥ 0."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class _LMI:
    """C(θ) = C0 + Σ_k θ[idx_k] V_k ⪰ 0, an m×m block."""

    name: str
    idx: np.ndarray  # (k,) parameter indices
    V: np.ndarray  # (k, m, m)
    C0: np.ndarray  # (m, m)

    def C(self, theta: np.ndarray) -> np.ndarray:
        return self.C0 + np.tensordot(theta[self.idx], self.V, axes=1)

    def dC(self, d: np.ndarray) -> np.ndarray:
        return np.tensordot(d[self.idx], self.V, axes=1)


@dataclass(frozen=True)
class _Constraints:
    """The feasible set: LMIs (rigid bodies, drag matrices) and linear rows G θ + h ≥ 0."""

    lmis: tuple[_LMI, ...]
    G: np.ndarray  # (q, p)
    h: np.ndarray  # (q,)
    names: tuple[str, ...]  # (q,) what each linear row is, for messages

    @property
    def size(self) -> int:
        """Σ block sizes (the barrier parameter's ν)."""
        return sum(c.V.shape[1] for c in self.lmis) + len(self.h)

    @property
    def empty(self) -> bool:
        return self.size == 0

    def margin(self, theta: np.ndarray) -> float:
        """Smallest eigenvalue over all blocks and rows (> 0: strictly feasible)."""
        m = [np.linalg.eigvalsh(c.C(theta))[0] for c in self.lmis]
        if len(self.h):
            m.append((self.G @ theta + self.h).min())
        return float(min(m)) if m else np.inf

    def max_step(self, theta: np.ndarray, d: np.ndarray) -> float:
        """Largest α with every constraint strictly feasible on [θ, θ + α d) (inf if unbounded)."""
        alpha = np.inf
        for c in self.lmis:
            alpha = min(alpha, _max_step_psd(c.C(theta), c.dC(d)))
        if len(self.h):
            s, ds = self.G @ theta + self.h, self.G @ d
            neg = ds < 0
            if neg.any():
                alpha = min(alpha, float(np.min(-s[neg] / ds[neg])))
        return alpha


def _repair_psd(X: np.ndarray, floor: float = 1e-14) -> np.ndarray:
    """X itself if it is numerically positive definite, else its eigenvalues lifted to ≥ floor·λ_max."""
    X = 0.5 * (X + X.T)
    try:
        np.linalg.cholesky(X)
        return X
    except np.linalg.LinAlgError:
        lam, U = np.linalg.eigh(X)
        return (U * np.maximum(lam, floor * max(lam.max(), 1e-300))) @ U.T


def _max_step_psd(X: np.ndarray, dX: np.ndarray) -> float:
    """Largest α with X + α dX ≻ 0 for X ≻ 0."""
    L = np.linalg.cholesky(_repair_psd(X))
    Li = np.linalg.inv(L)
    lam = np.linalg.eigvalsh(Li @ dX @ Li.T)[0]
    return np.inf if lam >= 0 else float(-1.0 / lam)


def build_constraints(parameters, constrained: bool = True, fixed: np.ndarray | None = None) -> _Constraints:
    """LMIs for rigid-body and drag-matrix blocks; linear rows for diagonal blocks and bounds."""
    p = parameters.p
    lmis, rows, h, names = [], [], [], []
    if constrained:
        for b in parameters.blocks:
            V = b.constraint_basis
            if V is None:
                continue
            idx = np.asarray(b.indices)
            if b.kind in ("drag_diagonal", "nonnegative"):
                for i in idx:
                    g = np.zeros(p)
                    g[i] = 1.0
                    rows.append(g), h.append(0.0), names.append(f"{parameters.names[i]} ≥ 0")
                continue
            lmis.append(_LMI(b.name, idx, np.asarray(V, dtype=float), np.zeros(V.shape[1:])))
        for bound, sign in ((parameters.lower, 1.0), (parameters.upper, -1.0)):
            if bound is None:
                continue
            for i, x in enumerate(bound):
                if np.isfinite(x):
                    g = np.zeros(p)
                    g[i] = sign
                    rows.append(g), h.append(-sign * x)
                    names.append(f"{parameters.names[i]} {'≥' if sign > 0 else '≤'} {x:g}")
    G = np.array(rows).reshape(-1, p)
    return _Constraints(tuple(lmis), G, np.asarray(h, dtype=float), tuple(names))
