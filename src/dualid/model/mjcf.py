"""The identified model as MuJoCo MJCF text, built through MuJoCo's own ``MjSpec``.

The identified URDF text (``model.urdf.identified_urdf``: inertials, <dynamics damping friction>) is
read by MuJoCo's URDF importer into an ``MjSpec``; then every identified joint gets its armature
(reflected rotor inertia, which URDF cannot carry), damping (viscous friction) and frictionloss
(Coulomb friction) set on the spec, gravity is set from the model, and ``MjSpec.to_xml`` writes the
MJCF. What MuJoCo keeps of the URDF is what its importer keeps: visual geoms are discarded (its URDF
default ``discardvisual``), links welded by fixed joints are fused into their parent body
(``fusestatic``), a <mimic> joint becomes a joint equality constraint, collision geoms stay when
their mesh can be found and read (``model.meshes``: relative, absolute and ``package://`` names;
paths are rewritten to point at the same files from the output folder; the others are left out and
said in the notes).

Joint ranges: a range copied from the URDF that the logged motion leaves (``logged``: the range
each joint went through in the logs) would make MuJoCo add limit forces to what was logged, so such
a joint is written without a range (as a continuous joint is), and the notes say so.

The fused links leave MuJoCo's writer a ``<frame>`` wrapper around their child bodies, which
Pinocchio's MJCF reader refuses (or loses the bodies under it); the frames are folded into the
poses of the elements they hold, so the written MJCF has bodies only. Several bodies directly in
the world (a fixed root with several moving children) are put in one jointless body, as
Pinocchio's MJCF reader reads only the world's first body.

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
from collections.abc import Iterable, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dualid.errors import ConsistencyError, ModelError
from dualid.model.meshes import mujoco_geometry
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


def _for_pinocchio(xml: str, base: str) -> str:
    """MuJoCo's MJCF text as Pinocchio's MJCF reader reads it whole: every <frame pos quat> replaced by the
    elements it holds, their pos and quat composed with the frame's (innermost first; empty frames removed),
    and, when the world holds several bodies (a fixed root link with several moving children, which MuJoCo
    fused into the world), those bodies and the world's geoms put in one jointless body ``base`` (Pinocchio
    reads only the world's first body)."""
    import mujoco

    root = ET.fromstring(xml)
    world = root.find("worldbody")
    if "<frame" not in xml and (world is None or len(world.findall("body")) < 2):
        return xml
    if len(world.findall("body")) > 1:
        holder = ET.Element("body", {"name": base})
        for child in list(world):
            if child.tag in ("body", "geom", "site", "frame"):
                world.remove(child)
                holder.append(child)
        world.insert(0, holder)
    while True:
        parents = {child: parent for parent in root.iter() for child in parent}
        frames = [f for f in root.iter("frame") if f.find(".//frame") is None]
        if not frames:
            break
        for frame in frames:
            extra = set(frame.attrib) - {"pos", "quat", "name"}
            if extra:
                raise ModelError(f"write_mjcf: MuJoCo wrote a <frame> with {sorted(extra)}, which dualid cannot fold "
                                 "into its bodies")
            p_f = np.fromstring(frame.get("pos", "0 0 0"), sep=" ")
            q_f = np.fromstring(frame.get("quat", "1 0 0 0"), sep=" ")
            parent = parents[frame]
            k = list(parent).index(frame)
            parent.remove(frame)
            for child in reversed(list(frame)):
                if set(child.attrib) & {"euler", "axisangle", "xyaxes", "zaxis", "fromto"}:
                    raise ModelError(f"write_mjcf: cannot fold a <frame> into a <{child.tag}> placed other than by pos and quat")
                if child.tag not in ("joint", "inertial"):  # a joint's pos and axis are in its body's frame
                    pos = np.zeros(3)
                    mujoco.mju_rotVecQuat(pos, np.fromstring(child.get("pos", "0 0 0"), sep=" "), q_f)
                    quat = np.zeros(4)
                    mujoco.mju_mulQuat(quat, q_f, np.fromstring(child.get("quat", "1 0 0 0"), sep=" "))
                    child.set("pos", " ".join(repr(float(x)) for x in pos + p_f))
                    child.set("quat", " ".join(repr(float(x)) for x in quat))
                parent.insert(k, child)
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="unicode") + "\n"


def _base_name(root: ET.Element) -> str:
    """A name for the body that holds the world's bodies (``_for_pinocchio``): the URDF's root link's."""
    children = {c.get("link") for c in root.iter("child")}
    roots = [link.get("name") for link in root.findall("link") if link.get("name") not in children]
    return roots[0] if len(roots) == 1 and roots[0] != "world" else "fixed_base"


def _logged_ranges(spec, logged: Mapping[str, tuple[float, float]] | None) -> list[str]:
    """Drop the range of every limited joint whose logged motion leaves it; the notes say which."""
    import mujoco

    notes = []
    limited = [j for j in spec.joints if j.limited != mujoco.mjtLimited.mjLIMITED_FALSE]
    if logged is None:
        if limited:
            notes.append("joint ranges copied from the URDF (no logged motion was given to check them against)")
        return notes
    for joint in limited:
        if joint.name not in logged:
            continue
        lo, hi = (float(x) for x in logged[joint.name])
        a, b = (float(x) for x in joint.range)
        slack = 1e-9 * max(1.0, abs(a), abs(b))
        if lo < a - slack or hi > b + slack:
            joint.limited = mujoco.mjtLimited.mjLIMITED_FALSE
            notes.append(f"joint {joint.name!r}: the logs reach [{lo:.4g}, {hi:.4g}], outside the URDF's range "
                         f"[{a:.4g}, {b:.4g}]; written without a range, so MuJoCo adds no limit force to the logged motion")
    return notes


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
    logged: Mapping[str, tuple[float, float]] | None = None,
    package_path: Iterable[str | Path] = (),
) -> MjcfText:
    """The MJCF of ``source_urdf`` with the identified inertials θ (model.parameters.p,), per-joint
    friction {joint: (damping [N m s/rad], Coulomb [N m])} and armature {joint: [kg m²]}.

    Mesh files of collision geoms are referred to relative to ``out_dir`` (absolute when None);
    ``package_path``: folders that hold the packages of ``package://`` mesh URIs (``model.meshes``).
    ``not_determined`` ({parameter label: why}) is said in XML comments on the bodies, as in the URDF.
    ``logged`` ({joint: (lowest, highest) position in the logs}): a joint whose logs leave its URDF range
    is written without one.
    ``dualid.report.mjcf.write_mjcf`` writes it to a file.
    """
    import mujoco

    source_urdf = Path(source_urdf)
    if model.base_coordinates:
        raise ModelError("write_mjcf: floating-base models are not supported yet (MuJoCo's free joint uses world-frame "
                         "linear velocities, Pinocchio's free flyer body-frame ones); write the URDF instead")
    comments = not_determined_comments(model, not_determined, "write_mjcf")
    text = identified_urdf(source_urdf, model, theta, friction=friction)  # armature goes on the spec below
    root = ET.fromstring(text)
    notes = mujoco_geometry(root, source_urdf.resolve().parent, package_path)
    try:
        spec = mujoco.MjSpec.from_string(ET.tostring(root, encoding="unicode"))
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
    notes += _logged_ranges(spec, logged)
    try:
        spec.compile()
    except ValueError as exc:
        raise ModelError(f"write_mjcf: MuJoCo refused the identified model of {source_urdf}: {exc}") from None
    notes += ["visual geoms dropped (MuJoCo's URDF import discards them)",
              "links welded by fixed joints fused into their moving body"]
    if out_dir is not None:  # relative to the output folder, where MuJoCo resolves them when it loads the file
        out_dir = Path(out_dir).resolve()
        for mesh in spec.meshes:
            mesh.file = os.path.relpath(mesh.file, out_dir)
        spec.modelfiledir = str(out_dir)  # to_xml compiles again: resolve them from there too
    with _xml_precision(FULL_PRECISION) as digits:
        xml = _comment_bodies(_for_pinocchio(spec.to_xml(), _base_name(root)), comments)
    if digits < FULL_PRECISION:
        notes.append(f"written at MuJoCo's default precision ({digits} significant digits): its precision setter "
                     "is not available in this build")
    return MjcfText(xml, digits, tuple(notes))
