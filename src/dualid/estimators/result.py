"""The immutable outcome of a fit: θ̂, the objective, solver status and per-body physical quantities."""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, field

import numpy as np

from dualid.model.closure import NOT_DETERMINED
from dualid.model.consistency import BodyProperties, body_properties
from dualid.model.margin import margin_info
from dualid.model.parameters import ParameterSpace


@dataclass(frozen=True, eq=False)
class NoiseRecord:
    """What ``dm`` estimated and chose: its noise model C_i = Σ_τ + M_i Σ_a M_i (both in the sensor chart)."""

    sigma_tau: np.ndarray  # (n, n) torque-noise covariance [force²]
    sigma_a: np.ndarray  # (n, n) acceleration-noise covariance [(coordinate/s²)²]
    torque_share: float  # share of the residual covariance the torque noise explains (mean tr(C⁻¹Σ_τ)/n)
    acceleration_share: float  # … and the acceleration noise (mean tr(C⁻¹MΣ_aM)/n)
    source: str  # "estimated" | "fixed" (given by the user)
    rounds: int  # noise-level / θ alternations
    pilot_objective: float  # the pilot's objective
    choice: str = "noise model"  # what θ̂ is: "noise model", or "wls: …" / "dm-paper: …" when dm fell back (and why)
    check_excess: float = float("nan")  # held-out loss beyond the noise model's prediction, share of WLS's (noise_model)
    check_measured_gap: float = float("nan")  # held-out loss dm − WLS, share of WLS's
    check_predicted_gap: float = float("nan")  # … as the noise model predicts it

    def as_dict(self) -> dict:
        return {"sigma_tau": np.asarray(self.sigma_tau).tolist(), "sigma_a": np.asarray(self.sigma_a).tolist(),
                "torque_share": self.torque_share, "acceleration_share": self.acceleration_share,
                "source": self.source, "rounds": self.rounds, "pilot_objective": self.pilot_objective,
                "choice": self.choice, "check_excess": self.check_excess,
                "check_measured_gap": self.check_measured_gap, "check_predicted_gap": self.check_predicted_gap}


@dataclass(frozen=True, eq=False)
class IdentificationResult:
    """θ̂ and how it was obtained. ``objective`` is the estimator's own objective at θ̂."""

    method: str  # e.g. "ols", "dual_metric"
    theta: np.ndarray  # (p,) identified parameters
    parameters: ParameterSpace
    objective: float
    status: str  # solver status ("optimal", ...)
    solver: str  # e.g. "CLARABEL", "newton"
    solve_time: float  # [s] wall time of the solve (excluding problem assembly)
    iterations: int | None = None
    constrained: bool = True
    info: dict = field(default_factory=dict)  # solver-specific: duality gap, KKT residual, covariance, …
    noise: NoiseRecord | None = None  # dm's noise model (estimators.noise_dm); None for the other estimators

    def __post_init__(self) -> None:
        theta = np.array(self.theta, dtype=float)
        theta.setflags(write=False)
        object.__setattr__(self, "theta", theta)
        if self.parameters.margin_reference is not None and theta.shape == (self.parameters.p,):
            # every estimator's result records the margin it was fitted under (dualid.model.margin)
            object.__setattr__(self, "info", {**self.info, **margin_info(self.parameters, theta, self.constrained)})

    @property
    def bodies(self) -> tuple[BodyProperties, ...]:
        return body_properties(self.parameters, self.theta)

    def not_determined(self, names: Collection[str] | None = None) -> dict[str, str]:
        """{parameter label: NOT_DETERMINED} for every parameter the data do not determine: one the fit completed on
        the closed feasible set (model.closure; info["projected_names"]); only those among ``names`` when
        given (e.g. the rigid-body parameters a URDF carries)."""
        return {n: NOT_DETERMINED for n in self.info.get("projected_names", ()) if names is None or n in names}

    def parameter_records(self, std_errors=None) -> list[dict]:
        """One entry per parameter: name, unit, value (θ̂), its ``std_error`` when std_errors (p,) are given, and
        ``determined_by_data: false`` with the note on a parameter the fit completed (``not_determined``)."""
        nd, P = self.not_determined(), self.parameters
        out = []
        for k, (n, u, x) in enumerate(zip(P.names, P.units, self.theta)):
            entry = {"name": n, "unit": u, "value": float(x)}
            if std_errors is not None:
                entry["std_error"] = std_errors[k]
            if n in nd:
                entry.update(determined_by_data=False, note=nd[n])
            out.append(entry)
        return out

    def body_records(self) -> list[dict]:
        """Each body's physical quantities at θ̂, with ``not_determined_by_data``: [its parameter labels] on a body
        one of whose parameters the fit completed (absent on the others)."""
        P, completed = self.parameters, self.not_determined()
        out = []
        for b, props in zip(P.blocks, self.bodies):  # body_properties: one entry per block, in order
            labels = [P.names[i] for i in b.indices if P.names[i] in completed]
            out.append({**props.as_dict(), **({"not_determined_by_data": labels} if labels else {})})
        return out

    @property
    def is_consistent(self) -> bool:
        return self.parameters.is_consistent(self.theta, tol=1e-7)

    def named(self) -> dict[str, float]:
        return {n: float(x) for n, x in zip(self.parameters.names, self.theta)}

    def as_dict(self) -> dict:
        return {
            "method": self.method,
            "objective": self.objective,
            "status": self.status,
            "solver": self.solver,
            "solve_time_s": self.solve_time,
            "iterations": self.iterations,
            "constrained": self.constrained,
            "parameters": self.parameter_records(),
            "bodies": self.body_records(),
            "info": {k: v for k, v in self.info.items() if isinstance(v, (int, float, str, bool))},
            **({"noise_model": self.noise.as_dict()} if self.noise is not None else {}),
        }
