"""Writing identified MJCF files (the text comes from ``dualid.model.mjcf.identified_mjcf``)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

from dualid.errors import OutputError
from dualid.model.mjcf import MjcfText, identified_mjcf
from dualid.model.rigid_body import RigidBodyModel


def write_mjcf(
    source_urdf: str | Path,
    model: RigidBodyModel,
    theta: np.ndarray,
    out_path: str | Path,
    overwrite: bool = False,
    friction: dict[str, tuple[float, float]] | None = None,
    armature: dict[str, float] | None = None,
    not_determined: dict[str, str] | None = None,
    logged: Mapping[str, tuple[float, float]] | None = None,
    package_path: Iterable[str | Path] = (),
) -> tuple[Path, MjcfText]:
    """Write ``identified_mjcf(source_urdf, model, θ, ...)`` to ``out_path``; refuses an existing file
    unless overwrite=True (``logged``, ``package_path``: see ``identified_mjcf``). Returns the written path and the MjcfText (its notes say what MuJoCo dropped)."""
    out_path = Path(out_path)
    if out_path.exists() and not overwrite:
        raise OutputError(f"write_mjcf: {out_path} already exists; pass overwrite=True to replace it")
    mjcf = identified_mjcf(source_urdf, model, theta, out_path.parent, friction=friction, armature=armature,
                           not_determined=not_determined, logged=logged, package_path=package_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    out_path.write_text(mjcf.xml)
    return out_path, mjcf
