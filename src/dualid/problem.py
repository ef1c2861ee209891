"""The identification problem: per-sample regressors, forces, metric and velocities, as a value.

    τ_i = Y_i θ + ε_i,     M_i(θ) = M_i0 + Σ_k θ_k M_ik,     i = 1..N

An ``IdentificationProblem`` is immutable (its arrays are read-only); transformations such as a
change of coordinates or a subsample return a new problem.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace

import numpy as np

from dualid.data.trajectory import Trajectory
from dualid.errors import DataError
from dualid.identifiability import Identifiability, identifiability
from dualid.linalg import triangular_factor
from dualid.model.base import Kind, Model
from dualid.model.metric import AffineMetric
from dualid.model.parameters import ParameterSpace

CHECK_CHUNK = 16384  # samples per block of the finiteness check and the column norms (no N-sized temporaries)


def _frozen(a, name: str, shape: tuple) -> np.ndarray:
    """A read-only float array: a private copy, unless ``a`` is already a read-only float64 array (then it
    is taken as it is, without copying: the caller gave up writing to it, see ``owned``)."""
    a = np.asarray(a)
    if a.dtype != np.float64 or a.flags.writeable:
        a = np.array(a, dtype=float)  # a private copy
    if a.shape != shape:
        raise DataError(f"{name}: expected shape {shape}, got {a.shape}")
    counts = [int(np.count_nonzero(~np.isfinite(a[s : s + CHECK_CHUNK]))) for s in range(0, a.shape[0], CHECK_CHUNK)]
    if any(counts):
        start = CHECK_CHUNK * next(k for k, c in enumerate(counts) if c)
        where = np.argwhere(~np.isfinite(a[start : start + CHECK_CHUNK]))[0]
        where[0] += start
        raise DataError(f"{name}: {sum(counts)} non-finite values (NaN or inf), first at index {where.tolist()}")
    if a.flags.writeable:
        a.setflags(write=False)
    return a


def owned(a: np.ndarray) -> np.ndarray:
    """``a`` (a freshly made float64 array nobody else writes to) marked read-only, so that
    IdentificationProblem takes it without a copy (at N = 10⁶ the Crazyflie's Y is 1.9 GB)."""
    a = np.asarray(a, dtype=float)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class IdentificationProblem:
    """Samples of inverse dynamics τ_i = Y_i θ with their metric M_i(θ), N samples, n dofs, p params."""

    Y: np.ndarray  # (N, n, p) regressor [force units per parameter unit]
    tau: np.ndarray  # (N, n) generalized forces (coordinate force units)
    metric: AffineMetric  # M_i(θ), (N, n, n) when evaluated
    v: np.ndarray  # (N, n) generalized velocities, for the energy residual v_iᵀ r_i
    parameters: ParameterSpace
    kind: Kind = "inertia"  # "inertia": M is the mass matrix; "drag": the resistance matrix
    coordinates: tuple[str, ...] = field(default=())  # names of the n coordinates
    # B_s (N, n, n) = ∂q_sensor/∂q: the chart the forces were measured in, as seen from this one
    # (τ = B_sᵀ τ_sensor); None: this problem is in its sensor chart. ``in_coordinates`` composes it,
    # so a sensor covariance Σ travels as Σ_i = B_sᵢᵀ Σ B_sᵢ (estimators fitted in the sensor chart: dm).
    sensor_chart: np.ndarray | None = None

    def __post_init__(self) -> None:
        Y = np.asarray(self.Y)
        if Y.ndim != 3:
            raise DataError(f"Y: expected shape (N, n, p), got {Y.shape}")
        N, n, p = Y.shape
        object.__setattr__(self, "Y", _frozen(Y, "Y", (N, n, p)))
        object.__setattr__(self, "tau", _frozen(self.tau, "tau", (N, n)))
        object.__setattr__(self, "v", _frozen(self.v, "v", (N, n)))
        if self.parameters.p != p:
            raise DataError(f"parameters: Y has {p} columns but the parameter space names {self.parameters.p}")
        if self.metric.shape != (N, n) or self.metric.n_params != p:
            raise DataError(
                f"metric: expected N={N} samples of {n}×{n} matrices in p={p} parameters, "
                f"got N={self.metric.shape[0]}, n={self.metric.shape[1]}, p={self.metric.n_params}"
            )
        if self.kind not in ("inertia", "drag"):
            raise DataError(f"kind: expected 'inertia' or 'drag', got {self.kind!r}")
        coords = tuple(self.coordinates) or tuple(f"q{j}" for j in range(n))
        if len(coords) != n:
            raise DataError(f"coordinates: expected {n} names, got {len(coords)}")
        object.__setattr__(self, "coordinates", coords)
        if self.sensor_chart is not None:
            S = np.asarray(self.sensor_chart, dtype=float)
            S = _frozen(np.broadcast_to(S, (N, n, n)) if S.shape == (n, n) else S, "sensor_chart", (N, n, n))
            if N and np.any(np.abs(np.linalg.det(S)) == 0.0):
                raise DataError("sensor_chart: expected invertible (n, n) Jacobians, got a singular one")
            object.__setattr__(self, "sensor_chart", S)
        if N == 0:
            raise DataError("the problem has no samples (N = 0)")

    # --- sizes ------------------------------------------------------------------------------
    @property
    def N(self) -> int:
        return self.Y.shape[0]

    @property
    def n(self) -> int:
        return self.Y.shape[1]

    @property
    def p(self) -> int:
        return self.Y.shape[2]

    # --- evaluation -------------------------------------------------------------------------
    def residual(self, theta: np.ndarray) -> np.ndarray:
        """r_i = Y_i θ − τ_i, (N, n)."""
        return self.Y @ np.asarray(theta, dtype=float) - self.tau

    def dual_metric_objective(self, theta: np.ndarray) -> float:
        """Σ r_iᵀ M_i(θ)⁻¹ r_i; +inf where some M_i(θ) is not positive definite."""
        r = self.residual(theta)
        M = self.metric.evaluate(theta)
        try:
            L = np.linalg.cholesky(M)
        except np.linalg.LinAlgError:
            return float("inf")
        z = np.linalg.solve(L, r[..., None])[..., 0]
        return float(np.sum(z * z))

    def identifiability(self) -> Identifiability:
        """Rank, null space and base parameters of the stacked regressor (dualid.identifiability), accumulated
        over blocks of samples (``identifiability_of``)."""
        return identifiability_of(self)

    def blocks(self):
        """The problem's samples as in-memory blocks: this problem itself (a ChunkedProblem, see
        dualid.streaming, yields one block per chunk of its source instead)."""
        yield self

    def column_norms(self) -> np.ndarray:
        """(p,) Euclidean norms of the stacked regressor's columns, accumulated over blocks of samples."""
        sq = np.zeros(self.p)
        for start in range(0, self.N, CHECK_CHUNK):
            Yc = self.Y[start : start + CHECK_CHUNK].reshape(-1, self.p)
            sq += np.einsum("kp,kp->p", Yc, Yc)
        return np.sqrt(sq)

    # --- transformations --------------------------------------------------------------------
    def subset(self, idx) -> "IdentificationProblem":
        """The problem restricted to samples idx (indices, slice or boolean mask)."""
        idx = np.arange(self.N)[idx]
        return IdentificationProblem(
            owned(self.Y[idx]), self.tau[idx], self.metric.take(idx), self.v[idx], self.parameters, self.kind,
            self.coordinates,
            None if self.sensor_chart is None else self.sensor_chart[idx],
        )

    def in_coordinates(self, B: np.ndarray, coordinates: tuple[str, ...] | None = None) -> "IdentificationProblem":
        """The same data in another chart q = φ(q̃), B = ∂φ/∂q̃ ((n, n) or (N, n, n), invertible).

        Forces are covectors and velocities vectors: τ̃ = Bᵀτ, Ỹ = BᵀY, M̃ = BᵀMB, ṽ = B⁻¹v. The
        sensor chart is composed: B̃_s = B_s B (identity B_s when the problem had none).
        """
        B = np.broadcast_to(np.asarray(B, dtype=float), (self.N, self.n, self.n))
        S = B if self.sensor_chart is None else self.sensor_chart @ B
        Bt = np.swapaxes(B, 1, 2)
        v = np.linalg.solve(B, self.v[..., None])[..., 0]
        return IdentificationProblem(
            owned(Bt @ self.Y),
            (Bt @ self.tau[..., None])[..., 0],
            self.metric.pullback(B),
            v,
            self.parameters,
            self.kind,
            coordinates or tuple(f"{c}~" for c in self.coordinates),
            S,
        )

    def in_sensor_chart(self) -> "IdentificationProblem":
        """The same data in the chart the forces were measured in (itself when sensor_chart is None)."""
        if self.sensor_chart is None:
            return self
        back = self.in_coordinates(np.linalg.inv(self.sensor_chart))
        return replace(back, sensor_chart=None)

    @staticmethod
    def concatenate(problems: list["IdentificationProblem"]) -> "IdentificationProblem":
        """Stack the samples of several problems (e.g. several runs) of the same system."""
        first = problems[0]
        if len(problems) == 1:
            return first
        for q in problems[1:]:
            if q.parameters != first.parameters or q.kind != first.kind or q.n != first.n:
                raise DataError("concatenate: problems describe different systems (parameters, kind or n differ)")
        charts = None
        if any(q.sensor_chart is not None for q in problems):
            eye = np.eye(first.n)
            charts = np.concatenate(
                [q.sensor_chart if q.sensor_chart is not None else np.broadcast_to(eye, (q.N, q.n, q.n)) for q in problems]
            )
        return IdentificationProblem(
            owned(np.concatenate([q.Y for q in problems])),
            np.concatenate([q.tau for q in problems]),
            AffineMetric.concatenate([q.metric for q in problems]),
            np.concatenate([q.v for q in problems]),
            first.parameters,
            first.kind,
            first.coordinates,
            charts,
        )


def additive(kernel):
    """Mark a pass over the data whose value is a sum of per-sample terms (a float, an array, or a tuple of them;
    None left alone). On a problem spread over partitions (one with ``map_sum``, ``dualid.distributed``) the pass
    runs where each partition lives and only the sums travel; on any other problem it runs as written."""

    @functools.wraps(kernel)
    def run(problem, *args, **kwargs):
        spread = getattr(problem, "map_sum", None)
        return kernel(problem, *args, **kwargs) if spread is None else spread(run, *args, **kwargs)

    return run


def stacked(kernel):
    """Mark a pass whose value is rows to stack (an (N, …) array, one row per sample, or a triangular factor): on a
    problem spread over partitions it runs on each partition and the rows are concatenated in the partitions' order
    (``map_concat``)."""

    @functools.wraps(kernel)
    def run(problem, *args, **kwargs):
        spread = getattr(problem, "map_concat", None)
        return kernel(problem, *args, **kwargs) if spread is None else spread(run, *args, **kwargs)

    return run


def add_sums(x, y):
    """x + y for the values of ``additive`` passes: floats and arrays added, sets joined, tuples element by element, None kept."""
    if x is None or y is None:
        return None if x is None and y is None else (x if y is None else y)
    if isinstance(x, (set, frozenset)):
        return x | y
    if isinstance(x, tuple):
        return tuple(add_sums(a, b) for a, b in zip(x, y, strict=True))
    return x + y


def identifiability_of(problem) -> Identifiability:
    """``problem.identifiability()`` for an IdentificationProblem or a ChunkedProblem. With more than 4p rows the
    stacked regressor A is replaced by its triangular factor R (AᵀA = RᵀR: same singular values, null space,
    column norms and pivoted-QR regrouping), accumulated over blocks of samples (TSQR: R = qr([R; A_block]) on
    column-scaled blocks, memory O(block·p), no copy of Y)."""
    p = problem.p
    if problem.N * problem.n > 4 * p:
        scale = problem.column_norms()
        scale[scale == 0] = 1.0
        R = np.linalg.qr(_scaled_factor(problem, scale), mode="r")  # spread: the factors of the partitions, stacked
        A = R * scale  # the factor of the unscaled A
    else:
        A = np.concatenate([b.Y.reshape(-1, p) for b in problem.blocks()])
    return identifiability(A, problem.parameters)


@stacked
def _scaled_factor(problem, scale: np.ndarray) -> np.ndarray:
    """R with RᵀR = AᵀA for the column-scaled stacked regressor A = [Y_i / scale] (TSQR over blocks of samples)."""
    blocks = (block.Y[rows].reshape(-1, problem.p) / scale for block, rows, _ in sample_blocks(problem, CHECK_CHUNK))
    return triangular_factor(blocks, problem.p)


def strided_rows(N: int, max_samples: int) -> slice:
    """Every k-th of N samples, k the smallest stride that leaves at most ``max_samples`` (every sample if N ≤ it)."""
    return slice(0, None, -(-N // max_samples))


def sample_blocks(problem, chunk: int):
    """(block, rows, offset) over every sample of ``problem`` (an IdentificationProblem or a ChunkedProblem):
    ``block`` an in-memory IdentificationProblem, ``rows`` a slice of at most ``chunk`` of its samples, and
    ``offset`` the index of the slice's first sample in the whole problem. The kernels that pass over the data
    (statistics, the Newton derivatives) iterate this way, so they work on data that are never all in memory."""
    offset = 0
    for block in problem.blocks():
        for start in range(0, block.N, chunk):
            rows = slice(start, min(start + chunk, block.N))
            yield block, rows, offset + start
        offset += block.N


def build_problem(model: Model, trajectories: list[Trajectory] | Trajectory) -> IdentificationProblem:
    """The identification problem of a model over one or several trajectories."""
    if isinstance(trajectories, Trajectory):
        trajectories = [trajectories]
    problems = []
    for traj in trajectories:
        if tuple(traj.coordinates) != tuple(model.coordinates):
            raise DataError(
                f"trajectory {traj.name!r}: coordinates {list(traj.coordinates)} do not match the model's "
                f"{list(model.coordinates)} (same names in the same order); load the log with the model's joint order"
            )
        if model.kind == "inertia" and traj.a is None:
            raise DataError(
                f"trajectory {traj.name!r} has no accelerations; an inertia-dominated model needs them "
                "(differentiate the velocities first, see dualid.data.preprocessing)"
            )
        problems.append(
            IdentificationProblem(
                Y=owned(model.regressor(traj.q, traj.v, traj.a)),
                tau=traj.tau,
                metric=model.metric(traj.q),
                v=traj.v,
                parameters=model.parameters,
                kind=model.kind,
                coordinates=model.coordinates,
            )
        )
    return IdentificationProblem.concatenate(problems)
