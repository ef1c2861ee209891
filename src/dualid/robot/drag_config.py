"""The ``model`` section of a fit config for a drag-dominated system (``model.kind: drag``)::

    model:
      kind: drag
      urdf: swimmer.urdf              # the kinematic tree (or omit it and give drag.chain)
      drag: {base: planar, bodies: {...}, damping: [...]}   # dualid.model.drag_spec.DragSpec

``model.floating_base`` and ``model.gravity`` do not apply (a drag model has no inertia): refused.
"""

from __future__ import annotations

from typing import Mapping

from dualid.errors import ConfigError, ModelError
from dualid.model.drag_spec import DragSpec

KINDS = ("inertia", "drag")


def drag_spec(m: Mapping) -> DragSpec:
    """The checked drag spec of a ``model`` mapping whose kind is drag (ConfigError naming the key)."""
    for key in ("floating_base", "gravity"):
        if m.get(key) not in (None, False):
            raise ConfigError(f"model.{key}: not used by a drag model (model.kind: drag); give the base in "
                              "model.drag.base (fixed or planar)")
    if m.get("drag") is None:
        raise ConfigError("model.drag: a drag model (model.kind: drag) needs its drag spec: "
                          "{base, bodies: {NAME: {frame, diagonal | full}}, damping}")
    try:
        spec = DragSpec.from_dict(m["drag"], "model.drag")
    except ModelError as exc:
        raise ConfigError(str(exc)) from None
    if (m.get("urdf") is None) == (spec.chain is None):
        raise ConfigError("model: a drag model needs exactly one of model.urdf (a kinematic tree) or "
                          f"model.drag.chain (link lengths); got {'both' if spec.chain else 'neither'}")
    return spec


def check_kind(m: Mapping) -> str:
    kind = m.get("kind", "inertia")
    if kind not in KINDS:
        raise ConfigError(f"model.kind: expected one of {list(KINDS)}, got {kind!r}")
    if kind == "inertia" and m.get("drag") is not None:
        raise ConfigError("model.drag: only used with model.kind: drag")
    return kind

