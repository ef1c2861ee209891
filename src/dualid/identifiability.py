"""What a stacked regressor determines: rank, null space and the regrouped *base parameters*.

With A the stacked regressor (N·n, p) and s its column norms, the column-scaled A_s = A / s is
factored by a QR with column pivoting, A_s P = Q [R₁₁ R₁₂], whose first r pivots (r the rank under
dualid.linalg's rule) are independent columns (the columns are weighted by ``lead_preference`` first,
so among dependent columns an inertia or a first moment leads; s below includes that weight). Every
other column is a combination of them, A_s,dep = A_s,ind K with K = R₁₁⁻¹ R₁₂, so

    A θ = A_ind β,     β_k = θ_k + Σ_j c_kj θ_j,   c_kj = K_kj s_j / s_k   (unit: unit(θ_k)/unit(θ_j))

for each independent parameter k (the base parameter is named after it) and dependent j. β is the
same for every θ that predicts the same forces on these data: it is what the data determine.
Coefficients with |K_kj| < DROP_TOL (scaled, i.e. relative to the columns' sizes) are set to zero,
in the stored map as well as in the printed expression, so β = C θ holds with the map shown.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from dualid.errors import DataError, IdentifiabilityError
from dualid.linalg import rank_from_singular_values
from dualid.model.parameters import ParameterSpace

DROP_TOL = 1e-8  # |K_kj| (column-scaled) below which a regrouping coefficient is numerical noise
_SUPERSCRIPT = str.maketrans("0123456789-", "⁰¹²³⁴⁵⁶⁷⁸⁹⁻")
_ORDER = ("kg", "N", "m", "s", "rad")


def _unit_powers(unit: str) -> dict[str, int]:
    """{symbol: exponent} of a unit such as "kg m^2" or "N m s/rad" (one "/" at most)."""
    num, _, den = unit.partition("/")
    out: dict[str, int] = {}
    for part, sign in ((num, 1), (den, -1)):
        for token in part.split():
            sym, _, exp = token.partition("^")
            if token == "1":
                continue
            out[sym] = out.get(sym, 0) + sign * (int(exp) if exp else 1)
    return {k: v for k, v in out.items() if v}


def _format_powers(powers: dict[str, int]) -> str:
    def term(sym: str, e: int) -> str:
        return sym if e == 1 else sym + str(e).translate(_SUPERSCRIPT)

    order = sorted(powers, key=lambda s: (_ORDER.index(s) if s in _ORDER else len(_ORDER), s))
    num = " ".join(term(s, powers[s]) for s in order if powers[s] > 0)
    den = " ".join(term(s, -powers[s]) for s in order if powers[s] < 0)
    if not den:
        return num
    if not num:  # m⁻¹, s⁻¹ m⁻²
        return " ".join(term(s, powers[s]) for s in order)
    return f"{num}/{den if ' ' not in den else '(' + den + ')'}"


def readable_unit(unit: str) -> str:
    """"kg m^2" → "kg m²"; "N m s/rad" stays as it is."""
    return _format_powers(_unit_powers(unit)) if re.fullmatch(r"[A-Za-z0-9^ /\-]*", unit) else unit


def unit_ratio(num: str, den: str) -> str:
    """The unit of num/den, e.g. ("kg m^2", "kg") → "m²"; "" when dimensionless."""
    a, b = _unit_powers(num), _unit_powers(den)
    return _format_powers({k: a.get(k, 0) - b.get(k, 0) for k in set(a) | set(b) if a.get(k, 0) != b.get(k, 0)})


@dataclass(frozen=True)
class BaseParameter:
    """β = θ_name + Σ coefficient·θ_dependent: one regrouped base parameter."""

    name: str  # the independent parameter it is named after
    unit: str  # readable unit of β (= of θ_name)
    terms: tuple[tuple[str, float, str], ...]  # (dependent name, coefficient, coefficient unit)

    def expression(self, digits: int = 4) -> str:
        """e.g. "Link1.Izz + 0.09 m²·Link2.m + Joint1.Ia"."""
        parts = [self.name]
        for dep, c, u in self.terms:
            sign = "−" if c < 0 else "+"
            if not u and abs(abs(c) - 1.0) < 1e-9:  # "+ Joint1.Ia", not "+ 1·Joint1.Ia"
                parts.append(f"{sign} {dep}")
            else:
                parts.append(f"{sign} {abs(c):.{digits}g}{' ' + u if u else ''}·{dep}")
        return " ".join(parts)


@dataclass(frozen=True, eq=False)
class BaseParameters:
    """The regrouping β = C θ (r, p) of a parameter space by a stacked regressor (module docstring)."""

    parameters: ParameterSpace
    independent: tuple[int, ...]  # (r,) indices of the parameters the base parameters are named after
    dependent: tuple[int, ...]  # indices of parameters that enter some base parameter through a coefficient
    no_effect: tuple[int, ...]  # indices of parameters whose regressor column is zero: in no base parameter
    C: np.ndarray  # (r, p): β = C θ; C[k, independent[k]] = 1

    def __post_init__(self) -> None:
        C = np.array(self.C, dtype=float)
        C.setflags(write=False)
        object.__setattr__(self, "C", C)

    @property
    def rank(self) -> int:
        return len(self.independent)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.parameters.names[k] for k in self.independent)

    @property
    def units(self) -> tuple[str, ...]:
        return tuple(readable_unit(self.parameters.units[k]) for k in self.independent)

    @property
    def items(self) -> tuple[BaseParameter, ...]:
        P = self.parameters
        out = []
        for row, k in enumerate(self.independent):
            terms = tuple(
                (P.names[j], float(self.C[row, j]), unit_ratio(P.units[k], P.units[j]))
                for j in np.flatnonzero(self.C[row]) if j != k
            )
            out.append(BaseParameter(P.names[k], readable_unit(P.units[k]), terms))
        return tuple(out)

    def values(self, theta: np.ndarray) -> np.ndarray:
        """β = C θ (r,) of a full parameter vector θ (p,)."""
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (self.parameters.p,):
            raise DataError(f"base parameters: expected θ of shape ({self.parameters.p},), got {theta.shape}")
        return self.C @ theta

    def regressor(self, Y: np.ndarray) -> np.ndarray:
        """The base regressor Y[..., independent] (…, r): Y θ = Y_base β on the data that defined it."""
        return np.asarray(Y)[..., list(self.independent)]

    def embed(self) -> np.ndarray:
        """E (p, r) with C E = I: β placed on its independent parameter, dependents at zero."""
        E = np.zeros((self.parameters.p, self.rank))
        E[list(self.independent), np.arange(self.rank)] = 1.0
        return E

    def describe(self, theta: np.ndarray | None = None, max_items: int | None = None) -> str:
        """One line per base parameter (name [unit] = expression, with its value when θ is given);
        complete unless max_items is given, and then it says how many more there are."""
        P = self.parameters
        beta = None if theta is None else self.values(theta)
        lines = []
        items = self.items
        shown = items if max_items is None else items[:max_items]
        for k, b in enumerate(shown):
            value = "" if beta is None else f" = {beta[k]:.6g}"
            lines.append(f"  β{k + 1} [{b.unit}] {b.expression()}{value}")
        if len(shown) < len(items):
            lines.append(f"  … and {len(items) - len(shown)} more")
        if self.no_effect:
            lines.append(f"  no effect on these data ({len(self.no_effect)}): "
                         + ", ".join(P.names[j] for j in self.no_effect))
        return "\n".join(lines)


def lead_preference(name: str) -> float:
    """Column weight in the pivoting: 4 for inertias, 2 for first moments, 1 for masses and the rest, so that
    among dependent columns the one kept is, as in the classic regrouping (Khalil & Gautier), an inertia or a first
    moment, which absorbs the masses and rotor inertias (armature) that act like it."""
    last = name.rsplit(".", 1)[-1]
    if last in ("Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz"):
        return 4.0
    return 2.0 if last.startswith("mc_") else 1.0


def base_parameters(A: np.ndarray, parameters: ParameterSpace, rank: int | None = None) -> BaseParameters:
    """The regrouping of ``parameters`` by the stacked regressor A (N·n, p) (module docstring); ``rank``:
    the rank under dualid.linalg's rule when the caller has it already."""
    A = np.asarray(A, dtype=float)
    p = parameters.p
    if A.ndim != 2 or A.shape[1] != p:
        raise DataError(f"base parameters: expected a stacked regressor with {p} columns, got shape {A.shape}")
    s = np.linalg.norm(A, axis=0)
    zero = s <= 1e-300
    s[zero] = 1.0
    s = s / np.array([lead_preference(name) for name in parameters.names])
    As = A / s
    if As.shape[0] > 4 * p:  # the column geometry of A is that of R (AᵀA = RᵀR): factor the small R
        As = np.linalg.qr(As, mode="r")
    if rank is None:
        rank = rank_from_singular_values(np.linalg.svd(As, compute_uv=False))
    _, R, piv = scipy.linalg.qr(As, mode="economic", pivoting=True)
    ind = np.array(piv[:rank], dtype=int)
    dep = np.array(piv[rank:], dtype=int)
    K = scipy.linalg.solve_triangular(R[:rank, :rank], R[:rank, rank:]) if rank and len(dep) else np.zeros((rank, 0))
    K[np.abs(K) < DROP_TOL] = 0.0
    K[:, zero[dep]] = 0.0
    order = np.argsort(ind)  # base parameters in the parameter space's order
    ind, K = ind[order], K[order]
    C = np.zeros((rank, p))
    C[np.arange(rank), ind] = 1.0
    C[:, dep] = K * s[dep][None, :] / s[ind][:, None]
    used = np.any(C[:, dep] != 0, axis=0)
    return BaseParameters(
        parameters,
        tuple(int(j) for j in ind),
        tuple(int(j) for j in sorted(dep[used])),
        tuple(int(j) for j in sorted(dep[~used])),
        C,
    )


@dataclass(frozen=True)
class Identifiability:
    """What the stacked regressor determines: rank, conditioning, the unidentifiable directions and the
    base parameters."""

    rank: int
    n_params: int
    condition_number: float  # σ_max / σ_min over the identifiable directions (column-scaled)
    singular_values: np.ndarray  # of the column-scaled stacked regressor
    null_space: np.ndarray  # (p, p − rank) directions of θ that do not change Yθ
    unidentifiable: tuple[str, ...]  # parameters that have a component in the null space
    names: tuple[str, ...]
    base: BaseParameters | None = None

    @property
    def full_rank(self) -> bool:
        return self.rank == self.n_params

    def describe(self, max_items: int | None = None) -> str:
        """A readable account: rank, the base parameters (complete unless max_items says otherwise, and
        then with how many more) and the parameters with no effect."""
        if self.full_rank:
            return f"all {self.n_params} parameters are identifiable (condition number {self.condition_number:.3g})"
        lines = [
            f"rank {self.rank} of {self.n_params}: {self.n_params - self.rank} unidentifiable "
            f"direction(s); condition number of the identifiable part {self.condition_number:.3g}"
        ]
        if self.base is not None and max_items == 0:  # the summary alone
            lines.append(f"{self.base.rank} base parameters, {len(self.base.no_effect)} parameters with no effect "
                         "(listed in full by describe(); in a fit: identifiability.txt)")
        elif self.base is not None:
            lines.append(f"{self.base.rank} base parameters (QR with column pivoting; β = the named parameter + "
                         "the dependent ones it absorbs):")
            lines.append(self.base.describe(max_items=max_items))
        return "\n".join(lines)


def identifiability(A: np.ndarray, parameters: ParameterSpace) -> Identifiability:
    """Rank, null space and base parameters of the stacked regressor A (N·n, p) (columns scaled to unit
    norm first; the rank rule is dualid.linalg's)."""
    p = parameters.p
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1.0
    # SVD of the p×p triangular factor: cheap for N·n ≫ p
    if A.shape[0] > 4 * p:
        R = np.linalg.qr(A / scale, mode="r")
        _, s, Vt = np.linalg.svd(R)
    else:
        _, s, Vt = np.linalg.svd(A / scale, full_matrices=True)
    s_full = np.zeros(p)
    s_full[: len(s)] = s
    rank = rank_from_singular_values(s_full)
    null = Vt[rank:].T / scale[:, None]  # back to unscaled θ directions
    if null.size:
        null = null / np.linalg.norm(null, axis=0)
    in_null = np.linalg.norm(null, axis=1) > 1e-6 if null.size else np.zeros(p, bool)
    cond = float(s_full[0] / s_full[rank - 1]) if rank > 0 else float("inf")
    return Identifiability(
        rank=rank,
        n_params=p,
        condition_number=cond,
        singular_values=s_full,
        null_space=null,
        unidentifiable=tuple(nm for nm, z in zip(parameters.names, in_null) if z),
        names=parameters.names,
        base=base_parameters(A, parameters, rank),
    )


def check_identifiable(problem, rank: int | None = None, what: str = "regressor") -> None:
    """Raise IdentifiabilityError when the data of ``problem`` (an IdentificationProblem) do not determine θ (too
    few equations or rank < p): the estimators' check before a fit."""
    N, n, p = problem.N, problem.n, problem.p
    if N * n < p:
        raise IdentifiabilityError(
            f"too few samples: {N} samples × {n} coordinates = {N * n} equations for {p} parameters; "
            f"need at least {int(np.ceil(p / n))} exciting samples (or pass allow_unidentifiable=True)"
        )
    ident = None
    if rank is None:
        ident = problem.identifiability()
        rank = ident.rank
    if rank < p:
        ident = ident or problem.identifiability()  # the null space, for the message
        raise IdentifiabilityError(
            f"the {what} has rank {rank} < {p} parameters, so θ is not unique. "
            f"Not identifiable: {', '.join(ident.unidentifiable) or '(combinations below)'}.\n"
            f"{ident.describe()}\n"
            "Excite the system more, fix or regularize these parameters, or pass allow_unidentifiable=True "
            "to accept one of the minimisers."
        )
