"""The noise benchmarks' data and scores: benchmarks/authors_example.py (dualid.bench.authors_arm) and
benchmarks/noise_sources.py (dualid.bench.mujoco_arms), each on a tiny case.

References: MuJoCo's inverse dynamics against Pinocchio's regressor at the true parameters; the pseudo-inertia
geodesic in closed form (a body scaled by s is at sqrt(2)·|log s|, P being 4×4) and its frame invariance.
"""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from dualid.bench import authors_arm
from dualid.bench import mujoco_arms as ma
from dualid.errors import ConfigError
from dualid.evaluation.parameter_error import geodesic_distance

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def _script(name):
    sys.path.insert(0, str(BENCH))
    spec = importlib.util.spec_from_file_location(f"bench_{name}", BENCH / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("robot", sorted(ma.ROBOTS))
def test_mujoco_torque_is_the_regressor_at_the_true_parameters(robot):
    """MuJoCo (armature, damping, plus the Coulomb term) and Pinocchio's regressor with joint terms agree."""
    rng = np.random.default_rng(1)
    arm = ma.sim_arm(robot, rng)
    _, q, v, a = ma.excitation(rng, arm.n, 0.1, 200.0)
    tau = arm.torque(q, v, a)
    Y = arm.ident.regressor(q, v, a)
    assert np.abs(Y @ arm.theta_true - tau).max() < 1e-9 * np.abs(tau).max()
    assert np.abs(tau - ma.inverse_dynamics(arm.mj, q, v, a)).max() > 1e-3  # the Coulomb term is there
    assert arm.ident.parameters.is_consistent(arm.theta_true)


def test_unknown_robot_is_a_config_error():
    with pytest.raises(ConfigError, match="panda"):
        ma.robot_urdf("nao")


def test_geodesic_closed_forms_and_frame_invariance():
    truth = authors_arm.true_parameters()
    assert geodesic_distance(truth, truth) < 1e-12
    for s in (0.5, 2.0, 10.0):
        assert geodesic_distance(truth, s * truth) == pytest.approx(np.sqrt(2.0) * abs(np.log(s)), rel=1e-10)
    other = pin.Inertia(0.9, np.array([0.1, 0.0, -0.02]), np.diag([0.03, 0.05, 0.06])).toDynamicParameters()
    d = geodesic_distance(truth, other)
    X = pin.SE3(pin.exp3(np.array([0.3, -1.0, 0.5])), np.array([0.2, -0.4, 1.0]))
    moved = [pin.Inertia.FromDynamicParameters(t).se3Action(X).toDynamicParameters() for t in (truth, other)]
    assert geodesic_distance(*moved) == pytest.approx(d, rel=1e-9)
    bad = truth.copy()
    bad[0] = -1.0
    assert geodesic_distance(truth, bad) == np.inf


def test_authors_example_reproduces_the_paper_gap_on_their_default_seed():
    """Their seed 42, N = 1000, both noises: the paper's objective is far closer to the truth than WLS."""
    bench = _script("authors_example")
    rows = {r["method"]: r for r in bench.run_seed(42, "both", ["wls", "dm-paper"], sizes=(1000,))}
    assert rows["dm-paper"]["geodesic"] < 0.15 < 0.35 < rows["wls"]["geodesic"]
    q, v, a, tau = authors_arm.samples(42, torque_noise=False, encoder_noise=False)
    P = authors_arm.problem(q, v, a, tau)  # checks Pinocchio against MuJoCo at the filtered states
    assert np.abs(P.residual(authors_arm.true_parameters())).max() < 0.02 * np.abs(tau).max()  # filter bias only


def test_noise_sources_truth_scores_the_floor(tmp_path):
    bench = _script("noise_sources")
    rows = bench.run_dataset("ur5", 0, "both 5% + 1 mrad", ["wls"], train_s=1.5, test_s=1.0)
    truth, wls = rows
    assert truth["method"] == "truth" and truth["floor_ratio"] == pytest.approx(1.0, abs=1e-12)
    assert truth["clean_error"] < 1e-10 and truth["base_error"] < 1e-10
    assert wls["floor_ratio"] > 1.0 and wls["clean_error"] > 1e-3 and wls["consistent"]
    out = tmp_path / "noise.json"
    out.write_text("{}")
    with pytest.raises(SystemExit) as exc:
        bench.main(["--quick", "--method", "ols", "--out", str(out)])
    assert exc.value.code == 2 and out.read_text() == "{}"
    with pytest.raises(SystemExit) as exc:  # a .md for --out would be written over by the result's own .md
        bench.main(["--quick", "--method", "ols", "--out", str(tmp_path / "noise.md"), "--force"])
    assert exc.value.code == 2 and not (tmp_path / "noise.md").exists()


def test_the_second_start_check_solves_dms_objective_again():
    """noise_sources.second_start re-solves dm's fit (its closed set, its levels) from two other starts."""
    from dualid.estimators.noise_dm import NoiseModelDM
    from tests.test_noise_dm import eiv_problem

    bench = _script("noise_sources")
    problem, _ = eiv_problem(7, N=1000, torque=0.05, regressor=0.1)
    est = NoiseModelDM()
    result = est.fit(problem)
    assert result.noise.choice == "noise model"
    gap = bench.second_start(est, problem, result)
    assert gap is not None and gap > -1e-6  # no lower objective from another start


def test_the_instrumental_variables_fit_is_exact_at_exact_states_and_beats_attenuation():
    """noise_sources.iv_reference: with the regressor at the exact states (Y = Z, τ = Zθ*) it reproduces θ*'s
    torques; with 1 mrad of encoder noise in Y (τ exact), its base-parameter error is below WLS's, which the noise
    attenuates."""
    from types import SimpleNamespace

    bench = _script("noise_sources")
    problem, held, _, Z = bench.dataset("ur5", 0, "encoder 1 mrad", test_s=1.0)  # 8 s of training: N = 1,600
    tau = Z @ held.theta_true
    exact = SimpleNamespace(Y=Z, tau=tau, p=problem.p, parameters=problem.parameters,
                            residual=lambda th: Z @ th - tau)
    theta = bench.iv_reference(exact, Z)
    assert np.linalg.norm(Z @ theta - tau) < 1e-9 * np.linalg.norm(tau)
    iv = held.scores(bench.iv_reference(problem, Z))["base_error"]
    wls = bench.fit_one("wls", problem, held, None)["base_error"]
    assert iv < 0.7 * wls, (iv, wls)
