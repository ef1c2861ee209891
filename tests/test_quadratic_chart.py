"""The chart in which the quadratic and regularized fits reach cvxpy (estimators.quadratic_fit.signal_scale).

The stress corpus had Clarabel stop with a numerical error ("CLARABEL failed") on two feasible fits of the same
3-DoF arm with one coordinate in other units: the energy fit at ×1e-6 and the pullback fit with the constrained
OLS fit as prior at ×1e6. Cause: the chart θ = s ⊙ φ took s from the raw regressor's column norms, which a unit
change of one coordinate moves by up to 1e6 while the weighted (W = Σ̂⁻¹) and energy normal matrices do not move;
the scaled Hessian's diagonal then spread over 12 decades. The chart of the fit's own weighted statistics fixes the
first; the second is a fit whose infimum is not attained, which Clarabel now reports as such (optimal_inaccurate).
"""

from __future__ import annotations

import numpy as np
import pytest

from dualid.bench.corpus import cases
from dualid.estimators.methods import make_estimator
from dualid.estimators.newton.objective import energy_statistics, statistics
from dualid.estimators.quadratic_fit import fit_quadratic, signal_scale
from dualid.estimators.quadratic_newton import fit_quadratic_newton
from dualid.model.consistency import prior_blocks, pullback_metric

CASES = {c.name: c for c in cases(large=False)}


@pytest.fixture(scope="module")
def units():
    """{factor: problem}: the corpus arm (seed 12, RPR, N = 200, 5 % noise) with q1 in units ×factor."""
    return {f: CASES[f"units {f} on q1, 3 dof, 5 %"].build()[0] for f in ("1e-6", "1e6")}


def test_pullback_fit_with_the_ols_prior_in_units_1e6_is_solved_by_clarabel(units):
    problem = units["1e6"]
    prior = fit_quadratic(problem, statistics(problem), method="ols", constrained=True, solver="CLARABEL",  # not on
                          solver_options=None, allow_unidentifiable=True).theta  # the closed set: a mass at the bound
    result = make_estimator("pullback", theta0=prior, allow_unidentifiable=True, options={"solver": "cvxpy"}).fit(problem)
    assert result.status == "optimal" and result.solver == "CLARABEL", result.info["solver_chain"]
    assert result.info["solver_chain"].startswith("CLARABEL optimal (certified by newton: ")
    assert result.info["fallback_used"] is False
    assert result.info["cvxpy_above_certified"] <= 1e-7


def test_energy_fit_in_units_1e_minus_6_does_not_fail_and_matches_units_1e6(units):
    """The energy fit's statistics do not depend on the units, nor does its chart now: Clarabel ends the same way
    in both units. It ends optimal_inaccurate, truthfully: this fit's infimum is not attained. With the first link's
    mass bounded, j0.m ≤ M, the optimum sits on the bound and f* falls as M grows (dualid's interior point on the
    bounded problem: 264.612 at M = 10, 264.561 at M = 100); the chain says so before that interior point takes over."""
    results = {f: make_estimator("energy", allow_unidentifiable=True, options={"solver": "cvxpy"}).fit(p) for f, p in units.items()}
    for f, r in results.items():
        assert "CLARABEL failed" not in r.info["solver_chain"], (f, r.info["solver_chain"])
        assert r.info["solver_chain"] == "CLARABEL returned optimal_inaccurate → newton optimal", f
        assert r.status == "optimal" and r.solver == "newton"
    assert results["1e-6"].objective == pytest.approx(results["1e6"].objective, rel=1e-8)
    default = {f: make_estimator("energy", allow_unidentifiable=True).fit(p) for f, p in units.items()}  # the Newton
    assert all(r.info["solver_chain"] == "newton optimal" for r in default.values())  # fit on the closed set
    assert default["1e-6"].objective == pytest.approx(default["1e6"].objective, rel=1e-8)
    assert default["1e-6"].objective <= results["1e-6"].objective * (1 + 1e-9)
    problem = units["1e-6"]
    stats = energy_statistics(problem)
    bounded = {}
    for M in (10.0, 100.0):
        theta, _ = fit_quadratic_newton(stats.H, stats.g, stats.c, problem.parameters.with_bounds(upper={"j0.m": M}))
        assert theta[problem.parameters.names.index("j0.m")] == pytest.approx(M, rel=1e-4)  # at the bound
        bounded[M] = stats.objective(problem, theta)
    assert bounded[100.0] < bounded[10.0] * (1 - 1e-4)
    assert results["1e-6"].objective < bounded[100.0]


@pytest.mark.parametrize("kind", ["wls", "energy", "pullback", "logdet"])
def test_the_chart_is_the_weighted_column_norm_over_the_weighted_signal_in_every_unit_and_noise_level(units, kind):
    """s_k = √(c / (H_kk + γ g_kk)) from H_kk = Σ_i Y_ikᵀ W Y_ik and c = Σ_i τ_iᵀ W τ_i summed here from the problem's
    own arrays (not the statistics module) and g the prior's pullback metric (0 without a prior), 1/√g_kk for a
    parameter only the prior sees, 1 for one nothing sees; the same s in units ×1e-6 and ×1e6, and, without a prior,
    with W scaled by 1e20 (a noise level 1e-10 times smaller: exact data; with a prior that changes the problem)."""
    theta0 = CASES["units 1e6 on q1, 3 dof, 5 %"].build()[1]  # the true θ: consistent, interior, chart-free
    out = {1.0: [], 1e20: []}
    for f, problem in units.items():
        Y, tau = problem.Y, problem.tau  # (N, n, p), (N, n)
        if kind == "energy":
            W = problem.v[:, :, None] * problem.v[:, None, :]  # (N, n, n): (vᵀr)² = rᵀ v vᵀ r
        else:
            r = problem.residual(theta0)
            W = np.broadcast_to(np.linalg.inv(r.T @ r / problem.N), (problem.N, problem.n, problem.n))
        H_kk = np.einsum("iak,iab,ibk->k", Y, W, Y)
        c = float(np.einsum("ia,iab,ib->", tau, W, tau))
        gamma = 0.1 * problem.N * problem.n
        reg = (kind, theta0, gamma) if kind in ("pullback", "logdet") else None
        g = np.zeros(problem.p)
        if reg is not None:
            g = np.concatenate([np.diag(pullback_metric(V, C0)) for _, V, C0 in
                                prior_blocks(kind, problem.parameters, theta0)])
            assert np.all(g > 0)
        stats = energy_statistics(problem) if kind == "energy" else statistics(problem, W[0])
        for scale in (1.0, 1e20):
            s = signal_scale(scale * stats.H, scale * stats.c, problem.parameters, reg)
            seen = H_kk > 0
            assert 13 <= seen.sum() < problem.p
            expected = np.sqrt(scale * c / (scale * H_kk[seen] + (gamma * g[seen] if reg else 0.0)))
            assert np.allclose(s[seen], expected, rtol=1e-9)
            if reg is None:
                assert np.all(s[~seen] == 1.0)
            else:  # the first link's mass, first moments and inertia the data do not see: the prior's own size
                assert np.allclose(s[~seen], 1 / np.sqrt(g[~seen]), rtol=1e-12)
            out[scale].append(s)
    for scale, charts in out.items():
        assert np.allclose(charts[1], charts[0], rtol=1e-6), scale
    if reg is None:
        assert np.allclose(out[1e20][0], out[1.0][0], rtol=1e-6)


def test_crazyflie_pullback_fit_in_units_1e3_is_solved_by_clarabel():
    """A near-singular prior body (the pendulum links' thin inertia, pullback curvature ~1e16) with the data's
    chart alone left the prior term 1e10 above the data term in the scaled problem: Clarabel stopped
    (InsufficientProgress). The chart with the prior's curvature lets it finish, certified."""
    from dualid.bench.corpus import cad_prior

    problem, theta_true = CASES["crazyflie, units 1e3 on q1, 5 %"].build()[:2]
    result = make_estimator("pullback", theta0=cad_prior(theta_true, 0), allow_unidentifiable=True,
                            options={"solver": "cvxpy"}).fit(problem)
    assert result.info["solver_chain"].startswith("CLARABEL optimal (certified by newton: "), result.info["solver_chain"]
    assert result.status == "optimal" and result.solver == "CLARABEL"
