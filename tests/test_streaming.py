"""Chunked statistics and streamed fits: the same numbers as the materialised problem."""

from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest

from dualid.estimators.methods import make_estimator
from dualid.estimators.newton import dual_metric_derivatives
from dualid.estimators.newton.objective import energy_statistics, statistics
from dualid.estimators.newton.objective import weighted_sums
from dualid.estimators.newton.weighted import whitener
from dualid.model.rigid_body import RigidBodyModel
from dualid.problem import IdentificationProblem
from dualid.streaming import ArraySource, ChunkedProblem, ParquetSource


def _arm():
    m, parent = pin.Model(), 0
    for j in range(3):
        joint = (pin.JointModelRZ(), pin.JointModelRY(), pin.JointModelRY())[j]
        parent = m.addJoint(parent, joint, pin.SE3(np.eye(3), np.array([0, 0, 0.3 if j else 0.0])), f"j{j}")
        m.appendBodyToJoint(parent, pin.Inertia(2.0 - 0.4 * j, np.array([0.02, 0.01, 0.12]),
                                                np.diag([0.05, 0.04, 0.01])), pin.SE3.Identity())
    return RigidBodyModel(m)


@pytest.fixture(scope="module")
def data():
    model = _arm()
    rng = np.random.default_rng(3)
    N = 700
    q = rng.uniform(-2, 2, size=(N, model.nq))
    v, a = rng.normal(size=(N, model.nv)), rng.normal(size=(N, model.nv))
    tau = model.regressor(q, v, a) @ model.nominal
    tau = tau + 0.05 * np.abs(tau).mean(axis=0) * rng.normal(size=tau.shape)
    whole = IdentificationProblem(model.regressor(q, v, a), tau, model.metric(q), v, model.parameters,
                                  coordinates=model.coordinates)
    return model, (q, v, a, tau), whole


def _chunked(data, chunk=128, progress=None):
    model, (q, v, a, tau), _ = data
    return ChunkedProblem(model, ArraySource(q, v, a, tau, chunk=chunk), progress)


def _rel(x, y):
    return float(np.max(np.abs(np.asarray(x) - np.asarray(y))) / np.max(np.abs(y)))


def test_chunked_statistics_equal_the_materialised_ones(data):
    _, _, whole = data
    chunked = _chunked(data)
    Yf, tf, vf = whole.Y.reshape(-1, whole.p), whole.tau.reshape(-1), whole.v
    W = np.array([[2.0, 0.3, 0.0], [0.3, 1.0, 0.1], [0.0, 0.1, 0.5]])
    WY = np.einsum("ab,nbp->nap", W, whole.Y)
    reference = {  # materialised, no chunks: (H, g, c)
        "ols": (Yf.T @ Yf, Yf.T @ tf, tf @ tf),
        "wls": (np.einsum("nap,naq->pq", whole.Y, WY), np.einsum("nap,na->p", WY, whole.tau),
                np.einsum("na,ab,nb->", whole.tau, W, whole.tau)),
    }
    e = np.einsum("nap,na->np", whole.Y, vf)
    y = np.einsum("na,na->n", whole.tau, vf)
    reference["energy"] = (e.T @ e, e.T @ y, y @ y)
    for problem in (whole, chunked):
        for key, st in (("ols", statistics(problem, chunk=50)), ("wls", statistics(problem, W, chunk=50)),
                        ("energy", energy_statistics(problem, chunk=50))):
            H, g, c = reference[key]
            assert _rel(st.H, H) < 1e-12 and _rel(st.g, g) < 1e-12 and abs(st.c - c) / c < 1e-12, key
    # a constant weight C: Σ Y_iᵀ C⁻¹ Y_i against dense solves
    theta = data[0].nominal
    C = whole.metric.evaluate(theta)[0]
    CiY = np.linalg.solve(C, whole.Y)
    H = np.einsum("nap,naq->pq", whole.Y, CiY)
    g = np.einsum("nap,na->p", CiY, whole.tau)
    for problem in (whole, chunked):
        Hc, gc, cc = weighted_sums(problem, whitener(problem, C).T, chunk=64)
        assert _rel(Hc, H) < 1e-12 and _rel(gc, g) < 1e-12
    # the dual-metric derivatives, chunked over the source's blocks and the solver's chunks
    d0, d1 = dual_metric_derivatives(whole, theta, 2, 10_000), dual_metric_derivatives(chunked, theta, 2, 50)
    assert abs(d0.f - d1.f) / d0.f < 1e-12 and _rel(d1.grad, d0.grad) < 1e-12 and _rel(d1.hess, d0.hess) < 1e-12
    assert np.allclose(chunked.column_norms(), whole.column_norms(), rtol=1e-12)
    assert chunked.identifiability().rank == whole.identifiability().rank


@pytest.mark.parametrize("key", ["ols", "wls", "energy", "dm", "dm-paper"])
def test_streamed_fit_equals_the_in_memory_fit(data, key):
    _, _, whole = data
    passes = []
    chunked = _chunked(data, progress=lambda k, done, N: passes.append((k, done, N)))
    est = make_estimator(key, allow_unidentifiable=True)
    a, b = est.fit(whole), est.fit(chunked)
    assert b.status == a.status
    # the arm's first body is partly unidentifiable: compare objectives and predictions Y θ̂ (unique), the latter
    # to the conic solvers' accuracy on this ill-conditioned arm (Clarabel ends optimal_inaccurate and the interior-point
    # fallback takes over; the statistics agree to ~1e-15, the fits to ~1e-7)
    pa, pb = whole.residual(a.theta), whole.residual(b.theta)
    assert abs(b.objective - a.objective) <= 1e-6 * abs(a.objective)
    assert np.max(np.abs(pb - pa)) <= 1e-4 * np.max(np.abs(whole.tau))
    # progress: every pass reports up to N, one report per chunk
    assert passes and passes[-1][1:] == (whole.N, whole.N) and {k for k, _, _ in passes} == set(range(1, chunked.passes + 1))


def test_parquet_source_streams_the_same_samples(data, tmp_path):
    import pandas as pd

    model, (q, v, a, tau), whole = data
    cols = {f"q_{j}": q[:, j] for j in range(q.shape[1])}
    for name, x in (("v", v), ("a", a), ("tau", tau)):
        cols.update({f"{name}_{c}": x[:, k] for k, c in enumerate(model.coordinates)})
    path = tmp_path / "run.parquet"
    pd.DataFrame(cols).to_parquet(path, index=False)
    src = ParquetSource(path, model.coordinates, q.shape[1], chunk=100)
    streamed = ChunkedProblem(model, src)
    assert streamed.N == whole.N
    st, ref = statistics(streamed), statistics(whole)
    assert _rel(st.H, ref.H) < 1e-12 and _rel(st.g, ref.g) < 1e-12


def test_fit_stream_cli_prints_the_fit_and_its_passes(tmp_path):
    import pandas as pd
    from typer.testing import CliRunner

    from dualid.cli import app
    from tests.test_bad_inputs import URDF

    urdf = tmp_path / "arm.urdf"
    urdf.write_text(URDF)
    model = RigidBodyModel.from_urdf(urdf)
    rng = np.random.default_rng(1)
    N = 600
    q = rng.uniform(-2, 2, size=(N, model.nq))
    v, a = rng.normal(size=(N, model.nv)), rng.normal(size=(N, model.nv))
    tau = model.regressor(q, v, a) @ model.nominal
    cols = {f"q_{j}": q[:, j] for j in range(model.nq)}
    for name, x in (("v", v), ("a", a), ("tau", tau)):
        cols.update({f"{name}_{c}": x[:, k] for k, c in enumerate(model.coordinates)})
    pd.DataFrame(cols).to_parquet(tmp_path / "run.parquet", index=False)
    result = CliRunner().invoke(app, ["fit-stream", "--model", str(urdf), "--data", str(tmp_path / "run.parquet"),
                                      "--method", "ols", "--chunk", "128"])
    assert result.exit_code == 0, result.output
    # the masses alone are not identifiable here: as dualid fit, one minimiser, and a note naming them
    assert "note: the data determine 6 of 20 parameter combinations" in result.output
    assert "Joint2.m" in result.output.split("note:")[1].split("ols:")[0]
    assert "ols: optimal" in result.output and "N = 600" in result.output and "passes over the data" in result.output
    # exact data (the masses alone are not identifiable here, so no parameter is checked): the fit is exact
    objective = float(result.output.split("objective ")[1].split(",")[0])
    assert objective < 1e-10 * float(np.sum(tau**2))
    assert "Joint2.m" in result.output
    strict = CliRunner().invoke(app, ["fit-stream", "--model", str(urdf), "--data", str(tmp_path / "run.parquet"),
                                      "--method", "ols", "--strict"])
    assert strict.exit_code == 1 and "--strict: the data determine 6 of 20" in strict.output
    assert "ols: optimal" not in strict.output and "Traceback" not in strict.output


@pytest.mark.parametrize("key", ["logdet", "pullback"])
def test_streamed_regularized_fit_equals_the_in_memory_fit(data, key):
    model, _, whole = data
    theta0 = model.nominal.copy()
    theta0[0::10] += 0.05  # each body a little heavier: a strictly consistent prior
    est = make_estimator(key, theta0=theta0, allow_unidentifiable=True)
    a, b = est.fit(whole), est.fit(_chunked(data))
    assert a.status == b.status == "optimal"
    assert abs(b.objective - a.objective) <= 1e-8 * abs(a.objective)


def _passive_and_rejected(data, monkeypatch, check_samples):
    """(the data with joint 2 passive, in memory and streamed, and its τ), with dm's CHECK_SAMPLES set and its held-out
    check forced to reject: the pilot is the paper's optimum, and dm falls back to it."""
    import dualid.estimators.noise_dm as noise_dm
    from dualid.estimators.noise_model import NoiseCheck

    model, (q, v, a, tau), whole = data
    tau = tau.copy()
    tau[:, 2] = 0.0  # a passive joint
    monkeypatch.setattr(noise_dm, "CHECK_SAMPLES", check_samples)
    monkeypatch.setattr(noise_dm.NoiseModelDM, "_check",
                        lambda self, sensor, theta, noise: NoiseCheck(1.0, 0.01, 1.0, 0.0, True))
    return replace(whole, tau=tau), ChunkedProblem(model, ArraySource(q, v, a, tau, chunk=128)), tau


@pytest.mark.parametrize("check_samples", [200, 100])  # 700 samples in memory: all of them; a subsample of 100
def test_streamed_dm_falls_back_to_the_whole_datas_paper_optimum(data, monkeypatch, check_samples):
    """A passive coordinate makes dm's pilot the paper's optimum; on streamed data (and in memory above 4 ×
    CHECK_SAMPLES) the pilot, levels and check come from a strided subsample. When dm falls back (its check forced to
    reject here), it returns the paper's optimum of all the samples, not the subsample's."""
    passive, chunked, tau = _passive_and_rejected(data, monkeypatch, check_samples)
    est = make_estimator("dm", allow_unidentifiable=True)
    streamed, in_memory = est.fit(chunked), est.fit(passive)
    paper = make_estimator("dm-paper", allow_unidentifiable=True).fit(passive)
    for fit in (streamed, in_memory):
        assert fit.noise.choice.startswith("dm-paper: the residual is not the modelled noise")
        assert np.max(np.abs(passive.residual(fit.theta) - passive.residual(paper.theta))) <= 1e-6 * np.abs(tau).max()


def test_large_in_memory_dm_takes_its_levels_and_first_round_from_the_streamed_subsample(data, monkeypatch):
    """Above 4 × CHECK_SAMPLES samples in memory, dm's pilot, noise levels, check and first round come from the same
    strided subsample as on streamed data (the last round from every sample): the two fits are the same."""
    import dualid.estimators.noise_dm as noise_dm

    model, (q, v, a, tau), _ = data
    rng = np.random.default_rng(5)
    a_measured = a + 0.3 * rng.normal(size=a.shape)  # acceleration noise inside the regressor: dm keeps its model
    noisy = IdentificationProblem(model.regressor(q, v, a_measured), tau, model.metric(q), v, model.parameters,
                                  coordinates=model.coordinates)
    monkeypatch.setattr(noise_dm, "CHECK_SAMPLES", 100)  # every seventh of the 700 samples
    solves, solve = [], noise_dm.NoiseModelDM._solve

    def recorded(self, problem, cons, theta, noise, *args, **kwargs):  # the samples each noise-model solve sees
        if np.any(noise.sigma_a):
            solves.append(problem.N)
        return solve(self, problem, cons, theta, noise, *args, **kwargs)

    monkeypatch.setattr(noise_dm.NoiseModelDM, "_solve", recorded)
    est = make_estimator("dm", allow_unidentifiable=True)
    in_memory = est.fit(noisy)
    assert solves == [100, 700]  # the first round's θ only feeds the levels: from the subsample
    solves.clear()
    streamed = est.fit(ChunkedProblem(model, ArraySource(q, v, a_measured, tau, chunk=128)))
    assert solves == [100, 700]
    assert in_memory.noise.choice == streamed.noise.choice == "noise model"
    assert np.allclose(in_memory.noise.sigma_a, streamed.noise.sigma_a, rtol=1e-10, atol=0)
    assert abs(in_memory.objective - streamed.objective) <= 1e-9 * abs(streamed.objective)
    assert np.max(np.abs(noisy.residual(in_memory.theta) - noisy.residual(streamed.theta))) <= 1e-7 * np.abs(tau).max()


@pytest.mark.parametrize("retry", ["fails", "is rejected"])
def test_streamed_dm_fits_the_whole_datas_paper_optimum_once(data, monkeypatch, retry):
    """A passive coordinate on streamed data: when the noise-model rounds fail from the pilot, dm starts again from the
    paper's optimum of all samples; when that fails too, or its fit is rejected by the check, dm falls back to that
    optimum, fitted once (each is a streamed ``dm-paper`` fit)."""
    import dualid.estimators.noise_dm as noise_dm
    from dualid.errors import SolverError

    passive, chunked, tau = _passive_and_rejected(data, monkeypatch, 200)  # the pilot: the subsample's paper optimum
    fits, rounds, paper_optimum, own_rounds = [], [], noise_dm.NoiseModelDM._paper_optimum, noise_dm.NoiseModelDM._rounds

    def counted(self, problem):
        fits.append(problem.N)
        return paper_optimum(self, problem)

    def failing(self, *args, **kwargs):  # the first call (from the pilot) fails; the retry as ``retry`` says
        rounds.append(1)
        if len(rounds) == 1 or retry == "fails":
            raise SolverError("no convergence", status="max_iterations")
        return own_rounds(self, *args, **kwargs)

    monkeypatch.setattr(noise_dm.NoiseModelDM, "_paper_optimum", counted)
    monkeypatch.setattr(noise_dm.NoiseModelDM, "_rounds", failing)
    result = make_estimator("dm", allow_unidentifiable=True).fit(chunked)
    paper = make_estimator("dm-paper", allow_unidentifiable=True).fit(passive)
    assert fits == [175, 700]  # the subsample's pilot, then every sample's optimum: not fitted again for the fallback
    why = "its noise-model fit did not converge (max_iterations)" if retry == "fails" else \
        "the residual is not the modelled noise"
    assert result.noise.choice.startswith(f"dm-paper: {why}")
    assert np.max(np.abs(passive.residual(result.theta) - passive.residual(paper.theta))) <= 1e-6 * np.abs(tau).max()
