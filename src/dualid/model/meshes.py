"""Mesh file names of a URDF as the world writes them, resolved to files.

A URDF names meshes by a path relative to its own folder, an absolute path, a ``file://`` URI or a
``package://PKG/path`` URI (ROS). ``package://PKG/path`` is looked up, in order, in the folders of
``package_path`` (dualid's ``--package-path`` or the fit config's ``model.package_path``) and then of
the ``ROS_PACKAGE_PATH`` environment variable: a folder ``D`` resolves it to ``D/PKG/path``, or to
``D/path`` when ``D`` itself is named ``PKG`` (as ROS and Pinocchio's ``package_dirs`` do).

MuJoCo reads STL, OBJ and MSH meshes; ``mujoco_geometry`` prepares a URDF's geometry for MuJoCo's URDF
importer: visual elements removed (the importer discards them anyway), collision meshes made absolute,
and collision geoms whose mesh cannot be found or read by MuJoCo removed, each said in a note (the
identified dynamics do not depend on them; a contact simulation does).
"""

from __future__ import annotations

import os
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Iterable
from pathlib import Path

from dualid.errors import DualidWarning

MUJOCO_MESH_FORMATS = (".stl", ".obj", ".msh")  # what MuJoCo's mesh loader reads


def package_dirs(package_path: Iterable[str | Path] = ()) -> tuple[Path, ...]:
    """The folders searched for ``package://`` URIs: ``package_path`` first, then ``ROS_PACKAGE_PATH``'s."""
    env = [p for p in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep) if p]
    return tuple(Path(p) for p in [*package_path, *env])


def resolve_mesh(filename: str, source_dir: Path, package_path: Iterable[str | Path] = ()) -> Path | None:
    """The existing file a URDF's mesh ``filename`` names (relative to ``source_dir``), or None."""
    if filename.startswith("file://"):
        filename = filename[len("file://"):]
    if filename.startswith("package://"):
        package, _, rest = filename[len("package://"):].partition("/")
        for folder in package_dirs(package_path):
            for candidate in (folder / package / rest, folder / rest if folder.name == package else None):
                if candidate is not None and candidate.is_file():
                    return candidate.resolve()
        return None
    if "://" in filename:  # http://, model:// (Gazebo) …: nothing dualid can read
        return None
    path = Path(filename) if os.path.isabs(filename) else source_dir / filename
    return path.resolve() if path.is_file() else None


def mujoco_geometry(root: ET.Element, source_dir: Path, package_path: Iterable[str | Path] = ()) -> list[str]:
    """Prepare ``root`` (a URDF's <robot>, changed in place) for MuJoCo's URDF importer; returns the notes.

    Visual elements are removed; each collision mesh is made absolute, or its <collision> removed when
    the file cannot be found (named in a note with the folders searched) or is in a format MuJoCo does
    not read; each note is also a DualidWarning.
    """
    package_path = tuple(package_path)
    missing: list[str] = []
    unreadable: list[str] = []
    for link in root.findall("link"):
        for visual in link.findall("visual"):
            link.remove(visual)
        for collision in link.findall("collision"):
            mesh = collision.find("geometry/mesh")
            if mesh is None:
                continue
            filename = mesh.get("filename", "")
            path = resolve_mesh(filename, source_dir, package_path)
            if path is None:
                missing.append(filename)
            elif path.suffix.lower() not in MUJOCO_MESH_FORMATS:
                unreadable.append(filename)
            else:
                mesh.set("filename", str(path))
                continue
            link.remove(collision)
    notes = []
    if missing:
        searched = ", ".join(str(d) for d in package_dirs(package_path)) or "none given"
        notes.append(f"{len(missing)} collision mesh{'es' * (len(missing) > 1)} not found and left out of the MJCF "
                     f"(e.g. {missing[0]}); give the folder holding the package with --package-path or the config's "
                     f"model.package_path, or set ROS_PACKAGE_PATH (folders searched: {searched})")
    if unreadable:
        notes.append(f"{len(unreadable)} collision mesh{'es' * (len(unreadable) > 1)} in a format MuJoCo does not read "
                     f"left out of the MJCF (e.g. {unreadable[0]}; MuJoCo reads {', '.join(MUJOCO_MESH_FORMATS)})")
    for note in notes:
        warnings.warn(f"MJCF: {note}", DualidWarning, stacklevel=3)
    return notes
