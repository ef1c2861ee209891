"""What the identified model says physically, beside the URDF: the joint friction curves τ_f(v) of every
method and reference, and each link's mass, centre of mass and principal moments against the URDF's."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from dualid.model.consistency import body_properties
from dualid.report.document import Image, Section, Table, Text
from dualid.report.figures import new_figure
from dualid.report.signals import style
from dualid.robot.fit import FitOutcome

BODY_NOTE = ("A link's mass, centre of mass and inertia are set by the data only in the combinations listed under "
             "Identifiability; the rest comes from the physical-consistency constraints and the solver, so compare "
             "predictions (Scores) before reading differences here.")


def _thetas(o: FitOutcome) -> dict[str, np.ndarray]:
    """label → θ of every successful fit, then every reference."""
    return {m: f.result.theta for m, f in o.fits.items() if f.ok} | {lab: th for lab, (th, _) in o.references.items()}


def friction_plot(o: FitOutcome) -> Figure | None:
    """τ_f(v) = b v + f_c tanh(v / v_c) per joint over the training runs' velocity range; None without friction."""
    model = o.model
    if not hasattr(model, "friction") or not (model.viscous or model.coulomb):
        return None
    thetas = _thetas(o)
    frictions = {lab: model.friction(th) for lab, th in thetas.items()}
    joints = list(next(iter(frictions.values())))
    fig, axes = new_figure(1, len(joints), figsize=(min(11.0, 3.2 * len(joints) + 2.2), 2.8))
    for ax, joint in zip(axes[0], joints):
        j = model.coordinates.index(joint)
        vmax = max(float(np.nanmax(np.abs(r.v[:, j]))) for r in o.train) or 1.0
        v = np.linspace(-vmax, vmax, 201)
        for k, (lab, fr) in enumerate(frictions.items()):
            b, fc = fr[joint]
            ax.plot(v, b * v + fc * np.tanh(v / model.coulomb_velocity), lw=1.0, label=lab, **style(lab, k))
        ax.axhline(0.0, color="black", lw=0.5)
        ax.axvline(0.0, color="black", lw=0.5)
        ax.set_title(joint, fontsize=8)
        ax.set_xlabel("velocity [rad/s]", fontsize=8)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
    axes[0, 0].set_ylabel("friction torque [N m]", fontsize=8)
    axes[0, -1].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0), frameon=False)
    fig.subplots_adjust(left=0.08, right=0.8, bottom=0.18, top=0.88, wspace=0.3)
    return fig


def friction_section(o: FitOutcome, png) -> Section:
    fig = friction_plot(o)
    if fig is None:
        return Section("Joint friction")
    vc = o.model.coulomb_velocity
    return Section("Joint friction", (Image("friction.png", png(fig),
                                            f"Identified joint friction τ_f = b·v + f_c·tanh(v / {vc:g} rad/s) over "
                                            "the training runs' velocities (dashed: references)."),))


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
