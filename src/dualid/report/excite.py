"""Files of ``dualid excite``: the trajectory CSV, its Fourier coefficients, plots against the limits and
the predicted identifiability (JSON and Markdown), written under the output-directory policy.

The CSV has columns ``time, q[k], v[k], a[k], tau_nom[k]`` (k = 0-based joint index in the model's
order, SI units): once a simulator or the robot adds measured torques as ``tau[k]``, ``dualid fit
--model ROBOT.urdf --data RUN.csv`` reads it as it is (the array column map of ``dualid.robot.inputs``).
``tau_nom`` is the URDF's torque along the motion (a feed-forward), which ``dualid fit`` ignores.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from dualid.excite import Excitation, check_limits
from dualid.excite.predict import Prediction
from dualid.report.figures import new_figure, save_figure
from dualid.report.io import markdown_table, write_json
from dualid.report.outdir import write_output

QUANTITIES = (("q", "position", "rad"), ("v", "velocity", "rad/s"), ("a", "acceleration", "rad/s²"),
              ("tau_nom", "torque (URDF)", "N m"))


def trajectory_table(result: Excitation, rate: float) -> tuple[list[str], np.ndarray]:
    """(column names, (T, 1 + 4n) values) of the trajectory CSV at ``rate`` [Hz]."""
    t = result.trajectory.times(rate)
    q, v, a = result.trajectory.evaluate(t)
    tau = result.design.torque(q, v, a)
    n = result.design.n
    names = ["time"] + [f"{key}[{k}]" for key, _, _ in QUANTITIES for k in range(n)]
    return names, np.column_stack([t, q, v, a, tau])


def coefficients(result: Excitation) -> dict:
    """The Fourier coefficients and how to evaluate them (the YAML file's content)."""
    tr, d = result.trajectory, result.design
    return {
        "formula": "q_j(t) = q0_j + sum_k (a_jk/(k w)) sin(k w t) - (b_jk/(k w)) cos(k w t), w = 2 pi / period",
        "period": float(tr.period),
        "omega": float(tr.omega),
        "harmonics": int(tr.harmonics),
        "joints": {j: {"q_start": float(d.q_start[k]), "q0": float(tr.q0[k]), "a": tr.a[k].tolist(), "b": tr.b[k].tolist()}
                   for k, j in enumerate(d.joints)},
    }


def trajectory_plot(result: Excitation, rate: float = 200.0) -> Figure:
    """One row per joint, one column per quantity (q, v, a, τ) with its limits as dashed lines."""
    _, data = trajectory_table(result, rate)
    d, L = result.design, result.design.limits
    n = d.n
    fig, axes = new_figure(n, 4, figsize=(14, 1.9 * n + 1), sharex=True)
    t = data[:, 0]
    bounds = {"q": (L.lower, L.upper), "v": (-L.velocity, L.velocity), "a": (-L.acceleration, L.acceleration),
              "tau_nom": (-L.effort, L.effort)}
    for c, (key, label, unit) in enumerate(QUANTITIES):
        for j in range(n):
            ax = axes[j, c]
            ax.plot(t, data[:, 1 + c * n + j], lw=1.0)
            for bound in bounds[key]:
                if np.isfinite(bound[j]):
                    ax.axhline(bound[j], color="#d62728", ls="--", lw=0.8)
            ax.grid(alpha=0.3)
            if j == 0:
                ax.set_title(f"{label} [{unit}]", fontsize=9)
            if c == 0:
                ax.set_ylabel(d.joints[j], fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    fig.suptitle(f"excitation ({result.config.criterion}); dashed: limits", fontsize=10)
    fig.tight_layout()
    return fig


def prediction_record(result: Excitation, prediction: Prediction, notes: list[str]) -> dict:
    ident = prediction.identifiability
    check = check_limits(result.design, result.trajectory, result.config.check_rate)
    return {
        "criterion": result.config.criterion,
        "criterion_value": result.value,
        "criteria": prediction.criteria,
        "samples": prediction.samples,
        "rate_hz": prediction.rate,
        "rank": ident.rank,
        "n_params": ident.n_params,
        "unidentifiable": list(ident.unidentifiable),
        "base_parameters": len(prediction.base_names),
        "cond_base_column_scaled": prediction.cond,
        "cond_base_raw": prediction.cond_raw,
        "cond_full_identifiable_part": ident.condition_number,
        "torque_noise": dict(zip(result.design.joints, prediction.torque_noise.tolist())),
        "base": [{"name": nm, "nominal": float(b), "standard_error": float(se)}
                 for nm, b, se in zip(prediction.base_names, prediction.beta_nominal, prediction.standard_errors)],
        "limit_check": {"rate_hz": check.rate, "worst_ratio": check.worst, "ok": check.ok},
        "restarts": [{"status": r.status, "message": r.message, "iterations": r.iterations, "value": r.value,
                      "scale": r.scale} for r in result.restarts],
        "chosen_restart": result.best,
        "notes": notes,
    }


def _markdown(record: dict) -> str:
    lines = [f"# Excitation trajectory ({record['criterion']})", "",
             f"- samples: {record['samples']} at {record['rate_hz']:g} Hz (one period)",
             f"- rank {record['rank']} of {record['n_params']} parameters; {record['base_parameters']} base parameters",
             f"- condition number of the base regressor: {record['cond_base_column_scaled']:.4g} (columns scaled to "
             f"unit norm), {record['cond_base_raw']:.4g} (raw)",
             "- criteria (minimised): " + ", ".join(f"{k} {v:.4g}" for k, v in record["criteria"].items()),
             f"- limits at {record['limit_check']['rate_hz']:g} Hz, worst |value|/limit: "
             + ", ".join(f"{k} {v:.3f}" for k, v in record["limit_check"]["worst_ratio"].items())
             + (" (all hold)" if record["limit_check"]["ok"] else " (VIOLATED)"), ""]
    if record["notes"]:
        lines += ["## Notes", ""] + [f"- {n}" for n in record["notes"]] + [""]
    lines += ["## Base parameters and predicted standard errors (OLS, torque noise "
              + ", ".join(f"{j} {s:g} N m" for j, s in record["torque_noise"].items()) + ")", ""]
    big = max([abs(b["nominal"]) for b in record["base"]] + [0.0])
    lines += markdown_table(["base parameter", "URDF value", "standard error", "relative"],
                            [[b["name"], f"{b['nominal']:.4g}", f"{b['standard_error']:.3g}",
                              f"{b['standard_error'] / abs(b['nominal']):.3g}" if abs(b["nominal"]) > 1e-9 * big else "—"]
                             for b in record["base"]])
    lines += ["", "## Restarts", ""]
    lines += markdown_table(["restart", "SLSQP status", "iterations", "criterion", "scale at the 1 kHz check"],
                            [[k, f"{r['status']} ({r['message']})", r["iterations"], f"{r['value']:.4g}", f"{r['scale']:.4f}"]
                             for k, r in enumerate(record["restarts"])])
    return "\n".join(lines) + "\n"


def write_excite(result: Excitation, prediction: Prediction, out: str | Path, force: bool = False,
                 notes: list[str] | None = None) -> dict[str, Path]:
    """Write trajectory.csv, coefficients.yaml, trajectory.png, identifiability.json/.md into ``out``."""
    import yaml

    record = prediction_record(result, prediction, list(notes or []))

    def write(d: Path) -> dict[str, Path]:
        names, data = trajectory_table(result, result.config.rate)
        csv = d / "trajectory.csv"
        np.savetxt(csv, data, delimiter=",", header=",".join(names), comments="", fmt="%.10g")
        coef = d / "coefficients.yaml"
        coef.write_text(yaml.safe_dump(coefficients(result), sort_keys=False))
        md = d / "identifiability.md"
        md.write_text(_markdown(record))
        return {"csv": csv, "coefficients": coef, "json": write_json(d / "identifiability.json", record), "md": md,
                "png": save_figure(trajectory_plot(result, min(result.config.rate, 200.0)), d / "trajectory.png")}

    return write_output(out, force, write)
