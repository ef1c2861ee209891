"""The immutable outcome of a fit: θ̂, the objective, solver status and per-body physical quantities."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dualid.model.parameters import ParameterSpace


@dataclass(frozen=True)
class BodyProperties:
    """Physical quantities of one parameter block at θ̂."""

    name: str
    kind: str
    margin: float  # smallest eigenvalue of the block's constraint matrix (≥ 0: consistent)
    mass: float | None = None  # [kg] (rigid bodies)
    com: tuple[float, float, float] | None = None  # [m] centre of mass in the body frame
    inertia_com: tuple[tuple[float, ...], ...] | None = None  # [kg m²] about the centre of mass
    principal_moments: tuple[float, float, float] | None = None  # [kg m²]
    coefficients: tuple[float, ...] | None = None  # drag / friction coefficients

    def as_dict(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if v is not None}


def body_properties(parameters: ParameterSpace, theta: np.ndarray) -> tuple[BodyProperties, ...]:
    out = []
    for b in parameters.blocks:
        th = np.asarray(theta)[list(b.indices)]
        C = b.constraint_matrix(theta)
        margin = float(np.linalg.eigvalsh(C)[0]) if C is not None else float("nan")
        if b.kind == "rigid_body":
            m, h = th[0], th[1:4]
            Ixx, Ixy, Iyy, Ixz, Iyz, Izz = th[4:]
            I_origin = np.array([[Ixx, Ixy, Ixz], [Ixy, Iyy, Iyz], [Ixz, Iyz, Izz]])
            c = h / m if m > 0 else np.full(3, np.nan)
            I_com = I_origin - m * (np.dot(c, c) * np.eye(3) - np.outer(c, c)) if m > 0 else I_origin
            out.append(
                BodyProperties(
                    b.name,
                    b.kind,
                    margin,
                    mass=float(m),
                    com=tuple(float(x) for x in c),
                    inertia_com=tuple(tuple(float(x) for x in row) for row in I_com),
                    principal_moments=tuple(float(x) for x in np.linalg.eigvalsh(I_com)),
                )
            )
        else:
            out.append(BodyProperties(b.name, b.kind, margin, coefficients=tuple(float(x) for x in th)))
    return tuple(out)


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

    def __post_init__(self) -> None:
        theta = np.array(self.theta, dtype=float)
        theta.setflags(write=False)
        object.__setattr__(self, "theta", theta)

    @property
    def bodies(self) -> tuple[BodyProperties, ...]:
        return body_properties(self.parameters, self.theta)

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
            "parameters": [
                {"name": n, "unit": u, "value": float(x)}
                for n, u, x in zip(self.parameters.names, self.parameters.units, self.theta)
            ],
            "bodies": [b.as_dict() for b in self.bodies],
            "info": {k: v for k, v in self.info.items() if isinstance(v, (int, float, str, bool))},
        }
