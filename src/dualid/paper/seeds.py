"""The study over several simulated data sets: one data set per seed, every fit pooled, and paired
differences between methods on the same (data set, subset, test run).

A single simulated data set makes the high-data column one fit; differences between methods of a
few hundredths can then be luck of that data set. Pooling over data-set seeds and reporting paired
differences (method − reference on the same fit inputs, with their spread and how often the method
is ahead) says how much of a difference is the method's.
"""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, replace
from functools import partial
import multiprocessing

import numpy as np

from dualid.errors import ConfigError
from dualid.paper.results import FitRecord, StudyResult, Summary
from dualid.paper.study import DEFAULT_METHODS, Case, StudyPlan, StudyProgress, run_study
from dualid.systems.base import make_system


@dataclass(frozen=True)
class PairedDifference:
    """score(method) − score(reference) over the pairs of fits of one case that both succeeded."""

    case: str
    method: str
    reference: str
    n_pairs: int  # (data seed, subset seed, test run) triples
    mean: np.ndarray  # (n,) per coordinate
    std: np.ndarray  # (n,)
    wins: np.ndarray  # (n,) pairs in which the method scored higher


def _pairs(records: Sequence[FitRecord], case: str, method: str) -> dict[tuple, FitRecord]:
    return {(r.data_seed, r.seed): r for r in records if r.case == case and r.method == method and r.ok}


def paired_difference(result: StudyResult, case: str, method: str, reference: str) -> PairedDifference:
    a, b = _pairs(result.records, case, method), _pairs(result.records, case, reference)
    keys = sorted(set(a) & set(b), key=str)
    n = len(result.coordinates)
    if not keys:
        nan = np.full(n, np.nan)
        return PairedDifference(case, method, reference, 0, nan, nan, np.zeros(n, int))
    d = np.concatenate([a[k].scores - b[k].scores for k in keys])  # (pairs × runs, n)
    return PairedDifference(case, method, reference, d.shape[0], d.mean(0), d.std(0), (d > 0).sum(0))


def pool(studies: Sequence[StudyResult], data_seeds: Sequence[int]) -> StudyResult:
    """One StudyResult whose records are every data set's (tagged with its seed) and whose summaries
    pool them; traces and the per-run configuration are the first data set's."""
    if not studies or len(studies) != len(data_seeds):
        raise ConfigError(f"pool: expected one study per data seed, got {len(studies)} studies for seeds {list(data_seeds)}")
    first = studies[0]
    for s in studies[1:]:
        if (s.methods, s.cases, s.coordinates, s.test_runs) != (first.methods, first.cases, first.coordinates,
                                                                   first.test_runs):
            raise ConfigError("pool: the studies differ in methods, cases, coordinates or test runs")
    records = tuple(replace(r, data_seed=int(seed)) for s, seed in zip(studies, data_seeds) for r in s.records)
    truth = tuple(replace(r, data_seed=int(seed)) for s, seed in zip(studies, data_seeds) for r in s.truth_records)
    n = len(first.coordinates)
    summaries = tuple(Summary.of(c, m, [r for r in records if r.case == c and r.method == m], n)
                      for c in first.cases for m in first.methods)
    config = {**first.config, "data_seeds": [int(x) for x in data_seeds],
              "elapsed_s": float(sum(s.config.get("elapsed_s", 0.0) for s in studies)),
              "descriptions": [s.config.get("description", "") for s in studies]}
    return replace(first, records=records, summaries=summaries, truth=Summary.of("truth", "truth", truth, n),
                   truth_records=truth, config=config)


def run_data_seeds(
    system_name: str,
    data_seeds: int | Sequence[int] = 5,
    case: Case = "both",
    seeds: int = 5,
    noise: str = "realistic",
    size: str = "default",
    ablation=None,
    methods=None,
    progress=None,
    margin: float | None = None,
    workers: int = 1,
    **system_options,
) -> StudyResult:
    """Simulate one data set per seed, run the study on each and pool them (see ``pool``).

    workers > 1: the data sets are simulated and their plans built here, then every (data set, training set,
    method) fit is one job of a pool of that many forked processes, the costliest first (``dm``, then the
    high-data case), so the cores stay busy to the end; the pooled result is the same as one process's and
    ``progress`` (a callback (done, total, description) or a rich Progress) is called here as jobs finish."""
    data_list = list(range(data_seeds)) if isinstance(data_seeds, (int, np.integer)) else [int(s) for s in data_seeds]
    if not data_list:
        raise ConfigError(f"data_seeds: expected at least one data-set seed, got {data_seeds!r}")
    if workers < 1:
        raise ConfigError(f"workers: expected a positive number of processes, got {workers!r}")
    kw = ({} if methods is None else {"methods": methods}) | ({} if margin is None else {"margin": margin})
    if workers == 1:
        one = partial(_one_data_set, system_name, case=case, seeds=seeds, noise=noise, size=size, ablation=ablation,
                      progress=progress, tag=len(data_list) > 1, study_options=kw, system_options=system_options)
        return pool([one(seed) for seed in data_list], data_list)
    plans = []
    for seed in data_list:
        if callable(progress) and not hasattr(progress, "add_task"):
            progress(0, len(data_list) * _fits_per_data_set(case, seeds, kw), f"data set {seed}: simulating")
        system = make_system(system_name, seed=seed, noise=noise, size=size, **system_options)
        plans.append(StudyPlan.of(system, case=case, seeds=seeds, ablation=ablation, **kw))
    studies = _fit_in_pool(plans, data_list, workers, progress)
    studies = [replace(s, config={**s.config, "noise": noise, "size": size, "system_seed": seed})
               for s, seed in zip(studies, data_list)]
    return pool(studies, data_list)


_PLANS: list[StudyPlan] = []  # the plans a forked worker inherits (set just before the pool forks)


def _run_job(d: int, job: tuple[int, str]):
    return _PLANS[d].fit(job)


def _cost_rank(plan: StudyPlan, job: tuple[int, str]) -> tuple:
    """Longest first: dualid's cross-validated ``dm``, then the paper's ``dm-paper``; high data before low."""
    return (job[1] != "dm", job[1] != "dm-paper", plan.trains[job[0]][0] != "high")


def _fit_in_pool(plans: list[StudyPlan], data_list: list[int], workers: int, progress) -> list[StudyResult]:
    global _PLANS
    jobs = sorted(((d, j) for d, plan in enumerate(plans) for j in plan.jobs),
                  key=lambda dj: _cost_rank(plans[dj[0]], dj[1]))
    tracker = StudyProgress(progress, len(jobs))
    fits: dict = {}
    _PLANS = plans
    try:
        with ProcessPoolExecutor(max_workers=min(workers, len(jobs)),
                                 mp_context=multiprocessing.get_context("fork")) as pool_:
            futures = {pool_.submit(_run_job, d, j): (d, j) for d, j in jobs}
            for future in as_completed(futures):
                d, j = futures[future]
                fits[d, j] = future.result()
                prefix = f"data set {data_list[d]}: " if len(plans) > 1 else ""
                tracker.step(prefix + plans[d].describe(j))
    finally:
        _PLANS = []
    return [plan.assemble([fits[d, j] for j in plan.jobs]) for d, plan in enumerate(plans)]


def _one_data_set(system_name: str, seed: int, *, case, seeds, noise, size, ablation, progress, tag: bool,
                  study_options: dict, system_options: dict) -> StudyResult:
    callback = callable(progress) and not hasattr(progress, "add_task")  # a callback, not a rich Progress
    if callback and tag:
        progress = partial(_tagged, progress, f"data set {seed}")
    if callback:
        progress(0, _fits_per_data_set(case, seeds, study_options), "simulating")
    system = make_system(system_name, seed=seed, noise=noise, size=size, **system_options)
    study = run_study(system, case=case, seeds=seeds, progress=progress, ablation=ablation, **study_options)
    return replace(study, config={**study.config, "noise": noise, "size": size, "system_seed": seed})


def _fits_per_data_set(case, seeds: int, study_options: dict) -> int:
    subsets = (seeds if case in ("both", "low") else 0) + (case in ("both", "high"))
    return subsets * len(study_options.get("methods") or DEFAULT_METHODS)


def _tagged(progress, prefix: str, done: int, total: int, description: str) -> None:
    progress(done, total, f"{prefix}: {description}")
