"""What a designed trajectory will let an identification determine, before it is run.

From the trajectory sampled at ``rate`` with the URDF's torque (no noise): the rank, null space and
condition number of the full stacked regressor (``IdentificationProblem.identifiability``, the rule
``dualid fit`` reports), the condition number of the base regressor (column-scaled, and raw), the three
criteria, and the standard errors of the base parameters an ordinary least-squares fit would have with
torque noise of σ_j on joint j: sqrt(diag((Σ_i W_iᵀ S⁻¹ W_i)⁻¹)), S = diag(σ²), over one period.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dualid.data.trajectory import Trajectory
from dualid.errors import ConfigError
from dualid.excite.config import CRITERIA
from dualid.excite.design import Design
from dualid.excite.fourier import FourierTrajectory
from dualid.problem import Identifiability, build_problem


@dataclass(frozen=True, eq=False)
class Prediction:
    rate: float  # [Hz] of the samples the prediction is for
    samples: int
    identifiability: Identifiability  # of the full parameter vector
    base_names: tuple[str, ...]
    cond: float  # base regressor, columns scaled to unit norm
    cond_raw: float  # base regressor as is (unit-dependent)
    criteria: dict[str, float]  # dm, logdet, cond (the minimised values)
    torque_noise: np.ndarray  # (n,) σ [N m]
    beta_nominal: np.ndarray  # (p_b,) base parameters of the URDF's θ
    standard_errors: np.ndarray  # (p_b,) predicted, OLS, one period


def torque_noise(design: Design, noise) -> np.ndarray:
    """σ (n,) from a number or a {joint: σ} mapping (every joint named)."""
    if isinstance(noise, dict):
        missing = [j for j in design.joints if j not in noise]
        unknown = [j for j in noise if j not in design.joints]
        if missing or unknown:
            raise ConfigError(f"excite config: torque_noise: expected a σ for each joint {list(design.joints)}; "
                              f"missing {missing}, unknown {unknown}")
        sigma = np.array([noise[j] for j in design.joints], dtype=float)
    else:
        sigma = np.full(design.n, float(noise))
    if not np.all(np.isfinite(sigma) & (sigma > 0)):
        raise ConfigError(f"excite config: torque_noise: expected positive numbers [N m], got {noise!r}")
    return sigma


def base_condition(W: np.ndarray) -> tuple[float, float]:
    """(column-scaled, raw) condition number of the stacked base regressor W (N, n, p_b)."""
    A = W.reshape(-1, W.shape[-1])
    out = []
    for M in (A / np.maximum(np.linalg.norm(A, axis=0), 1e-300), A):
        s = np.linalg.svd(M, compute_uv=False)
        out.append(float(s[0] / s[-1]) if s[-1] > 0 else float("inf"))
    return out[0], out[1]


def predict(design: Design, traj: FourierTrajectory, rate: float, noise=0.1) -> Prediction:
    """The prediction for ``traj`` sampled at ``rate`` (see the module docstring)."""
    t = traj.times(rate)
    q, v, a = traj.evaluate(t)
    sigma = torque_noise(design, noise)
    tau = design.torque(q, v, a)
    problem = build_problem(design.model, Trajectory(t, q, v, tau, a, design.joints, name="designed"))
    W = design.base.regressor(problem.Y)
    cond, cond_raw = base_condition(W)
    Z = W / sigma[None, :, None]
    F = np.einsum("nap,naq->pq", Z, Z)
    try:
        se = np.sqrt(np.diag(np.linalg.inv(F)))
    except np.linalg.LinAlgError:
        se = np.full(W.shape[-1], np.inf)
    criteria = {c: design.criterion(c, q, v, a) for c in CRITERIA}
    return Prediction(rate, t.size, problem.identifiability(), design.base.names, cond, cond_raw, criteria, sigma,
                      design.base.values(design.theta_nom), se)
