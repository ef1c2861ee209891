"""dm's choice between its GLS fit and its pilot by cross-validation (estimators/weight_cv.py, FeasibleGLS.select).

Specified against an independent re-computation: the folds refitted by hand, with the library's cvxpy WLS as the
pilot (dm fits its pilot by its own interior point); the choice is the same in every chart; the pilot branch
returns the pilot's weighted fit with the weight it used (so the sandwich rebuilds it); failures are recorded.
"""

import dataclasses

import numpy as np
import pytest

from dualid import WLS
from dualid.errors import ConfigError, SolverError
from dualid.estimators import gls as gls_module
from dualid.estimators.gls import FeasibleGLS
from dualid.estimators.uncertainty import base_uncertainty
from dualid.estimators.weight_cv import choose_weight, cv_rows
from tests.factories import drag_problem, random_chart
from tests.test_invariance import rel


def _metric_noise(rng, N=300, scale=0.3):
    """Residuals with covariance ∝ M_i(θ_true): the dual metric's own noise model, which GLS (κ > 0) fits."""
    problem, theta = drag_problem(rng, N=N, n=3)
    L = np.linalg.cholesky(problem.metric.evaluate(theta))
    tau = problem.tau + scale * np.einsum("nab,nb->na", L, rng.standard_normal((N, 3)))
    return dataclasses.replace(problem, tau=tau), theta


def _scores(problem, thetas_per_fold, folds=5):
    """(torque scores, motion scores) from the folds by hand: torque NRMSE per coordinate against rms(τ); motion:
    the forward-dynamics error M(θ)⁻¹ r (explicit inverses) per coordinate against the two candidates' mean."""
    N = problem.N
    edges = np.linspace(0, N, folds + 1).astype(int)
    sse = {k: np.zeros(problem.n) for k in ("pilot", "gls")}
    motion = {k: np.zeros(problem.n) for k in ("pilot", "gls")}
    for k in range(folds):
        held = np.arange(edges[k], edges[k + 1])
        test = problem.subset(held)
        for name, th in thetas_per_fold(problem.subset(np.setdiff1d(np.arange(N), held))).items():
            r = test.tau - np.einsum("nap,p->na", test.Y, th)
            sse[name] += np.sum(r**2, axis=0)
            motion[name] += np.sum(np.einsum("nab,nb->na", np.linalg.inv(test.metric.evaluate(th)), r) ** 2, axis=0)
    rms = np.sqrt(np.mean(problem.tau**2, axis=0))
    scale = (motion["pilot"] + motion["gls"]) / 2
    return ({name: float(np.sqrt(np.mean(s / N / rms**2))) for name, s in sse.items()},
            {name: float(np.sqrt(np.mean(s / scale))) for name, s in motion.items()})


def _by_hand(problem, folds=5):
    """The cross-validation scores recomputed from the folds: pilot = the library's WLS (cvxpy), GLS = dm unselected."""
    return _scores(problem, lambda train: {
        "pilot": WLS(allow_unidentifiable=True).fit(train).theta,
        "gls": FeasibleGLS(select="none", allow_unidentifiable=True).fit(train).theta}, folds)


def test_the_scores_are_the_cross_validated_torque_and_motion_errors_of_pilot_and_gls():
    problem, _ = _metric_noise(np.random.default_rng(3))
    res = FeasibleGLS().fit(problem)
    torque, motion = _by_hand(problem)
    assert res.info["cv_folds"] == 5 and res.info["cv_samples"] == problem.N
    assert res.info["cv_criteria"] == "torque+motion"
    for name in ("pilot", "gls"):
        assert res.info["cv_score"][name] == pytest.approx(torque[name], rel=1e-6)
        assert res.info["cv_motion_score"][name] == pytest.approx(motion[name], rel=1e-6)


def test_the_gls_fit_is_kept_only_when_it_loses_on_neither_torque_nor_motion():
    """Random candidate pairs: select="cv" keeps the GLS candidate iff it is no worse on both scores, "cv-torque" iff
    no worse on torque; among the pairs are some where the two rules disagree (the motion score decides)."""
    problem, theta = _metric_noise(np.random.default_rng(11), N=150)
    rng = np.random.default_rng(12)
    split = 0
    for _ in range(30):
        pair = {"pilot": theta * (1 + 0.05 * rng.standard_normal(theta.size)),
                "gls": theta * (1 + 0.05 * rng.standard_normal(theta.size))}
        torque, motion = _scores(problem, lambda train: pair)
        both = choose_weight(problem, lambda sub: (pair["pilot"], pair["gls"]), 5)
        alone = choose_weight(problem, lambda sub: (pair["pilot"], pair["gls"]), 5, "cv-torque")
        assert alone["cv_criteria"] == "torque" and both["cv_criteria"] == "torque+motion"
        wins = torque["gls"] <= torque["pilot"], motion["gls"] <= motion["pilot"]
        assert both["weight_choice"] == ("gls" if all(wins) else "pilot")
        assert alone["weight_choice"] == ("gls" if wins[0] else "pilot")
        split += both["weight_choice"] != alone["weight_choice"]
    assert split >= 3


def test_metric_isotropic_residuals_keep_the_gls_fit():
    problem, _ = _metric_noise(np.random.default_rng(4), scale=0.5)
    res = FeasibleGLS().fit(problem)
    plain = FeasibleGLS(select="none").fit(problem)
    assert res.info["weight_choice"] == "gls"
    assert res.info["cv_score"]["gls"] < res.info["cv_score"]["pilot"]
    assert res.info["kappa"] > 0
    np.testing.assert_array_equal(res.theta, plain.theta)


def test_the_pilot_branch_returns_the_pilots_weighted_fit_with_its_weight(monkeypatch):
    """When the pilot predicts better, dm is the pilot's own weighted fit: θ = WLS's, κ = 0 and Σ = WLS's weight
    (recorded, so the sandwich rebuilds the weight that was used), the estimated (Σ, κ) kept beside it."""
    problem, _ = _metric_noise(np.random.default_rng(5))
    monkeypatch.setattr(gls_module, "choose_weight", lambda sensor, fit_pair, folds, select: {
        "weight_choice": "pilot", "cv_score": {"pilot": 1.0, "gls": 2.0}, "cv_folds": folds, "cv_samples": sensor.N})
    calls = []
    fit_weighted = gls_module.fit_weighted
    monkeypatch.setattr(gls_module, "fit_weighted", lambda *a, **k: calls.append(a[2]) or fit_weighted(*a, **k))
    est = FeasibleGLS()
    res = est.fit(problem)
    wls = WLS().fit(problem)
    assert rel(res.theta, wls.theta) < 1e-6
    # the pilot's own fit is returned (not fitted again), under dm's name; with other solver options it is refitted
    assert calls == ["ols", "wls", "dm"] and res.method == "dm"
    np.testing.assert_array_equal(res.theta, res.info["theta_ref"])
    calls.clear()
    tight = FeasibleGLS(solver_options={"tol": 1e-10}).fit(problem)
    assert calls == ["ols", "wls", "dm", "dm"] and rel(tight.theta, res.theta) < 1e-6
    assert res.info["kappa"] == 0.0 and res.info["kappa_share"] == 0.0 and res.info["estimated_covariance"]["kappa"] > 0
    # what the result says about its weight describes the weight used, not the GLS fit it did not return
    assert res.info["covariance_model"] == "the sample covariance of the OLS residuals (the WLS pilot's weight)"
    assert "sigma_structure" not in res.info and res.info["estimated_covariance"]["sigma_structure"] == "full"
    np.testing.assert_allclose(res.info["sigma"], wls.info["covariance_matrix"], rtol=1e-6)
    base = problem.identifiability().base
    sandwich = base_uncertainty(problem, res, est, base).covariance
    np.testing.assert_allclose(sandwich, base_uncertainty(problem, wls, WLS(), base).covariance, rtol=1e-4, atol=1e-12)


def test_the_choice_and_the_fit_are_the_same_in_every_chart():
    rng = np.random.default_rng(6)
    problem, _ = _metric_noise(rng)
    B = random_chart(rng, problem.N, problem.n, per_sample=True) * 10.0 ** rng.uniform(-6, 6, (1, 1, problem.n))
    a, b = FeasibleGLS().fit(problem), FeasibleGLS().fit(problem.in_coordinates(B))
    assert a.info["weight_choice"] == b.info["weight_choice"]
    assert a.info["cv_score"]["gls"] == pytest.approx(b.info["cv_score"]["gls"], rel=1e-8)
    assert rel(a.theta, b.theta) < 1e-6


def test_large_problems_choose_on_an_evenly_strided_subsample():
    assert cv_rows(10_000) == slice(0, None, 1)
    assert cv_rows(50_000) == slice(0, None, 3)
    assert len(range(50_000)[cv_rows(50_000)]) <= 20_000


def test_a_fold_that_cannot_be_fitted_keeps_the_gls_fit_and_says_so():
    problem, _ = _metric_noise(np.random.default_rng(7), N=100)
    calls = []

    def fit_pair(sub):
        calls.append(sub.N)
        if len(calls) == 2:
            raise SolverError("no strictly feasible start", status="no_start")
        return np.zeros(problem.p), np.zeros(problem.p)

    info = choose_weight(problem, fit_pair, 5)
    assert info == {"cv_folds": 5, "cv_samples": 100, "cv_criteria": "torque+motion", "weight_choice": "gls", "cv_fallback":
                    "fold 2 of 5 could not be fitted (SolverError: no strictly feasible start); the GLS fit is kept"}


def test_no_selection_where_there_is_no_weighted_pilot():
    problem, theta = _metric_noise(np.random.default_rng(8), N=80)
    given = FeasibleGLS(sigma=np.ones(3), kappa=0.5, theta_ref=theta).fit(problem)
    assert given.info["weight_choice"] == "gls (no selection: Σ and κ were given)"
    off = FeasibleGLS(select="none").fit(problem)
    assert off.info["weight_choice"] == "gls (select='none')"
    paper = FeasibleGLS(pilot="dm-paper").fit(problem)
    assert paper.info["weight_choice"] == "gls (no selection: the pilot (dm-paper) is not a weighted least squares)"


@pytest.mark.parametrize("kwargs, match", [
    ({"select": "aic"}, "select: expected one of ('cv', 'cv-torque', 'none'), got 'aic'"),
    ({"cv_folds": 1}, "cv_folds: expected an integer ≥ 2, got 1"),
    ({"cv_folds": 2.5}, "cv_folds: expected an integer ≥ 2, got 2.5"),
])
def test_constructor_errors(kwargs, match):
    with pytest.raises(ConfigError) as exc:
        FeasibleGLS(**kwargs)
    assert str(exc.value) == match


def test_a_passive_coordinate_is_scaled_by_the_pilots_held_out_error():
    """τ_a ≡ 0 (a passive joint) has no torque scale: its NRMSE is taken relative to the pilot's error there."""
    problem, theta = _metric_noise(np.random.default_rng(9), N=100)
    tau = problem.tau.copy()
    tau[:, 2] = 0.0
    problem = dataclasses.replace(problem, tau=tau)
    th_pilot, th_gls = theta, 1.1 * theta
    info = choose_weight(problem, lambda sub: (th_pilot, th_gls), 5)
    rms = np.sqrt(np.mean(tau**2, axis=0))
    e = {name: np.sqrt(np.mean(problem.residual(th) ** 2, axis=0)) for name, th in (("pilot", th_pilot), ("gls", th_gls))}
    rms[2] = e["pilot"][2]
    for name in ("pilot", "gls"):
        assert info["cv_score"][name] == pytest.approx(float(np.sqrt(np.mean((e[name] / rms) ** 2))), rel=1e-12)


def test_too_few_samples_to_cross_validate_keep_the_gls_fit_and_say_so():
    problem, _ = _metric_noise(np.random.default_rng(10), N=40)
    res = FeasibleGLS(allow_unidentifiable=True).fit(problem.subset(np.arange(3)))
    assert res.info["weight_choice"] == "gls"
    assert res.info["cv_fallback"] == "3 samples, too few to cross-validate (at least 4); the GLS fit is kept"
    few = FeasibleGLS(allow_unidentifiable=True).fit(problem.subset(np.arange(6)))
    assert few.info["cv_folds"] == 3 and few.info["cv_samples"] == 6  # 2 samples per fold at least


def test_the_fit_report_states_the_choice_and_both_scores():
    from dualid.report.fit_report import weight_note

    info = {"weight_choice": "pilot", "cv_score": {"gls": 0.38812, "pilot": 0.38634}, "cv_folds": 5, "cv_samples": 4000,
            "cv_criteria": "torque+motion", "cv_motion_score": {"gls": 1.0213, "pilot": 0.97864}}
    assert weight_note("dm", info) == ("dm: weight: its pilot's weighted fit (κ = 0), chosen by 5-fold cross-validation "
                                       "(torque and motion) on 4000 samples (held-out torque NRMSE: GLS 0.3881, pilot "
                                       "0.3863; motion error, relative: GLS 1.021, pilot 0.9786)")
    torque_only = {k: v for k, v in info.items() if k not in ("cv_criteria", "cv_motion_score")}
    assert weight_note("dm", torque_only) == ("dm: weight: its pilot's weighted fit (κ = 0), chosen by 5-fold "
                                              "cross-validation on 4000 samples (held-out torque NRMSE: GLS 0.3881, "
                                              "pilot 0.3863)")
    assert weight_note("dm", {**info, "weight_choice": "gls"}).startswith("dm: weight: the GLS fit Σ + κM(θ_ref), chosen")
    fallback = {"weight_choice": "gls", "cv_fallback": "3 samples, too few to cross-validate (at least 4); the GLS fit is kept"}
    assert weight_note("dm", fallback) == ("dm: weight: gls; 3 samples, too few to cross-validate (at least 4); the GLS "
                                           "fit is kept")


def test_a_candidate_whose_metric_is_singular_loses_on_motion():
    """θ = 0 has M(q, 0) singular (no inertia, nothing to simulate): its motion error is infinite and the GLS fit,
    the true θ here, is kept; the other way round the pilot is returned."""
    problem, theta = _metric_noise(np.random.default_rng(13), N=100)
    zero = np.zeros_like(theta)
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.cholesky(problem.metric.evaluate(zero)[:1])
    kept = choose_weight(problem, lambda sub: (zero, theta), 5)
    assert kept["weight_choice"] == "gls" and kept["cv_motion_score"]["pilot"] == np.inf
    returned = choose_weight(problem, lambda sub: (theta, zero), 5)
    assert returned["weight_choice"] == "pilot" and returned["cv_motion_score"]["gls"] == np.inf
