"""The chart-invariant margin C_b(θ) ⪰ ε·C_b(θ_ref) (dualid.model.margin, estimators/least_squares.py).

Specifications: the cvxpy SDP and Newton agree with the margin active; M_i(θ̂) ⪰ ε·M_i(θ_ref) at θ̂ of every
constrained method, at the training samples and at configurations the fit never saw; the same θ̂ in every chart
(configuration-dependent and units over 1e-6…1e6); a broken shift makes these checks fail; exact error messages.
"""

import dataclasses

import numpy as np
import pytest

from dualid import DualMetric
from dualid.errors import ConfigError, ModelError
from dualid.estimators.least_squares import margin_reference, with_margin
from dualid.estimators.methods import make_estimator
from dualid.metric_guard import generalized_eigenvalues
from dualid.model.consistency import feasible_set
from dualid.model.parameters import ParameterSpace
from tests.factories import drag_problem, random_chart
from tests.test_newton import crazyflie_like, rigid_body_problem

EPS = 0.6


@pytest.fixture(scope="module")
def rigid():
    """The Crazyflie-like chain (n = 8, p = 30, a null space) and unseen configurations of the same model."""
    model = crazyflie_like()
    problem, truth = rigid_body_problem(model, 80, seed=3, noise=0.3)
    unseen, _ = rigid_body_problem(model, 200, seed=11, noise=0.0)
    return problem, unseen, truth


def margined(problem, theta_ref, eps=EPS):
    return dataclasses.replace(problem, parameters=problem.parameters.with_margin(theta_ref, eps, "test"))


def rel(a, b):
    return np.linalg.norm(np.asarray(a) - np.asarray(b)) / max(np.linalg.norm(b), 1e-300)


def binding_reference(problem):
    """θ_ref = 2 θ̂ of the plain dual-metric fit: the margin C(θ) ⪰ 2ε·C(θ̂) cuts the plain optimum off (2ε > 1)."""
    return 2.0 * DualMetric(allow_unidentifiable=True).fit(problem).theta


@pytest.mark.parametrize("which", ["drag", "rigid"])
def test_sdp_and_newton_agree_with_the_margin_active(which, rigid):
    problem = rigid[0] if which == "rigid" else drag_problem(np.random.default_rng(4), N=40, noise=0.3)[0]
    plain = DualMetric(allow_unidentifiable=True).fit(problem)
    shifted = margined(problem, binding_reference(problem))
    newton = DualMetric(solver="newton", allow_unidentifiable=True).fit(shifted)
    sdp = DualMetric(solver="cvxpy", fallback=(), allow_unidentifiable=True).fit(shifted)
    assert newton.status == "optimal" and sdp.status == "optimal"
    assert rel(sdp.objective, newton.objective) < 1e-6
    assert newton.objective > plain.objective * (1 + 1e-4)  # the margin binds ...
    assert newton.info["margin_active"] and newton.info["margin_epsilon"] == EPS  # ... and says where
    assert newton.info["margin_reference"] == "test"
    for r in (newton, sdp):
        assert r.info["margin_min_ratio"] >= EPS - 1e-6


@pytest.mark.parametrize("key", ["ols", "wls", "energy", "logdet", "pullback", "dm", "dm-paper"])
def test_every_method_keeps_the_metric_above_eps_times_the_reference_also_at_unseen_configurations(key, rigid):
    problem, unseen, truth = rigid
    theta_ref = binding_reference(problem)
    est = make_estimator(key, theta0=truth, allow_unidentifiable=True)
    result = est.fit(margined(problem, theta_ref))
    assert result.info["margin_enforced"] is True
    for data in (problem, unseen):  # unseen: 200 configurations and velocities the fit never saw
        lam = generalized_eigenvalues(data, result.theta, theta_ref)
        assert lam.min() >= EPS * (1 - 1e-6), key
    # the property is not vacuous: without the margin some method falls below ε somewhere
    if key == "dm-paper":
        plain = est.fit(problem)
        assert generalized_eigenvalues(unseen, plain.theta, theta_ref).min() < EPS


def test_newton_dm_paper_with_the_margin_is_the_same_in_every_chart(rigid):
    """Configuration-dependent charts and unit scalings 1e-6…1e6: θ_ref carried (fixed), θ̂ does not move."""
    problem = rigid[0]
    shifted = margined(problem, binding_reference(problem))
    base = DualMetric(allow_unidentifiable=True).fit(shifted)
    rng = np.random.default_rng(0)
    charts = {
        "per_sample": random_chart(rng, problem.N, problem.n, per_sample=True),
        "units": np.diag(10.0 ** rng.uniform(-6, 6, problem.n)),
    }
    for name, B in charts.items():
        other = shifted.in_coordinates(B)
        assert other.parameters == shifted.parameters, name  # the margin travels with the problem
        r = DualMetric(allow_unidentifiable=True).fit(other)
        assert rel(r.theta, base.theta) < 1e-5, name
        assert abs(r.info["margin_min_ratio"] - base.info["margin_min_ratio"]) < 1e-6, name


_ORIGINAL_SHIFT = ParameterSpace.margin_shift


def _negated(self, block):
    s = _ORIGINAL_SHIFT(self, block)
    return None if s is None else -s


def test_a_broken_shift_is_caught(rigid, monkeypatch):
    """Mutants of the shift: dropped (plain consistency) or with the wrong sign. The ratio check fails."""
    problem = rigid[0]
    theta_ref = binding_reference(problem)
    for mutant in (lambda self, b: None, _negated):
        with monkeypatch.context() as mp:
            mp.setattr(ParameterSpace, "margin_shift", mutant)
            r = DualMetric(allow_unidentifiable=True).fit(margined(problem, theta_ref))
        assert generalized_eigenvalues(problem, r.theta, theta_ref).min() < EPS * (1 - 1e-3)


def test_feasible_set_is_consistency_shifted_by_eps_times_the_reference():
    problem, theta = drag_problem(np.random.default_rng(1), N=10)
    cons = feasible_set(problem.parameters.with_margin(theta, 0.25))
    np.testing.assert_allclose(cons.G @ theta + cons.h, 0.75 * theta)  # θ_k − ε θ_ref,k on θ = θ_ref
    assert cons.names[0] == f"body0.d_long ≥ {0.25 * theta[0]:g}"


def test_the_margin_is_carried_by_bounds_subsets_and_charts():
    problem, theta = drag_problem(np.random.default_rng(2), N=10)
    space = problem.parameters.with_margin(theta, 0.1, "prior")
    assert space.with_bounds(lower=np.zeros(problem.p)).margin_reference == space.margin_reference
    p2 = dataclasses.replace(problem, parameters=space)
    assert p2.subset(slice(0, 5)).parameters == space
    assert p2.in_coordinates(np.eye(problem.n) * 2).parameters == space
    assert space.without_margin() == problem.parameters
    with pytest.raises(ModelError, match=r"^concatenate: add the margin \(with_margin\) after concatenating"):
        space.concatenate(problem.parameters)


def test_wls_pilot_reference_and_with_margin(rigid):
    problem = rigid[0]
    theta_ref, label = margin_reference(problem, "wls")
    assert label == "wls pilot" and problem.parameters.is_consistent(theta_ref, tol=1e-7)
    out = with_margin(problem, 0.1)
    assert out.parameters.margin_epsilon == 0.1 and out.parameters.margin_label == "wls pilot"
    r = make_estimator("wls", allow_unidentifiable=True).fit(out)
    assert r.info["margin_reference"] == "wls pilot" and r.info["margin_min_ratio"] >= 0.1 - 1e-6


@pytest.mark.parametrize(
    "eps, reference, prior, message",
    [
        (1.0, "wls", None, "margin.epsilon: expected a number in [0, 1), got 1.0"),
        (-0.1, "wls", None, "margin.epsilon: expected a number in [0, 1), got -0.1"),
        ("a", "wls", None, "margin.epsilon: expected a number in [0, 1), got 'a'"),
        (float("nan"), "wls", None, "margin.epsilon: expected a number in [0, 1), got nan"),
        (0.1, "prior", None, "margin.reference: 'prior' needs a prior θ₀, and this fit has none"),
        (0.1, "ols", None, "margin.reference: expected one of ('wls', 'prior') or a vector θ_ref, got 'ols'"),
        (0.1, np.ones(3), None, "margin.reference: expected θ_ref of shape (9,), got (3,)"),
        (0.1, np.full(9, np.nan), None, "margin.reference: θ_ref has non-finite entries (NaN or inf)"),
        (0.1, "prior", -np.ones(9), "margin.reference: θ_ref is not physically consistent: block 'body0' has "
         "constraint-matrix smallest eigenvalue -1 < 0; the margin C_b(θ) ⪰ ε·C_b(θ_ref) needs a consistent reference"),
    ],
)
def test_bad_margins_raise_config_errors(eps, reference, prior, message):
    problem, _ = drag_problem(np.random.default_rng(0), N=10)
    with pytest.raises(ConfigError) as exc:
        with_margin(problem, eps, reference, prior)
    assert str(exc.value) == message


def test_the_study_puts_every_method_under_the_margin_against_a_wls_pilot():
    """run_study(margin=ε): each training set gets its own WLS pilot; every fit records and satisfies the margin."""
    from dualid.paper.study import run_study
    from dualid.problem import build_problem
    from dualid.systems.base import make_system

    system = make_system("pan-tilt", seed=0, noise="realistic", size="small")
    r = run_study(system, case="high", methods=("ols", "dm-paper"), margin=0.9)
    assert r.config["margin_epsilon"] == 0.9
    problem = build_problem(system.model, list(system.train))
    pilot, _ = margin_reference(problem, "wls")
    for rec in r.records:
        assert rec.ok and rec.info["margin_reference"] == "wls pilot", rec.method
        assert generalized_eigenvalues(problem, np.array(rec.theta), pilot).min() >= 0.9 * (1 - 1e-6), rec.method


def test_the_sandwich_sees_the_margin_as_the_active_constraint(rigid):
    """uncertainty.active_constraints: where the margin binds, C_b(θ̂) − ε·C_b(θ_ref) is singular (C_b(θ̂) is not)."""
    from dualid.evaluation.uncertainty import active_constraints

    problem = rigid[0]
    shifted = margined(problem, binding_reference(problem))
    r = DualMetric(allow_unidentifiable=True).fit(shifted)
    _, names = active_constraints(shifted, r.theta)
    active = set(r.info["margin_active"].split(", "))
    assert active and {n.split(" (")[0] for n in names} >= active
    assert not active_constraints(problem, r.theta)[1]  # without the margin nothing is on the boundary
