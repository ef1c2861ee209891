"""Reading a URDF with its values checked before Pinocchio sees them.

urdfdom (Pinocchio's URDF reader) prints a line and goes on for values it cannot use: a mass
"nan" or "heavy" leaves the link with zero inertia, an axis "0 0 0" makes a joint that moves
nothing. ``read_urdf`` refuses such files with a ModelError naming the file, the element and the
value, so a fit never starts from a silently different model:

- the file is XML (a parse error names its line and column) with a <robot> root;
- link and joint names are present and unique; joint parents/children name declared links
  (an undeclared "world" parent is allowed: see urdf_for_pinocchio);
- every <inertial>: mass finite and ≥ 0 kg, inertia about the centre of mass finite, positive
  semi-definite and satisfying the triangle inequalities of its principal moments (a real body's);
  origin xyz/rpy three finite numbers;
- every moving joint: a known type, an axis of three finite numbers that is not zero;
- <dynamics damping friction armature>: finite and ≥ 0.

What vendors' URDFs commonly do and a fit can still use is accepted with a DualidWarning:

- a massless frame (mass 0) that carries a non-zero inertia (e.g. Franka's panda_link8): a body
  without mass has no inertia, so the inertia is ignored (``urdf_for_pinocchio`` drops it);
- an element given twice where one is read (two <origin> in a joint, two <axis>, <mass>, …):
  the first is used, as urdfdom does;
- a <mimic> joint: Pinocchio's regressor does not support mimic joints, so dualid models it as a
  joint of its own, whose position and effort must be logged like any other joint's.
"""

from __future__ import annotations

import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from dualid.errors import DualidWarning, MissingFileError, ModelError

JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "floating", "planar")
_INERTIA_KEYS = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
_SINGLE = {"link": ("inertial",), "inertial": ("origin", "mass", "inertia"),
           "joint": ("origin", "parent", "child", "axis", "limit", "dynamics", "mimic")}  # urdfdom reads the first


def _warn(message: str) -> None:
    warnings.warn(message, DualidWarning, stacklevel=3)


def _check_duplicates(element: ET.Element, where: str, path: Path) -> None:
    """Warn for each child element that urdfdom reads once but ``element`` has more than once."""
    for tag in _SINGLE.get(element.tag, ()):
        count = len(element.findall(tag))
        if count > 1:
            _warn(f"{path}: {where} has {count} <{tag}> elements; the first is used (as urdfdom does), the others "
                  "are ignored")


def _check_origins(element, where: str, path) -> None:
    """Every <origin xyz= rpy=> of ``element`` holds three finite numbers."""
    for el in element.findall("origin"):
        for key in ("xyz", "rpy"):
            if el.get(key) is not None:
                _numbers(el.get(key), 3, f"{where} <origin {key}>", path)


def _numbers(text: str | None, count: int, where: str, path: Path) -> np.ndarray:
    try:
        x = np.array([float(v) for v in (text or "").split()])
    except ValueError:
        x = np.array([])
    if x.shape != (count,) or not np.all(np.isfinite(x)):
        raise ModelError(f"{path}: {where}: expected {count} finite number{'s' * (count > 1)}, got {text!r}")
    return x


def _inertia(inertial: ET.Element, link: str, path: Path) -> None:
    """Check one <inertial> (a massless frame with a non-zero inertia: warned; ``massless_frames`` lists them)."""
    where = f"link {link!r} <inertial>"
    _check_duplicates(inertial, where, path)
    mass_el = inertial.find("mass")
    if mass_el is None:
        raise ModelError(f"{path}: {where} has no <mass value=...>")
    mass = _numbers(mass_el.get("value"), 1, f"{where} <mass value>", path)[0]
    if mass < 0:
        raise ModelError(f"{path}: {where} <mass value>: expected a mass ≥ 0 kg, got {mass_el.get('value')!r}")
    _check_origins(inertial, where, path)
    inertia_el = inertial.find("inertia")
    if inertia_el is None:
        if mass > 0:
            raise ModelError(f"{path}: {where} has a mass of {mass} kg but no <inertia>")
        return
    values = {}
    for key in _INERTIA_KEYS:
        raw = inertia_el.get(key, "0")
        values[key] = _numbers(raw, 1, f"{where} <inertia {key}>", path)[0]
    I = np.array([[values["ixx"], values["ixy"], values["ixz"]],
                  [values["ixy"], values["iyy"], values["iyz"]],
                  [values["ixz"], values["iyz"], values["izz"]]])
    lam = np.linalg.eigvalsh(I)  # principal moments about the centre of mass [kg m²], ascending
    tol = 1e-9 * max(float(np.abs(lam).max()), 1e-12)
    shown = ", ".join(f"{k}={inertia_el.get(k, '0')}" for k in _INERTIA_KEYS)
    if mass == 0 and np.abs(lam).max() > 0:
        _warn(f"{path}: {where}: a mass of 0 kg with a non-zero inertia ({shown}); treated as a massless frame "
              "(its inertia is ignored: a body without mass has none). Give the link its mass if it has one")
        return
    if lam[0] < -tol:
        raise ModelError(
            f"{path}: {where} <inertia>: expected a positive semi-definite matrix, got principal moments "
            f"{np.array2string(lam, precision=4)} kg m² ({shown})")
    if lam[0] + lam[1] < lam[2] - tol:
        raise ModelError(
            f"{path}: {where} <inertia>: principal moments {np.array2string(lam, precision=4)} kg m² break the "
            f"triangle inequality (the two smallest must sum to at least the largest; no body has them) ({shown})")


def massless_frames(root: ET.Element) -> list[str]:
    """Names of the links whose first <inertial> has mass 0 and a non-zero inertia (checked by ``read_urdf``)."""
    out = []
    for link in root.findall("link"):
        inertial = link.find("inertial")
        mass = None if inertial is None else inertial.find("mass")
        inertia = None if inertial is None else inertial.find("inertia")
        if mass is not None and inertia is not None and float(mass.get("value")) == 0 and any(
                float(inertia.get(k, "0")) != 0 for k in _INERTIA_KEYS):
            out.append(link.get("name"))
    return out


def urdf_for_pinocchio(path: str | Path) -> str | None:
    """The checked URDF's text as Pinocchio should read it, or None when the file can be read as it is.

    - ``<link name="world"/>`` declared when a joint uses an undeclared "world" parent: many URDFs (e.g.
      Gazebo-style ones such as the DFKI pendulum's) weld the robot to a "world" link they never declare,
      which urdfdom rejects; declaring the empty link is exactly what those files mean;
    - the <inertial> of a massless frame with a non-zero inertia removed (a link without <inertial> is
      massless to Pinocchio, which merges it into its parent joint's body).
    """
    root = read_urdf(path)
    changed = False
    links = {link.get("name") for link in root.findall("link")}
    parents = {p.get("link") for joint in root.findall("joint") for p in joint.findall("parent")}
    if "world" not in links and "world" in parents:
        root.insert(0, ET.Element("link", {"name": "world"}))
        changed = True
    frames = set(massless_frames(root))
    for link in root.findall("link"):
        if link.get("name") in frames:
            for inertial in link.findall("inertial"):
                link.remove(inertial)
            changed = True
    return ET.tostring(root, encoding="unicode") if changed else None


def read_urdf(path: str | Path) -> ET.Element:
    """The checked <robot> element of a URDF file (see the module docstring for the checks)."""
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"no URDF file at {path}")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        line, column = exc.position
        raise ModelError(f"{path}: not a valid URDF: XML parse error at line {line}, column {column} ({exc})") from None
    if root.tag != "robot":
        raise ModelError(f"{path}: not a URDF: expected a <robot> root element, got <{root.tag}>")
    links = root.findall("link")
    joints = root.findall("joint")
    for kind, elements in (("link", links), ("joint", joints)):
        names = [el.get("name") for el in elements]
        if any(not n for n in names):
            raise ModelError(f"{path}: a <{kind}> has no name")
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ModelError(f"{path}: {kind} names must be unique; {dup} appear more than once")
    if not joints and not links:
        raise ModelError(f"{path}: the <robot> has no links and no joints")
    declared = {el.get("name") for el in links}
    for link in links:
        _check_duplicates(link, f"link {link.get('name')!r}", path)
        for inertial in link.findall("inertial")[:1]:  # urdfdom reads the first (others: warned above)
            _inertia(inertial, link.get("name"), path)
    joint_names = {el.get("name") for el in joints}
    for joint in joints:
        name, kind = joint.get("name"), joint.get("type")
        _check_duplicates(joint, f"joint {name!r}", path)
        mimic = joint.find("mimic")
        if mimic is not None and kind != "fixed":
            if mimic.get("joint") not in joint_names:
                raise ModelError(f"{path}: joint {name!r} <mimic joint>: expected the name of a joint of the URDF, got "
                                 f"{mimic.get('joint')!r}")
            _warn(f"{path}: joint {name!r} mimics joint {mimic.get('joint')!r} (<mimic>); Pinocchio's regressor does "
                  "not support mimic joints, so dualid models it as a joint of its own: log its position and effort "
                  "like any other joint's (the MJCF keeps the coupling as an equality constraint)")
        if kind not in JOINT_TYPES:
            raise ModelError(f"{path}: joint {name!r}: unknown type {kind!r}; expected one of {', '.join(JOINT_TYPES)}")
        for tag in ("parent", "child"):
            el = joint.find(tag)
            link = None if el is None else el.get("link")
            if not link:
                raise ModelError(f"{path}: joint {name!r} has no <{tag} link=...>")
            if link not in declared and not (tag == "parent" and link == "world"):
                raise ModelError(f"{path}: joint {name!r}: {tag} link {link!r} is not declared; links: {sorted(declared)}")
        _check_origins(joint, f"joint {name!r}", path)
        axis = joint.find("axis")
        if kind in ("revolute", "continuous", "prismatic", "planar") and axis is not None:
            a = _numbers(axis.get("xyz"), 3, f"joint {name!r} <axis xyz>", path)
            if np.linalg.norm(a) == 0:
                raise ModelError(f"{path}: joint {name!r} <axis xyz>: expected a non-zero direction, got {axis.get('xyz')!r}")
        for dyn in joint.findall("dynamics"):
            for key in ("damping", "friction", "armature"):
                if dyn.get(key) is not None:
                    x = _numbers(dyn.get(key), 1, f"joint {name!r} <dynamics {key}>", path)[0]
                    if x < 0:
                        raise ModelError(f"{path}: joint {name!r} <dynamics {key}>: expected a value ≥ 0, got {dyn.get(key)!r}")
    return root
