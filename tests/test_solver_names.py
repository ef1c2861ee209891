"""One solver vocabulary for every estimator: solver="newton" (dualid's interior point) or "cvxpy" (the conic
reference, its backend chosen by cvxpy_solver), each method keeping its own default."""

import numpy as np
import pytest

from dualid.errors import ConfigError, SolverOptionError
from dualid.estimators.methods import METHODS, make_estimator
from tests.factories import drag_problem

QUADRATIC = ("ols", "wls", "energy")


@pytest.fixture(scope="module")
def problem():
    return drag_problem(np.random.default_rng(3), N=60, n=3, noise=0.05)[0]


def test_each_method_keeps_its_default_solver():
    defaults = {key: make_estimator(key).solver for key, m in METHODS.items() if not m.needs_prior}
    assert defaults == {"ols": "cvxpy", "ols_unconstrained": "cvxpy", "wls": "newton", "energy": "newton",
                        "dm": "newton", "dm-paper": "newton"}  # OLS: its end point is a prior (least_squares.OLS)
    assert all(make_estimator(k).cvxpy_solver == "CLARABEL" for k in defaults)


@pytest.mark.parametrize("key", [*QUADRATIC, "dm-paper", "dm"])
def test_every_method_accepts_newton(key, problem):
    result = make_estimator(key, allow_unidentifiable=True, options={"solver": "newton"}).fit(problem)
    assert result.solver == "newton" and result.status == "optimal"


@pytest.mark.parametrize("key", QUADRATIC)
def test_the_quadratic_fits_agree_between_newton_and_cvxpy(key, problem):
    newton = make_estimator(key, allow_unidentifiable=True, options={"solver": "newton"}).fit(problem)
    cvxpy = make_estimator(key, allow_unidentifiable=True, options={"solver": "cvxpy"}).fit(problem)
    assert newton.objective == pytest.approx(cvxpy.objective, rel=1e-7)
    assert newton.info["solver_chain"] == "newton optimal"


def test_cvxpy_solver_picks_the_conic_backend(problem):
    scs = make_estimator("dm-paper", allow_unidentifiable=True,
                         options={"solver": "cvxpy", "cvxpy_solver": "SCS", "fallback": ()}).fit(problem)
    assert scs.solver == "sdp/SCS"
    energy = make_estimator("energy", allow_unidentifiable=True, options={"solver": "cvxpy", "cvxpy_solver": "SCS"})
    assert energy.fit(problem).info["solver_chain"].startswith("SCS ")


def test_dm_takes_the_same_names():
    dm = make_estimator("dm", options={"solver": "cvxpy", "cvxpy_solver": "SCS"})
    assert (dm.solver, dm.cvxpy_solver) == ("cvxpy", "SCS")


@pytest.mark.parametrize("key", [*QUADRATIC, "dm-paper", "dm"])
@pytest.mark.parametrize("name, hint", [("CLARABEL", "CLARABEL"), ("SCS", "SCS"), ("sdp_scs", "SCS"),
                                        ("gurobi", None)])
def test_other_solver_names_are_refused_with_the_pair_that_selects_them(key, name, hint):
    with pytest.raises(SolverOptionError, match=r"solver must be one of \('newton', 'cvxpy'\)") as exc:
        make_estimator(key, options={"solver": name})
    assert (f"solver='cvxpy', cvxpy_solver='{hint}'" in str(exc.value)) == (hint is not None)


def test_newton_options_of_the_quadratic_fits_are_checked():
    make_estimator("ols", options={"solver": "newton", "solver_options": {"tol": 1e-8, "max_iter": 50}})
    with pytest.raises(ConfigError, match="solver 'newton' accepts the solver_options tol and max_iter"):
        make_estimator("ols", options={"solver": "newton", "solver_options": {"eps": 1e-9}})


def test_the_cli_flag_sets_solver_and_backend():
    from dualid.cli.fit import _solver_overrides
    from dualid.robot.config import FitConfig

    cfg = FitConfig.from_dict({"model": {"urdf": "x.urdf"}, "train": ["a.csv"]})
    out = dict(_solver_overrides(cfg, ["wls=cvxpy:SCS", "dm-paper=newton"]))
    assert dict(out["wls"]) == {"solver": "cvxpy", "cvxpy_solver": "SCS"}
    assert dict(out["dm-paper"]) == {"solver": "newton"}
