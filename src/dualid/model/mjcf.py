"""The identified model as MuJoCo MJCF text, built through MuJoCo's own ``MjSpec``.

The identified URDF text (``model.urdf.identified_urdf``: inertials, <dynamics damping friction>) is
read by MuJoCo's URDF importer into an ``MjSpec``; then every identified joint gets its armature
(reflected rotor inertia, which URDF cannot carry), damping (viscous friction) and frictionloss
(Coulomb friction) set on the spec, gravity is set from the model, and ``MjSpec.to_xml`` writes the
MJCF. What MuJoCo keeps of the URDF is what its importer keeps: visual geoms are discarded (its URDF
default ``discardvisual``), links welded by fixed joints are fused into their parent body
(``fusestatic``), collision geoms stay (their mesh files must exist; relative paths are rewritten to
point at the same files from the output folder).

Precision: MuJoCo's XML writer prints 6 significant digits by default, which changes a mass matrix
by ~1e-6 relative. dualid raises it to 17 (a lossless round trip of doubles) through MuJoCo's
``_mjPRIVATE__set_xml_precision``; when that symbol is missing (another MuJoCo build) the text is
written at MuJoCo's default and ``MjcfText.precision``/``notes`` say so.

Coulomb friction: dualid's model uses the smooth sign fc·tanh(v/v_c); MuJoCo's frictionloss is a
dry-friction constraint with the same magnitude fc (the two agree for |v| ≫ v_c).
"""

from __future__ import annotations

import ctypes
import glob
import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dualid.errors import ConsistencyError, ModelError
from dualid.model.rigid_body import RigidBodyModel
from dualid.model.urdf import identified_urdf, not_determined_comments

FULL_PRECISION = 17  # significant digits for a lossless round trip of a double


@dataclass(frozen=True)
class MjcfText:
    """The MJCF text and how it was made."""

    xml: str
    precision: int  # significant digits of the numbers in ``xml``
    notes: tuple[str, ...] = ()  # what MuJoCo dropped or changed, and any fallback used


def _mujoco_library():
    import mujoco

    paths = glob.glob(os.path.join(os.path.dirname(mujoco.__file__), "libmujoco.so*")) + glob.glob(
        os.path.join(os.path.dirname(mujoco.__file__), "libmujoco*.dylib"))
    if not paths:
        return None
    try:
        lib = ctypes.CDLL(paths[0])
        lib._mjPRIVATE__set_xml_precision.argtypes = [ctypes.c_int]
        lib._mjPRIVATE__get_xml_precision.restype = ctypes.c_int
    except (OSError, AttributeError):
        return None
    return lib


@contextmanager
def _xml_precision(digits: int):
    """Yield the precision MuJoCo's XML writer uses inside the block (``digits`` when it can be set)."""
    lib = _mujoco_library()
    if lib is None:
        yield 6
        return
    before = lib._mjPRIVATE__get_xml_precision()
    lib._mjPRIVATE__set_xml_precision(digits)
    try:
        yield digits
    finally:
        lib._mjPRIVATE__set_xml_precision(before)


def _absolute_meshes(urdf_text: str, source_dir: Path) -> tuple[str, list[str]]:
    """The URDF text with relative mesh filenames made absolute (MuJoCo reads the text, not the file)."""
    root = ET.fromstring(urdf_text)
    uris = []
    for mesh in root.iter("mesh"):
        filename = mesh.get("filename", "")
        if "://" in filename:
            uris.append(filename)
        elif filename and not os.path.isabs(filename):
            mesh.set("filename", str((source_dir / filename).resolve()))
    return ET.tostring(root, encoding="unicode"), uris


def _comment_bodies(xml: str, comments: dict[str, list[str]]) -> str:
    """``xml`` with each joint's comments as the first lines inside the body that joint moves (MjSpec keeps no
    comments of the URDF it read; its writer puts every opening tag on a line of its own)."""
    root = ET.fromstring(xml)
    for joint, texts in comments.items():
        bodies = [b.get("name") for b in root.iter("body") if any(j.get("name") == joint for j in b.findall("joint"))]
        found = [] if len(bodies) != 1 else list(
            re.finditer(rf'^( *)<body name="{re.escape(bodies[0])}"[^\n]*>\n', xml, re.MULTILINE))
        if len(found) != 1:
            raise ModelError(f"write_mjcf: cannot place the note on joint {joint!r}'s body in MuJoCo's MJCF: expected "
                             f"one <body> holding that joint on a line of its own, found bodies {bodies} and "
                             f"{len(found)} such lines")
        indent = found[0].group(1) + "  "
        lines = "".join(f"{indent}<!--{text}-->\n" for text in texts)
        xml = xml[:found[0].end()] + lines + xml[found[0].end():]
    return xml


def identified_mjcf(
    source_urdf: str | Path,
    model: RigidBodyModel,
    theta: np.ndarray,
    out_dir: str | Path | None = None,
    friction: dict[str, tuple[float, float]] | None = None,
    armature: dict[str, float] | None = None,
    not_determined: Mapping[str, str] | None = None,
) -> MjcfText:
    """The MJCF of ``source_urdf`` with the identified inertials θ (model.parameters.p,), per-joint
    friction {joint: (damping [N m s/rad], Coulomb [N m])} and armature {joint: [kg m²]}.

    Mesh files of collision geoms are referred to relative to ``out_dir`` (absolute when None).
    ``not_determined`` ({parameter label: why}) is said in XML comments on the bodies, as in the URDF.
    ``dualid.report.mjcf.write_mjcf`` writes it to a file.
    """
    import mujoco

    source_urdf = Path(source_urdf)
    if model.base_coordinates:
        raise ModelError("write_mjcf: floating-base models are not supported yet (MuJoCo's free joint uses world-frame "
                         "linear velocities, Pinocchio's free flyer body-frame ones); write the URDF instead")
    comments = not_determined_comments(model, not_determined, "write_mjcf")
    text = identified_urdf(source_urdf, model, theta, friction=friction)  # armature goes on the spec below
    text, uris = _absolute_meshes(text, source_urdf.resolve().parent)
    if uris:
        raise ModelError(f"write_mjcf: {source_urdf} refers to meshes by URI ({uris[0]}, …), which MuJoCo cannot "
                         "resolve; give file paths")
    try:
        spec = mujoco.MjSpec.from_string(text)
    except ValueError as exc:
        raise ModelError(f"write_mjcf: MuJoCo could not read the identified URDF of {source_urdf}: {exc}") from None
    spec.option.gravity = np.asarray(model.gravity, dtype=float)
    joints = {j.name: j for j in spec.joints}
    for what, values in (("friction", friction or {}), ("armature", armature or {})):
        for name, value in values.items():
            if name not in joints:
                raise ModelError(f"write_mjcf: {what} for unknown joint {name!r}; MuJoCo's joints are {sorted(joints)}")
            numbers = value if what == "friction" else (value,)
            if not all(np.isfinite(x) and x >= 0 for x in numbers):
                raise ConsistencyError(f"write_mjcf: joint {name!r} {what} must be finite and ≥ 0, got {value}")
            if what == "friction":
                damping = np.zeros_like(joints[name].damping)  # MuJoCo 4: [linear, polynomial terms]
                damping.flat[0] = float(value[0])
                joints[name].damping = damping if damping.ndim else float(value[0])
                joints[name].frictionloss = float(value[1])
            else:
                joints[name].armature = float(value)
    try:
        spec.compile()
    except ValueError as exc:
        raise ModelError(f"write_mjcf: MuJoCo refused the identified model of {source_urdf}: {exc}") from None
    notes = ["visual geoms dropped (MuJoCo's URDF import discards them)",
             "links welded by fixed joints fused into their moving body"]
    if out_dir is not None:  # relative to the output folder, where MuJoCo resolves them when it loads the file
        out_dir = Path(out_dir).resolve()
        for mesh in spec.meshes:
            mesh.file = os.path.relpath(mesh.file, out_dir)
        spec.modelfiledir = str(out_dir)  # to_xml compiles again: resolve them from there too
    with _xml_precision(FULL_PRECISION) as digits:
        xml = _comment_bodies(spec.to_xml(), comments)
    if digits < FULL_PRECISION:
        notes.append(f"written at MuJoCo's default precision ({digits} significant digits): its precision setter "
                     "is not available in this build")
    return MjcfText(xml, digits, tuple(notes))
