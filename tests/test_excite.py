"""``dualid excite``: the Fourier trajectory, the design problem, the optimiser and the command.

References: finite differences (trajectory derivatives, constraint Jacobians), pin.rnea (torques),
dualid's own identifiability (rank of the base parameters), the log reader and ``dualid fit``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yaml
from typer.testing import CliRunner

from dualid.cli import app
from dualid.data.io import load_log
from dualid.errors import ConfigError, ModelError
from dualid.excite import ExciteConfig, FourierTrajectory, build_design, check_limits, optimize, random_trajectory
from dualid.excite.fourier import free_basis
from dualid.excite.optimize import _Problem
from dualid.excite.predict import base_condition, predict
from dualid.model.rigid_body import RigidBodyModel
from dualid.robot.inputs import array_column_map

DFKI = Path(__file__).resolve().parents[1] / "examples" / "dfki" / "data"
URDF = DFKI / "pendubot_model_2.1.urdf"
runner = CliRunner()
TINY = {"period": 4.0, "harmonics": 3, "grid": 40, "restarts": 1, "maxiter": 40, "acceleration": 30, "rate": 100,
        "limits": {"Joint1": {"velocity": 6, "effort": 4}, "Joint2": {"velocity": 6, "effort": 4, "lower": -2, "upper": 2}}}


def _text(result) -> str:
    return " ".join((result.output + (result.stderr if result.stderr_bytes is not None else "")).split())


@pytest.fixture(scope="module")
def design():
    return build_design(RigidBodyModel.from_urdf(URDF), ExciteConfig.from_dict(TINY))


def _random_at_rest(rng, n=3, K=4, period=2.5):
    return FourierTrajectory.at_rest(period, rng.uniform(-1, 1, n), rng.normal(size=(n, 2 * (K - 1))))


def test_velocity_and_acceleration_are_the_derivatives_of_position():
    traj = _random_at_rest(np.random.default_rng(0))
    t, h = np.linspace(0.1, 2.3, 17), 1e-5
    q, v, a = traj.evaluate(t)
    qp, vp, _ = traj.evaluate(t + h)
    qm, vm, _ = traj.evaluate(t - h)
    np.testing.assert_allclose(v, (qp - qm) / (2 * h), atol=1e-7)
    np.testing.assert_allclose(a, (vp - vm) / (2 * h), atol=1e-6)


def test_the_trajectory_starts_and_ends_at_rest_at_the_start_configuration():
    rng = np.random.default_rng(1)
    q_start = rng.uniform(-1, 1, 3)
    traj = FourierTrajectory.at_rest(2.5, q_start, rng.normal(size=(3, 6)))
    q, v, a = traj.evaluate(np.array([0.0, 2.5]))
    np.testing.assert_allclose(q, [q_start, q_start], atol=1e-12)
    np.testing.assert_allclose(v, 0, atol=1e-12)
    np.testing.assert_allclose(a, 0, atol=1e-12)
    assert np.abs(traj.evaluate(np.array([1.0]))[1]).max() > 0.1  # it moves in between


def test_the_free_basis_is_the_affine_map_of_the_coefficients():
    rng = np.random.default_rng(2)
    traj = _random_at_rest(rng)
    t = np.linspace(0, 2.5, 11)
    Bq, Bv, Ba = free_basis(t, 2.5, 4)
    q, v, a = traj.evaluate(t)
    x = traj.free_coefficients()
    np.testing.assert_allclose(q, traj.evaluate(np.zeros(1))[0] + Bq @ x.T, atol=1e-12)
    np.testing.assert_allclose(v, Bv @ x.T, atol=1e-12)
    np.testing.assert_allclose(a, Ba @ x.T, atol=1e-12)


def test_one_harmonic_cannot_rest():
    with pytest.raises(ConfigError, match="harmonics: rest at start and end needs at least 2 harmonics, got 1"):
        FourierTrajectory.at_rest(1.0, np.zeros(2), np.zeros((2, 0)))


def test_torque_is_inverse_dynamics_and_its_jacobian_is_exact(design):
    rng = np.random.default_rng(3)
    q, v, a = rng.normal(size=(3, 5, 2))
    tau, dq, dv, da = design.torque(q, v, a, jacobian=True)
    model = design.rigid.model
    ref = np.stack([pin.rnea(model, model.createData(), q[t], v[t], a[t]) for t in range(5)])
    np.testing.assert_allclose(tau, ref, atol=1e-12)  # the URDF has no friction and no armature
    problem = _Problem(design, ExciteConfig.from_dict(TINY))
    x = 0.3 * rng.normal(size=2 * problem.m)
    J = problem.constraints_jacobian(x)
    h = 1e-6
    fd = np.stack([(problem.constraints(x + h * e) - problem.constraints(x - h * e)) / (2 * h)
                   for e in np.eye(x.size)], axis=1)
    np.testing.assert_allclose(J, fd, atol=1e-6)


def test_base_parameters_span_the_regressor(design):
    rng = np.random.default_rng(4)
    from dualid.excite.design import random_states

    q, v, a = random_states(rng, design.limits, design.q_start, 100)
    Y = design.regressor(q, v, a).reshape(-1, design.model.parameters.p)
    base = design.base
    theta = rng.normal(size=Y.shape[1])
    np.testing.assert_allclose(Y @ theta, base.regressor(Y) @ base.values(theta), atol=1e-9)  # at other states
    assert base.rank == np.linalg.matrix_rank(Y / np.linalg.norm(Y, axis=0).clip(1e-300))


def test_optimised_tiny_problem_holds_its_limits_at_1khz_and_beats_random(design):
    cfg = ExciteConfig.from_dict({**TINY, "criterion": "cond"})
    result = optimize(design, cfg)
    check = check_limits(design, result.trajectory, 1000.0)
    assert check.ok, check.worst
    assert max(check.worst.values()) > 0.5  # it uses the room it has
    t = result.trajectory.times(100)

    def cond(traj):
        q, v, a = traj.evaluate(t)
        return base_condition(design.base.regressor(design.regressor(q, v, a)))[0]

    rng = np.random.default_rng(0)
    randoms = [random_trajectory(design, cfg, rng) for _ in range(3)]
    assert all(check_limits(design, r, 1000.0).ok for r in randoms)
    assert cond(result.trajectory) < min(cond(r) for r in randoms)


def test_floating_base_models_are_refused():
    rigid = RigidBodyModel.from_urdf(URDF, floating_base=True)
    with pytest.raises(ModelError, match="excite: the model has a floating base"):
        build_design(rigid, ExciteConfig())


def test_config_errors_name_the_key():
    with pytest.raises(ConfigError, match=r"excite config: harmonics: Input should be greater than or equal to 2 \(got 1\)"):
        ExciteConfig.from_dict({"harmonics": 1})
    with pytest.raises(ConfigError, match="excite config: limits: unknown joints \\['J9'\\]; the model's joints are "
                                          "\\['Joint1', 'Joint2'\\]"):
        build_design(RigidBodyModel.from_urdf(URDF), ExciteConfig.from_dict({"limits": {"J9": {"velocity": 1}}}))


# --- the command ----------------------------------------------------------------------------------
def _run_excite(tmp_path, *extra, config=None):
    cfg = tmp_path / "excite.yaml"
    cfg.write_text(yaml.safe_dump(config or {**TINY, "maxiter": 20}))
    return runner.invoke(app, ["excite", "--model", str(URDF), "--out", str(tmp_path / "ex"), "--config", str(cfg),
                               *extra])


def test_excite_writes_a_csv_that_dualid_fit_reads_after_simulation(tmp_path):
    result = _run_excite(tmp_path, "--seed", "1")
    assert result.exit_code == 0, _text(result)
    out = tmp_path / "ex"
    for name in ("trajectory.csv", "coefficients.yaml", "trajectory.png", "identifiability.json", "identifiability.md"):
        assert (out / name).is_file(), name
    assert "URDF has no" not in _text(result) and "min_distance not set" in _text(result)
    coef = yaml.safe_load((out / "coefficients.yaml").read_text())
    assert coef["harmonics"] == 3 and set(coef["joints"]) == {"Joint1", "Joint2"}

    # simulate: τ = rnea + noise, appended as tau[k] (what a robot or a simulator logs)
    import pandas as pd

    table = pd.read_csv(out / "trajectory.csv")
    rigid = RigidBodyModel.from_urdf(URDF)
    data = rigid.model.createData()
    q, v, a = (table[[f"{s}[{k}]" for k in range(2)]].to_numpy() for s in ("q", "v", "a"))
    tau = np.stack([pin.rnea(rigid.model, data, q[t], v[t], a[t]) for t in range(len(table))])
    np.testing.assert_allclose(tau, table[["tau_nom[0]", "tau_nom[1]"]].to_numpy(), atol=1e-6)
    tau += 0.01 * np.random.default_rng(0).normal(size=tau.shape)
    for k in range(2):
        table[f"tau[{k}]"] = tau[:, k]
    run = tmp_path / "run.csv"
    table.to_csv(run, index=False)
    cmap = array_column_map(rigid.coordinates, list(table.columns))
    traj = load_log(run, cmap, rigid.coordinates)
    np.testing.assert_allclose(traj.q, q)
    np.testing.assert_allclose(traj.v, v)
    fit = runner.invoke(app, ["fit", "--model", str(URDF), "--data", str(run), "--method", "ols",
                              "--out", str(tmp_path / "fit")])
    assert fit.exit_code == 0, _text(fit)
    assert (tmp_path / "fit" / "ols.urdf").is_file()


def test_excite_refuses_an_existing_output_and_a_bad_config(tmp_path):
    (tmp_path / "ex").mkdir()
    (tmp_path / "ex" / "mine.txt").write_text("x")
    result = _run_excite(tmp_path)
    assert result.exit_code == 2
    assert f"error: output directory {tmp_path / 'ex'}: exists and is not empty; choose another or pass --force" \
        in _text(result)
    result = _run_excite(tmp_path, config={"bogus": 1})
    assert result.exit_code == 2
    assert f"error: excite config {tmp_path / 'excite.yaml'}: bogus: Extra inputs are not permitted (got 1)" in _text(result)
    result = _run_excite(tmp_path, "--criterion", "aopt", "--force")
    assert result.exit_code == 2
    assert "error: excite config: criterion: Input should be 'dm', 'logdet' or 'cond' (got 'aopt')" in _text(result)


def test_excite_missing_urdf_is_exit_2(tmp_path):
    result = runner.invoke(app, ["excite", "--model", str(tmp_path / "none.urdf"), "--out", str(tmp_path / "ex")])
    assert result.exit_code == 2
    assert f"error: RigidBodyModel.from_urdf: no URDF file at {tmp_path / 'none.urdf'}" in _text(result)


def test_prediction_matches_the_problems_identifiability(design):
    rng = np.random.default_rng(5)
    cfg = ExciteConfig.from_dict(TINY)
    traj = random_trajectory(design, cfg, rng)
    pred = predict(design, traj, 100.0, 0.1)
    assert pred.identifiability.rank == len(pred.base_names) == design.base.rank
    assert np.all(pred.standard_errors > 0) and np.all(np.isfinite(pred.standard_errors))
    # doubling the noise doubles the standard errors
    np.testing.assert_allclose(predict(design, traj, 100.0, 0.2).standard_errors, 2 * pred.standard_errors, rtol=1e-9)


# --- collision geometry -----------------------------------------------------------------------------
def _box_link(name: str, size: str, z: float) -> str:
    geometry = f'<geometry><box size="{size}"/></geometry>'
    return (f'<link name="{name}"><inertial><origin xyz="0 0 {z}"/><mass value="1"/>'
            f'<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>'
            f'<collision><origin xyz="0 0 {z}"/>{geometry}</collision></link>')


def _boxes_urdf(tmp_path) -> Path:
    """A double pendulum over a floor block: the lower link's tip hangs 0.05 m above the block."""
    joint = ('<joint name="{n}" type="revolute"><parent link="{p}"/><child link="{c}"/><origin xyz="0 0 {z}"/>'
             '<axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="50" velocity="5"/></joint>')
    text = ('<robot name="boxes">' + _box_link("base", "1 1 0.1", -0.55) + _box_link("l1", "0.04 0.04 0.3", -0.15)
            + _box_link("l2", "0.04 0.04 0.15", -0.075) + joint.format(n="J1", p="base", c="l1", z=0.0)
            + joint.format(n="J2", p="l1", c="l2", z=-0.3) + "</robot>")
    path = tmp_path / "boxes.urdf"
    path.write_text(text)
    return path


def test_link_distance_comes_from_the_collision_geometry(tmp_path):
    from dualid.excite.collision import link_distance

    rigid = RigidBodyModel.from_urdf(_boxes_urdf(tmp_path))
    distance, note = link_distance(_boxes_urdf(tmp_path), rigid)
    assert note == "minimum link distance constrained on 1 collision pairs of boxes.urdf"
    np.testing.assert_allclose(distance(np.zeros((1, 2))), [0.05], atol=1e-9)  # tip at −0.45, floor top at −0.5
    d, G = distance.gradient(np.array([[0.3, 0.2]]))
    h = 1e-4
    fd = [(distance(np.array([[0.3 + h * e0, 0.2 + h * e1]])) - distance(np.array([[0.3 - h * e0, 0.2 - h * e1]])))[0]
          / (2 * h) for e0, e1 in ((1, 0), (0, 1))]
    np.testing.assert_allclose(G[0], fd, atol=1e-4)
    none, why = link_distance(URDF, RigidBodyModel.from_urdf(URDF))
    assert none is None
    assert why == "pendubot_model_2.1.urdf has no <collision> geometry: the minimum link distance was not constrained"


def test_min_distance_holds_at_1khz_on_the_optimised_trajectory(tmp_path):
    from dualid.excite.collision import link_distance

    urdf = _boxes_urdf(tmp_path)
    rigid = RigidBodyModel.from_urdf(urdf)
    cfg = ExciteConfig.from_dict({"period": 3.0, "harmonics": 3, "grid": 30, "restarts": 1, "maxiter": 15,
                                  "acceleration": 20, "min_distance": 0.0495, "joint_terms": None})
    distance, _ = link_distance(urdf, rigid)
    result = optimize(build_design(rigid, cfg), cfg, distance=distance)
    q = result.trajectory.evaluate(result.trajectory.times(1000.0))[0]
    assert distance(q).min() >= 0.0495 - 1e-9  # without the constraint this optimum comes to 0.0488 m
    assert result.check.ok


def test_excite_help_shows_flags_without_a_bool_metavar():
    text = " ".join(runner.invoke(app, ["excite", "--help"]).output.split())
    assert "--force" in text and "--force <bool>" not in text


def test_the_dfki_example_config_is_valid():
    cfg = ExciteConfig.from_yaml(DFKI.parent / "excite.yaml")
    design = build_design(RigidBodyModel.from_urdf(URDF), cfg)
    np.testing.assert_allclose(design.limits.effort, [5, 5])
    assert design.limits.notes == ()


def test_limits_the_urdf_does_not_give_are_noted():
    design = build_design(RigidBodyModel.from_urdf(URDF), ExciteConfig())
    assert design.limits.notes == (
        "joint 'Joint2': the URDF's effort limit is 0, read as 'not given'",
        "joint 'Joint1': no acceleration limit (none in the URDF or the config)",
        "joint 'Joint2': no acceleration, effort limit (none in the URDF or the config)",
    )
    np.testing.assert_allclose(design.limits.effort, [6.0, np.inf])
    np.testing.assert_allclose(design.limits.velocity, [20.0, 20.0])
