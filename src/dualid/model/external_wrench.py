"""External wrenches (contact forces, thrust, a push) in the inverse dynamics of a rigid-body model.

A wrench f = [force; torque] on a Pinocchio frame does the work fᵀ J_f(q) v, with J_f the frame's
Jacobian in the frame ``reference`` the wrench is expressed in (local, local_world_aligned, world:
Pinocchio's ReferenceFrame). The inverse dynamics become

    τ = rnea(q, v, a) − Σ_f J_f(q)ᵀ f     ⇔     Y(q, v, a) θ = τ + Σ_f J_f(q)ᵀ f,

so the wrenches add a known, parameter-free generalized force to the measured τ (the regressor and
the metric are unchanged); ``apply_wrenches`` folds them into a trajectory's τ. Pinocchio's own
``rnea(model, data, q, v, a, fext)`` (fext per joint, in the joint frame) is the same equation; the
tests check the two against each other.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from dualid.data.trajectory import Trajectory
from dualid.errors import DataError, ModelError
from dualid.model.rigid_body import RigidBodyModel

REFERENCE_FRAMES = {"local": pin.LOCAL, "local_world_aligned": pin.LOCAL_WORLD_ALIGNED, "world": pin.WORLD}


def frame_id(rigid: RigidBodyModel, name: str) -> int:
    """The id of Pinocchio frame ``name``; ModelError listing the model's frames when it has none."""
    model = rigid.model
    if not model.existFrame(name):
        names = list(dict.fromkeys(f.name for f in model.frames if f.name != "universe"))
        raise ModelError(f"external wrench: the model has no frame {name!r}; its frames are {names}")
    return model.getFrameId(name)


def wrench_force(rigid: RigidBodyModel, q: np.ndarray, wrench: np.ndarray, specs) -> np.ndarray:
    """Σ_f J_f(q)ᵀ f (T, nv) [N, N m] for wrenches (T, 6k) on the frames of ``specs`` [{frame, reference}]."""
    q = rigid.configuration(q)
    wrench = np.asarray(wrench, dtype=float)
    if wrench.shape != (q.shape[0], 6 * len(specs)):
        raise DataError(f"external wrench: expected shape ({q.shape[0]}, {6 * len(specs)}) for {len(specs)} wrenches, "
                        f"got {wrench.shape}")
    frames = []
    for s in specs:
        if s["reference"] not in REFERENCE_FRAMES:
            raise ModelError(f"external wrench {s.get('name', s['frame'])!r}: reference must be one of "
                             f"{list(REFERENCE_FRAMES)}, got {s['reference']!r}")
        frames.append((frame_id(rigid, s["frame"]), REFERENCE_FRAMES[s["reference"]]))
    model, data = rigid.model, rigid.model.createData()
    out = np.zeros((q.shape[0], rigid.nv))
    for t in range(q.shape[0]):
        pin.computeJointJacobians(model, data, q[t])
        pin.updateFramePlacements(model, data)
        for k, (fid, ref) in enumerate(frames):
            out[t] += pin.getFrameJacobian(model, data, fid, ref).T @ wrench[t, 6 * k: 6 * k + 6]
    return out


def apply_wrenches(rigid: RigidBodyModel, traj: Trajectory) -> Trajectory:
    """The run with its external wrenches folded into τ (τ + Σ J_fᵀ f) and ``wrench`` cleared; the step
    is recorded. A run without wrenches is returned as it is."""
    if traj.wrench is None:
        return traj
    specs = traj.meta.get("wrenches")
    if not specs:
        raise DataError(f"run {traj.name!r}: it has external wrenches but no meta['wrenches'] saying on which frames")
    tau = traj.tau + wrench_force(rigid, traj.q, traj.wrench, specs)
    step = {"external_wrenches": [f"{s['name']} on {s['frame']} ({s['reference']})" for s in specs]}
    return traj.with_step(step, tau=tau, wrench=None)
