"""Stress subset for the dual-metric Newton solver: convergence, iteration bound and agreement with the SDP.

Each case is one where the SDP (Clarabel) reports optimal. Before the primal and dual step lengths were
decoupled these took 24–42 iterations (arm7: 42 at N = 100) or jammed (DFKI: 106); the bounds below
fail on that code. Objectives are compared, never raw θ (the problems are rank deficient).
"""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import numpy as np
import pytest

from dualid.estimators.dual_metric import fit_dual_metric_sdp
from dualid.estimators.newton import fit_dual_metric_newton
from dualid.robot.defaults import FIXED_PREPROCESSING_0_1

DFKI = Path(__file__).resolve().parents[1] / "examples" / "dfki" / "data"

TYPICAL, WORST = 15, 30


def _sdp(problem):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fit_dual_metric_sdp(problem)


def _check(problem, max_iterations: int):
    newton = fit_dual_metric_newton(problem)
    sdp = _sdp(problem)
    assert sdp.status == "optimal"
    assert newton.iterations <= max_iterations, newton.info["f_history"]
    # Newton converges to 1e-9; the SDP's own accuracy is the looser of the two
    assert newton.objective <= sdp.objective * (1 + 1e-6)
    np.testing.assert_allclose(newton.objective, sdp.objective, rtol=1e-6)
    return newton


@pytest.fixture(scope="module")
def bench_samples(tmp_path_factory):
    from dualid.bench.runner import base_samples

    cache = tmp_path_factory.mktemp("bench")
    return {name: base_samples(name, cache, 200) for name in ("arm7", "crazyflie")}


@pytest.mark.parametrize("N", [100, 200])
def test_arm7_rank_deficient_converges_in_typical_iterations(bench_samples, N):
    from dualid.bench.runner import build_problem

    _check(build_problem(bench_samples["arm7"], N), TYPICAL)


def test_crazyflie_null_space_converges_in_typical_iterations(bench_samples):
    from dualid.bench.runner import build_problem

    _check(build_problem(bench_samples["crazyflie"], 200), TYPICAL)


@pytest.mark.parametrize("scale", [1e-6, 1e6])
def test_tiny_and_huge_units_take_the_same_path(bench_samples, scale):
    """Coordinates in tiny/huge units (a constant diagonal chart 1e±6 … 1): f and the iterations are unchanged."""
    from dualid.bench.runner import build_problem

    problem = build_problem(bench_samples["arm7"], 100)
    base = fit_dual_metric_newton(problem)
    B = np.diag(np.geomspace(1.0, scale, problem.n))
    other = fit_dual_metric_newton(problem.in_coordinates(np.broadcast_to(B, (problem.N,) + B.shape).copy()))
    np.testing.assert_allclose(other.objective, base.objective, rtol=1e-9)
    assert other.iterations <= TYPICAL


def _dfki_problem(mass_bound: float | None = 5.0):
    """trajectory_00 with the default preprocessing (what `dualid fit` runs on it), N = 1000."""
    from dualid.robot.config import FitConfig
    from dualid.robot.fit import build_model, build_problem, column_map, load_runs

    cfg = FitConfig.from_dict({"model": {"urdf": str(DFKI / "pendubot_model_2.1.urdf")},
                               "train": [str(DFKI / "trajectory_00.csv")],
                               "preprocessing": [dict(x) for x in FIXED_PREPROCESSING_0_1]})
    rigid, model = build_model(cfg)
    joints = tuple(rigid.coordinates)
    runs = load_runs(cfg.train, column_map(cfg.columns, joints, cfg.train[0]), joints, cfg.preprocessing)
    problem = build_problem(model, runs)
    if mass_bound is not None:  # without it the infimum lies at Joint1.m → ∞ (see below)
        upper = {n: mass_bound for n in problem.parameters.names if n.endswith(".m")}
        problem = dataclasses.replace(problem, parameters=problem.parameters.with_bounds({}, upper))
    return problem




def test_dfki_real_data_with_active_constraints_converges_and_tiling_keeps_the_path():
    """Real pendubot data, masses ≤ 5 kg: joint 1's armature and viscous friction, a mass bound and two
    eigenvalues of each pseudo-inertia end active. Was 49 iterations with one common step length."""
    problem = _dfki_problem()
    newton = _check(problem, WORST)
    tiled = fit_dual_metric_newton(problem.subset(np.tile(np.arange(problem.N), 3)))
    np.testing.assert_allclose(tiled.objective, 3 * newton.objective, rtol=1e-8)
    assert tiled.iterations == newton.iterations


def test_dfki_without_mass_bounds_stops_within_the_iteration_bound():
    """Without mass bounds the DM infimum is not attained (f keeps falling as Joint1.m → ∞, a direction the
    data do not see); the solver stops at the tolerance within the bound (was: 106 iterations, i.e. a
    failure at the default limit of 100). Only the bound is asserted: the point reached is not unique."""
    from dualid.errors import OptimumAtInfinityWarning

    with pytest.warns(OptimumAtInfinityWarning, match="Joint1.m"):  # and it says so (tests/test_optimum_at_infinity.py)
        newton = fit_dual_metric_newton(_dfki_problem(mass_bound=None))
    assert newton.iterations <= WORST + 5  # 31 with the centring steps (interior_point.CENTRALITY_MIN), 30 before
