"""The metric M_i(θ) = M_i0 + Σ_k θ_k M_ik, affine in θ, stored in factored form.

A rigid body contributes J_bᵀ G_b(θ_b) J_b to the mass matrix (J_b its 6×n body Jacobian, G_b its
spatial inertia, linear in its 10 parameters); a drag body contributes J_bᵀ D_b(θ_b) J_b. So the
metric is a sum of *terms*, each

    J_iᵀ G(θ) J_i,   G(θ) = Σ_k θ[indices_k] E_k,   J_i ∈ R^{d×n},  E_k ∈ S^d

and the dense N·p·n² tensor M_ik is not materialised for large systems (``basis()`` builds it for the SDP).
E may be shared by all samples (k, d, d) or per sample (N, k, d, d) (the generic dense case).

For a few coordinates (n ≤ DENSE_MAX_N) and at most DENSE_MAX_FLOATS numbers the metric keeps M_ik dense once it
has served a few passes (``dense_rows``): M_i(θ) is then one matrix–vector product and [M_ik w_i]_k one batched
product instead of several small products per term, 6–19× faster for n = 2…4; at n = 6 the gain varies from run to
run (1.3–3×) while the build passes 60 ms per 4,000 samples, and from n = 7 the dense form gains at most 1.3× (at
n = 8 its M_i(θ) is 1.8× slower; benchmarks/metric_dense.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dualid.errors import ModelError

DENSE_MAX_N = 4  # coordinates: up to this many the dense M_ik replaces the factored products (module doc)
DENSE_MAX_FLOATS = 4_000_000  # … while N·n²·p stays below this (32 MB) …
DENSE_AFTER = 4  # … once it has served this many times its samples (two passes of the dual-metric derivatives, 1.3 of
# dm's noise-model derivatives; ``dense_rows``)


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.flags.writeable and a.base is None:
        a.setflags(write=False)
        return a
    b = np.array(a, dtype=float)
    b.setflags(write=False)
    return b


@dataclass(frozen=True, eq=False)
class MetricTerm:
    """J_iᵀ (Σ_k θ[indices_k] E_k) J_i for every sample i."""

    indices: tuple[int, ...]  # (k,) parameter indices
    E: np.ndarray  # (k, d, d) or (N, k, d, d), symmetric, in units of the parameters' coefficients
    J: np.ndarray  # (N, d, n) Jacobian from coordinates to the term's frame

    def __post_init__(self) -> None:
        E = np.asarray(self.E, dtype=float)
        J = np.asarray(self.J, dtype=float)
        if J.ndim != 3:
            raise ModelError(f"MetricTerm: J must have shape (N, d, n), got {J.shape}")
        N, d, _ = J.shape
        k = len(self.indices)
        if E.shape not in ((k, d, d), (N, k, d, d)):
            raise ModelError(f"MetricTerm: E must have shape ({k}, {d}, {d}) or ({N}, {k}, {d}, {d}), got {E.shape}")
        if not np.allclose(E, np.swapaxes(E, -1, -2)):
            raise ModelError("MetricTerm: every E_k must be symmetric")
        object.__setattr__(self, "indices", tuple(int(i) for i in self.indices))
        if len(set(self.indices)) != len(self.indices):
            raise ModelError(f"MetricTerm: parameter indices must be distinct, got {self.indices}")
        object.__setattr__(self, "E", _readonly(E))
        object.__setattr__(self, "J", _readonly(J) if J.strides[0] != 0 else J)

    @property
    def per_sample(self) -> bool:
        return self.E.ndim == 4

    def G(self, theta: np.ndarray) -> np.ndarray:
        """(d, d) or (N, d, d): Σ_k θ[indices_k] E_k."""
        t = np.asarray(theta)[list(self.indices)]
        return np.tensordot(t, self.E, axes=([0], [-3]))

    def take(self, idx: np.ndarray) -> "MetricTerm":
        return MetricTerm(self.indices, self.E[idx] if self.per_sample else self.E, self.J[idx])


@dataclass(frozen=True, eq=False)
class AffineMetric:
    """M_i(θ) for N samples of an n-dimensional system with p parameters."""

    n_params: int  # p
    terms: tuple[MetricTerm, ...]
    M0: np.ndarray | None = None  # (N, n, n) parameter-free part, e.g. known rotor inertia

    def __post_init__(self) -> None:
        if not self.terms and self.M0 is None:
            raise ModelError("AffineMetric needs at least one term or a constant part M0")
        shapes = {(t.J.shape[0], t.J.shape[2]) for t in self.terms}
        if self.M0 is not None:
            M0 = _readonly(self.M0)
            if M0.ndim != 3 or M0.shape[1] != M0.shape[2]:
                raise ModelError(f"AffineMetric: M0 must have shape (N, n, n), got {M0.shape}")
            object.__setattr__(self, "M0", M0)
            shapes.add((M0.shape[0], M0.shape[1]))
        if len(shapes) != 1:
            raise ModelError(f"AffineMetric: terms disagree on (N, n): {sorted(shapes)}")
        for t in self.terms:
            bad = [i for i in t.indices if not 0 <= i < self.n_params]
            if bad:
                raise ModelError(f"AffineMetric: term indices {bad} outside 0..{self.n_params - 1}")

    @property
    def shape(self) -> tuple[int, int]:
        """(N, n)."""
        if self.terms:
            return self.terms[0].J.shape[0], self.terms[0].J.shape[2]
        return self.M0.shape[0], self.M0.shape[1]

    # --- evaluation -------------------------------------------------------------------------
    def evaluate(self, theta: np.ndarray, rows: slice | np.ndarray = slice(None), symmetric: bool = True) -> np.ndarray:
        """M_i(θ) for the selected samples, (N', n, n); symmetric=False skips the final symmetrisation (M_i is then
        symmetric up to rounding: a caller that reads only its lower triangle, e.g. a Cholesky factorisation)."""
        theta = np.asarray(theta, dtype=float)
        K = self.dense_rows(rows)
        if K is not None:
            c = K.shape[0]
            M = (K.reshape(-1, self.n_params) @ self._used(theta)).reshape(c, *K.shape[1:3])
            if self.M0 is not None:
                M += self.M0[rows]
            return 0.5 * (M + np.swapaxes(M, 1, 2)) if symmetric else M
        M = None
        for t in self.terms:
            G = t.G(theta)
            if t.per_sample:
                G = G[rows]
            J = t.J[rows]  # (N', d, n)
            Jt = np.swapaxes(J, 1, 2)
            # the Newton kernels' order (G J first: benchmarks/derivatives_speed.md); the symmetrised M keeps its own
            # order, so both give the values they gave before they shared this code
            term = np.matmul(Jt, np.matmul(G, J)) if not symmetric else Jt @ G @ J
            if M is None:
                M = term
            else:
                M += term
        if self.M0 is not None:
            M = self.M0[rows].copy() if M is None else M + self.M0[rows]
        return 0.5 * (M + np.swapaxes(M, 1, 2)) if symmetric else M

    def quad(self, w: np.ndarray, rows: slice | np.ndarray = slice(None)) -> np.ndarray:
        """(N', p): w_iᵀ M_ik w_i for w (N', n)."""
        K = self.dense_rows(rows)
        if K is not None:
            return np.einsum("ca,cak->ck", w, dense_apply(K, w))
        out = np.zeros((w.shape[0], self.n_params))
        for t, u, Eu in self.factors(w, rows):
            out[:, _as_slice(t.indices)] += np.einsum("ckd,cd->ck", Eu, u)
        return out

    def apply(self, w: np.ndarray, rows: slice | np.ndarray = slice(None)) -> np.ndarray:
        """(N', n, p): the columns M_ik w_i for w (N', n)."""
        K = self.dense_rows(rows)
        if K is not None:
            return dense_apply(K, w)
        out = np.zeros((w.shape[0], w.shape[1], self.n_params))
        for t, _, Eu in self.factors(w, rows):
            out[:, :, _as_slice(t.indices)] += np.matmul(np.swapaxes(t.J[rows], 1, 2), np.swapaxes(Eu, 1, 2))
        return out

    def apply_quad(self, w: np.ndarray, rows: slice | np.ndarray = slice(None),
                   out: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(out − [M_ik w_i]_k (N', n, p), Σ_i w_iᵀ M_ik w_i (p,)) in one pass over the factors, which the
        two share (u_i = J_i w_i and E_k u_i); ``out`` (N', n, p) is updated in place (zeros if None).
        The dual-metric gradient and Hessian need exactly this pair."""
        out = np.zeros((w.shape[0], w.shape[1], self.n_params)) if out is None else out
        K = self.dense_rows(rows)
        if K is not None:
            P = dense_apply(K, w)
            out -= P
            return out, np.einsum("ca,cak->k", w, P)
        wMw = np.zeros(self.n_params)
        for t, u, Eu in self.factors(w, rows):
            idx = _as_slice(t.indices)
            out[:, :, idx] -= np.matmul(np.swapaxes(t.J[rows], 1, 2), np.swapaxes(Eu, 1, 2))  # J_iᵀ E_k u_i
            wMw[idx] += np.einsum("ckd,cd->k", Eu, u)
        return out, wMw

    def factors(self, w: np.ndarray, rows):
        """Per term: (term, u_i = J_i w_i (c, d), E_k u_i (c, k, d)); a shared E is one GEMM."""
        for t in self.terms:
            J = t.J[rows]  # (c, d, n)
            u = np.einsum("cdn,cn->cd", J, w)
            c, d = u.shape
            if t.per_sample:
                Eu = np.einsum("ckde,ce->ckd", t.E[rows], u)
            else:
                k = t.E.shape[0]
                Eu = (u @ t.E.transpose(2, 0, 1).reshape(d, k * d)).reshape(c, k, d)  # E_k symmetric
            yield t, u, Eu

    @property
    def dense(self) -> np.ndarray | None:
        """K (N, n, n, p), K[i, a, b, k] = (M_ik)_ab (symmetric up to rounding), once built (``dense_rows``); else None."""
        return self.__dict__.get("_dense")

    def dense_rows(self, rows) -> np.ndarray | None:
        """K[rows] of the dense form for a small system (module doc), built once this metric has served DENSE_AFTER × N
        samples (each call counts its rows): a metric used for one pass, such as a block of streamed data, never pays
        for it. None otherwise: the factored products."""
        K = self.dense
        if K is None:
            N, n = self.shape
            if not self.terms or n > DENSE_MAX_N or N * n * n * self.n_params > DENSE_MAX_FLOATS:
                return None
            if isinstance(rows, slice):
                count = len(range(N)[rows])
            else:  # indices, or a boolean mask: the rows it selects
                count = int(np.count_nonzero(rows)) if np.asarray(rows).dtype == bool else len(rows)
            self.__dict__["_served"] = self.__dict__.get("_served", 0) + count
            if self.__dict__["_served"] < DENSE_AFTER * N:
                return None
            K = self._dense_basis()
            K.setflags(write=False)
            self.__dict__["_dense"] = K
        return K[rows]

    def _used(self, theta: np.ndarray) -> np.ndarray:
        """θ with the entries no term uses set to 0 (the dense product reads every entry; 0·NaN would be NaN)."""
        used = self.__dict__.get("_used_mask")
        if used is None:
            used = np.zeros(self.n_params, dtype=bool)
            used[[i for t in self.terms for i in t.indices]] = True
            self.__dict__["_used_mask"] = used
        return np.where(used, theta, 0.0)

    def __getstate__(self) -> dict:  # pickled (e.g. to a Dask worker) without the dense form, rebuilt there if used
        return {k: v for k, v in self.__dict__.items() if k not in ("_dense", "_served")}

    def basis(self, rows: slice | np.ndarray = slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """Dense (M_0 (N', n, n), M_k (N', p, n, n)); costs N'·p·n² memory: the SDP's form (by the einsum the SDP was
        validated with: its conic solver's status on degenerate problems, f* = 0 or an infimum not attained, moves with
        the input's rounding, as on 5 of 15 corpus references with the dense form's GEMM)."""
        N, n = self.shape
        idx = np.arange(N)[rows]
        Mk = np.zeros((len(idx), self.n_params, n, n))
        for t in self.terms:
            J = t.J[rows]
            E = t.E[rows] if t.per_sample else t.E[None]
            Mk[:, list(t.indices)] += np.einsum("ndi,nkde,nej->nkij", J, E, J)
        M0 = self.M0[rows] if self.M0 is not None else np.zeros((len(idx), n, n))
        return M0, Mk

    def _dense_basis(self) -> np.ndarray:
        """K (N, n, n, p), K[i, a, b, k] = (M_ik)_ab, by one GEMM per term of shared E."""
        N, n = self.shape
        K = np.zeros((N, n, n, self.n_params))
        for t in self.terms:
            if t.per_sample:
                K[..., list(t.indices)] += np.einsum("ndi,nkde,nej->nijk", t.J, t.E, t.J)
                continue
            d, k = t.J.shape[1], len(t.indices)  # J_iᵀ (E_k J_i): E_k J_i for every i and k as one GEMM, …
            Jt = np.swapaxes(t.J, 1, 2)  # (N, n, d)
            EJ = (Jt.reshape(N * n, d) @ t.E.transpose(2, 1, 0).reshape(d, d * k)).reshape(N, n, d, k)
            EJ = np.ascontiguousarray(np.swapaxes(EJ, 1, 2)).reshape(N, d, n * k)  # (E_k J_i)_db at [i, d, (b, k)]
            K[..., _as_slice(t.indices)] += np.matmul(Jt, EJ).reshape(N, n, n, k)  # … then J_iᵀ · per sample
        return K

    # --- transformations --------------------------------------------------------------------
    def take(self, idx: np.ndarray) -> "AffineMetric":
        """The metric at samples idx (with the dense M_ik at those samples, if this metric has made it)."""
        taken = AffineMetric(
            self.n_params,
            tuple(t.take(idx) for t in self.terms),
            None if self.M0 is None else self.M0[idx],
        )
        if self.dense is not None and taken.shape[0] * self.dense[0].size <= DENSE_MAX_FLOATS:
            K = np.array(self.dense[idx])  # a copy: the subset does not keep the whole form alive
            K.setflags(write=False)
            taken.__dict__["_dense"] = K
        return taken

    def pullback(self, B: np.ndarray) -> "AffineMetric":
        """M̃_i = B_iᵀ M_i B_i for a change of coordinates q = φ(q̃), B = ∂φ/∂q̃ ((n, n) or (N, n, n))."""
        N, n = self.shape
        B = np.broadcast_to(np.asarray(B, dtype=float), (N, n, n))
        terms = tuple(MetricTerm(t.indices, t.E, t.J @ B) for t in self.terms)
        M0 = None if self.M0 is None else np.swapaxes(B, 1, 2) @ self.M0 @ B
        return AffineMetric(self.n_params, terms, M0)

    def with_n_params(self, p: int, offset: int = 0) -> "AffineMetric":
        """The same metric inside a larger θ ∈ R^p whose slice [offset, offset+self.p) is this θ."""
        if offset + self.n_params > p:
            raise ModelError(f"with_n_params: {offset} + {self.n_params} > {p}")
        terms = tuple(MetricTerm(tuple(i + offset for i in t.indices), t.E, t.J) for t in self.terms)
        return AffineMetric(p, terms, self.M0)

    def plus(self, other: "AffineMetric") -> "AffineMetric":
        """The sum of two metrics over the same samples and parameter vector."""
        if other.n_params != self.n_params or other.shape != self.shape:
            raise ModelError(
                f"AffineMetric.plus: shapes differ ({self.shape}, p={self.n_params}) vs "
                f"({other.shape}, p={other.n_params})"
            )
        if self.M0 is None:
            M0 = other.M0
        elif other.M0 is None:
            M0 = self.M0
        else:
            M0 = self.M0 + other.M0
        return AffineMetric(self.n_params, self.terms + other.terms, M0)

    @staticmethod
    def from_dense(Mk: np.ndarray, M0: np.ndarray | None = None) -> "AffineMetric":
        """A metric from dense per-sample bases M_k (N, p, n, n) (costly; prefer factored terms)."""
        Mk = np.asarray(Mk, dtype=float)
        if Mk.ndim != 4 or Mk.shape[2] != Mk.shape[3]:
            raise ModelError(f"from_dense: Mk must have shape (N, p, n, n), got {Mk.shape}")
        N, p, n, _ = Mk.shape
        J = np.broadcast_to(np.eye(n), (N, n, n))
        return AffineMetric(p, (MetricTerm(tuple(range(p)), Mk, J),), M0)

    @staticmethod
    def concatenate(metrics: list["AffineMetric"]) -> "AffineMetric":
        """Stack the samples of several metrics with the same term structure (e.g. several runs)."""
        first = metrics[0]
        if len(metrics) == 1:
            return first
        for m in metrics[1:]:
            if m.n_params != first.n_params or len(m.terms) != len(first.terms):
                raise ModelError("AffineMetric.concatenate: metrics have different structure")
        terms = []
        for j, t in enumerate(first.terms):
            parts = [m.terms[j] for m in metrics]
            if any(q.indices != t.indices for q in parts):
                raise ModelError("AffineMetric.concatenate: terms have different parameter indices")
            E = np.concatenate([q.E for q in parts]) if t.per_sample else t.E
            terms.append(MetricTerm(t.indices, E, np.concatenate([np.asarray(q.J) for q in parts])))
        if any((m.M0 is None) != (first.M0 is None) for m in metrics):
            raise ModelError("AffineMetric.concatenate: some metrics have M0 and some do not")
        M0 = None if first.M0 is None else np.concatenate([m.M0 for m in metrics])
        return AffineMetric(first.n_params, tuple(terms), M0)


def dense_apply(K: np.ndarray, w: np.ndarray) -> np.ndarray:
    """[M_ik w_i]_k (c, n, p) from the dense K (c, n, n, p): Σ_b (M_ik)_ba w_ib, a (1 × n)(n × n·p) product per sample."""
    c, n, _, p = K.shape
    return np.matmul(w[:, None, :], K.reshape(c, n, n * p))[:, 0].reshape(c, n, p)


def _as_slice(indices: tuple[int, ...]):
    """A slice when the indices are consecutive (cheap in-place updates), else the index list."""
    if indices and list(indices) == list(range(indices[0], indices[0] + len(indices))):
        return slice(indices[0], indices[0] + len(indices))
    return list(indices)
