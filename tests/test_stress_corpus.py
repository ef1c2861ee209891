"""Fast subset of the stress corpus (benchmarks/stress_corpus.py): every method of the method table, with
each solver where there is a choice, on small corpus problems (prismatic and continuous joints, N = 12,
a point-mass link on the consistency boundary, a coordinate in units ×1e6). Every fit must end optimal,
without a raw warning reaching the caller, and agree with its reference (``dualid.bench.corpus_run``).
Also: the prior lift (``model.prior_lift``) is chart-invariant, recorded, and makes the boundary-prior fits
solvable that fail without it.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from dualid.bench.corpus import cases
from dualid.bench.corpus_run import fits
from dualid.errors import ConfigError, ConsistencyError, SolverError
from dualid.model.parameters import rigid_body_space
from dualid.model.prior_lift import centred_moments, lift_prior

QUICK = [c for c in cases(large=False) if c.quick and c.name != "chain RR, 2 dof, exact"]
# What the corpus measured the library NOT to do yet (benchmarks/stress_corpus/results.md): each must be reported
# (a status other than optimal, or an error), never passed off as optimal. A fix makes its entry fail here: remove it.
KNOWN = {
    # (the dm-bfp Newton rows of these two cases were here, 1.4e-5 / 2.5e-6 above the CLARABEL solve: its weighted fits
    # stopped along j0.m's ray; fixed by model/closure.py)
    # no finite minimiser (j0.m → ∞, tests/test_newton_unattained.py; flagged optimum_at_infinity): Newton and the SDP
    # stop at tolerance-dependent points
    ("rank-deficient 4 dof, N = 12", "dm-paper", "", "newton"): "infimum not attained: 1.4e-5 from the SDP's stop",
    ("point-mass link, 3 dof, 5 %", "dm-paper", "", "newton"): "infimum not attained: 2.3e-5 from the SDP's stop",
}
# Where the outcome is Clarabel's to decide, by release: the row is good, or it is not labelled optimal.
SOLVER_DECIDES = {
    # the SDP itself on that unattained infimum: Clarabel 0.11 ends optimal_inaccurate, 0.10 optimal
    ("rank-deficient 4 dof, N = 12", "dm-paper", "", "sdp_clarabel"): "Clarabel's stop on the ray",
}


@pytest.fixture(scope="module", params=QUICK, ids=[c.name for c in QUICK])
def corpus_rows(request):
    problem, theta = request.param.build()
    return request.param.name, fits(problem, theta, sdp=request.param.sdp)


def _good(r) -> bool:
    return (r["status"] == "optimal" and r["raw_warnings"] == 0 and r.get("rel_gap") is not None
            and abs(r["rel_gap"]) <= 1e-6 and r["pred_diff"] <= 1e-5)


def test_every_method_and_solver_is_optimal_and_agrees_with_its_reference(corpus_rows):
    case, rows = corpus_rows
    rows = [r for r in rows if "floor off" not in r["variant"]]
    assert {r["method"] for r in rows} == {"ols", "wls", "energy", "logdet", "pullback", "dm", "dm-paper"}
    assert {r["solver_choice"] for r in rows if r["method"] == "dm-paper"} == {"newton", "sdp_clarabel"}
    for r in rows:
        key = (case, r["method"], r["variant"], r["solver_choice"])
        what = f"{key}: {r['status']} gap {r.get('rel_gap')} {r.get('error') or r.get('chain')}"
        assert r["raw_warnings"] == 0, what
        if key in SOLVER_DECIDES:
            assert _good(r) or r["status"] != "optimal", what
            continue
        if key in KNOWN:
            assert not _good(r), f"{what}: fixed? remove it from KNOWN"
            # reported: a status other than optimal, a measured gap, or the failed reference recorded
            assert r["status"] != "optimal" or r.get("rel_gap") is not None or "ref_error" in r, what
            continue
        assert _good(r), what


def _thin_body(rng):
    """10 parameters of a body whose smallest centred second moment is 1e-12 of its largest (a boundary prior)."""
    R = pin.exp3(rng.normal(size=3))
    S = R @ np.diag([1e-14, 1e-3, 4e-3]) @ R.T
    return pin.Inertia(2.0, np.array([0.1, -0.05, 0.2]), np.trace(S) * np.eye(3) - S).toDynamicParameters()


def test_prior_lift_raises_small_second_moments_and_commutes_with_frame_and_unit_changes():
    rng = np.random.default_rng(0)
    space = rigid_body_space(["a", "b"])
    fine = pin.Inertia.FromBox(1.0, 0.3, 0.1, 0.05).toDynamicParameters()  # ℓ² = 0.3²/12 = 0.0075 m²
    theta = np.concatenate([_thin_body(rng), fine])
    lifted, report = lift_prior(space, theta, 1e-3)
    assert list(report) == ["a"] and report["a"]["lifted"]
    np.testing.assert_array_equal(lifted[10:], fine)  # a body above the floor is untouched
    m, c, sigma, _ = centred_moments(lifted[:10])
    assert m == pytest.approx(2.0) and np.allclose(c, [0.1, -0.05, 0.2])
    np.testing.assert_allclose(sigma, [1e-3 * 2.0 * 0.0075, 1e-3, 4e-3], rtol=1e-6)
    # a rigid change of body a's frame, then lengths in mm and mass in g: lift ∘ change = change ∘ lift
    M = pin.SE3(pin.exp3(rng.normal(size=3)), rng.normal(size=3))

    def change(th):
        a = pin.Inertia.FromDynamicParameters(th[:10]).se3Action(M)
        b = pin.Inertia.FromDynamicParameters(th[10:])
        return np.concatenate([pin.Inertia(1e3 * I.mass, 1e3 * I.lever, 1e9 * I.inertia).toDynamicParameters()
                               for I in (a, b)])

    np.testing.assert_allclose(lift_prior(space, change(theta), 1e-3)[0], change(lifted), rtol=1e-7)
    assert lift_prior(space, theta, 0.0) == (pytest.approx(theta), {})


def test_boundary_prior_fails_without_the_lift_and_is_solved_and_recorded_with_it():
    """A log-det / pullback prior taken from a constrained OLS fit (a body on the consistency boundary, completed by
    the closure): without the floor Clarabel (the reference) fails or is inaccurate, on both, and falls back to
    dualid's interior point (the default), which itself may not converge from its cold start (then Clarabel is its
    fallback); either chain says so. Whether the
    chain gets to the optimum depends on the Clarabel release (on the pullback one, 0.10: optimal; 0.11: line
    search failed, the fit reported optimal_inaccurate), and Clarabel may also call an uncertified point optimal:
    either way nothing inaccurate is called optimal. With the
    floor either solver alone solves both (Clarabel's answer certified by the interior point) and the result says
    which bodies were lifted."""
    from dualid.estimators.methods import make_estimator

    problem, _ = [c for c in cases(large=False) if c.name.startswith("chain RPR")][0].build()
    theta_ols = make_estimator("ols", allow_unidentifiable=True).fit(problem).theta
    for kind in ("logdet", "pullback"):
        for solver, first in (("newton", ("newton failed", "newton optimal")), ("cvxpy", ("CLARABEL returned optimal_inaccurate",
                                                                      "CLARABEL failed (solver_error)",
                                                                      "CLARABEL optimal, not certified"))):
            before = make_estimator(kind, theta0=theta_ols, allow_unidentifiable=True,
                                    options={"prior_floor": 0.0, "solver": solver})
            try:
                r = before.fit(problem)
                failed, chain = r.status != "optimal", r.info["solver_chain"]
            except SolverError:
                failed, chain = True, ""
            # (Clarabel: inaccurate in the raw-regressor chart, failed in the weighted fit's own chart,
            # estimators.quadratic_fit.signal_scale): either way not optimal on its own
            assert chain.startswith(first) or (failed and not chain), chain  # (no chain: the fit raised)
            assert failed or chain.endswith("newton optimal"), chain  # optimal only where the interior point got there
            after = make_estimator(kind, theta0=theta_ols, allow_unidentifiable=True, options={"solver": solver})
            after = after.fit(problem)
            assert after.status == "optimal" and after.info["solver_chain"].startswith(
                "newton optimal" if solver == "newton" else "CLARABEL optimal ("), after.info["solver_chain"]
            assert after.info["prior_floor"] == 1e-4 and set(after.info["prior_lifted"]) == {"j0", "j1", "j2"}


def test_prior_floor_is_checked_and_an_inconsistent_prior_is_still_refused():
    from dualid import RegularizedWLS

    with pytest.raises(ConfigError, match=r"prior_floor must be a number in \[0, 1\), got -1"):
        RegularizedWLS(theta0=np.ones(20), prior_floor=-1)
    problem, theta = [c for c in cases(large=False) if c.name.startswith("chain RR,")][0].build()
    bad = theta.copy()
    bad[4] = -1.0  # Ixx < 0: not a body, lifting must not repair it
    with pytest.raises(ConsistencyError, match="nominal θ₀ is not physically consistent"):
        RegularizedWLS(theta0=bad, allow_unidentifiable=True).fit(problem)


def test_a_prior_outside_the_cone_by_rounding_only_is_lifted_with_the_floor_and_refused_without():
    """A constrained fit leaves a body at margin ~ −1e-12 (N = 12 data, the Crazyflie base in the corpus): within
    ParameterSpace.is_consistent's tolerance, so the lift moves it inside (recorded); prior_floor=0 refuses it."""
    from dualid import RegularizedWLS

    problem, theta = [c for c in cases(large=False) if c.name.startswith("chain RR,")][0].build()
    m, c, sigma, R = centred_moments(theta[:10])
    sigma[0] = -1e-13 * sigma[-1]
    S = (R * sigma) @ R.T
    prior = theta.copy()
    prior[:10] = pin.Inertia(m, c, np.trace(S) * np.eye(3) - S).toDynamicParameters()
    assert min(problem.parameters.consistency_margins(prior).values()) < 0
    result = RegularizedWLS(theta0=prior, allow_unidentifiable=True).fit(problem)
    assert result.info["prior_lifted"]["j0"]["lifted"] and result.info["prior_lifted"]["j0"]["sigma_min_before"] < 0
    with pytest.raises(ConsistencyError, match="nominal θ₀ is not physically consistent: block 'j0'"):
        RegularizedWLS(theta0=prior, allow_unidentifiable=True, prior_floor=0.0).fit(problem)


def test_the_corpus_copy_of_the_default_preprocessing_is_the_library_default():
    """bench does not import robot (layering), so corpus_extra copies robot.defaults' preprocessing: they agree."""
    from dualid.bench.corpus_extra import DEFAULT_PREPROCESSING
    from dualid.robot.defaults import FIXED_PREPROCESSING_0_1

    assert DEFAULT_PREPROCESSING == FIXED_PREPROCESSING_0_1
