"""Corpus problems beyond the random chains: N = 1e6, tiled real DFKI data, the paper's systems.

- ``chain RP, 2 dof, N = 1e6``: 10⁴ random states of a 2-joint chain, each repeated 100 times with independent
  torque noise (5 %): N = 10⁶ samples (Y ≈ 320 MB). Only the methods that scale (ols, wls, dm, dm-paper by
  Newton): no SDP, no prior fits (``Case.methods``).
- DFKI pendubot (examples/dfki/data, real logs): runs 00–03 with the library's default preprocessing
  (``robot.defaults.FIXED_PREPROCESSING_0_1``, copied here: bench does not import robot; a test checks the copy)
  and with the example's (examples/dfki/fit.yaml), the model with the default joint terms (viscous, Coulomb,
  armature), tiled ×10 (N ≈ 4·10⁴). Prior: the URDF's inertials, joint terms from OLS floored > 0.
- The paper's systems, simulated (``systems``): the Crazyflie–pendulum and the LandSalp (drag model), with
  their own CAD-like priors (``SystemData.theta_nominal``).

Each builder returns (problem, θ_true or None, prior); nothing is written. The cases are listed in
``corpus.cases``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

DFKI = Path(__file__).resolve().parents[3] / "examples" / "dfki" / "data"
# = dualid.robot.defaults.FIXED_PREPROCESSING_0_1 (tests/test_stress_corpus.py checks that they agree)
DEFAULT_PREPROCESSING = (
    {"resample": {"rate": 500.0}},
    {"differentiate": {"method": "savgol", "window": 0.05}},
    {"filter_lowpass": {"cutoff": 20.0, "fields": ["tau"]}},
    {"downsample": {"factor": 5}},
)
EXAMPLE_PREPROCESSING = (  # examples/dfki/fit.yaml
    {"resample": {"rate": 500}},
    {"differentiate": {"method": "savgol", "window": 0.1, "velocity": True}},
    {"filter_lowpass": {"cutoff": 10, "fields": ["tau"]}},
    {"downsample": {"factor": 5}},
)
DFKI_COLUMNS = {
    "time": "time",
    "joints": {
        "Joint1": {"position": "pos_meas1", "velocity": "vel_meas1", "effort": "tau_meas1"},
        "Joint2": {"position": "pos_meas2", "velocity": "vel_meas2", "effort": "tau_meas2"},
    },
}
SCALABLE = ("ols", "wls", "dm", "dm-paper")  # the methods run at N = 1e6 (dm and dm-paper by Newton only)


def chain_tiled(make_model, seed: int, n_states: int, reps: int, noise: float):
    """The model make_model() (a pin.Model) at n_states random states, each repeated reps times with independent
    noise."""
    def build():
        import pinocchio as pin

        from dualid.model.rigid_body import RigidBodyModel
        from dualid.problem import IdentificationProblem, owned

        rb = RigidBodyModel(make_model())
        pin.seed(seed)
        rng = np.random.default_rng(seed)
        n = rb.model.nv
        q = np.stack([pin.randomConfiguration(rb.model, -np.ones(rb.model.nq), np.ones(rb.model.nq))
                      for _ in range(n_states)])
        v, a = rng.normal(size=(2, n_states, n))
        Y0 = rb.regressor(q, v, a)
        tau0 = Y0 @ rb.nominal
        base = IdentificationProblem(owned(Y0), tau0, rb.metric(q), v, rb.parameters, coordinates=rb.coordinates)
        tiled = base.subset(np.tile(np.arange(n_states), reps))  # (N, n, p): one copy of Y
        scale = noise * np.sqrt(np.mean(tau0**2, axis=0))
        tau = tiled.tau + scale * rng.normal(size=tiled.tau.shape)  # independent noise on every repeat
        problem = dataclasses.replace(tiled, tau=tau)
        return problem, rb.nominal, None
    return build


def dfki(preprocessing, runs=(0, 1, 2, 3), tile: int = 10):
    def build():
        from dualid.data import load_log
        from dualid.data.preprocessing import preprocess
        from dualid.model import RigidBodyModel, with_joint_terms
        from dualid.problem import build_problem

        rigid = RigidBodyModel.from_urdf(DFKI / "pendubot_model_2.1.urdf")
        model = with_joint_terms(rigid, viscous=True, coulomb=True, armature=True)
        joints = tuple(rigid.coordinates)
        trajs = [preprocess(load_log(DFKI / f"trajectory_0{k}.csv", DFKI_COLUMNS, joints), [dict(s) for s in
                                                                                          preprocessing])
                 for k in runs]
        problem = build_problem(model, trajs)
        if tile > 1:
            problem = problem.subset(np.tile(np.arange(problem.N), tile))
        return problem, None, _urdf_prior(problem, rigid)
    return build


def _urdf_prior(problem, rigid):
    """The URDF's inertials, joint terms from the unconstrained OLS fit floored at 1e-3 × the largest of their
    block (as ``robot.fit.prior_theta`` does for prior source "urdf": a log-det prior needs them > 0)."""
    from dualid.estimators.least_squares import OLS

    p0 = rigid.parameters.p
    ols = OLS(constrained=False, allow_unidentifiable=True).fit(problem).theta
    prior = np.array(ols, dtype=float)
    prior[:p0] = rigid.nominal
    for b in problem.parameters.blocks:
        idx = np.array(b.indices)
        if idx[0] >= p0:
            top = max(float(np.max(np.abs(ols[idx]))), 1e-12)
            prior[idx] = np.maximum(ols[idx], 1e-3 * top)
    return prior


def system(name: str, size: str = "small"):
    def build():
        from dualid.problem import build_problem
        from dualid.systems.base import make_system

        sd = make_system(name, seed=0, noise="realistic", size=size)
        return build_problem(sd.model, list(sd.train)), sd.theta_true, sd.theta_nominal
    return build
