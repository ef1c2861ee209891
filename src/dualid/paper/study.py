"""The paper's experiments on a simulated system: fit every method, predict the test runs, score.

For each case ("low": a random rank-preserving subset of ``system.low_data_samples`` training
samples per seed; "high": every training sample) and each method, θ̂ is fitted on the training
problem, the forward dynamics are predicted on every test run from the measured states and inputs,
and compared with the measured signal (accelerations for inertia-dominated systems, velocities for
drag-dominated ones) per coordinate:

- score: max normalized cross-correlation over shifts within ±T_slowest/72;
- RMSE per coordinate (chart-dependent), and the chart-invariant sqrt(mean eᵀ M_true e).

Mean and standard deviation are taken over the pooled (seed, test run) pairs of successful fits;
failed fits (solver or metric errors) are recorded with their message and excluded from the
statistics, never zero-filled.

``ablation="units"`` fits in re-charted coordinates q = B q̃ with a constant diagonal B that
changes units (lengths to mm, angles to degrees) and predicts with the physical θ̂ in the original
model: the dual-metric fit must not move, the others may.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from dualid.errors import ConfigError, DualidError, IdentifiabilityError
from dualid.estimators import methods as methods_table
from dualid.estimators.least_squares import with_margin
from dualid.evaluation.prediction import PredictionData, measured_signal
from dualid.evaluation.scores import metric_rmse, rmse, score_run, shift_window
from dualid.metric_guard import guard_info
from dualid.paper.results import FitRecord, StudyResult, Summary, Trace
from dualid.problem import IdentificationProblem, build_problem
from dualid.systems.base import SystemData

Case = Literal["both", "low", "high"]
DEFAULT_METHODS = ("ols_unconstrained", "ols", "wls", "energy", "logdet", "pullback", "dm-paper", "dm")
LOW_DATA_MAX_TRIES = 2000  # random subsets drawn per seed before giving up on keeping the rank

_LINEAR = re.compile(r"^(v_?|p_?|pos_?|d)?[xyz]$", re.IGNORECASE)  # names of translational coordinates


# --- methods --------------------------------------------------------------------------------
def make_estimator(method: str, system: SystemData):
    """The estimator behind a method name, under the same physical-consistency constraints.

    allow_unidentifiable=True everywhere: the floating-base pendulum has an exact null space.
    """
    return methods_table.make_estimator(
        method, theta0=system.theta_nominal, gamma=system.gamma, per_equation=True, allow_unidentifiable=True
    )


def units_chart(coordinates: Sequence[str]) -> np.ndarray:
    """Diagonal of B = ∂q/∂q̃ for a change of units: translations in mm (B = 1e-3 m/mm) for
    coordinates named x, y, z, vx, vy, vz, px, … ; every other coordinate is taken as an angle and
    expressed in degrees (B = π/180 rad/deg)."""
    return np.array([1e-3 if _LINEAR.match(c) else math.pi / 180.0 for c in coordinates])


def _ablation_chart(ablation, problem: IdentificationProblem) -> np.ndarray | None:
    """The constant B (n, n) of an ablation, or None."""
    if ablation is None:
        return None
    if isinstance(ablation, str):
        if ablation != "units":
            raise ConfigError(f"ablation: expected None, 'units' or a constant matrix B, got {ablation!r}")
        return np.diag(units_chart(problem.coordinates))
    B = np.asarray(ablation, dtype=float)
    n = problem.n
    if B.shape == (n,):
        B = np.diag(B)
    if B.shape != (n, n):
        raise ConfigError(f"ablation: expected a diagonal ({n},) or a matrix ({n}, {n}), got shape {B.shape}")
    if not np.all(np.isfinite(B)) or abs(np.linalg.det(B)) == 0.0:
        raise ConfigError("ablation: the chart B must be finite and invertible")
    return B


# --- progress -------------------------------------------------------------------------------
class StudyProgress:
    """Either a callback progress(done, total, description) or a rich.progress.Progress."""

    def __init__(self, progress, total: int):
        self.done, self.total, self.callback, self.rich, self.task = 0, total, None, None, None
        if progress is None:
            return
        if hasattr(progress, "add_task") and hasattr(progress, "update"):
            self.rich = progress
            self.task = progress.add_task("identification study", total=total)
        elif callable(progress):
            self.callback = progress
        else:
            raise ConfigError(f"progress: expected a callable (done, total, description) or a rich Progress, got {progress!r}")

    def step(self, description: str) -> None:
        self.done += 1
        if self.callback is not None:
            self.callback(self.done, self.total, description)
        elif self.rich is not None:
            self.rich.update(self.task, advance=1, description=description)


# --- the study ------------------------------------------------------------------------------
def low_data_subset(problem: IdentificationProblem, n_samples: int, seed: int, rank: int | None = None,
                    max_tries: int = LOW_DATA_MAX_TRIES) -> np.ndarray:
    """Sorted indices of n_samples random samples whose regressor keeps the full problem's rank."""
    if rank is None:
        rank = problem.identifiability().rank
    if not 0 < n_samples <= problem.N:
        raise ConfigError(f"low-data case: expected 1 ≤ samples ≤ {problem.N} (training samples), got {n_samples}")
    rng = np.random.default_rng(seed)
    best = -1
    for _ in range(max_tries):
        idx = np.sort(rng.choice(problem.N, size=n_samples, replace=False))
        r = problem.subset(idx).identifiability().rank
        if r == rank:
            return idx
        best = max(best, r)
    raise IdentifiabilityError(
        f"low-data case: no random subset of {n_samples} of {problem.N} samples reached the full regressor rank "
        f"{rank} in {max_tries} draws (seed {seed}; best rank {best}); use more samples"
    )


def _evaluate(system: SystemData, theta: np.ndarray, max_shift: int, metrics: list[np.ndarray],
              forward: list[PredictionData]):
    S, R, E, P = [], [], [], []
    for run, M, fd in zip(system.test, metrics, forward):
        meas = measured_signal(system.model, run)
        pred = fd.predict(theta)
        S.append(score_run(pred, meas, max_shift))
        R.append(rmse(pred, meas))
        E.append(metric_rmse(pred, meas, M))
        P.append(pred)
    return np.array(S), np.array(R), np.array(E), P


def _fit_one(estimator, problem, system, case, method, seed, max_shift, evaluation) -> tuple[FitRecord, list | None]:
    """Fit, then score on the test runs; evaluation = (true metrics, θ-independent prediction data) per run."""
    stage = "fit"
    try:
        result = estimator.fit(problem)
        stage = "prediction"
        S, R, E, P = _evaluate(system, result.theta, max_shift, *evaluation)
    except DualidError as exc:  # SolverError, MetricError, IdentifiabilityError, ConsistencyError, …
        msg = f"{type(exc).__name__} during {stage}: {exc}"
        return FitRecord(case, method, seed, problem.N, False, error=msg), None
    info = {k: v for k, v in result.info.items() if isinstance(v, (bool, int, float, str))}
    if method != "truth":  # how far M(θ̂) moved from M(θ_prior): a collapsed or blown-up metric is flagged
        info.update(guard_info(problem, result.theta, system.theta_nominal, reference="prior θ₀"))
    rec = FitRecord(
        case, method, seed, problem.N, True, theta=tuple(float(x) for x in result.theta),
        objective=float(result.objective), solve_time=float(result.solve_time), status=str(result.status),
        scores=S, rmse=R, metric_rmse=E, info=info,
    )
    return rec, P


def run_study(
    system: SystemData,
    case: Case = "both",
    seeds: int | Sequence[int] = 5,
    methods: Sequence[str] | Mapping[str, Any] = DEFAULT_METHODS,
    progress: Callable[[int, int, str], None] | Any | None = None,
    ablation: None | str | np.ndarray = None,
    trace_run: int = 0,
    margin: float | None = None,
) -> StudyResult:
    """Fit each method in each case, predict every test run, score; see the module docstring.

    seeds: the number of low-data subsets (seeds 0..seeds−1) or the seeds themselves.
    methods: names (see DEFAULT_METHODS) or a mapping name → estimator (anything with fit(problem)).
    progress: a callback progress(done, total, description) or a rich Progress.
    ablation: None, "units" (see ``units_chart``) or a constant chart B ((n,) diagonal or (n, n)).
    trace_run: index of the test run whose predicted signals are kept for trajectory plots.
    margin: ε of the chart-invariant margin C_b(θ) ⪰ ε·C_b(θ_WLS) on every method (dualid.estimators.least_squares),
    against a constrained WLS pilot on each training set in the simulated chart (before an ablation's chart).
    """
    plan = StudyPlan.of(system, case, seeds, methods, ablation, trace_run, margin)
    tracker = StudyProgress(progress, len(plan.jobs))
    fits = []
    for job in plan.jobs:
        fits.append(plan.fit(job))
        tracker.step(plan.describe(job))
    return plan.assemble(fits)


@dataclass(frozen=True)
class StudyPlan:
    """One study's shared inputs, built once (training problem, rank, low-data subsets, the test runs'
    prediction data and true metrics) and its jobs, one per (training set, method): ``fit`` runs one job
    (in any process that holds the plan), ``assemble`` turns every job's output, in job order, into the study."""

    system: SystemData
    problem: IdentificationProblem
    cases: tuple[str, ...]
    seed_list: list[int]
    estimators: dict
    trains: list[tuple[str, int | None, IdentificationProblem]]
    subsets: dict[str, list[int]]
    jobs: list[tuple[int, str]]  # (index into trains, method)
    evaluation: tuple
    max_shift: int
    trace_run: int
    config: dict

    @classmethod
    def of(cls, system: SystemData, case: Case = "both", seeds: int | Sequence[int] = 5,
           methods: Sequence[str] | Mapping[str, Any] = DEFAULT_METHODS, ablation=None, trace_run: int = 0,
           margin: float | None = None) -> "StudyPlan":
        cases = {"both": ("low", "high"), "low": ("low",), "high": ("high",)}.get(case)
        if cases is None:
            raise ConfigError(f"case: expected 'both', 'low' or 'high', got {case!r}")
        seed_list = list(range(seeds)) if isinstance(seeds, (int, np.integer)) else [int(s) for s in seeds]
        if "low" in cases and not seed_list:
            raise ConfigError(f"seeds: the low-data case needs at least one seed, got {seeds!r}")
        estimators = _estimators(methods, system)
        if not system.test:
            raise ConfigError(f"system {system.name!r} has no test runs to predict")
        if not 0 <= trace_run < len(system.test):
            raise ConfigError(f"trace_run: expected an index in [0, {len(system.test) - 1}], got {trace_run}")
        t0 = time.perf_counter()
        problem = build_problem(system.model, list(system.train))
        rank = problem.identifiability().rank
        B = _ablation_chart(ablation, problem)
        dt = float(np.median(np.diff(system.test[0].t)))
        max_shift = shift_window(system.slowest_period, dt)
        forward = [PredictionData.of(system.model, run.q, run.v, run.tau) for run in system.test]
        evaluation = ([fd.metric.evaluate(system.theta_true) for fd in forward], forward)  # built once per run
        trains, subsets = [], {}
        for case_name, seed in [("low", s) for s in seed_list if "low" in cases] + [("high", None)] * ("high" in cases):
            train = problem
            if case_name == "low":
                idx = low_data_subset(problem, system.low_data_samples, seed, rank)
                subsets[str(seed)] = idx.tolist()
                train = problem.subset(idx)
            if margin is not None:
                train = with_margin(train, margin, "wls")
            trains.append((case_name, seed, train if B is None else train.in_coordinates(B)))
        config = {
            "seeds": seed_list if "low" in cases else [],
            "low_data_samples": system.low_data_samples if "low" in cases else None,
            "low_data_subsets": subsets, "training_samples": problem.N, "regressor_rank": rank,
            "n_params": problem.p, "slowest_period": system.slowest_period, "dt": dt, "max_shift": max_shift,
            "gamma": system.gamma,
            "ablation": None if ablation is None else (ablation if isinstance(ablation, str) else "chart"),
            "ablation_B_diag": None if B is None else np.diag(B).tolist(), "margin_epsilon": margin,
            "setup_s": time.perf_counter() - t0, "description": system.description,
        }
        jobs = [(k, m) for k in range(len(trains)) for m in estimators]
        return cls(system, problem, tuple(cases), seed_list, estimators, trains, subsets, jobs, evaluation,
                   max_shift, trace_run, config)

    def describe(self, job: tuple[int, str]) -> str:
        case_name, seed, _ = self.trains[job[0]]
        return f"{case_name}{'' if seed is None else f' seed {seed}'}: {job[1]}"

    def fit(self, job: tuple[int, str]) -> tuple[FitRecord, np.ndarray | None, float]:
        """One job: its record, the trace run's prediction (kept for the first subset and the high case only)
        and its wall time [s]."""
        k, method = job
        case_name, seed, train = self.trains[k]
        t0 = time.perf_counter()
        rec, preds = _fit_one(self.estimators[method], train, self.system, case_name, method, seed, self.max_shift,
                              self.evaluation)
        keep = preds is not None and (seed is None or seed == self.seed_list[0])
        return rec, preds[self.trace_run] if keep else None, time.perf_counter() - t0

    def assemble(self, fits: Sequence[tuple[FitRecord, np.ndarray | None, float]]) -> StudyResult:
        system, problem, run = self.system, self.problem, self.system.test[self.trace_run]
        measured_trace = measured_signal(system.model, run)
        records = [rec for rec, _, _ in fits]
        traces = [Trace(rec.case, rec.method, run.name, run.t, measured_trace, pred)
                  for (k, _), (rec, pred, _) in zip(self.jobs, fits)
                  if self.trains[k][1] is None or self.trains[k][1] == self.seed_list[0]]
        n = problem.n
        summaries = tuple(Summary.of(c, m, [r for r in records if r.case == c and r.method == m], n)
                          for c in self.cases for m in self.estimators)
        truth_rec, truth_pred = _fit_one(_Fixed(system.theta_true), problem, system, "truth", "truth", None,
                                         self.max_shift, self.evaluation)
        if truth_pred is not None:
            traces.extend(Trace(c, "truth", run.name, run.t, measured_trace, truth_pred[self.trace_run])
                          for c in self.cases)
        config = {**self.config, "elapsed_s": self.config["setup_s"] + sum(t for _, _, t in fits)}
        return StudyResult(
            system=system.name, kind=problem.kind,
            signal="acceleration" if problem.kind == "inertia" else "velocity",
            coordinates=tuple(problem.coordinates), shape_coordinates=tuple(system.shape_coordinates),
            parameter_names=tuple(problem.parameters.names), methods=tuple(self.estimators), cases=self.cases,
            test_runs=tuple(r.name for r in system.test), records=tuple(records), summaries=summaries,
            truth=Summary.of("truth", "truth", [truth_rec], n), truth_records=(truth_rec,), traces=tuple(traces),
            config=config,
        )


def _estimators(methods, system: SystemData) -> dict:
    if isinstance(methods, Mapping):
        estimators = dict(methods)
    else:
        if isinstance(methods, str):
            raise ConfigError(f"methods: expected a sequence of method names, got the string {methods!r}")
        estimators = {m: make_estimator(m, system) for m in methods}
    if not estimators:
        raise ConfigError("methods: expected at least one method")
    return estimators


@dataclass(frozen=True)
class _Fixed:
    """An 'estimator' that returns given parameters (the truth reference)."""

    theta: np.ndarray

    def fit(self, problem):
        from dualid.estimators.result import IdentificationResult

        return IdentificationResult("fixed", self.theta, problem.parameters, float("nan"), "given", "none", 0.0)
