"""Pan–tilt point mass: a mass m at distance L on a massless link, pan ψ about z, tilt φ about the
horizontal axis, viscous damping in each joint. Closed form; the teaching example of the paper.

    x(q) = L [cos φ cos ψ, cos φ sin ψ, sin φ],   J = ∂x/∂q (3×2)
    τ = m Jᵀ(J a + J̇ v + g e_z) + diag(b) v,       M(q) = m JᵀJ

θ = [m, b_pan, b_tilt]  (kg, N m s/rad, N m s/rad), all ≥ 0.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from dualid.model.base import Kind
from dualid.model.metric import AffineMetric, MetricTerm
from dualid.model.parameters import ParameterBlock, ParameterSpace


def position(q: np.ndarray, length: float) -> np.ndarray:
    """x (T, 3) of the point mass [m]."""
    psi, phi = q[:, 0], q[:, 1]
    return length * np.stack([np.cos(phi) * np.cos(psi), np.cos(phi) * np.sin(psi), np.sin(phi)], axis=1)


def jacobian(q: np.ndarray, length: float) -> np.ndarray:
    """J (T, 3, 2) = ∂x/∂q [m/rad]."""
    psi, phi = q[:, 0], q[:, 1]
    J = np.empty((q.shape[0], 3, 2))
    J[:, 0, 0] = -np.cos(phi) * np.sin(psi)
    J[:, 1, 0] = np.cos(phi) * np.cos(psi)
    J[:, 2, 0] = 0.0
    J[:, 0, 1] = -np.sin(phi) * np.cos(psi)
    J[:, 1, 1] = -np.sin(phi) * np.sin(psi)
    J[:, 2, 1] = np.cos(phi)
    return length * J


def jacobian_dot_v(q: np.ndarray, v: np.ndarray, length: float) -> np.ndarray:
    """J̇ v (T, 3): the velocity-product part of the point's acceleration [m/s²]."""
    psi, phi = q[:, 0], q[:, 1]
    dpsi, dphi = v[:, 0], v[:, 1]
    cpsi, spsi, cphi, sphi = np.cos(psi), np.sin(psi), np.cos(phi), np.sin(phi)
    ax = -cphi * cpsi * dpsi**2 + 2 * sphi * spsi * dpsi * dphi - cphi * cpsi * dphi**2
    ay = -cphi * spsi * dpsi**2 - 2 * sphi * cpsi * dpsi * dphi - cphi * spsi * dphi**2
    az = -sphi * dphi**2
    return length * np.stack([ax, ay, az], axis=1)


@dataclass(frozen=True)
class PanTilt:
    length: float = 0.3  # L [m]
    gravity: float = 9.81  # [m/s²], along −z
    kind: ClassVar[Kind] = "inertia"
    coordinates = ("pan", "tilt")
    parameters = ParameterSpace(
        names=("m", "b_pan", "b_tilt"),
        units=("kg", "N m s/rad", "N m s/rad"),
        blocks=(
            ParameterBlock("mass", "nonnegative", (0,)),
            ParameterBlock("damping", "nonnegative", (1, 2)),
        ),
    )

    def regressor(self, q, v, a) -> np.ndarray:
        q, v, a = (np.atleast_2d(np.asarray(x, dtype=float)) for x in (q, v, a))
        J = jacobian(q, self.length)
        acc = np.einsum("tij,tj->ti", J, a) + jacobian_dot_v(q, v, self.length)
        acc[:, 2] += self.gravity
        Y = np.zeros((q.shape[0], 2, 3))
        Y[:, :, 0] = np.einsum("tij,ti->tj", J, acc)
        Y[:, 0, 1] = v[:, 0]
        Y[:, 1, 2] = v[:, 1]
        return Y

    def bias_regressor(self, q, v) -> np.ndarray:
        return self.regressor(q, v, np.zeros_like(np.atleast_2d(v)))

    def metric(self, q) -> AffineMetric:
        J = jacobian(np.atleast_2d(np.asarray(q, dtype=float)), self.length)
        return AffineMetric(3, (MetricTerm((0,), np.eye(3)[None], J),))
