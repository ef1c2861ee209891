"""Physical consistency of parameters, in one place. The constraint matrices C_b(θ) are defined by
``ParameterBlock.constraint_basis`` (pseudo-inertia for rigid bodies, drag matrix for drag); this
module holds every use of them:

- per-body quantities (mass, centre of mass, inertia about it) via Pinocchio's ``pin.Inertia``;
- the feasible set as small LMIs and linear rows for dualid's interior-point solvers
  (``feasible_set``: margins, step lengths);
- the same constraints for cvxpy (``cvxpy_constraints``);
- the geometric priors on C_b (log-det divergence and constant pullback metric, ``regularizer_value``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from dualid.errors import ConsistencyError, ModelError
from dualid.model.parameters import ParameterSpace


def body_at_com(theta_b: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """(m [kg], c (3,) [m], I_c (3, 3) [kg m²] about the centre of mass) of 10 dynamic parameters
    [m, mc, I about the body frame] (Pinocchio's order); needs m > 0."""
    inertia = pin.Inertia.FromDynamicParameters(np.asarray(theta_b, dtype=float))
    return float(inertia.mass), np.array(inertia.lever), np.array(inertia.inertia)


def inertia_about_origin(theta_b: np.ndarray) -> np.ndarray:
    """I (3, 3) [kg m²] about the body frame's origin, straight from the parameters."""
    Ixx, Ixy, Iyy, Ixz, Iyz, Izz = np.asarray(theta_b, dtype=float)[4:10]
    return np.array([[Ixx, Ixy, Ixz], [Ixy, Iyy, Iyz], [Ixz, Iyz, Izz]])


@dataclass(frozen=True)
class BodyProperties:
    """Physical quantities of one parameter block at θ̂."""

    name: str
    kind: str
    margin: float  # smallest eigenvalue of the block's constraint matrix (≥ 0: consistent)
    mass: float | None = None  # [kg] (rigid bodies)
    com: tuple[float, float, float] | None = None  # [m] centre of mass in the body frame
    inertia_com: tuple[tuple[float, ...], ...] | None = None  # [kg m²] about the centre of mass
    principal_moments: tuple[float, float, float] | None = None  # [kg m²]
    coefficients: tuple[float, ...] | None = None  # drag / friction coefficients

    def as_dict(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if v is not None}


def body_properties(parameters: ParameterSpace, theta: np.ndarray) -> tuple[BodyProperties, ...]:
    out = []
    for b in parameters.blocks:
        th = np.asarray(theta)[list(b.indices)]
        C = b.constraint_matrix(theta)
        margin = float(np.linalg.eigvalsh(C)[0]) if C is not None else float("nan")
        if b.kind == "rigid_body":
            if th[0] > 0:
                m, c, I_com = body_at_com(th)
            else:  # no centre of mass: report the inertia about the body frame's origin
                m, c, I_com = float(th[0]), np.full(3, np.nan), inertia_about_origin(th)
            out.append(
                BodyProperties(
                    b.name,
                    b.kind,
                    margin,
                    mass=float(m),
                    com=tuple(float(x) for x in c),
                    inertia_com=tuple(tuple(float(x) for x in row) for row in I_com),
                    principal_moments=tuple(float(x) for x in np.linalg.eigvalsh(I_com)),
                )
            )
        else:
            out.append(BodyProperties(b.name, b.kind, margin, coefficients=tuple(float(x) for x in th)))
    return tuple(out)


# --- the feasible set for interior-point solvers ---------------------------------------------
@dataclass(frozen=True)
class LMI:
    """C(θ) = C0 + Σ_k θ[idx_k] V_k ⪰ 0, an m×m block."""

    name: str
    idx: np.ndarray  # (k,) parameter indices
    V: np.ndarray  # (k, m, m)
    C0: np.ndarray  # (m, m)

    def __post_init__(self) -> None:
        k, m, _ = self.V.shape  # V flattened once to (k, m·m): C(θ) is then one small product, the one tensordot
        object.__setattr__(self, "_V2", np.ascontiguousarray(self.V.reshape(k, m * m)))  # makes (bit for bit), without
        # its Python overhead (which dominated the interior point's iterations on p-sized problems)

    def C(self, theta: np.ndarray) -> np.ndarray:
        m = self.C0.shape[0]
        return self.C0 + (theta[self.idx] @ self._V2).reshape(m, m)

    def dC(self, d: np.ndarray) -> np.ndarray:
        m = self.C0.shape[0]
        return (d[self.idx] @ self._V2).reshape(m, m)


@dataclass(frozen=True)
class FeasibleSet:
    """The feasible set: LMIs (rigid bodies, drag matrices) and linear rows G θ + h ≥ 0."""

    lmis: tuple[LMI, ...]
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
        alpha = max_step_blocks([c.C(theta) for c in self.lmis], [c.dC(d) for c in self.lmis])
        if len(self.h):
            s, ds = self.G @ theta + self.h, self.G @ d
            neg = ds < 0
            if neg.any():
                alpha = min(alpha, float(np.min(-s[neg] / ds[neg])))
        return alpha


def repair_psd(X: np.ndarray, floor: float = 1e-14) -> np.ndarray:
    """X itself if it is numerically positive definite, else its eigenvalues lifted to ≥ floor·λ_max."""
    X = 0.5 * (X + X.T)
    try:
        np.linalg.cholesky(X)
        return X
    except np.linalg.LinAlgError:
        lam, U = np.linalg.eigh(X)
        return (U * np.maximum(lam, floor * max(lam.max(), 1e-300))) @ U.T


def max_step_blocks(X: list, dX: list) -> float:
    """Largest α with X_b + α dX_b ≻ 0 for every block b (X_b ≻ 0): one batched call per block size."""
    sizes: dict[int, list[int]] = {}
    for b, x in enumerate(X):
        sizes.setdefault(x.shape[0], []).append(b)
    return min((max_step_psd_batched(np.stack([X[b] for b in bs]), np.stack([dX[b] for b in bs]))
                for bs in sizes.values()), default=np.inf)


def max_step_psd_batched(X: np.ndarray, dX: np.ndarray) -> float:
    """Largest α with X_b + α dX_b ≻ 0 for every b, X (B, m, m) ≻ 0 (one batched Cholesky / inverse / eigvalsh)."""
    X = 0.5 * (X + np.swapaxes(X, 1, 2))
    try:
        L = np.linalg.cholesky(X)
    except np.linalg.LinAlgError:  # some X_b PD only up to rounding: repaired one by one (rare)
        L = np.linalg.cholesky(np.stack([repair_psd(x) for x in X]))
    Li = np.linalg.inv(L)
    lam = float(np.linalg.eigvalsh(Li @ dX @ np.swapaxes(Li, 1, 2))[:, 0].min())
    return np.inf if lam >= 0 else float(-1.0 / lam)


def feasible_set(parameters, constrained: bool = True, fixed: np.ndarray | None = None) -> FeasibleSet:
    """LMIs for rigid-body and drag-matrix blocks; linear rows for diagonal blocks and bounds. With a margin
    (ParameterSpace.with_margin) every block is shifted: C0 = −ε·C_b(θ_ref), rows θ_k ≥ ε·θ_ref,k."""
    p = parameters.p
    lmis, rows, h, names = [], [], [], []
    if constrained:
        for b in parameters.blocks:
            V = b.constraint_basis
            if V is None:
                continue
            idx = np.asarray(b.indices)
            shift = parameters.margin_shift(b)  # ε·C_b(θ_ref): the margin C_b(θ) ⪰ ε·C_b(θ_ref), or None
            if b.kind in ("drag_diagonal", "nonnegative"):
                for j, i in enumerate(idx):
                    g = np.zeros(p)
                    g[i] = 1.0
                    lo = 0.0 if shift is None else float(shift[j, j])
                    rows.append(g), h.append(-lo), names.append(f"{parameters.names[i]} ≥ {lo:g}")
                continue
            C0 = np.zeros(V.shape[1:]) if shift is None else -shift
            lmis.append(LMI(b.name, idx, np.asarray(V, dtype=float), C0))
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
    return FeasibleSet(tuple(lmis), G, np.asarray(h, dtype=float), tuple(names))


# --- cvxpy ------------------------------------------------------------------------------------
def cvxpy_constraints(theta, parameters: ParameterSpace) -> list:
    """cvxpy constraints C_b(θ_b) ⪰ 0 (⪰ ε·C_b(θ_ref) with a margin) for every block, and the bounds."""
    import cvxpy as cp

    cons = []
    for b in parameters.blocks:
        V = b.constraint_basis
        if V is None:
            continue
        th = theta[list(b.indices)]
        shift = parameters.margin_shift(b)  # ε·C_b(θ_ref): the margin C_b(θ) ⪰ ε·C_b(θ_ref), or None
        if b.kind in ("drag_diagonal", "nonnegative"):
            cons.append(th >= (0 if shift is None else np.diag(shift)))  # diag(θ_b) ⪰ 0 is non-negativity
            continue
        k, m, _ = V.shape
        C = cp.reshape(V.reshape(k, m * m).T @ th, (m, m), order="C")
        cons.append(0.5 * (C + C.T) >> (0 if shift is None else shift))
    if parameters.lower is not None:
        lo = np.asarray(parameters.lower)
        fin = np.isfinite(lo)
        if fin.any():
            cons.append(theta[np.flatnonzero(fin)] >= lo[fin])
    if parameters.upper is not None:
        hi = np.asarray(parameters.upper)
        fin = np.isfinite(hi)
        if fin.any():
            cons.append(theta[np.flatnonzero(fin)] <= hi[fin])
    return cons


def cvxpy_feasible_set(theta, cons: FeasibleSet) -> list:
    """cvxpy constraints of a FeasibleSet (e.g. one closed over unseen parameters): C0 + Σ θ[idx_k] V_k ⪰ 0 per LMI
    and G θ + h ≥ 0."""
    import cvxpy as cp

    out = []
    for c in cons.lmis:
        k, m, _ = c.V.shape
        C = c.C0 + cp.reshape(c.V.reshape(k, m * m).T @ theta[[int(i) for i in c.idx]], (m, m), order="C")
        out.append(0.5 * (C + C.T) >> 0)
    if len(cons.h):
        out.append(cons.G @ theta + cons.h >= 0)
    return out


# --- geometric priors on the constraint matrices ------------------------------------------------
def prior_blocks(kind: str, parameters: ParameterSpace, theta0: np.ndarray):
    """Per block: (indices, V (k, m, m), C0 (m, m)) for the blocks a geometric prior applies to."""
    out = []
    for b in parameters.blocks:
        V = b.constraint_basis
        if V is None:
            continue
        out.append((list(b.indices), V, b.constraint_matrix(theta0)))
    if not out:
        raise ModelError(f"{kind} regularization: the parameter space has no constrained blocks to regularize")
    return out


def pullback_metric(V: np.ndarray, C0: np.ndarray) -> np.ndarray:
    """g_kl = tr(C0⁻¹ V_k C0⁻¹ V_l): the constant pullback of the affine-invariant metric at C0."""
    A = np.linalg.solve(C0, V)  # (k, m, m): C0⁻¹ V_k
    return np.einsum("kab,lba->kl", A, A)


def regularizer_value(kind: str, parameters: ParameterSpace, theta: np.ndarray, theta0: np.ndarray) -> float:
    """R(θ): Σ_b log-det divergence D(C_b(θ)‖C_b(θ₀)) or Σ_b (θ_b − θ_b0)ᵀ g_b (θ_b − θ_b0)."""
    total = 0.0
    for idx, V, C0 in prior_blocks(kind, parameters, theta0):
        if kind == "logdet":
            C = np.tensordot(theta[idx], V, axes=1)
            sign, logdet = np.linalg.slogdet(C)
            if sign <= 0:
                return float("inf")
            total += -logdet + np.linalg.slogdet(C0)[1] + np.trace(np.linalg.solve(C0, C)) - C.shape[0]
        else:
            d = theta[idx] - theta0[idx]
            total += float(d @ pullback_metric(V, C0) @ d)
    return float(total)


def _clip_psd(C: np.ndarray, eps: float = 1e-2) -> np.ndarray:
    lam, U = np.linalg.eigh(C)
    top = np.abs(lam).max()
    top = top if top > 0 else 1.0
    return (U * np.maximum(lam, eps * top)) @ U.T


def central_point(theta_ols: np.ndarray, cons: FeasibleSet, eps: float = 1e-2) -> np.ndarray:
    """A strictly feasible point near θ_ols: each block's matrix with its eigenvalues lifted to ≥ eps·λ_max."""
    theta = theta_ols.copy()
    for c in cons.lmis:
        k, m, _ = c.V.shape
        target = _clip_psd(c.C(theta), eps) - c.C0
        theta[c.idx] = np.linalg.lstsq(c.V.reshape(k, m * m).T, target.reshape(-1), rcond=None)[0]
    if len(cons.h):
        for j in range(len(cons.h)):
            g = cons.G[j]
            i = int(np.flatnonzero(g)[0])
            s = g[i] * theta[i] + cons.h[j]
            scale = max(abs(theta[i]), abs(cons.h[j]), 1e-6)
            if s < 1e-2 * scale:
                theta[i] += (1e-2 * scale - s) / g[i]
    return theta


def lifted_blocks(theta: np.ndarray, cons: FeasibleSet, floor: float) -> np.ndarray:
    """θ with every LMI block whose smallest eigenvalue is below floor × its largest lifted to it, by the least change
    of its parameters: a conic solver meets its constraints only to its tolerance (a closed block's smallest eigenvalue
    −1e-11 seen), and ``model.closure``'s completion needs θ strictly inside."""
    theta = np.array(theta, dtype=float)
    for c in cons.lmis:
        lam, U = np.linalg.eigh(c.C(theta))
        low = floor * np.abs(lam).max()
        if lam[0] < low:
            k, m, _ = c.V.shape
            lift = (U * (np.maximum(lam, low) - lam)) @ U.T
            theta[c.idx] += np.linalg.lstsq(c.V.reshape(k, m * m).T, lift.reshape(-1), rcond=None)[0]
    return theta


def check_nominal(parameters: ParameterSpace, theta0: np.ndarray, strict: bool) -> np.ndarray:
    """θ₀ must have p finite entries and be physically consistent (strictly, for log-det priors)."""
    theta0 = np.asarray(theta0, dtype=float)
    if theta0.shape != (parameters.p,):
        raise ConsistencyError(f"nominal θ₀: expected shape ({parameters.p},), got {theta0.shape}")
    if not np.all(np.isfinite(theta0)):
        raise ConsistencyError("nominal θ₀ has non-finite entries (NaN or inf)")
    for name, margin in parameters.consistency_margins(theta0).items():
        if margin < 0 or (strict and margin <= 0):
            need = "positive definite" if strict else "positive semidefinite"
            raise ConsistencyError(
                f"nominal θ₀ is not physically consistent: block {name!r} has constraint-matrix "
                f"smallest eigenvalue {margin:.3g}; it must be {need}"
            )
    return theta0
