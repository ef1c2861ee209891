"""The values a study returns: one record per fit, summaries over seeds and runs, traces for plots.

``as_dict`` gives plain Python containers (NaN where a value is missing); the report leaf turns
them into JSON and Markdown.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dualid.errors import ConfigError


@dataclass(frozen=True, eq=False)
class FitRecord:
    """One fit (method, case, seed) and its scores on every test run, or why it failed."""

    case: str  # "low" | "high"
    method: str
    seed: int | None  # the low-data subset's seed; None for the high-data case
    n_samples: int  # training samples used
    ok: bool
    error: str = ""  # "<ErrorType> during <stage>: <message>" when not ok
    theta: tuple[float, ...] = ()
    objective: float = float("nan")
    solve_time: float = float("nan")  # [s]
    status: str = ""
    scores: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))  # (runs, n)
    rmse: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))  # (runs, n) signal units
    metric_rmse: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (runs,)
    data_seed: int = 0  # the simulated data set's seed
    info: dict = field(default_factory=dict)  # the fit's scalar diagnostics (solver chain, metric guard, …)

    def as_dict(self, runs: Sequence[str], coordinates: Sequence[str]) -> dict:
        d: dict[str, Any] = {"case": self.case, "method": self.method, "seed": self.seed,
                             "data_seed": self.data_seed, "n_samples": self.n_samples, "ok": self.ok}
        if not self.ok:
            d["error"] = self.error
            return d
        d.update(
            theta=list(self.theta), objective=self.objective, solve_time_s=self.solve_time, status=self.status,
            info=self.info,
            runs={
                run: {
                    "score": dict(zip(coordinates, self.scores[k].tolist())),
                    "rmse": dict(zip(coordinates, self.rmse[k].tolist())),
                    "metric_rmse": float(self.metric_rmse[k]),
                }
                for k, run in enumerate(runs)
            },
        )
        return d


@dataclass(frozen=True, eq=False)
class Summary:
    """Mean and std over the pooled (seed, test run) pairs of one method's successful fits."""

    case: str
    method: str
    n_fits: int
    n_failed: int
    score_mean: np.ndarray  # (n,)  NaN when every fit failed
    score_std: np.ndarray
    rmse_mean: np.ndarray  # (n,) signal units per coordinate
    rmse_std: np.ndarray
    metric_rmse_mean: float
    metric_rmse_std: float

    @staticmethod
    def of(case: str, method: str, records: Sequence[FitRecord], n: int) -> "Summary":
        ok = [r for r in records if r.ok]
        if not ok:
            nan = np.full(n, np.nan)
            return Summary(case, method, len(records), len(records), nan, nan, nan, nan, float("nan"), float("nan"))
        S = np.concatenate([r.scores for r in ok])
        R = np.concatenate([r.rmse for r in ok])
        E = np.concatenate([r.metric_rmse for r in ok])
        return Summary(
            case, method, len(records), len(records) - len(ok), S.mean(0), S.std(0), R.mean(0), R.std(0),
            float(E.mean()), float(E.std()),
        )

    def as_dict(self, coordinates: Sequence[str]) -> dict:
        c = list(coordinates)
        return {
            "n_fits": self.n_fits,
            "n_failed": self.n_failed,
            "score_mean": dict(zip(c, self.score_mean.tolist())),
            "score_std": dict(zip(c, self.score_std.tolist())),
            "rmse_mean": dict(zip(c, self.rmse_mean.tolist())),
            "rmse_std": dict(zip(c, self.rmse_std.tolist())),
            "metric_rmse_mean": self.metric_rmse_mean,
            "metric_rmse_std": self.metric_rmse_std,
        }


@dataclass(frozen=True, eq=False)
class Trace:
    """Predicted and measured signal on one test run (for trajectory plots); predicted None if failed."""

    case: str
    method: str
    run: str
    t: np.ndarray  # (T,) [s]
    measured: np.ndarray  # (T, n)
    predicted: np.ndarray | None  # (T, n)


@dataclass(frozen=True, eq=False)
class StudyResult:
    system: str
    kind: str  # "inertia" | "drag"
    signal: str  # "acceleration" | "velocity": what is predicted and scored
    coordinates: tuple[str, ...]
    shape_coordinates: tuple[str, ...]
    parameter_names: tuple[str, ...]
    methods: tuple[str, ...]
    cases: tuple[str, ...]
    test_runs: tuple[str, ...]
    records: tuple[FitRecord, ...]
    summaries: tuple[Summary, ...]
    truth: Summary  # the true θ's prediction: what noise and unmodelled effects allow
    traces: tuple[Trace, ...]
    config: dict  # seeds, max_shift, ablation chart, low-data size, …
    truth_records: tuple[FitRecord, ...] = ()  # the true θ's record per data set (pooled in ``truth``)

    def summary(self, case: str, method: str) -> Summary:
        for s in self.summaries:
            if s.case == case and s.method == method:
                return s
        raise ConfigError(f"no summary for case {case!r}, method {method!r}; cases {self.cases}, methods {self.methods}")

    def failures(self) -> tuple[FitRecord, ...]:
        return tuple(r for r in self.records if not r.ok)

    def as_dict(self) -> dict:
        c = self.coordinates
        return {
            "system": self.system,
            "kind": self.kind,
            "signal": self.signal,
            "coordinates": list(c),
            "shape_coordinates": list(self.shape_coordinates),
            "parameter_names": list(self.parameter_names),
            "methods": list(self.methods),
            "test_runs": list(self.test_runs),
            "config": self.config,
            "truth": self.truth.as_dict(c),
            "cases": {
                case: {
                    "summary": {s.method: s.as_dict(c) for s in self.summaries if s.case == case},
                    "fits": [r.as_dict(self.test_runs, c) for r in self.records if r.case == case],
                }
                for case in self.cases
            },
        }
