"""Where the files of a fit say which parameters the data do not determine (a mass dm's fit completed:
``estimators.newton.closure``; the result's info["projected_names"]): parameters.yaml's ``bodies`` entries and the
XML comments of the written URDF and MJCF (``model.urdf.not_determined_comments``), in closure.NOT_DETERMINED's words.
"""

from __future__ import annotations

from collections.abc import Collection

from dualid.estimators.newton.closure import NOT_DETERMINED
from dualid.estimators.result import IdentificationResult


def not_determined(result: IdentificationResult, names: Collection[str] | None = None) -> dict[str, str]:
    """{parameter label: NOT_DETERMINED} for every parameter the fit completed (only those among ``names`` when
    given, e.g. the rigid-body model's parameters the URDF carries)."""
    return {n: NOT_DETERMINED for n in result.info.get("projected_names", ()) if names is None or n in names}


def body_records(result: IdentificationResult) -> list[dict]:
    """parameters.yaml's ``bodies``: each body's physical quantities at θ̂, with ``not_determined_by_data``: [its
    parameter labels] on a body one of whose parameters the fit completed (absent on the others)."""
    P, completed = result.parameters, not_determined(result)
    out = []
    for b, props in zip(P.blocks, result.bodies):  # body_properties: one entry per block, in order
        labels = [P.names[i] for i in b.indices if P.names[i] in completed]
        out.append({**props.as_dict(), **({"not_determined_by_data": labels} if labels else {})})
    return out
