"""Identify the DFKI double pendulum with the library alone (public ``dualid`` names only).

    python examples/dfki/fit_dfki.py [OUT_DIR]

Loads four training and two held-out runs, differentiates the encoder positions, fits the
dual-metric and WLS estimators with joint friction and armature, validates both on the held-out
runs, writes the dual-metric URDF and prints the base parameters with their 95 % intervals. The same fit from the command line:
``dualid fit --config examples/dfki/fit.yaml --out DIR``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import dualid

DATA = Path(__file__).resolve().parent / "data"
COLUMNS = {
    "time": "time",
    "joints": {
        "Joint1": {"position": "pos_meas1", "velocity": "vel_meas1", "effort": "tau_meas1"},
        "Joint2": {"position": "pos_meas2", "velocity": "vel_meas2", "effort": "tau_meas2"},
    },
}
STEPS: list[dict] = [
    {"resample": {"rate": 500}},
    {"differentiate": {"method": "savgol", "window": 0.1, "velocity": True}},
    {"filter_lowpass": {"cutoff": 10, "fields": ["tau"]}},
    {"downsample": {"factor": 5}},
]


def load(names: list[str], joints: tuple[str, ...]) -> list[dualid.Trajectory]:
    return [dualid.preprocess(dualid.load_log(DATA / f"{n}.csv", COLUMNS, joints), STEPS) for n in names]


def main(out: Path) -> dict[str, dualid.Validation]:
    urdf = DATA / "pendubot_model_2.1.urdf"
    rigid = dualid.RigidBodyModel.from_urdf(urdf)
    model = dualid.with_joint_terms(rigid, viscous=True, coulomb=True, armature=True)
    train = load([f"trajectory_0{k}" for k in range(4)], tuple(rigid.coordinates))
    test = load(["trajectory_04", "trajectory_05"], tuple(rigid.coordinates))
    problem = dualid.build_problem(model, train)
    estimators = {key: dualid.make_estimator(key, allow_unidentifiable=True) for key in ("wls", "dm")}
    results = {key: est.fit(problem) for key, est in estimators.items()}
    validations = {key: dualid.validate(model, r.theta, test, label=key) for key, r in results.items()}
    theta = results["dm"].theta
    out.mkdir(parents=True, exist_ok=True)
    dualid.write_urdf(urdf, rigid, theta[: rigid.parameters.p], out / "dm.urdf", overwrite=True,
                      friction=model.friction(theta), armature=model.armature_values(theta))
    for key, v in validations.items():
        rmse = np.round(v.mean("tau_rmse"), 4)
        print(f"{key}: held-out effort RMSE per joint {rmse} N m ({results[key].solver}, {results[key].status})")
    # what the data determine: the base parameters, with 95 % intervals (sandwich over 100 segments)
    base = problem.identifiability().base
    uncertainty = dualid.base_uncertainty(problem, results["dm"], estimators["dm"], base, blocks=100)
    for rec in uncertainty.records():
        print(f"  {rec['expression']} = {rec['value']:.4g} [{rec['lower']:.4g}, {rec['upper']:.4g}] {rec['unit']}")
    return validations


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("results/dfki-library"))
