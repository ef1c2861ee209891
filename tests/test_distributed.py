"""Fits spread over a Dask cluster: the same θ as the in-memory fit, with no regressor built on the client, and
the same θ when a worker dies mid-fit."""

import os
import signal

import numpy as np
import pandas as pd
import pinocchio as pin
import pytest

from distributed import Client, LocalCluster, WorkerPlugin

from dualid.distributed import DaskProblem, frame_columns
from dualid.estimators.methods import make_estimator
from dualid.estimators.noise_dm import NoiseModelDM
from dualid.model.rigid_body import RigidBodyModel
from dualid.problem import IdentificationProblem

METHODS = ("ols", "wls", "dm-paper", "dm")


def _free_body():
    """One free-floating rigid body: its 10 parameters are all identifiable, so θ̂ is unique and comparable to 1e-10."""
    m = pin.Model()
    j = m.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base")
    m.appendBodyToJoint(j, pin.Inertia(3.0, np.array([0.05, -0.02, 0.1]), np.diag([0.08, 0.06, 0.04])),
                        pin.SE3.Identity())
    return RigidBodyModel(m)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """Four Parquet files of 250 samples each with torque noise and noise in the logged accelerations (so that
    ``dm`` keeps its acceleration-noise model and runs every one of its passes), and the in-memory problem."""
    model = _free_body()
    rng = np.random.default_rng(5)
    pin.seed(5)
    N = 1000
    q = np.stack([pin.randomConfiguration(model.model, -np.ones(model.nq), np.ones(model.nq)) for _ in range(N)])
    v, a = rng.normal(size=(N, model.nv)), rng.normal(size=(N, model.nv))
    tau = model.regressor(q, v, a) @ model.nominal
    tau = tau + 0.05 * np.abs(tau).mean(axis=0) * rng.normal(size=tau.shape)
    a = a + 0.3 * rng.normal(size=a.shape)
    table = pd.DataFrame(np.column_stack([q, v, a, tau]), columns=frame_columns(model))
    folder = tmp_path_factory.mktemp("fleet")
    paths = []
    for k in range(4):
        paths.append(folder / f"robot{k}.parquet")
        table.iloc[250 * k : 250 * (k + 1)].to_parquet(paths[-1], index=False)
    whole = IdentificationProblem(model.regressor(q, v, a), tau, model.metric(q), v, model.parameters,
                                  coordinates=model.coordinates)
    return model, paths, whole


@pytest.fixture(scope="module")
def client():
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as c:
        c.run(lambda: __import__("dualid.estimators.methods"))  # the workers' first import, once
        yield c


# dm at the simulation's noise levels: one free body's mass matrix is constant, so a full torque covariance absorbs
# M Σ_a M and the estimated levels find no acceleration noise; given, the noise model's passes all run on the workers
LEVELS = {"sigma_tau": np.diag([0.58, 0.60, 0.57, 0.006, 0.0074, 0.0017]), "sigma_a": 0.09 * np.eye(6)}


def _fit(method, problem):
    result = (NoiseModelDM(**LEVELS) if method == "dm" else make_estimator(method)).fit(problem)
    if method == "dm":  # the comparison covers the noise model's passes, not only its fallback
        assert result.noise.choice == "noise model" and result.noise.acceleration_share > 0
    return result.theta


def _rel(x, y):
    return float(np.max(np.abs(x - y)) / np.max(np.abs(y)))


@pytest.mark.parametrize("method", METHODS)
def test_two_workers_fit_the_in_memory_theta(data, client, method):
    model, paths, whole = data
    problem = DaskProblem.from_files(model, paths, client, chunk=100)
    theta = _fit(method, problem)
    assert _rel(theta, _fit(method, whole)) < 1e-10
    assert problem.passes >= 2 and problem.client_passes == 0  # every pass ran on the workers: Y never travelled
    assert len(client.scheduler_info()["workers"]) == 2


def test_a_missing_partition_is_seen(data, client):
    """The 1e-10 comparison discriminates: the fit without one of the four files is far from the whole one."""
    model, paths, whole = data
    theta = _fit("ols", DaskProblem.from_files(model, paths[:3], client))
    assert _rel(theta, _fit("ols", whole)) > 1e-4


def test_a_dask_dataframe_fits_the_in_memory_theta(data, client):
    import dask.dataframe as dd

    model, paths, whole = data
    frame = dd.read_parquet([str(p) for p in paths])
    problem = DaskProblem.from_dataframe(model, frame, client, chunk=128)
    assert problem.N == whole.N
    assert _rel(_fit("ols", problem), _fit("ols", whole)) < 1e-10
    assert problem.client_passes == 0


def test_progress_reports_every_sample_of_every_pass(data, client):
    model, paths, whole = data
    seen = {}
    problem = DaskProblem.from_files(model, paths, client, progress=lambda k, done, N: seen.__setitem__(k, (done, N)))
    _fit("ols", problem)
    assert seen and all(v == (whole.N, whole.N) for v in seen.values()) and len(seen) == problem.passes


def test_fit_stream_runs_its_passes_on_a_scheduler(client, tmp_path):
    from typer.testing import CliRunner

    from dualid.cli import app
    from tests.test_bad_inputs import URDF

    urdf = tmp_path / "arm.urdf"
    urdf.write_text(URDF)
    model = RigidBodyModel.from_urdf(urdf)
    rng = np.random.default_rng(1)
    q = rng.uniform(-2, 2, size=(600, model.nq))
    v, a = rng.normal(size=(600, model.nv)), rng.normal(size=(600, model.nv))
    tau = model.regressor(q, v, a) @ model.nominal
    table = pd.DataFrame(np.column_stack([q, v, a, tau]), columns=frame_columns(model))
    args = ["fit-stream", "--model", str(urdf), "--method", "ols"]
    for k in range(3):
        table.iloc[200 * k : 200 * (k + 1)].to_parquet(tmp_path / f"run{k}.parquet", index=False)
        args += ["--data", str(tmp_path / f"run{k}.parquet")]
    result = CliRunner().invoke(app, args + ["--scheduler", client.scheduler.address])
    assert result.exit_code == 0, result.output
    assert "Dask cluster: 2 workers" in result.output and "ols: optimal" in result.output and "N = 600" in result.output
    objective = float(result.output.split("objective ")[1].split(",")[0])
    assert objective < 1e-10 * float(np.sum(tau**2))  # exact data: the fit over the three files is exact
    result = CliRunner().invoke(app, args[:-2] + ["--scheduler", "tcp://127.0.0.1:9"])
    assert result.exit_code == 2 and "no Dask scheduler reached" in result.output


class _KillOnce(WorkerPlugin):
    """Kills its worker's process (SIGKILL, no goodbye) when the ``after``-th partition task starts, once for the
    cluster (a flag file records it)."""

    def __init__(self, folder, after):
        self.count, self.flag, self.after = folder / "started", folder / "killed", after

    def transition(self, key, start, finish, **kwargs):
        if finish != "executing" or "_on_partition" not in str(key):
            return
        with open(self.count, "a") as f:
            f.write(".")
        if os.path.getsize(self.count) >= self.after and not self.flag.exists():
            self.flag.touch()
            os.kill(os.getpid(), signal.SIGKILL)


@pytest.mark.parametrize("method", ["dm-paper", "dm"])
def test_a_worker_killed_mid_fit_changes_nothing(data, client, tmp_path, method):
    model, paths, whole = data
    client.register_plugin(_KillOnce(tmp_path, after=6), name=f"kill-once-{method}")  # 2nd task of the 2nd pass
    problem = DaskProblem.from_files(model, paths, client, chunk=100)
    theta = _fit(method, problem)
    assert (tmp_path / "killed").exists()  # a worker did die mid-fit
    assert _rel(theta, _fit(method, whole)) < 1e-10
