"""What the identified model says physically, beside the URDF: the joint friction curves τ_f(v) of every
method and reference, and each link's mass, centre of mass and principal moments against the URDF's."""

from __future__ import annotations

import numpy as np

from dualid.model.consistency import body_properties
from dualid.report.document import Image, Section, Table, Text
from dualid.report.signals import style
from dualid.report.svgplot import curves_svg
from dualid.robot.fit import FitOutcome

BODY_NOTE = ("A link's mass, centre of mass and inertia are set by the data only in the combinations listed under "
             "Identifiability; the rest comes from the physical-consistency constraints and the solver, so compare "
             "predictions (Scores) before reading differences here.")


def _thetas(o: FitOutcome) -> dict[str, np.ndarray]:
    """label → θ of every successful fit, then every reference."""
    return {m: f.result.theta for m, f in o.fits.items() if f.ok} | {lab: th for lab, (th, _) in o.references.items()}


def friction_plot(o: FitOutcome) -> str | None:
    """SVG: τ_f(v) = b v + f_c tanh(v / v_c) per joint over the training runs' velocity range; None without friction."""
    model = o.model
    if not hasattr(model, "friction") or not (model.viscous or model.coulomb):
        return None
    frictions = {lab: model.friction(th) for lab, th in _thetas(o).items()}
    panels = []
    for joint in next(iter(frictions.values())):
        j = model.coordinates.index(joint)
        vmax = max(float(np.nanmax(np.abs(r.v[:, j]))) for r in o.train) or 1.0
        v = np.linspace(-vmax, vmax, 201)
        panels.append((joint, v, {lab: fr[joint][0] * v + fr[joint][1] * np.tanh(v / model.coulomb_velocity)
                                  for lab, fr in frictions.items()}))
    styles = {lab: style(lab, k) for k, lab in enumerate(frictions)}
    return curves_svg("joint friction", panels, "velocity [rad/s]", "N m", styles)


def friction_section(o: FitOutcome) -> Section:
    svg = friction_plot(o)
    if svg is None:
        return Section("Joint friction")
    vc = o.model.coulomb_velocity
    return Section("Joint friction", (Image("friction.svg", b"",
                                            f"Identified joint friction τ_f = b·v + f_c·tanh(v / {vc:g} rad/s) over "
                                            "the training runs' velocities (dashed: references).", svg=svg),))


def _vector(x) -> str:
    """Three numbers to 3 digits; one below 1e-9 × the largest is solver round-off, shown as 0."""
    x = np.asarray(x, dtype=float)
    tiny = 1e-9 * float(np.nanmax(np.abs(x))) if np.isfinite(x).any() else 0.0
    return ", ".join("—" if not np.isfinite(v) else "0" if abs(v) <= tiny else f"{v:.3g}" for v in x)


def body_section(o: FitOutcome) -> Section:
    """One table per link: the URDF's and every model's mass (and its ratio to the URDF's), centre of mass and
    principal moments of inertia about it."""
    P = o.problem.parameters
    urdf = np.zeros(P.p)
    urdf[:o.rigid.parameters.p] = o.rigid.nominal
    rows: dict[str, list] = {}
    for lab, th in {"URDF": urdf, **_thetas(o)}.items():
        for body in body_properties(P, th):
            if body.kind == "rigid_body":
                rows.setdefault(body.name, []).append((lab, body))
    tables = []
    for name, entries in rows.items():
        m0 = entries[0][1].mass
        cells = tuple((lab, f"{b.mass:.4g}", "—" if lab == "URDF" or not m0 else f"{b.mass / m0:.2f}",
                       _vector(b.com), _vector(b.principal_moments)) for lab, b in entries)
        tables.append(Table(("source", "mass [kg]", "× URDF", "centre of mass [m]", "principal moments [kg m²]"),
                            cells, title=name))
    if not tables:
        return Section("Links against the URDF")
    return Section("Links against the URDF", (Text(BODY_NOTE), *tables))
