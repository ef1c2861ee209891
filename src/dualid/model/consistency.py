"""Physical consistency of parameters, in one place: the per-body quantities behind the
constraints (mass, centre of mass, inertia about it, via Pinocchio's ``pin.Inertia``) and the
report of every block's margin. The constraint matrices themselves are defined by
``ParameterBlock.constraint_basis`` (pseudo-inertia for rigid bodies, drag matrix for drag).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from dualid.model.parameters import ParameterSpace


def body_at_com(theta_b: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """(m [kg], c (3,) [m], I_c (3, 3) [kg m²] about the centre of mass) of 10 dynamic parameters
    [m, mc, I about the body frame] (Pinocchio's order); needs m > 0."""
    inertia = pin.Inertia.FromDynamicParameters(np.asarray(theta_b, dtype=float))
    return float(inertia.mass), np.array(inertia.lever), np.array(inertia.inertia)


def inertia_about_origin(theta_b: np.ndarray) -> np.ndarray:
    """I (3, 3) [kg m²] about the body frame's origin, straight from the parameters."""
    Ixx, Ixy, Iyy, Ixz, Iyz, Izz = np.asarray(theta_b, dtype=float)[4:10]
    return np.array([[Ixx, Ixy, Ixz], [Ixy, Iyy, Iyz], [Ixz, Iyz, Izz]])


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
            if th[0] > 0:
                m, c, I_com = body_at_com(th)
            else:  # no centre of mass: report the inertia about the body frame's origin
                m, c, I_com = float(th[0]), np.full(3, np.nan), inertia_about_origin(th)
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


