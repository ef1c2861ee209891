"""Minimum distance between links from the URDF's collision geometry (Pinocchio + Coal/hpp-fcl).

Only when the URDF has <collision> elements: ``link_distance`` returns None (and says so) otherwise.
Pairs of geometries on the same body or on a parent and child body are not checked (they touch at
their joint by construction). The ground is checked only if the URDF models it as a link with
collision geometry. The distance's derivative along q is taken by finite differences per joint.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from dualid.errors import ModelError
from dualid.model.rigid_body import RigidBodyModel
from dualid.model.urdf_check import read_urdf

STEP = 1e-6  # [rad] finite-difference step of ∂d/∂q


@dataclass(frozen=True, eq=False)
class LinkDistance:
    rigid: RigidBodyModel
    geometry: pin.GeometryModel
    pairs: int

    def __call__(self, q: np.ndarray) -> np.ndarray:
        """d (T,) [m]: the smallest distance over the checked pairs at each configuration (T, n)."""
        qc = self.rigid.configuration(q)
        data, gdata = self.rigid.model.createData(), pin.GeometryData(self.geometry)
        out = np.empty(qc.shape[0])
        for t in range(qc.shape[0]):
            pin.computeDistances(self.rigid.model, data, self.geometry, gdata, qc[t])
            out[t] = min(r.min_distance for r in gdata.distanceResults)
        return out

    def gradient(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(d (T,), ∂d/∂q (T, n)) by forward differences."""
        d0 = self(q)
        G = np.empty(q.shape)
        for j in range(q.shape[1]):
            qj = np.array(q, dtype=float)
            qj[:, j] += STEP
            G[:, j] = (self(qj) - d0) / STEP
        return d0, G


def link_distance(urdf: str | Path, rigid: RigidBodyModel) -> tuple[LinkDistance | None, str]:
    """(the distance function, a note) — (None, why) when the URDF has no collision geometry."""
    urdf = Path(urdf)
    root = read_urdf(urdf)
    if root.find("link/collision") is None:
        return None, f"{urdf.name} has no <collision> geometry: the minimum link distance was not constrained"
    links = {link.get("name") for link in root.findall("link")}
    if "world" not in links and any(p.get("link") == "world" for p in root.iter("parent")):
        root.insert(0, ET.Element("link", {"name": "world"}))  # as RigidBodyModel.from_urdf does
    try:
        geom = pin.buildGeomFromUrdfString(rigid.model, ET.tostring(root, encoding="unicode"),
                                           pin.GeometryType.COLLISION, package_dirs=[str(urdf.parent)])
    except (RuntimeError, ValueError) as exc:
        raise ModelError(f"{urdf}: Pinocchio could not read its collision geometry: {exc}") from None
    parents = rigid.model.parents
    for i in range(geom.ngeoms):
        for k in range(i + 1, geom.ngeoms):
            a, b = geom.geometryObjects[i].parentJoint, geom.geometryObjects[k].parentJoint
            if a != b and parents[a] != b and parents[b] != a:
                geom.addCollisionPair(pin.CollisionPair(i, k))
    if not geom.collisionPairs:
        return None, f"{urdf.name}: no pair of non-adjacent links has collision geometry: the distance was not constrained"
    return LinkDistance(rigid, geom, len(geom.collisionPairs)), (
        f"minimum link distance constrained on {len(geom.collisionPairs)} collision pairs of {urdf.name}")
