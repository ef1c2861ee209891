"""The plausible-parameters step of ``fit_robot`` and its config (``prior.plausible``).

``prior.plausible``: true (default) | false | {level: 0.95, joint: false}. With a prior and the method's
uncertainty of the base parameters, the model files carry θ closest to the prior whose base parameters
lie in the fit's confidence region (``evaluation.plausible_region``: radius² χ²₁(level), every linear
combination of β within its own interval; ``joint: true``: χ²_r(level), the joint region). level 0, or a
method without uncertainty (uncertainty.method: none, or its computation failed), falls back to the
exact-prediction choice (``evaluation.plausible``), and the result's ``note`` says why.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Mapping

import numpy as np

from dualid.errors import ConfigError, ModelFileWarning, PlausibleWarning
from dualid.evaluation.plausible import (HEAVY_RATIO, PlausibleParameters, heavy_links, moving_mass,
                                         plausible_parameters)
from dualid.evaluation.plausible_newton import MASSLESS_SHARE, ball_prior, rounded_prior
from dualid.evaluation.plausible_region import LEVEL, check_level, plausible_in_region, training_rmse
from dualid.evaluation.uncertainty import BaseUncertainty
from dualid.problem import IdentificationProblem

PLAUSIBLE_LEVEL = LEVEL
PLAUSIBLE_KEYS = ("level", "joint")


def plausible_option(x) -> tuple[bool, float, bool]:
    """(on, level, joint) from ``prior.plausible``: a bool or a mapping {level, joint}."""
    if isinstance(x, bool):
        return x, LEVEL, False
    if isinstance(x, Mapping):
        unknown = [k for k in x if k not in PLAUSIBLE_KEYS]
        if unknown:
            raise ConfigError(f"prior.plausible: unknown keys {unknown}; known keys: {list(PLAUSIBLE_KEYS)}")
        joint = x.get("joint", False)
        if not isinstance(joint, bool):
            raise ConfigError(f"prior.plausible.joint: expected true or false, got {joint!r}")
        return True, check_level(x.get("level", LEVEL), "prior.plausible.level"), joint
    raise ConfigError(f"prior.plausible: expected true, false or a mapping {{level: …, joint: …}}, got {x!r}")


def plausible_dict(prior) -> bool | dict:
    """The config's ``prior.plausible`` as written back (from_dict accepts it)."""
    if not prior.plausible:
        return False
    return {"level": prior.plausible_level, "joint": prior.plausible_joint}


def choose_plausible(problem: IdentificationProblem, theta_hat: np.ndarray, theta0: np.ndarray,
                     base: BaseUncertainty | None, base_error: str, level: float,
                     joint: bool) -> PlausibleParameters:
    """θ_plausible of one method (module docstring); raises what the estimators raise. The prior's rigid bodies are
    made at most 10 % rounder first (``evaluation.plausible_newton.rounded_prior``: a thin CAD link would make the
    divergence 1/λ² stiff along one direction and push the fit's disagreement into that link's mass)."""
    theta0, ball = ball_prior(problem, theta0)
    if ball:  # no prior body at all: a regularised one at the data's scale (said: a fallback that is used)
        warnings.warn(PlausibleWarning(ball), stacklevel=2)
    rounded = rounded_prior(problem.parameters, theta0)
    P = problem.parameters
    replaced = [b.name for b in P.blocks if b.kind == "rigid_body"  # rounding keeps the mass, replacing does not
                and not np.isclose(rounded[b.indices[0]], theta0[b.indices[0]], rtol=1e-9, atol=0.0)]
    if replaced:  # a fallback that is used is said (console, report, parameters.yaml)
        warnings.warn(PlausibleWarning(
            f"the prior has no consistent body for {', '.join(replaced)} (no mass or a singular inertia): its plausible "
            f"parameters are drawn toward a regularised body instead ({MASSLESS_SHARE:g} × the other bodies' mean mass, "
            "at the joint frame, their mean radius of gyration)"), stacklevel=2)
    theta0 = rounded
    if level > 0 and base is not None:
        return plausible_in_region(problem, theta_hat, theta0, base, level, joint)
    p = plausible_parameters(problem, theta_hat, theta0)
    p = dataclasses.replace(p, training_rmse_hat=training_rmse(problem, theta_hat),
                            training_rmse=training_rmse(problem, p.theta))
    if level == 0:
        return dataclasses.replace(p, note="prior.plausible.level: 0 (the training predictions exactly)")
    return dataclasses.replace(p, fallback_used=True, note=(
        f"no uncertainty of the base parameters ({base_error or 'none'}): the exact-prediction choice instead of "
        f"the {level:g} confidence region"))


def refused_files(method: str, P, theta: np.ndarray, theta0: np.ndarray, which: str, links: dict[str, str],
                  step_on: bool = False) -> str:
    """Why ``method``'s model files are not written ("" when they are): a link heavier than HEAVY_RATIO × the prior's
    whole moving mass (a simulator would carry a body no arm has; MuJoCo refuses 10³–10⁹ kg links). Warned
    (``ModelFileWarning``); ``which``: the θ the files would carry, ``links``: {joint: its child link}, ``step_on``:
    prior.plausible was on (so a raw θ̂ means the step failed)."""
    heavy = heavy_links(P, theta, theta0)
    if not heavy:
        return ""
    total = moving_mass(P, theta0)
    named = ", ".join(f"link {links.get(j, j)!r} {m:.4g} kg (prior {m0:.4g} kg)" for j, m, m0 in heavy)
    hint = ("" if which != "raw" else "; the plausible step failed (its error says why)" if step_on else
            "; keep prior.plausible on (the default) to draw what the data leave free toward the prior")
    reason = (f"{'the raw fit θ̂' if which == 'raw' else 'θ_plausible'} puts {named} above {HEAVY_RATIO:g} × the prior's whole moving mass ({total:.4g} kg){hint}")
    warnings.warn(ModelFileWarning(f"{method}: model files not written: {reason}"), stacklevel=2)
    return reason
