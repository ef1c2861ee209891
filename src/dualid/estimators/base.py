"""What every estimator shares: checks on the problem, physical-consistency constraints, solving.

Estimators take hyperparameters in their constructor and the problem in ``fit``; they hold no
state between fits and return an immutable ``IdentificationResult``.
"""

from __future__ import annotations

import os
import time
import warnings
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np

from dualid.errors import ConfigError, SolverError, SolverOptionError, SolverOutputWarning
from dualid.problem import IdentificationProblem

SOLVERS = ("CLARABEL", "SCS")  # the conic solvers behind solver="cvxpy" (cvxpy_solver=...)
SOLVER_NAMES = ("newton", "cvxpy")  # every estimator's solver=: dualid's interior point, or the conic reference
DEFAULT_OPTIONS = {
    "CLARABEL": {"tol_gap_abs": 1e-10, "tol_gap_rel": 1e-10, "tol_feas": 1e-10, "max_iter": 500},
    "SCS": {"eps": 1e-9, "max_iters": 200000},
}


def check_solver(solver, cvxpy_solver, who: str) -> None:
    """SolverOptionError unless solver is one of SOLVER_NAMES and cvxpy_solver one of SOLVERS; a conic solver's or
    the SDP's name given as solver gets a hint to the pair that selects it."""
    if solver not in SOLVER_NAMES:
        backend = {"sdp": cvxpy_solver, "sdp_clarabel": "CLARABEL", "sdp_scs": "SCS"}.get(solver, solver)
        hint = (f" (for {backend}: solver='cvxpy', cvxpy_solver={backend!r})"
                if isinstance(backend, str) and backend in SOLVERS else "")
        raise SolverOptionError(f"{who}: solver must be one of {SOLVER_NAMES}, got {solver!r}{hint}")
    if cvxpy_solver not in SOLVERS:
        raise SolverOptionError(f"{who}: cvxpy_solver must be one of {SOLVERS}, got {cvxpy_solver!r}")


def freeze_options(options: Mapping[str, Any] | None, what: str) -> tuple[tuple[str, Any], ...] | None:
    """A solver-options mapping as a sorted tuple of (key, value) pairs, so estimators stay hashable
    values; ``dict(frozen)`` gives it back."""
    if options is None:
        return None
    if not isinstance(options, (Mapping, tuple)):
        raise ConfigError(f"{what}: expected a mapping of option names to values, got {type(options).__name__}")
    items = tuple(sorted(dict(options).items()))
    for key, value in items:
        if not isinstance(key, str):
            raise ConfigError(f"{what}: option names must be strings, got {key!r}")
        if isinstance(value, (list, dict, np.ndarray)):
            raise ConfigError(f"{what}: option {key!r} must be a number, string or bool, got {type(value).__name__}")
    return items


def check_covariance(covariance, who: str) -> tuple[tuple[float, ...], ...] | None:
    """A given residual covariance (n, n): symmetric positive definite and finite; stored as tuples."""
    if covariance is None:
        return None
    C = np.asarray(covariance, dtype=float)
    if C.ndim != 2 or C.shape[0] != C.shape[1] or C.shape[0] == 0:
        raise ConfigError(f"{who}: covariance must be a square (n, n) matrix, got shape {C.shape}")
    if not np.all(np.isfinite(C)) or not np.allclose(C, C.T) or np.linalg.eigvalsh(0.5 * (C + C.T))[0] <= 0:
        raise ConfigError(f"{who}: covariance must be a finite symmetric positive-definite matrix")
    return tuple(tuple(float(x) for x in row) for row in C)


def is_problem_property(exc: SolverError) -> bool:
    """Infeasible, unbounded or an optimum at infinity: a property of the problem, which another solver cannot
    change (no fallback; the quadratic fits still check a cvxpy "infeasible" with dualid's interior point)."""
    return bool(exc.status) and any(s in exc.status for s in ("infeasible", "unbounded", "at_infinity"))


@contextmanager
def captured_warnings() -> Iterator[list[str]]:
    """Record the warnings raised inside (e.g. cvxpy's "Solution may be inaccurate") instead of printing
    them; the yielded list holds them, sorted and unique as "Category: message", once the block ends."""
    notes: list[str] = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield notes
    notes.extend(sorted({f"{w.category.__name__}: {w.message}" for w in caught}))


def parameter_scale(problem: IdentificationProblem) -> np.ndarray:
    """Per-parameter scale s_k (θ = s ⊙ φ) so the solver sees unit-norm regressor columns."""
    s = problem.column_norms()  # blockwise: np.linalg.norm(axis=0) would square a copy of Y
    ok = s > 0
    s[ok] = 1.0 / s[ok]
    s[~ok] = 1.0
    return s


@dataclass(frozen=True)
class Solved:
    value: np.ndarray
    status: str
    solver: str
    solve_time: float
    iterations: int | None


@contextmanager
def solver_stdout() -> Iterator[list[str]]:
    """What compiled solvers print to the process's standard output (file descriptor 1: SCS's "WARNING - large
    complementary slackness residual", "ERROR: could not determine problem status") inside the block, captured
    instead of reaching the terminal; the yielded list holds its non-empty lines once the block ends."""
    import ctypes
    import sys
    import tempfile

    lines: list[str] = []
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # no real stdout (e.g. a notebook): nothing to capture
        yield lines
        return
    libc = ctypes.CDLL(None)
    sys.stdout.flush()
    libc.fflush(None)
    saved = os.dup(fd)
    with tempfile.TemporaryFile() as scratch:  # a scratch buffer, not an output file
        os.dup2(scratch.fileno(), fd)
        try:
            yield lines
        finally:
            libc.fflush(None)
            os.dup2(saved, fd)
            os.close(saved)
            scratch.seek(0)
            lines.extend(x.strip() for x in scratch.read().decode(errors="replace").splitlines() if x.strip())


def solve_cvxpy(problem, variable, solver: str, solver_options: dict | None, what: str) -> Solved:
    """Solve a cvxpy problem; raise SolverError with the status unless it is optimal."""
    import cvxpy as cp

    if solver not in SOLVERS:
        raise ConfigError(f"solver: expected one of {SOLVERS}, got {solver!r}")
    options = dict(DEFAULT_OPTIONS.get(solver, {}))
    options.update(dict(solver_options or ()))
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*dimension greater than 2.*")
        try:
            with solver_stdout() as printed:
                problem.solve(solver=solver, **options)
        except (cp.error.SolverError, cp.error.DCPError) as exc:  # DCPError: rounding broke convexity (huge data)
            raise SolverError(f"{what}: {solver} failed: {exc}", status="solver_error") from exc
    for line in dict.fromkeys(printed):  # recorded by the caller's captured_warnings (solver_warnings)
        warnings.warn(f"{solver}: {line}", SolverOutputWarning, stacklevel=2)
    elapsed = time.perf_counter() - t0
    status = problem.status
    if status in (cp.INFEASIBLE, cp.INFEASIBLE_INACCURATE):
        raise SolverError(
            f"{what}: the problem is infeasible ({solver} status {status!r}); the constraints "
            "(physical consistency, bounds, positive-definite metric) admit no θ",
            status=status,
        )
    if status in (cp.UNBOUNDED, cp.UNBOUNDED_INACCURATE):
        raise SolverError(f"{what}: the problem is unbounded ({solver} status {status!r})", status=status)
    if status != cp.OPTIMAL and not (status == cp.OPTIMAL_INACCURATE and variable.value is not None):
        raise SolverError(f"{what}: {solver} returned status {status!r} without a solution", status=status)
    if variable.value is None or not np.all(np.isfinite(variable.value)):
        raise SolverError(f"{what}: {solver} reported {status!r} but returned no finite solution", status=status)
    iterations = getattr(problem.solver_stats, "num_iters", None)  # None without solver stats too
    return Solved(np.array(variable.value, dtype=float), status, solver, elapsed, iterations)
