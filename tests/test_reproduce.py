"""Smoke tests of the study on the small pan–tilt system: structure, failures, the units ablation."""

import json
from dataclasses import dataclass, replace

import numpy as np
import pytest

from dualid.errors import ConfigError, IdentifiabilityError, OutputError, SolverError
from dualid.estimators import OLS
from dualid.estimators.result import IdentificationResult
from dualid.paper.study import DEFAULT_METHODS, low_data_subset, run_study, units_chart
from dualid.problem import build_problem
from dualid.report.study import score_bars, study_json, study_markdown, trajectory_plot, write_report
from dualid.systems.base import make_system


@pytest.fixture(scope="module")
def system():
    return make_system("pan-tilt", seed=0, noise="realistic", size="small")


@pytest.fixture(scope="module")
def study(system):
    return run_study(system, case="both", seeds=2)


@dataclass(frozen=True)
class Broken:
    """A method whose solver always fails."""

    def fit(self, problem):
        raise SolverError("fake solver: status 'numerical_error'", status="numerical_error")


@dataclass(frozen=True)
class NegativeMass:
    """A 'fit' whose mass matrix is not positive definite: forward dynamics must fail."""

    def fit(self, problem):
        return IdentificationResult("negative", np.array([-1.0, 0.0, 0.0]), problem.parameters, 0.0, "optimal", "x", 0.0)


def test_json_structure(study, system):
    d = json.loads(study_json(study))
    assert d["system"] == "pan-tilt" and d["kind"] == "inertia" and d["signal"] == "acceleration"
    assert d["coordinates"] == ["pan", "tilt"]
    assert d["methods"] == list(DEFAULT_METHODS)
    assert set(d["cases"]) == {"low", "high"}
    assert d["config"]["seeds"] == [0, 1]
    assert d["config"]["max_shift"] == round(system.slowest_period / 72 / 0.005)
    for case, n_fits in (("low", 2), ("high", 1)):
        summary = d["cases"][case]["summary"]
        assert list(summary) == list(DEFAULT_METHODS)
        for m, s in summary.items():
            assert s["n_fits"] == n_fits and s["n_failed"] == 0
            assert set(s["score_mean"]) == {"pan", "tilt"}
            assert all(-1 <= v <= 1 for v in s["score_mean"].values())
            assert s["metric_rmse_mean"] > 0
        fits = d["cases"][case]["fits"]
        assert len(fits) == n_fits * len(DEFAULT_METHODS)
        assert all(f["ok"] and set(f["runs"]) == {"test_0", "test_1"} and len(f["theta"]) == 3 for f in fits)
        assert all(f["n_samples"] == (10 if case == "low" else 600) for f in fits)
    # every low-data subset has the configured size; the truth reference is there
    assert all(len(v) == system.low_data_samples for v in d["config"]["low_data_subsets"].values())
    assert 0.9 < d["truth"]["score_mean"]["tilt"] <= 1.0


def test_mean_and_std_pool_test_runs_and_seeds(study):
    recs = [r for r in study.records if r.case == "low" and r.method == "dm"]
    pooled = np.concatenate([r.scores for r in recs])  # (seeds × runs, n)
    s = study.summary("low", "dm")
    np.testing.assert_allclose(s.score_mean, pooled.mean(0))
    np.testing.assert_allclose(s.score_std, pooled.std(0))


def test_failures_are_reported_not_dropped(system):
    progress = []
    r = run_study(system, case="high", methods={"ols": OLS(allow_unidentifiable=True), "broken": Broken(),
                                                "negative": NegativeMass()},
                  progress=lambda done, total, what: progress.append((done, total, what)))
    assert progress[-1][:2] == (3, 3)
    failed = {f.method: f for f in r.failures()}
    assert set(failed) == {"broken", "negative"}
    assert failed["broken"].error == "SolverError during fit: fake solver: status 'numerical_error'"
    assert failed["negative"].error.startswith("MetricError during prediction: forward dynamics: M(q, θ) is not")
    s = r.summary("high", "broken")
    assert s.n_failed == 1 and np.all(np.isnan(s.score_mean))  # not zero-filled
    d = json.loads(study_json(r))  # NaN becomes null: valid JSON
    assert d["cases"]["high"]["summary"]["broken"]["score_mean"] == {"pan": None, "tilt": None}
    assert d["cases"]["high"]["fits"][1] == {"case": "high", "method": "broken", "seed": None, "data_seed": 0,
                                             "n_samples": 600,
                                             "ok": False, "error": failed["broken"].error}
    md = study_markdown(r)
    assert "## Failed fits" in md and "fake solver" in md and "| broken | failed | failed | 1/1 |" in md


def test_units_ablation_leaves_dm_unchanged(system, study):
    np.testing.assert_allclose(units_chart(("pan", "tilt")), [np.pi / 180] * 2)
    np.testing.assert_allclose(units_chart(("vx", "wx", "y", "alpha1")), [1e-3, np.pi / 180, 1e-3, np.pi / 180])
    methods = ("ols", "dm")
    for ablation in ("units", np.array([1.0, np.pi / 180])):  # pan in rad, tilt in degrees: non-uniform
        r = run_study(system, case="both", seeds=2, methods=methods, ablation=ablation)
        assert r.config["ablation_B_diag"] is not None
        for case in ("low", "high"):
            np.testing.assert_allclose(r.summary(case, "dm").score_mean, study.summary(case, "dm").score_mean,
                                       atol=1e-6, rtol=0)
            np.testing.assert_allclose(r.summary(case, "dm").metric_rmse_mean,
                                       study.summary(case, "dm").metric_rmse_mean, rtol=1e-4)  # SDP tolerance
    # OLS is not invariant to a non-uniform change of units: its fit moves
    ols_new = [x.theta for x in r.records if x.method == "ols" and x.case == "low"]
    ols_old = [x.theta for x in study.records if x.method == "ols" and x.case == "low"]
    assert np.max(np.abs(np.array(ols_new) - np.array(ols_old))) > 1e-3


def test_low_data_subsets_keep_the_rank(system):
    problem = build_problem(system.model, list(system.train))
    idx = low_data_subset(problem, 10, seed=3)
    assert len(idx) == 10 and np.all(np.diff(idx) > 0)
    assert problem.subset(idx).identifiability().rank == problem.identifiability().rank
    with pytest.raises(IdentifiabilityError, match=r"no random subset of 1 of 600 samples reached the full "
                                                   r"regressor rank 3 in 20 draws \(seed 0; best rank 2\)"):
        low_data_subset(problem, 1, seed=0, max_tries=20)
    with pytest.raises(IdentifiabilityError, match="no random subset of 1 of 600 samples"):
        run_study(replace(system, low_data_samples=1), case="low", seeds=1, methods=("ols",))


def test_input_errors(system):
    with pytest.raises(ValueError, match=r"case: expected 'both', 'low' or 'high', got 'medium'"):
        run_study(system, case="medium")
    with pytest.raises(ConfigError, match=r"^unknown method 'lasso'; known methods: ols, ols_unconstrained, wls, energy, logdet, pullback, dm, dm-paper$"):
        run_study(system, methods=("lasso",))
    with pytest.raises(ValueError, match=r"ablation: expected None, 'units' or a constant matrix B, got 'meters'"):
        run_study(system, case="high", methods=("ols",), ablation="meters")
    with pytest.raises(ValueError, match=r"ablation: expected a diagonal \(2,\) or a matrix \(2, 2\), got shape \(3,\)"):
        run_study(system, case="high", methods=("ols",), ablation=np.ones(3))
    with pytest.raises(ConfigError, match="^progress: expected a callable"):
        run_study(system, case="high", methods=("ols",), progress=42)


def test_report_files_and_refusal_to_overwrite(study, tmp_path):
    out = tmp_path / "report"
    written = write_report(study, out)
    names = sorted(p.name for p in out.iterdir())
    assert names == [".dualid-manifest.json", "results.json", "results.md", "score_bars_high.png", "score_bars_low.png",
                     "trajectory_high.png", "trajectory_low.png"]
    assert json.loads(written["json"].read_text())["system"] == "pan-tilt"
    md = written["markdown"].read_text()
    assert "## Low-data case (10 samples, 2 seeds)" in md and "| DM | " in md and "a:tilt" in md
    for p in out.glob("*.png"):
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(OutputError, match=f"^output directory {out}: exists and is not empty; choose another or pass --force$"):
        write_report(study, out)
    write_report(study, out, overwrite=True)
    with pytest.raises(ValueError, match=r"case: expected one of \['low', 'high'\]"):
        score_bars(study, "medium")
    with pytest.raises(ValueError, match=r"coordinate: expected one of \['pan', 'tilt'\], got 'roll'"):
        trajectory_plot(study, "high", coordinate="roll")


def test_pooled_data_sets_and_paired_differences(system):
    from dataclasses import replace as dc_replace

    from dualid.paper.seeds import paired_difference, pool

    a = run_study(system, case="both", seeds=2, methods=("ols", "wls", "dm"))
    b = run_study(dc_replace(system, test=system.test[::-1]), case="both", seeds=2, methods=("ols", "wls", "dm"))
    with pytest.raises(ConfigError, match="the studies differ in methods, cases, coordinates or test runs"):
        pool([a, b], [0, 1])
    pooled = pool([a, a], [3, 4])
    assert pooled.config["data_seeds"] == [3, 4] and {r.data_seed for r in pooled.records} == {3, 4}
    s1, s2 = a.summary("low", "dm"), pooled.summary("low", "dm")
    assert s2.n_fits == 2 * s1.n_fits
    np.testing.assert_allclose(s2.score_mean, s1.score_mean)  # the same data twice: the same means
    d = paired_difference(pooled, "low", "dm", "wls")
    dm = np.concatenate([r.scores for r in pooled.records if r.case == "low" and r.method == "dm"])
    wls = np.concatenate([r.scores for r in pooled.records if r.case == "low" and r.method == "wls"])
    np.testing.assert_allclose(d.mean, (dm - wls).mean(0))
    assert d.n_pairs == dm.shape[0] and np.array_equal(d.wins, (dm > wls).sum(0))
    assert "### Paired score difference against WLS" in study_markdown(pooled)
    # every fit carries the metric guard against the prior, and the tables count the flagged fits
    assert all({"metric_ratio_min", "metric_ratio_max", "degenerate"} <= set(r.info) for r in pooled.records if r.ok)
    assert "| failed | degenerate metric |" in study_markdown(pooled)


def _lines(log: list, done: int, total: int, description: str) -> None:
    log.append((done, total, description))


def test_data_sets_in_worker_processes_pool_to_the_same_study():
    """workers=2 simulates and studies the data sets in two processes: the pooled fits are one process's, in the
    same order (the pool calls the progress callback here as its jobs finish)."""
    from functools import partial

    from dualid.paper.seeds import run_data_seeds

    kw = dict(data_seeds=2, case="high", seeds=1, size="small", methods=("ols", "wls"))
    calls: list = []
    one = run_data_seeds("pan-tilt", **kw, progress=partial(_lines, calls))
    two = run_data_seeds("pan-tilt", **kw, workers=2, progress=partial(_lines, []))
    assert [(r.data_seed, r.case, r.method) for r in one.records] == [(r.data_seed, r.case, r.method)
                                                                      for r in two.records]
    for a, b in zip(one.records, two.records):
        np.testing.assert_array_equal(a.theta, b.theta)
        np.testing.assert_array_equal(a.scores, b.scores)
    assert calls[0] == (0, 2, "data set 0: simulating") and calls[-1] == (2, 2, "data set 1: high: wls")
    with pytest.raises(ConfigError, match="workers: expected a positive number of processes, got 0"):
        run_data_seeds("pan-tilt", **kw, workers=0)
