"""Optimising the Fourier coefficients: SLSQP (scipy.optimize) from several random starts.

The criterion is evaluated on ``grid`` samples per period, its gradient by scipy's finite differences;
the limits are inequality constraints on the same samples with exact Jacobians (position, velocity and
acceleration are linear in the coefficients, the torque's comes from ``pin.computeRNEADerivatives``).
Every start is a random series (amplitudes ∝ 1/k) scaled to half the largest feasible amplitude. After
SLSQP the result is checked at ``check_rate`` (1 kHz by default): between grid samples a limit may be
exceeded slightly, and then the whole motion is scaled down (q − q_start, v and a shrink linearly)
until every limit holds at that rate; the scale is recorded in the result, never hidden.
The random baseline of the benchmark (``random_trajectory``) is the same series scaled to the largest
amplitude that satisfies every limit at ``check_rate``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from dualid.errors import SolverError
from dualid.excite.config import ExciteConfig
from dualid.excite.design import Design
from dualid.excite.fourier import FourierTrajectory, free_basis

MARGIN = 1e-6  # the constraints keep this fraction of each limit free (SLSQP's feasibility tolerance)
REFINE = 5  # rounds of adding violating check-rate samples to the constraint times
Progress = Callable[[int, int, float | None], None]  # (restarts done, total, best value so far)


@dataclass(frozen=True)
class LimitCheck:
    """The largest |value| / limit of each kind over joints and samples at ``rate`` (≤ 1: the limit holds).
    Position: the excursion from q_start over the room to the limit on that side."""

    rate: float
    worst: dict[str, float]

    @property
    def ok(self) -> bool:
        return all(r <= 1.0 + 1e-9 for r in self.worst.values())


def check_limits(design: Design, traj: FourierTrajectory, rate: float) -> LimitCheck:
    """Every limit of ``design`` on ``traj`` sampled at ``rate`` [Hz]."""
    q, v, a = traj.evaluate(traj.times(rate))
    return LimitCheck(rate, _ratios(design, q, v, a, design.torque(q, v, a)))


def _ratio_arrays(design: Design, q, v, a, tau) -> dict[str, np.ndarray]:
    """|value| / limit per kind, each (T, n)."""
    L, dq = design.limits, q - design.q_start
    room = np.where(dq >= 0, L.upper - design.q_start, design.q_start - L.lower)
    with np.errstate(divide="ignore", invalid="ignore"):
        pos = np.where(np.abs(dq) > 0, np.abs(dq) / room, 0.0)
    return {"position": pos, "velocity": np.abs(v) / L.velocity, "acceleration": np.abs(a) / L.acceleration,
            "effort": np.abs(tau) / L.effort}


def _ratios(design: Design, q, v, a, tau) -> dict[str, float]:
    return {k: float(np.max(r)) for k, r in _ratio_arrays(design, q, v, a, tau).items()}


class _Problem:
    """The SLSQP problem on a time grid: x = the free coefficients (n·m,), m = 2(K − 1) per joint."""

    def __init__(self, design: Design, config: ExciteConfig, distance=None):
        self.design, self.config = design, config
        self.distance = distance if config.min_distance is not None else None  # LinkDistance or None
        self.t = np.linspace(0.0, config.period, config.grid, endpoint=False)  # criterion samples
        self.B = free_basis(self.t, config.period, config.harmonics)  # (B_q, B_v, B_a), each (T, m)
        self.m = self.B[0].shape[1]
        self.constrain_at(self.t)

    def constrain_at(self, t: np.ndarray) -> None:
        """Evaluate the constraints at times t (the grid, plus the samples where a check found a violation)."""
        self.tc = np.asarray(t, dtype=float)
        self.Bc = free_basis(self.tc, self.config.period, self.config.harmonics)
        self.A, self.b = self._linear()
        self._cache = self._dcache = None

    def states(self, x: np.ndarray, B=None):
        X = x.reshape(self.design.n, self.m)
        Bq, Bv, Ba = self.B if B is None else B
        return self.design.q_start + Bq @ X.T, Bv @ X.T, Ba @ X.T

    def trajectory(self, x: np.ndarray) -> FourierTrajectory:
        return FourierTrajectory.at_rest(self.config.period, self.design.q_start, x.reshape(self.design.n, self.m))

    def objective(self, x: np.ndarray) -> float:
        value = self.design.criterion(self.config.criterion, *self.states(x))
        return value if np.isfinite(value) else 1e6  # a singular design: far worse than any regular one

    def _linear(self):
        """g_lin = b + A x ≥ 0: the position, velocity and acceleration limits, each over its limit."""
        d, L = self.design, self.design.limits
        n, m = d.n, self.m
        rows, offsets = [], []
        for j in range(n):
            for basis, lo, hi in ((self.Bc[0], L.lower[j] - d.q_start[j], L.upper[j] - d.q_start[j]),
                                  (self.Bc[1], -L.velocity[j], L.velocity[j]),
                                  (self.Bc[2], -L.acceleration[j], L.acceleration[j])):
                for bound, sign in ((hi, -1.0), (lo, 1.0)):  # hi − B x ≥ 0, B x − lo ≥ 0
                    if not np.isfinite(bound):
                        continue
                    scale = max(abs(bound), 1e-12)
                    bound = bound * (1 - MARGIN)
                    block = np.zeros((basis.shape[0], n * m))
                    block[:, j * m:(j + 1) * m] = sign * basis / scale
                    rows.append(block)
                    offsets.append(np.full(basis.shape[0], -sign * bound / scale))
        if not rows:
            return np.zeros((0, n * m)), np.zeros(0)
        return np.vstack(rows), np.concatenate(offsets)

    def _torque(self, x: np.ndarray):
        key = x.tobytes()
        if self._cache is None or self._cache[0] != key:
            self._cache = (key, self.design.torque(*self.states(x, self.Bc), jacobian=True))
        return self._cache[1]

    def _distance(self, x: np.ndarray):
        key = x.tobytes()
        if self._dcache is None or self._dcache[0] != key:
            self._dcache = (key, self.distance.gradient(self.states(x, self.Bc)[0]))
        return self._dcache[1]

    def constraints(self, x: np.ndarray) -> np.ndarray:
        tau = self._torque(x)[0]
        eff = self.design.limits.effort
        k = np.isfinite(eff)
        g = [self.b + self.A @ x, (1 - MARGIN - tau[:, k] / eff[k]).ravel(), (1 - MARGIN + tau[:, k] / eff[k]).ravel()]
        if self.distance is not None:  # (d − d_min) / d_min ≥ 0 at every grid sample
            g.append(self._distance(x)[0] / self.config.min_distance - 1 - MARGIN)
        return np.concatenate(g)

    def constraints_jacobian(self, x: np.ndarray) -> np.ndarray:
        _, dq, dv, da = self._torque(x)
        Bq, Bv, Ba = self.Bc
        T, n, m = Bq.shape[0], self.design.n, self.m
        J = (dq[..., None] * Bq[:, None, None, :] + dv[..., None] * Bv[:, None, None, :]
             + da[..., None] * Ba[:, None, None, :]).reshape(T, n, n * m)  # ∂τ_i/∂x at each sample
        eff = self.design.limits.effort
        k = np.isfinite(eff)
        Jt = (J[:, k, :] / eff[k][None, :, None]).reshape(-1, n * m)
        rows = [self.A, -Jt, Jt]
        if self.distance is not None:
            G = self._distance(x)[1]  # (T, n) ∂d/∂q
            rows.append((G[:, :, None] * Bq[:, None, :]).reshape(T, n * m) / self.config.min_distance)
        return np.vstack(rows)

    def bounds(self) -> list[tuple[float | None, float | None]]:
        """|x_jk| ≤ the largest amplitude one harmonic alone may have: v_max, k ω·(position room) and
        a_max / (k ω) (each where finite); keeps SLSQP's steps inside a box around the feasible set."""
        d, L, K = self.design, self.design.limits, self.config.harmonics
        kw = np.arange(2, K + 1) * 2 * np.pi / self.config.period
        out = []
        for j in range(d.n):
            room = max(L.upper[j] - d.q_start[j], d.q_start[j] - L.lower[j])
            bound = np.minimum(np.minimum(np.full(K - 1, L.velocity[j]), 2 * kw * room), 2 * L.acceleration[j] / kw)
            out += [(None, None) if not np.isfinite(c) else (-float(c), float(c)) for c in np.concatenate([bound, bound])]
        return out

    def solve(self, x0: np.ndarray, maxiter: int):
        return minimize(self.objective, x0, method="SLSQP",
                        constraints=[{"type": "ineq", "fun": self.constraints, "jac": self.constraints_jacobian}],
                        bounds=self.bounds(), options={"maxiter": maxiter, "ftol": 1e-7})

    def violations(self, x: np.ndarray, t: np.ndarray, most: int = 200) -> np.ndarray:
        """Up to ``most`` times of t where x exceeds a limit (or comes closer than min_distance) most: the
        local maxima of each sample's largest |value|/limit, worst first."""
        B = free_basis(t, self.config.period, self.config.harmonics)
        q, v, a = self.states(x, B)
        ratio = np.max([r.max(axis=1) for r in _ratio_arrays(self.design, q, v, a, self.design.torque(q, v, a)).values()],
                       axis=0)
        if self.distance is not None:  # closer than min_distance counts as a violation too
            d = self.distance(q)
            with np.errstate(divide="ignore"):
                ratio = np.maximum(ratio, np.where(d > 0, self.config.min_distance / d, np.inf))
        peak = (ratio >= np.roll(ratio, 1)) & (ratio >= np.roll(ratio, -1))  # one sample per excursion
        bad = np.flatnonzero((ratio > 1.0) & peak)
        return t[bad[np.argsort(-ratio[bad])][:most]]

    def random_x(self, rng: np.random.Generator) -> np.ndarray:
        """Free coefficients with amplitudes ∝ 1/k (harmonics 2..K), unscaled."""
        K = self.config.harmonics
        k = np.concatenate([np.arange(2, K + 1)] * 2)
        return (rng.normal(size=(self.design.n, self.m)) / k).ravel()

    def max_scale(self, x: np.ndarray, t: np.ndarray, iterations: int = 40) -> float:
        """The largest s with every limit satisfied by s·x at times t (bisection on the torque)."""
        Bq, Bv, Ba = free_basis(t, self.config.period, self.config.harmonics)
        X = x.reshape(self.design.n, self.m)
        q1, v1, a1 = Bq @ X.T, Bv @ X.T, Ba @ X.T

        def ratio(s: float) -> float:
            q, v, a = self.design.q_start + s * q1, s * v1, s * a1
            worst = max(_ratios(self.design, q, v, a, self.design.torque(q, v, a)).values())
            if self.distance is not None:
                d = self.distance(q).min()
                worst = max(worst, self.config.min_distance / d if d > 0 else np.inf)
            return worst

        linear = _ratios(self.design, self.design.q_start + q1, v1, a1, np.zeros_like(v1))  # effort 0 here
        s_hi = 1.0 / max(max(linear.values()), 1e-300)
        if ratio(s_hi) <= 1.0:
            return s_hi
        if ratio(0.0) > 1.0:
            raise SolverError("excite: the start configuration violates a limit, so no motion from it is feasible")
        lo, hi = 0.0, s_hi
        for _ in range(iterations):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if ratio(mid) <= 1.0 else (lo, mid)
        return lo


@dataclass(frozen=True)
class Restart:
    """One SLSQP run: its status, the criterion it reached and the scale the 1 kHz check applied."""

    index: int
    status: int
    message: str
    iterations: int  # SLSQP iterations, summed over the re-solves of the 1 kHz refinement
    value: float  # the criterion after the scale (inf: failed)
    scale: float  # 1.0 when the optimum satisfied every limit at check_rate


@dataclass(frozen=True, eq=False)
class Excitation:
    """The designed trajectory and how it was found."""

    trajectory: FourierTrajectory
    design: Design
    config: ExciteConfig
    value: float  # the criterion (minimised) at the chosen trajectory, on the grid
    restarts: tuple[Restart, ...]
    best: int  # index of the chosen restart
    check: LimitCheck

    @property
    def scaled(self) -> bool:
        return self.restarts[self.best].scale < 1.0


def optimize(design: Design, config: ExciteConfig, progress: Progress | None = None, distance=None) -> Excitation:
    """The trajectory minimising ``config.criterion`` under the limits, best of ``config.restarts`` SLSQP runs.
    ``distance``: a ``collision.LinkDistance``, used when ``config.min_distance`` is set (a restart whose
    result comes closer than that at ``check_rate`` is counted as failed: criterion inf)."""
    problem = _Problem(design, config, distance)
    rng = np.random.default_rng(config.seed)
    check_t = np.linspace(0.0, config.period, max(int(round(config.period * config.check_rate)), 1) + 1)
    runs, xs = [], []
    best_value = None
    for r in range(config.restarts):
        x0 = problem.random_x(rng)
        x0 = x0 * 0.5 * problem.max_scale(x0, problem.t)
        problem.constrain_at(problem.t)
        res = problem.solve(x0, config.maxiter)
        iterations = int(res.nit)
        for _ in range(REFINE):  # add the check-rate samples that exceed a limit to the constraint times, re-solve
            worst = problem.violations(res.x, check_t)
            if worst.size == 0:
                break
            problem.constrain_at(np.union1d(problem.tc, worst))
            res = problem.solve(res.x, config.maxiter)
            iterations += int(res.nit)
        x = res.x
        scale = 1.0 if problem.violations(x, check_t, most=1).size == 0 else min(1.0, problem.max_scale(x, check_t))
        x = x * scale
        value = problem.objective(x)
        if problem.distance is not None and problem.distance(problem.trajectory(x).evaluate(check_t)[0]).min() \
                < config.min_distance:
            value = float("inf")
        runs.append(Restart(r, int(res.status), str(res.message), iterations, value, scale))
        xs.append(x)
        best_value = value if best_value is None else min(best_value, value)
        if progress is not None:
            progress(r + 1, config.restarts, best_value)
    best = int(np.argmin([run.value for run in runs]))
    if not np.isfinite(runs[best].value):
        raise SolverError(f"excite: none of the {config.restarts} restarts found a feasible trajectory: "
                          + "; ".join(f"restart {r.index}: {r.message}" for r in runs))
    traj = problem.trajectory(xs[best])
    check = check_limits(design, traj, config.check_rate)
    if not check.ok:  # pragma: no cover - the scale above makes every limit hold at check_rate
        raise SolverError(f"excite: the chosen trajectory exceeds a limit at {config.check_rate} Hz: {check.worst}")
    return Excitation(traj, design, config, runs[best].value, tuple(runs), best, check)


def random_trajectory(design: Design, config: ExciteConfig, rng: np.random.Generator) -> FourierTrajectory:
    """A random series of the same period and harmonics, scaled to the largest amplitude that keeps every
    limit at ``config.check_rate`` (the benchmark's baseline)."""
    problem = _Problem(design, config)
    x = problem.random_x(rng)
    check_t = np.linspace(0.0, config.period, max(int(round(config.period * config.check_rate)), 1) + 1)
    return problem.trajectory(x * problem.max_scale(x, check_t) * (1 - 1e-9))
