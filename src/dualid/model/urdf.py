"""Write identified inertial parameters (and joint friction) back into a copy of a URDF.

Each moving joint's identified body (10 parameters in the joint frame, which is the URDF frame of
the joint's child link) is written on that child link as mass, centre of mass and inertia about the
centre of mass (rpy 0, axes of the link frame). Pinocchio merges links welded by fixed joints into
the joint's body, and so did the identification: the whole identified body goes on the joint's
child link and the merged links' inertials are zeroed, so nothing is counted twice.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from dualid.errors import ConsistencyError, ModelError
from dualid.model.consistency import body_at_com
from dualid.model.rigid_body import RigidBodyModel


def _fmt(x: float) -> str:
    return repr(float(x))


def _check_body(name: str, theta_b: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    m = float(theta_b[0])
    if not np.isfinite(theta_b).all():
        raise ConsistencyError(f"write_urdf: body {name!r} has non-finite parameters {theta_b}")
    if m <= 0:
        raise ConsistencyError(
            f"write_urdf: body {name!r} has mass {m:.6g} kg (expected > 0); θ is not physically "
            "consistent and would make an invalid URDF"
        )
    m, c, Ic = body_at_com(theta_b)
    lam = np.linalg.eigvalsh(0.5 * (Ic + Ic.T))
    if lam[0] < -1e-12 * max(1.0, abs(lam[-1])):
        raise ConsistencyError(
            f"write_urdf: body {name!r} has an inertia about its centre of mass with eigenvalues "
            f"{lam} (expected ≥ 0); θ is not physically consistent and would make an invalid URDF"
        )
    return m, c, Ic


def _inertial_element(m: float, c: np.ndarray, Ic: np.ndarray) -> ET.Element:
    inertial = ET.Element("inertial")
    ET.SubElement(inertial, "origin", {"xyz": " ".join(_fmt(x) for x in c), "rpy": "0 0 0"})
    ET.SubElement(inertial, "mass", {"value": _fmt(m)})
    ET.SubElement(
        inertial,
        "inertia",
        {
            "ixx": _fmt(Ic[0, 0]),
            "ixy": _fmt(Ic[0, 1]),
            "ixz": _fmt(Ic[0, 2]),
            "iyy": _fmt(Ic[1, 1]),
            "iyz": _fmt(Ic[1, 2]),
            "izz": _fmt(Ic[2, 2]),
        },
    )
    return inertial


def _replace_inertial(link: ET.Element, inertial: ET.Element, comment: str) -> None:
    for old in link.findall("inertial"):
        link.remove(old)
    link.insert(0, inertial)
    link.insert(0, ET.Comment(comment))


def _merged_links(root: ET.Element, link: str) -> list[str]:
    """Links welded to ``link`` by chains of fixed joints (excluding ``link`` itself)."""
    out, stack = [], [link]
    while stack:
        parent = stack.pop()
        for joint in root.findall("joint"):
            if joint.get("type") == "fixed" and joint.find("parent").get("link") == parent:
                child = joint.find("child").get("link")
                out.append(child)
                stack.append(child)
    return out


def not_determined_comments(model: RigidBodyModel, not_determined: Mapping[str, str] | None,
                            where: str = "write_urdf") -> dict[str, list[str]]:
    """{body (block name): [comment text]} for the parameters ``not_determined`` names ({parameter label: why it is
    not determined by the data}, e.g. a mass the fit completed: model.closure), found through the
    model's parameter blocks; a label that is not one of the model's parameters is refused."""
    not_determined = dict(not_determined or {})
    P = model.parameters
    unknown = sorted(set(not_determined) - set(P.names))
    if unknown:
        raise ModelError(f"{where}: not_determined names {unknown}, which are not parameters of the model; expected "
                         f"inertial parameter names such as {P.names[0]!r}")
    out: dict[str, list[str]] = {}
    for b in P.blocks:
        labels = [P.names[i] for i in b.indices if P.names[i] in not_determined]
        if labels:
            out[b.name] = [f" dualid: {label}: {not_determined[label]} " for label in labels]
    return out


def _relocate_meshes(root: ET.Element, source_dir: Path, out_dir: Path) -> None:
    """Keep relative mesh filenames pointing at the same files from the written URDF's folder."""
    if source_dir == out_dir:
        return
    for mesh in root.iter("mesh"):
        filename = mesh.get("filename")
        if filename and "://" not in filename and not os.path.isabs(filename):
            mesh.set("filename", os.path.relpath(source_dir / filename, out_dir))


def identified_urdf(
    source_urdf: str | Path,
    model: RigidBodyModel,
    theta: np.ndarray,
    out_dir: str | Path | None = None,
    friction: dict[str, tuple[float, float]] | None = None,
    armature: dict[str, float] | None = None,
    not_determined: Mapping[str, str] | None = None,
) -> str:
    """The text of a copy of ``source_urdf`` with the identified inertials θ (and optional joint friction).

    ``model`` must be the RigidBodyModel of ``source_urdf`` and θ its parameter vector
    (model.parameters.p,). ``friction`` maps joint names to (damping [N m s/rad], Coulomb friction
    [N m]) written as <dynamics damping= friction=>; ``armature`` maps joint names to rotor inertia
    [kg m²], written as a non-standard <dynamics armature=> (URDF has no field for it; urdfdom and
    Pinocchio ignore it, ``dualid validate`` reads it back). ``not_determined`` maps parameter labels
    (model.parameters.names) to why the data do not determine them; each is said in an XML comment on the
    link that carries its body (``not_determined_comments``). Relative mesh filenames are rewritten to
    point at the same files from ``out_dir`` (the folder the text will be written to).
    ``dualid.report.urdf.write_urdf`` writes it to a file.
    """
    source_urdf = Path(source_urdf)
    theta = np.asarray(theta, dtype=float)
    if theta.shape != (model.parameters.p,):
        raise ModelError(
            f"write_urdf: θ must have shape ({model.parameters.p},) (the RigidBodyModel's parameters), got "
            f"{theta.shape}; pass only the rigid-body part θ[:{model.parameters.p}] of a larger model"
        )
    bodies = {b.name: _check_body(b.name, theta[list(b.indices)]) for b in model.parameters.blocks}
    notes = not_determined_comments(model, not_determined)

    tree = ET.parse(source_urdf, parser=ET.XMLParser(target=ET.TreeBuilder(insert_comments=True)))
    root = tree.getroot()
    links = {link.get("name"): link for link in root.findall("link")}
    joints = {joint.get("name"): joint for joint in root.findall("joint")}
    children = {joint.find("child").get("link") for joint in joints.values()}

    for name, (m, c, Ic) in bodies.items():
        if name in joints and joints[name].get("type") != "fixed":
            carrier = joints[name].find("child").get("link")
        elif model.base_coordinates and name == model.bodies[0]:  # free-flyer root: the URDF's root link
            roots = [link for link in links if link not in children]
            if len(roots) != 1:
                raise ModelError(f"write_urdf: cannot tell the URDF's root link among {roots}")
            carrier = roots[0]
        else:
            raise ModelError(
                f"write_urdf: the model's joint {name!r} is not a moving joint of {source_urdf}; "
                "was the model built from another URDF?"
            )
        merged = _merged_links(root, carrier)
        if carrier not in links:  # e.g. an undeclared "world" root welded to the robot's base link
            declared = [link for link in merged if link in links]
            if not declared:
                raise ModelError(f"write_urdf: no link of {source_urdf} carries body {name!r}")
            carrier, merged = declared[0], [link for link in merged if link != declared[0]]
        _replace_inertial(
            links[carrier],
            _inertial_element(m, c, Ic),
            f" dualid: identified inertia of the whole body moved by joint {name!r}"
            + (f" (includes the fixed-joint links {', '.join(merged)}, whose inertials are zeroed) " if merged else " "),
        )
        for k, text in enumerate(notes.get(name, ()), start=1):  # after the identified-inertia comment
            links[carrier].insert(k, ET.Comment(text))
        for link in merged:
            if link in links:
                _replace_inertial(
                    links[link],
                    _inertial_element(0.0, np.zeros(3), np.zeros((3, 3))),
                    f" dualid: zeroed; its mass is part of the identified inertial of link {carrier!r} ",
                )

    def dynamics_of(joint_name: str, what: str) -> ET.Element:
        if joint_name not in joints or joints[joint_name].get("type") == "fixed":
            moving = [n for n, j in joints.items() if j.get("type") != "fixed"]
            raise ModelError(f"write_urdf: {what} for unknown joint {joint_name!r}; moving joints are {moving}")
        dynamics = joints[joint_name].find("dynamics")
        return ET.SubElement(joints[joint_name], "dynamics") if dynamics is None else dynamics

    for joint_name, (damping, coulomb) in (friction or {}).items():
        dynamics = dynamics_of(joint_name, "friction")
        if not (damping >= 0 and coulomb >= 0):
            raise ConsistencyError(
                f"write_urdf: joint {joint_name!r} friction must be ≥ 0, got damping={damping}, friction={coulomb}"
            )
        dynamics.set("damping", _fmt(damping))
        dynamics.set("friction", _fmt(coulomb))
    for joint_name, value in (armature or {}).items():
        dynamics = dynamics_of(joint_name, "armature")
        if not value >= 0:
            raise ConsistencyError(f"write_urdf: joint {joint_name!r} armature must be ≥ 0, got {value}")
        dynamics.set("armature", repr(float(value)))

    undeclared = sorted({j.find("parent").get("link") for j in joints.values() if j.find("parent") is not None}
                        - set(links))
    for k, name in enumerate(undeclared):  # e.g. an implicit "world": other URDF tools refuse it undeclared
        root.insert(k, ET.Comment(f" dualid: declared the link {name!r} the source URDF referred to without declaring it "))
        root.insert(k + 1, ET.Element("link", {"name": name}))
    if out_dir is not None:
        _relocate_meshes(root, source_urdf.resolve().parent, Path(out_dir).resolve())
    ET.indent(tree, space="  ")
    return "<?xml version='1.0' encoding='utf-8'?>\n" + ET.tostring(root, encoding="unicode")
