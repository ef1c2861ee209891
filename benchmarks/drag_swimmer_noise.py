"""Which sensor noise makes the equation-error fits collapse on the swimmer (docs/drag.md)? One data seed.

Three training runs of the swimmer (seed 0 of the excitation, 20 s at 50 Hz, the TRUE system with its
unmodelled effects) are simulated once; each variant applies only some of the sensor noises of
``swimmer.Measurement`` (same noise seed), low-passes v and τ at 4 Hz as examples/drag/drag.yaml does,
and prints ‖θ̂ − θ*‖/‖θ*‖ for ols, dm, energy and dm-paper.

    PYTHONPATH=src python -W ignore benchmarks/drag_swimmer_noise.py > benchmarks/drag_swimmer_noise.txt
"""
import dataclasses
import tempfile
from pathlib import Path

import numpy as np

from dualid.data.preprocessing import filter_lowpass
from dualid.data.trajectory import Trajectory
from dualid.estimators.methods import make_estimator
from dualid.model.drag import DragModel
from dualid.model.drag_spec import DragSpec
from dualid.problem import build_problem
from dualid.systems import swimmer as sw

with tempfile.TemporaryDirectory() as tmp:
    urdf = Path(tmp) / "swimmer.urdf"
    urdf.write_text(sw.swimmer_urdf())
    model = DragModel.from_urdf(urdf, DragSpec.from_dict(sw.TRUE_DRAG))
truth=model.nominal
true=sw.TrueSwimmer(model,truth,sw.TrueEffects())
rng=np.random.default_rng(0)
sims=[sw.simulate(true, sw.excitation(rng), 20.0, 50.0) for _ in range(3)]
M0=sw.Measurement()
variants={"none":dict(position_std=0,heading_std=0,encoder_counts=10**9,velocity_std=(0,0,0,0),torque_std=0,torque_gain_std=0),
 "all":{}, "v only":dict(position_std=0,heading_std=0,encoder_counts=10**9,torque_std=0,torque_gain_std=0),
 "v base only":dict(position_std=0,heading_std=0,encoder_counts=10**9,velocity_std=(0.004,0.004,0.03,0),torque_std=0,torque_gain_std=0),
 "v joints only":dict(position_std=0,heading_std=0,encoder_counts=10**9,velocity_std=(0,0,0,0.02),torque_std=0,torque_gain_std=0),
 "tau only":dict(position_std=0,heading_std=0,encoder_counts=10**9,velocity_std=(0,0,0,0)),
 "q only":dict(velocity_std=(0,0,0,0),torque_std=0,torque_gain_std=0)}
for name,kw in variants.items():
    m=dataclasses.replace(M0,**kw)
    r=np.random.default_rng(1)
    runs=[]
    for k,(t,q,v,tau) in enumerate(sims):
        d=sw.measure(t,q,v,tau,r,m)
        tr=Trajectory(d["t"],d["q"],d["v"],d["tau"],None,model.coordinates,f"r{k}")
        runs.append(filter_lowpass(tr,4.0,fields=("v","tau")))
    P=build_problem(model,runs)
    out=[]
    for meth in ("ols","dm","energy","dm-paper"):
        th=make_estimator(meth).fit(P).theta
        out.append(f"{meth} {np.linalg.norm(th-truth)/np.linalg.norm(truth):.3f}")
    print(f"{name:14s}", "  ".join(out), flush=True)
