"""The generic drag model (dualid.model.drag): metric, derived regressor, references, consistency, CLI."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yaml
from typer.testing import CliRunner

from dualid import OLS, DualMetric
from dualid.cli import app
from dualid.errors import ConfigError, ModelError
from dualid.estimators.methods import make_estimator
from dualid.model.drag import DragModel
from dualid.model.drag_spec import DragSpec
from dualid.model.landsalp import LINK_LENGTH, WHEEL_ANGLES_DEG, LandSalpModel
from dualid.model.landsalp import configuration as landsalp_configuration
from dualid.problem import IdentificationProblem, build_problem
from dualid.robot.config import FitConfig
from dualid.systems import swimmer as sw

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "drag"
L = LINK_LENGTH
LANDSALP_URDF = f"""<robot name="landsalp">
  <link name="link2"/><link name="link1"/><link name="link3"/>
  <joint name="joint1" type="continuous"><parent link="link2"/><child link="link1"/>
    <origin xyz="{-L / 2} 0 0"/><axis xyz="0 0 1"/></joint>
  <joint name="joint2" type="revolute"><parent link="link2"/><child link="link3"/>
    <origin xyz="{L / 2} 0 0"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
</robot>"""
ARM_URDF = """<robot name="arm">
  <link name="base"/><link name="a"/><link name="b"/><link name="c"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="a"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="j2" type="revolute"><parent link="a"/><child link="b"/><origin xyz="0 0 0.3" rpy="0.3 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="j3" type="prismatic"><parent link="b"/><child link="c"/><origin xyz="0.4 0 0"/>
    <axis xyz="1 0 0"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
</robot>"""


def _landsalp_like(tmp_path) -> DragModel:
    path = tmp_path / "landsalp.urdf"
    path.write_text(LANDSALP_URDF)
    phi = np.deg2rad(WHEEL_ANGLES_DEG)
    spec = DragSpec.from_dict({"base": "planar", "damping": ["joint1", "joint2"], "bodies": {
        "link1": {"frame": "link1", "xyz": [-L / 2, 0, 0], "rpy": [0, 0, float(phi[0])], "diagonal": 3},
        "link2": {"frame": "link2", "rpy": [0, 0, float(phi[1])], "diagonal": 3},
        "link3": {"frame": "link3", "xyz": [L / 2, 0, 0], "rpy": [0, 0, float(phi[2])], "diagonal": 3}}})
    return DragModel.from_urdf(path, spec)


def _swimmer(tmp_path) -> DragModel:
    path = tmp_path / "swimmer.urdf"
    path.write_text(sw.swimmer_urdf())
    return DragModel.from_urdf(path, DragSpec.from_dict(sw.TRUE_DRAG))


def _arm(tmp_path, full=6) -> DragModel:
    path = tmp_path / "arm.urdf"
    path.write_text(ARM_URDF)
    spec = DragSpec.from_dict({"bodies": {"tool": {"frame": "c", "xyz": [0.1, 0, 0], "full": full},
                                          "upper": {"frame": "b", "diagonal": 6}}, "damping": ["j1", "j3"]})
    return DragModel.from_urdf(path, spec)


# --- the metric and its derived regressor --------------------------------------------------------
def test_landsalp_configured_the_same_way_gives_landsalps_metric_and_regressor(tmp_path):
    """A strong independent reference: LandSalp's hand-built Pinocchio model. Our chart has world-frame
    base rates (B maps them to LandSalp's body velocity), so D = Bᵀ D_LandSalp B and Y = Bᵀ Y_LandSalp(B v)."""
    model, ls = _landsalp_like(tmp_path), LandSalpModel()
    assert model.coordinates == ("x", "y", "theta", "joint1", "joint2")
    renamed = {"longitudinal": "vx", "lateral": "vy", "rotational": "wz", "damping": "damping"}
    assert model.parameters.names == tuple(n.split(".")[0] + "." + renamed[n.split(".")[1]] for n in ls.parameters.names)
    rng = np.random.default_rng(0)
    q, v, theta = rng.uniform(-2, 2, (25, 5)), rng.normal(size=(25, 5)), rng.uniform(0.1, 3, 11)
    c, s = np.cos(q[:, 2]), np.sin(q[:, 2])
    B = np.broadcast_to(np.eye(5), (25, 5, 5)).copy()  # body velocity (vx, vy) = R(theta)ᵀ (ẋ, ẏ)
    B[:, 0, 0], B[:, 0, 1], B[:, 1, 0], B[:, 1, 1] = c, s, -s, c
    np.testing.assert_allclose(model.chart_jacobian(q), B, rtol=0, atol=1e-15)
    q_ls = landsalp_configuration(*q.T)
    D = model.metric(q).evaluate(theta)
    np.testing.assert_allclose(D, np.swapaxes(B, 1, 2) @ ls.metric(q_ls).evaluate(theta) @ B, rtol=0, atol=1e-12)
    Y_ls = ls.regressor(q_ls, np.einsum("tij,tj->ti", B, v))
    np.testing.assert_allclose(model.regressor(q, v), np.swapaxes(B, 1, 2) @ Y_ls, rtol=0, atol=1e-12)


def _brute_force_metric(model: DragModel, q: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """D(q, θ) from Pinocchio's computeFrameJacobian sample by sample and the drag matrices, by finite
    differences of the chart (B from pin.integrate): no shared code with the factored metric."""
    pm, data = model.pinocchio_model, model.pinocchio_model.createData()
    C = model.drag_matrices(theta)
    out = []
    for qi in q:
        qp = model.configuration(qi[None])[0]
        B = np.empty((pm.nv, model.n))
        for k in range(model.n):
            e = np.zeros(model.n)
            e[k] = 1e-7
            B[:, k] = pin.difference(pm, model.configuration((qi - e)[None])[0],
                                     model.configuration((qi + e)[None])[0]) / 2e-7
        D = np.zeros((model.n, model.n))
        for b in model.spec.bodies:
            J = pin.computeFrameJacobian(pm, data, qp, pm.getFrameId(f"drag:{b.name}"), pin.LOCAL)
            rows = [0, 1, 5] if b.size == 3 else list(range(6))
            Jb = J[rows] @ B
            D += Jb.T @ C[b.name] @ Jb
        for (joint, _), th in zip(model.spec.damping, theta[-len(model.spec.damping):]):
            k = model.coordinates.index(joint)
            D[k, k] += th
        out.append(D)
    return np.array(out)


@pytest.mark.parametrize("which", ["swimmer", "arm"])
def test_metric_matches_a_brute_force_pinocchio_evaluation_and_Y_theta_is_D_v(tmp_path, which):
    model = _swimmer(tmp_path) if which == "swimmer" else _arm(tmp_path)
    rng = np.random.default_rng(1)
    q, v = rng.uniform(-1, 1, (12, model.n)), rng.normal(size=(12, model.n))
    theta = rng.uniform(0.1, 2, model.parameters.p)
    D = model.metric(q).evaluate(theta)
    np.testing.assert_allclose(D, _brute_force_metric(model, q, theta), rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(model.regressor(q, v) @ theta, np.einsum("tij,tj->ti", D, v), rtol=0, atol=1e-12)
    assert np.all(model.bias_regressor(q, v) == 0)


def test_the_chain_builder_and_the_swimmer_urdf_give_the_same_model(tmp_path):
    urdf = _swimmer(tmp_path)
    bodies = {k: {key: x for key, x in b.items() if key != "xyz"} for k, b in sw.TRUE_DRAG["bodies"].items()}
    spec = {**sw.TRUE_DRAG, "bodies": bodies, "chain": [sw.LINK_LENGTH] * sw.N_LINKS}  # chain frames: link centres
    chain = DragModel.from_chain(DragSpec.from_dict(spec))
    assert chain.coordinates == urdf.coordinates and chain.parameters.names == urdf.parameters.names
    q = np.random.default_rng(2).uniform(-1, 1, (10, urdf.n))
    np.testing.assert_allclose(chain.metric(q).evaluate(urdf.nominal), urdf.metric(q).evaluate(urdf.nominal),
                               rtol=0, atol=1e-12)


def test_full_block_parametrisation_matches_the_consistency_block(tmp_path):
    """The full body's θ is the upper triangle (row-major) of C_b, the same matrix the LMI constrains."""
    model = _arm(tmp_path)
    theta = np.random.default_rng(3).normal(size=model.parameters.p)
    block = model.parameters.blocks[0]
    assert block.kind == "drag_matrix" and len(block.indices) == 21
    np.testing.assert_array_equal(block.constraint_matrix(theta), model.drag_matrices(theta)["tool"])
    assert model.parameters.names[:3] == ("tool.vx", "tool.vx_vy", "tool.vx_vz")
    assert model.parameters.units[model.parameters.index("tool.vx_wx")] == "N s"
    assert model.parameters.units[model.parameters.index("j3.damping")] == "N s/m"


# --- fits -------------------------------------------------------------------------------------
def _exact_problem(model: DragModel, theta, rng, N=200, noise=0.0):
    q, v = rng.uniform(-1.5, 1.5, (N, model.n)), rng.normal(size=(N, model.n))
    metric = model.metric(q)
    Y = metric.apply(v)
    tau = Y @ theta + noise * rng.normal(size=(N, model.n))
    return IdentificationProblem(Y, tau, metric, v, model.parameters, "drag")


def test_every_method_recovers_the_truth_from_exact_data(tmp_path):
    model = _swimmer(tmp_path)
    problem = _exact_problem(model, model.nominal, np.random.default_rng(4))
    for method in ("ols", "wls", "energy", "dm", "dm-paper"):
        theta = make_estimator(method, theta0=model.nominal).fit(problem).theta
        np.testing.assert_allclose(theta, model.nominal, rtol=1e-4, atol=1e-6, err_msg=method)


@pytest.mark.parametrize("method,solver", [("ols", None), ("dm-paper", "newton"), ("dm-paper", "cvxpy"), ("dm", None)])
def test_a_full_6x6_drag_comes_out_positive_semidefinite(tmp_path, method, solver):
    """True C of rank 2, noisy torques, few samples: the unconstrained fit is indefinite, every estimator's
    C is PSD (the drag_matrix LMI in FeasibleSet for Newton, cvxpy's PSD cone for the SDP). Three joints do
    not determine two 6×6 drags (rank 20 of 29): the estimators accept one of the minimisers."""
    model = _arm(tmp_path)
    rng = np.random.default_rng(5)
    U = rng.normal(size=(6, 2))
    theta = np.zeros(model.parameters.p)
    theta[:21] = (U @ U.T)[np.triu_indices(6)]
    theta[21:] = rng.uniform(0.5, 1.0, model.parameters.p - 21)
    problem = _exact_problem(model, theta, rng, N=40, noise=0.3)
    free = make_estimator("ols_unconstrained", allow_unidentifiable=True).fit(problem).theta
    assert np.linalg.eigvalsh(model.drag_matrices(free)["tool"])[0] < -1e-3  # the constraint matters here
    options = {} if solver is None else {"solver": solver}
    result = make_estimator(method, allow_unidentifiable=True, options=options).fit(problem)
    C = model.drag_matrices(result.theta)["tool"]
    assert np.linalg.eigvalsh(C)[0] >= -1e-8 * np.abs(C).max(), method
    assert result.is_consistent


def test_dual_metric_fit_is_invariant_to_scaling_the_joint_coordinates(tmp_path):
    """Joint angles in other units (q̃ = q / s): Ỹ = BᵀY, D̃ = BᵀDB, τ̃ = Bᵀτ with B = diag(1, 1, 1, s): the
    dual-metric θ̂ is the same; OLS's moves."""
    model = _swimmer(tmp_path)
    problem = _exact_problem(model, model.nominal, np.random.default_rng(6), N=150, noise=0.05)
    B = np.diag([1.0, 1.0, 1.0, 180 / np.pi, 0.01, 1000.0])
    other = problem.in_coordinates(B)
    for est in (DualMetric(solver="newton"), make_estimator("dm")):
        a, b = est.fit(problem).theta, est.fit(other).theta
        assert np.linalg.norm(a - b) / np.linalg.norm(a) < 1e-6, type(est).__name__
    a, b = OLS().fit(problem).theta, OLS().fit(other).theta
    assert np.linalg.norm(a - b) / np.linalg.norm(a) > 1e-3


def test_build_problem_needs_no_accelerations(tmp_path):
    from dualid.data.trajectory import Trajectory

    model = _swimmer(tmp_path)
    rng = np.random.default_rng(7)
    q, v = rng.uniform(-1, 1, (30, model.n)), rng.normal(size=(30, model.n))
    tau = model.regressor(q, v) @ model.nominal
    run = Trajectory(np.arange(30) * 0.01, q, v, tau, None, model.coordinates, "run")
    problem = build_problem(model, [run])
    assert problem.kind == "drag" and problem.N == 30
    np.testing.assert_allclose(problem.residual(model.nominal), 0, atol=1e-12)


# --- errors -----------------------------------------------------------------------------------
SPEC = {"bodies": {"b": {"frame": "link1", "diagonal": 3}}, "chain": [0.3, 0.3]}


@pytest.mark.parametrize("change,message", [
    ({"bodies": {"b": {"frame": "link9", "diagonal": 3}}},
     "chain: model.drag.bodies.b.frame: no frame named 'link9'; frames: ['link1', 'joint1', 'link2'"),
    ({"bodies": {"b": {"frame": "link1", "diagonal": [1, 2, 3, 4]}}},
     "model.drag.bodies.b.diagonal: expected 3 (vx, vy, wz) or 6 (vx, vy, vz, wx, wy, wz) coefficients, got 4: "
     "[1, 2, 3, 4]"),
    ({"bodies": {"b": {"frame": "link1", "diagonal": 4}}},
     "model.drag.bodies.b.diagonal: expected 3 (vx, vy, wz) or 6 (vx, vy, vz, wx, wy, wz), got 4"),
    ({"bodies": {"b": {"frame": "link1", "diagonal": [1, -2, 3]}}},
     "model.drag.bodies.b.diagonal: expected finite coefficients ≥ 0, got [1, -2, 3]"),
    ({"bodies": {"b": {"frame": "link1", "diagonal": 3, "full": 3}}},
     "model.drag.bodies.b: give exactly one of 'diagonal' or 'full', got ['diagonal', 'full']"),
    ({"bodies": {"b": {"frame": "link1", "full": [[1, 2], [2, 1]]}}},
     "model.drag.bodies.b.full: expected a 3 (vx, vy, wz) or 6 (vx, vy, vz, wx, wy, wz) square matrix, got shape (2, 2)"),
    ({"bodies": {"b": {"frame": "link1", "full": [[1, 2, 0], [2, 1, 0], [0, 0, 1]]}}},
     "model.drag.bodies.b.full: a drag matrix must be positive semidefinite; smallest eigenvalue -1"),
    ({"bodies": {"b": {"frame": "link1", "diagonal": 3, "colour": "red"}}},
     "model.drag.bodies.b: unknown keys ['colour']; known keys: ['frame', 'diagonal', 'full', 'xyz', 'rpy']"),
    ({"damping": ["joint7"]}, "chain: model.drag.damping: no 1-DOF joint named 'joint7'; joints: ['joint1']"),
    ({"damping": {"joint1": -1}}, "model.drag.damping.joint1: expected a damping ≥ 0 [N m s/rad] or null, got -1"),
    ({"base": "floating"}, "model.drag.base: expected one of ['fixed', 'planar'], got 'floating'"),
    ({"chain": [0.3, -1]}, "model.drag.chain: expected a list of link lengths > 0 [m], got [0.3, -1]"),
    ({"bodies": {}}, "model.drag.bodies: expected a mapping {body: {frame, diagonal | full}} with at least one body"),
])
def test_spec_errors_name_the_key(change, message):
    with pytest.raises(ModelError) as info:
        DragModel.from_chain(DragSpec.from_dict({**SPEC, **change}))
    assert str(info.value).startswith(message), str(info.value)


@pytest.mark.parametrize("model,extra,message", [
    ({"kind": "drag"}, {}, "model.drag: a drag model (model.kind: drag) needs its drag spec"),
    ({"kind": "viscous"}, {}, "model.kind: expected one of ['inertia', 'drag'], got 'viscous'"),
    ({"kind": "drag", "drag": SPEC, "urdf": "a.urdf"}, {},
     "model: a drag model needs exactly one of model.urdf (a kinematic tree) or model.drag.chain (link lengths); got both"),
    ({"kind": "drag", "drag": SPEC, "floating_base": True}, {}, "model.floating_base: not used by a drag model"),
    ({"kind": "drag", "drag": SPEC}, {"joint_terms": {"viscous": True}},
     "joint_terms: not used by a drag model (model.kind: drag); damp joints with model.drag.damping"),
    ({"kind": "drag", "drag": {**SPEC, "bodies": {"b": {"diagonal": [1, 2]}}}}, {},
     "model.drag.bodies.b.diagonal: expected 3 (vx, vy, wz) or 6"),
    ({"urdf": "a.urdf", "drag": SPEC}, {}, "model.drag: only used with model.kind: drag"),
])
def test_config_errors(model, extra, message):
    with pytest.raises(ConfigError) as info:
        FitConfig.from_dict({"model": model, "train": ["a.csv"], **extra})
    assert str(info.value).startswith(message), str(info.value)


def test_config_round_trips_and_passes_the_schema():
    from dualid.robot.schema import check_shape

    raw = yaml.safe_load((EXAMPLE / "drag.yaml").read_text())
    check_shape(raw)
    config = FitConfig.from_dict(raw, EXAMPLE)
    assert config.model.kind == "drag" and config.model.drag.base == "planar"
    again = FitConfig.from_dict(config.as_dict())
    assert again.model == config.model
    check_shape(config.as_dict())


# --- the CLI on the example -----------------------------------------------------------------------
def test_cli_fits_the_example_swimmer(tmp_path):
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["fit", "--config", str(EXAMPLE / "drag.yaml"), "--method", "ols",
                                      "--test", str(EXAMPLE / "test_swim.csv"),
                                      "--method", "dm-paper", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "all 18 parameters are identifiable" in result.output
    for name in ("parameters.yaml", "parameters.json", "report.md", "report.html", "identifiability.txt",
                 "velocity_test_swim.png"):
        assert (out / name).is_file(), name
    record = yaml.safe_load((out / "parameters.yaml").read_text())
    assert record["complete"] and record["model"]["kind"] == "drag"
    dm = record["methods"]["dm-paper"]
    assert dm["physically_consistent"] and min(dm["drag_matrices"]["link1"]["eigenvalues"]) > 0
    ncc = dm["validation"]["mean"]["a_ncc"]
    assert min(ncc.values()) > 0.99, ncc  # the forward prediction v̂ = D̂⁻¹τ on held-out gaits
    assert "Velocity NCC" in (out / "report.md").read_text()
    html = (out / "report.html").read_text()
    assert "Velocity NCC" in html and "Base parameters" in html and "data:image/png;base64," in html
    assert record["run"]["dualid_version"] and any(i["role"] == "config" for i in record["run"]["inputs"])


def test_cli_bad_drag_spec_is_bad_input_with_the_key_named(tmp_path):
    raw = yaml.safe_load((EXAMPLE / "drag.yaml").read_text())
    raw["model"]["urdf"] = str(EXAMPLE / "swimmer.urdf")
    raw["train"] = [str(EXAMPLE / p) for p in raw["train"]]
    raw["test"] = []
    raw["model"]["drag"]["bodies"]["link2"]["frame"] = "fin"
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(raw))
    result = CliRunner().invoke(app, ["fit", "--config", str(path), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2
    text = " ".join((result.output + (result.stderr if result.stderr_bytes is not None else "")).split())
    assert "swimmer.urdf: model.drag.bodies.link2.frame: no frame named 'fin'; frames: [" in text, text


def test_a_base_length_logged_in_degrees_is_refused():
    from dualid.errors import DataError
    from dualid.robot.drag_fit import fit_drag

    raw = yaml.safe_load((EXAMPLE / "drag.yaml").read_text())
    raw["columns"]["units"]["position"]["x"] = "deg"
    with pytest.raises(DataError) as info:
        fit_drag(FitConfig.from_dict(raw, EXAMPLE))
    assert str(info.value) == "column map: coordinate 'x' is a length but its position unit is 'deg' (angular)"


def test_a_urdf_welded_to_an_undeclared_world_link_loads(tmp_path):
    path = tmp_path / "welded.urdf"
    path.write_text(ARM_URDF.replace('<link name="base"/>', '<link name="base"/>\n  <joint name="weld" type="fixed">'
                                     '<parent link="world"/><child link="base"/></joint>'))
    model = DragModel.from_urdf(path, DragSpec.from_dict({"bodies": {"tool": {"frame": "c", "diagonal": 6}}}))
    assert model.coordinates == ("j1", "j2", "j3") and model.linear_coordinates == ("j3",)


def test_the_chain_config_fits_the_example_logs_like_the_urdf():
    from dualid.robot.drag_fit import fit_drag

    raw = yaml.safe_load((EXAMPLE / "drag.yaml").read_text())
    raw.update(methods=["ols"], test=[])
    by_urdf = fit_drag(FitConfig.from_dict(raw, EXAMPLE)).fits["ols"].result.theta
    del raw["model"]["urdf"]
    raw["model"]["drag"]["chain"] = [sw.LINK_LENGTH] * sw.N_LINKS
    for body in raw["model"]["drag"]["bodies"].values():
        del body["xyz"]  # the chain's link frames are at the link centres
    by_chain = fit_drag(FitConfig.from_dict(raw, EXAMPLE)).fits["ols"].result.theta
    np.testing.assert_allclose(by_chain, by_urdf, rtol=1e-6, atol=1e-8)


def test_the_drag_workflow_parses_each_log_once(monkeypatch):
    import dualid.data.tables as tables
    from dualid.robot.drag_fit import fit_drag

    raw = yaml.safe_load((EXAMPLE / "drag.yaml").read_text())
    raw.update(methods=["ols"])
    config = FitConfig.from_dict(raw, EXAMPLE)
    parsed = []
    real = tables._read_table
    monkeypatch.setattr(tables, "_read_table", lambda path: parsed.append(Path(path).name) or real(path))
    fit_drag(config)
    logs = [Path(p).name for p in (*config.train, *config.test)]
    assert sorted(parsed) == sorted(logs)  # the first log: column map, default preprocessing, loading — parsed once


def test_the_drag_report_and_parameters_state_dms_noise_model(tmp_path):
    """dm's estimated noise model (estimators.noise_dm) is in the drag report's fit notes and in parameters.yaml, as
    in the robot's: the levels, their shares of the residual, and what dm returned."""
    import yaml

    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["fit", "--config", str(EXAMPLE / "drag.yaml"), "--method", "dm", "--out", str(out)])
    assert result.exit_code == 0, result.output
    record = yaml.safe_load((out / "parameters.yaml").read_text())["methods"]["dm"]["noise_model"]
    assert record["source"] == "estimated" and record["torque_share"] + record["acceleration_share"] == pytest.approx(1)
    report = (out / "report.md").read_text()
    assert "dm: noise model (estimated): torque noise sd [" in report
    assert f"shares of the residual: torque {record['torque_share']:.2f}" in report
