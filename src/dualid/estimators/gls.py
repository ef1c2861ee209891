"""Feasible generalised least squares with a dual-metric covariance model (candidate default ``dm``).

The residual r_i = Y_i θ − τ_i is modelled as zero-mean with covariance

    C_i = Σ_i + κ M_i(θ_ref)          Σ_i = B_iᵀ Σ B_i,   κ ≥ 0

Σ (n×n, full by default, or diagonal) is the covariance of the force sensors in the chart they measured
in (a covector covariance; B_i = ``problem.sensor_chart`` carries it to the problem's chart),
κ M_i(θ_ref) the part of the residual that is isotropic in the model's own metric, and θ_ref a
fixed pilot fit. Then θ̂ = argmin Σ r_iᵀ C_i⁻¹ r_i, one convex weighted least squares under the
same physical-consistency constraints as every estimator. The weights never depend on θ̂, so the
metric cannot run away with the estimate (the paper's DM inflates M under noise, the fixed point
θ_{k+1} = argmin Σ rᵀM(θ_k)⁻¹r shrinks it under model error).

Limits: κ → 0 gives WLS with W = Σ⁻¹ (joint-local residuals: sensor noise, friction); Σ → 0 gives
the frozen dual metric Σ r_iᵀ M_i(θ_ref)⁻¹ r_i. Since Σ_i and M_i both transform as B_iᵀ(·)B_i,
C_i⁻¹ weighs r_i the same in every chart: the fit is invariant under any change of coordinates
that the problem records (``in_coordinates``), including configuration-dependent ones.

(Σ, κ) are estimated from the pilot's residuals in the sensor chart, after scaling each coordinate
by its residual rms (so the estimate is equivariant under unit changes):
- ``covariance_model="likelihood"`` (default): Gaussian maximum likelihood
  max −½ Σ_i [log det C_i + r_iᵀ C_i⁻¹ r_i] over κ ≥ 0 and a full Σ ≻ 0 (``sigma_structure="full"``,
  the default: never below the likelihood of κ = 0 with the sample covariance, WLS's model) or a
  diagonal one (``"diagonal"``), by L-BFGS-B (``estimators.covariance_model``). A full Σ matters when
  the unexplained torque is correlated across joints (a torque-sensor gain error scales τ, whose
  joints the inertia couples): on the statistical benchmark's sensor case the diagonal model left
  dm 1.04–1.33× the best of OLS/WLS, the full one 0.67–1.07×;
- ``sigma_structure="auto"``: the diagonal, full or shrunk-full Σ with the best time-blocked cross-validated
  likelihood (``estimators.covariance_select``; not the default: the likelihood does not track θ̂'s quality
  under model error, docs/statistics.md);
- ``"moments"``: non-negative least squares Σ_i ‖r_i r_iᵀ − Σ − κ M_i‖_F² (the prototype; diagonal Σ).
The whole fit is done in the sensor chart; the final weighted problem is solved by whitening
(r̃_i = L_i⁻¹ r_i, C_i = L_i L_iᵀ, a per-sample change of coordinates) and the quadratic machinery
of ``least_squares``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from dualid.errors import ConfigError
from dualid.estimators.base import freeze_options
from dualid.estimators.covariance_model import full_likelihood_estimate, likelihood_estimate, moment_estimate
from dualid.estimators.covariance_select import select_structure
from dualid.estimators.least_squares import residual_covariance
from dualid.estimators.metric_guard import DEFAULT_BOUND, given_reference, reference_guard
from dualid.estimators.quadratic_fit import fit_weighted
from dualid.estimators.result import IdentificationResult
from dualid.estimators.weight_cv import CV_FOLDS, SELECTS, choose_weight
from dualid.problem import IdentificationProblem, strided_rows

PILOTS = ("wls", "ols", "dm-paper")
SOLVERS = ("newton", "CLARABEL", "SCS")
COVARIANCE_MODELS = ("likelihood", "moments")
COVARIANCE_SAMPLES = 20_000  # (Σ, κ) (at most n(n+1)/2 + 1 numbers) from at most this many evenly strided samples: the likelihood
# makes one pass over the samples it is given per L-BFGS iteration (recorded in info["covariance_samples"])
ESTIMATION_KEYS = ("sigma", "sigma_diag", "kappa", "kappa_share", "covariance_model", "covariance_samples")  # (Σ̂, κ̂)'s
# record (with the sigma_kappa_* and sigma_structure* keys of the estimators), set aside when dm returns its pilot
SIGMA_STRUCTURES = ("full", "diagonal", "auto")  # auto: chosen by cross-validation (estimators.covariance_select)
__all__ = ["FeasibleGLS", "fit_weighted", "full_likelihood_estimate", "likelihood_estimate", "moment_estimate"]


def _as_tuple(x, name: str, ndim: int) -> tuple | None:
    if x is None:
        return None
    a = np.asarray(x, dtype=float)
    if a.ndim != ndim:
        raise ConfigError(f"{name}: expected a {ndim}-d array, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ConfigError(f"{name}: expected finite values, got {a.tolist()}")
    return tuple(float(v) for v in a) if ndim == 1 else tuple(tuple(float(v) for v in row) for row in a)


# --- the estimator -----------------------------------------------------------------------------
class WeightedPilot(NamedTuple):
    """dm's OLS/WLS pilot: S (n, n), the covariance whose inverse weighs it (I for OLS, Σ̂ of the OLS residuals for
    WLS), and its fit on all the data (what dm returns when the cross-validation prefers the pilot)."""

    S: np.ndarray
    fit: IdentificationResult


@dataclass(frozen=True)
class FeasibleGLS:
    """Σ r_iᵀ (Σ_i + κ M_i(θ_ref))⁻¹ r_i with (Σ, κ) from a fixed pilot's residuals (module docstring).

    pilot: "wls" (default), "ols" or "dm-paper" (the paper's objective), fitted under the same
    constraints in the sensor chart; or give ``theta_ref`` (p,) to fix it. ``sigma`` (n,) diagonal or
    (n, n) and ``kappa`` fix the covariance model instead of estimating it (sigma in the sensor
    chart's force units squared, κ dimensionless). With both fixed the pilot only supplies
    M_i(θ_ref) (and is not fitted when κ = 0).
    """

    pilot: str = "wls"
    covariance_model: str = "likelihood"  # "likelihood" | "moments"
    sigma_structure: str = "full"  # "full" n×n Σ | "diagonal" | "auto" (the likelihood model; "moments": diagonal)
    theta_ref: tuple | None = None  # (p,) fixed pilot θ
    sigma: tuple | None = None  # (n,) or (n, n) fixed sensor covariance Σ
    kappa: float | None = None  # fixed κ ≥ 0
    sigma_floor: float = 1e-9  # σ_a ≥ floor × (coordinate a's residual variance), keeps C_i ≻ 0
    guard_bound: float = DEFAULT_BOUND  # metric guard against M_i(θ_ref) (dualid.estimators.guards)
    guard_reference: tuple | None = None  # (p,) guard against this θ (e.g. a prior) instead of the pilot
    constrained: bool = True
    solver: str = "newton"  # "newton" (dualid's interior point, constant metric) or a cvxpy solver
    solver_options: tuple | None = None  # newton: tol, max_iter; cvxpy: its options (a dict or pairs)
    allow_unidentifiable: bool = False
    select: str = "cv"  # "cv": the GLS fit unless its OLS/WLS pilot predicts held-out torque or motion better
    # (estimators.weight_cv); "cv-torque": judged on torque alone; "none": always the GLS fit
    cv_folds: int = CV_FOLDS
    name = "dm"

    def __post_init__(self) -> None:
        if self.pilot not in PILOTS:
            raise ConfigError(f"pilot: expected one of {PILOTS}, got {self.pilot!r}")
        if self.sigma_structure not in SIGMA_STRUCTURES:
            raise ConfigError(f"sigma_structure: expected one of {SIGMA_STRUCTURES}, got {self.sigma_structure!r}")
        if self.covariance_model not in COVARIANCE_MODELS:
            raise ConfigError(
                f"covariance_model: expected one of {COVARIANCE_MODELS}, got {self.covariance_model!r}"
            )
        object.__setattr__(self, "theta_ref", _as_tuple(self.theta_ref, "theta_ref", 1))
        object.__setattr__(self, "guard_reference", _as_tuple(self.guard_reference, "guard_reference", 1))
        if self.sigma is not None:
            s = np.asarray(self.sigma, dtype=float)
            if s.ndim == 1:
                if np.any(s < 0):
                    raise ConfigError(f"sigma: expected non-negative variances, got {s.tolist()}")
            elif s.ndim == 2 and s.shape[0] == s.shape[1]:
                if not np.allclose(s, s.T) or np.linalg.eigvalsh(0.5 * (s + s.T))[0] < 0:
                    raise ConfigError("sigma: expected a symmetric positive semidefinite (n, n) matrix")
            else:
                raise ConfigError(f"sigma: expected shape (n,) or (n, n), got {s.shape}")
            object.__setattr__(self, "sigma", _as_tuple(s, "sigma", s.ndim))
        if self.kappa is not None:
            if isinstance(self.kappa, bool) or not isinstance(self.kappa, (int, float, np.floating, np.integer)):
                raise ConfigError(f"kappa: expected a number ≥ 0, got {self.kappa!r}")
            if not (np.isfinite(self.kappa) and self.kappa >= 0):
                raise ConfigError(f"kappa: expected a finite number ≥ 0, got {self.kappa!r}")
            object.__setattr__(self, "kappa", float(self.kappa))
        if (self.sigma is None) != (self.kappa is None):
            raise ConfigError(
                f"sigma and kappa: give both (a fixed covariance model) or neither (estimated), got "
                f"sigma={'given' if self.sigma is not None else None}, kappa={self.kappa!r}"
            )
        if not (np.isfinite(self.sigma_floor) and 0 < self.sigma_floor < 1):
            raise ConfigError(f"sigma_floor: expected a number in (0, 1), got {self.sigma_floor!r}")
        if not (np.isfinite(self.guard_bound) and self.guard_bound > 1):
            raise ConfigError(f"guard_bound: expected a finite number > 1, got {self.guard_bound!r}")
        if self.solver not in SOLVERS:
            raise ConfigError(f"solver: expected one of {SOLVERS}, got {self.solver!r}")
        if self.select not in SELECTS:
            raise ConfigError(f"select: expected one of {SELECTS}, got {self.select!r}")
        if isinstance(self.cv_folds, bool) or not isinstance(self.cv_folds, (int, np.integer)) or self.cv_folds < 2:
            raise ConfigError(f"cv_folds: expected an integer ≥ 2, got {self.cv_folds!r}")
        object.__setattr__(self, "solver_options", freeze_options(self.solver_options, "FeasibleGLS: solver_options"))

    # --- steps --------------------------------------------------------------------------------
    def _common(self) -> dict:
        return {"constrained": self.constrained, "solver": self.solver,
                "solver_options": dict(self.solver_options or ()), "allow_unidentifiable": self.allow_unidentifiable}

    def reference(self, sensor: IdentificationProblem) -> tuple[np.ndarray, str]:
        """θ_ref and how it was obtained, in the sensor chart."""
        return self._pilot(sensor)[:2]

    def _pilot(self, sensor: IdentificationProblem) -> tuple[np.ndarray, str, WeightedPilot | None]:
        """(θ_ref, how it was obtained, the OLS/WLS pilot's weight and fit; None for a given θ_ref or the paper's
        DM), in the sensor chart."""
        if self.theta_ref is not None:
            theta = np.array(self.theta_ref)
            if theta.shape != (sensor.p,):
                raise ConfigError(f"theta_ref: expected shape ({sensor.p},), got {theta.shape}")
            return theta, "given", None
        c = self._common()
        if self.pilot in ("wls", "ols"):
            # OLS/WLS by the interior-point Newton method on a constant metric (OLS: M_i = I;
            # WLS: M_i = Σ̂ from the OLS residuals), which fits on the closed feasible set where the infimum is
            # reached only as an unseen mass grows (newton.closure): a pilot stopped along that ray moves with
            # rounding, and the weights with it (re-chart change of dm up to 1.2e-5, docs/statistics.md). If Newton
            # fails, ``fit_weighted`` fits the same problem by cvxpy, polished on the closed set as well. Where the
            # closure projects a parameter out, the library's WLS is this same fit (``quadratic_fit.closed_fit``),
            # bit for bit; elsewhere it is its cvxpy solver's. Whatever the final fit's solver it is the same pilot,
            # so the solvers fit the same weighted problem; what ran is in the label (result.info["pilot"]), which
            # also says so when the user's solver is a cvxpy one (the pilot is not that solver's)
            pilot, fallback = self._newton_pilot(sensor, {**c, "solver": "newton", "solver_options": {}})
            how = fallback or ("by dualid's Newton method on the closed set" if c["solver"] != "newton" else "")
            return pilot.fit.theta, self.pilot + (f" ({how})" if how else ""), pilot
        from dualid.estimators.dual_metric import DualMetric

        return DualMetric(constrained=c["constrained"],
                          allow_unidentifiable=c["allow_unidentifiable"]).fit(sensor).theta, "dm-paper", None

    def _newton_pilot(self, sensor: IdentificationProblem, newton: dict) -> tuple[WeightedPilot, str]:
        """(pilot, fallback): OLS, then for a WLS pilot the weighted fit with S = Σ̂ of the OLS residuals (S = I for
        OLS); fallback: what ``fit_weighted`` recorded when Newton failed and cvxpy fitted instead ("" if nothing)."""
        eye = np.eye(sensor.n)[None]  # one (1, n, n) block: a constant weight, factored once (newton.weighted)
        ols = fit_weighted(sensor, eye, "ols", newton, {})
        notes = [f"ols: {ols.info['solver_fallback']}"] if "solver_fallback" in ols.info else []
        if self.pilot == "ols":
            return WeightedPilot(np.eye(sensor.n), ols), "; ".join(notes)
        S = residual_covariance(sensor, ols.theta)
        wls = fit_weighted(sensor, S[None], "wls", newton, {})
        notes += [f"wls: {wls.info['solver_fallback']}"] if "solver_fallback" in wls.info else []
        return WeightedPilot(S, wls), "; ".join(notes)

    def covariance(self, sensor: IdentificationProblem, theta_ref: np.ndarray,
                   M: np.ndarray | None = None, r: np.ndarray | None = None) -> tuple[np.ndarray, float, dict]:
        """(Σ (n, n), κ, info) in the sensor chart: given, or estimated from the residuals at θ_ref;
        M (N', n, n) and r (N', n): M_i(θ_ref) and the residuals when the caller has them already (or for
        the samples it chose; both or neither)."""
        n = sensor.n
        info: dict = {}
        if self.sigma is not None and self.kappa is not None:
            S = np.asarray(self.sigma)
            S = np.diag(S) if S.ndim == 1 else S
            if S.shape != (n, n):
                raise ConfigError(f"sigma: expected {n} coordinates, got shape {np.asarray(self.sigma).shape}")
            info["covariance_model"] = "given"
            return S, self.kappa, info
        r = sensor.residual(theta_ref) if r is None else r
        M = sensor.metric.evaluate(theta_ref) if M is None else M
        rms = np.sqrt(np.mean(r * r, axis=0))
        floor_abs = 1e-150
        scale = np.where(rms > 1e-9 * max(rms.max(), floor_abs), rms, max(1e-9 * rms.max(), floor_abs))
        rh = r / scale
        Mh = M / np.outer(scale, scale)
        if self.covariance_model == "moments":
            sig, kappa = moment_estimate(rh, Mh)
            Sh = np.diag(np.maximum(sig, self.sigma_floor))
            info.update(covariance_model="moments", sigma_structure="diagonal")
        elif self.sigma_structure == "auto":
            Sh, kappa, info = select_structure(rh, Mh, self.sigma_floor)
            info.update(covariance_model="likelihood")
        elif self.sigma_structure == "diagonal":
            sig, kappa, info = likelihood_estimate(rh, Mh, self.sigma_floor)
            Sh = np.diag(sig)
            info.update(covariance_model="likelihood", sigma_structure="diagonal")
        else:
            Sh, kappa, info = full_likelihood_estimate(rh, Mh, self.sigma_floor)
            info.update(covariance_model="likelihood", sigma_structure="full")
        # the share of the residual's second moment κ M explains, in the scaled chart
        total = float(np.sum(rh * rh))
        info["kappa_share"] = float(kappa * np.einsum("naa->", Mh) / total) if total > 0 else 0.0
        return Sh * np.outer(scale, scale), kappa, info

    def fit(self, problem: IdentificationProblem) -> IdentificationResult:
        sensor = problem.in_sensor_chart()
        need_pilot = not (self.kappa == 0.0 and self.sigma is not None) or self.theta_ref is not None
        if need_pilot:
            theta_ref, pilot, weighted_pilot = self._pilot(sensor)
        else:
            theta_ref, pilot, weighted_pilot = None, "none (κ = 0)", None
        # (Σ, κ) from the residuals of at most COVARIANCE_SAMPLES evenly strided samples: few numbers, and the
        # likelihood's iterations each pass over the samples it is given
        rows = strided_rows(sensor.N, COVARIANCE_SAMPLES)
        step = rows.step
        M_some = r_some = None
        if theta_ref is not None:
            some = sensor if isinstance(sensor, IdentificationProblem) else sensor.subset(rows)  # streamed: collect
            rows = rows if some is sensor else slice(None)
            M_some = some.metric.evaluate(theta_ref, rows)
            r_some = some.Y[rows] @ theta_ref - some.tau[rows]
        S, kappa, info = self.covariance(sensor, theta_ref, M_some, r_some)
        if step > 1:
            info["covariance_samples"] = len(range(sensor.N)[rows])

        def C(block, rows):  # Σ + κ M_i(θ_ref) for a block of samples
            return S[None] if kappa == 0 else S + kappa * block.metric.evaluate(theta_ref, rows)

        info.update(
            pilot=pilot,
            kappa=float(kappa),
            sigma_diag=np.diag(S).tolist(),
            sigma=S.tolist(),
            feedback=False,  # the weights are fixed before the fit: no dependence on θ̂
            theta_ref=None if theta_ref is None else np.asarray(theta_ref, dtype=float).tolist(),
        )
        result = fit_weighted(sensor, C, self.name, self._common(), info,
                              what=f"the residual covariance Σ + κ M_i(θ_ref) (κ = {kappa:.3g})")
        result = self._select(sensor, result, info, weighted_pilot)
        ref = given_reference(sensor, self.guard_reference, "FeasibleGLS")
        label = "given guard_reference" if ref is not None else f"pilot ({pilot})"
        ref = theta_ref if ref is None else ref
        guard = reference_guard(sensor, result.theta, ref, label if ref is not None else "no pilot (Σ, κ = 0 given)",
                                self.guard_bound)
        result = dataclasses.replace(result, info={**result.info, **guard})
        return result

    def _select(self, sensor: IdentificationProblem, result: IdentificationResult, info: dict,
                pilot: WeightedPilot | None) -> IdentificationResult:
        """The GLS fit ``result`` (``info``: what fit() recorded before the fit), or its pilot's weighted fit when that
        predicts held-out folds better (estimators.weight_cv)."""
        if self.select == "none" or pilot is None or self.sigma is not None:
            why = ("select='none'" if self.select == "none" else
                   "no selection: Σ and κ were given" if self.sigma is not None else
                   f"no selection: the pilot ({info['pilot']}) is not a weighted least squares")
            return dataclasses.replace(result, info={**result.info, "weight_choice": f"gls ({why})"})
        plain = dataclasses.replace(self, select="none", allow_unidentifiable=True)

        def fit_pair(sub):  # the whole estimator on a sub-problem: (its pilot, its GLS fit)
            r = plain.fit(sub)
            return np.asarray(r.info["theta_ref"]), r.theta

        cv = choose_weight(sensor, fit_pair, self.cv_folds, self.select)
        if cv["weight_choice"] == "gls":
            return dataclasses.replace(result, info={**result.info, **cv})
        # the weight used is the pilot's; what was estimated for the GLS fit is kept under "estimated_covariance"
        def of_estimate(key: str) -> bool:
            return key in ESTIMATION_KEYS or key.startswith(("sigma_kappa", "sigma_structure"))

        used = "identity (the OLS pilot's weight)" if info["pilot"].startswith("ols") else \
            "the sample covariance of the OLS residuals (the WLS pilot's weight)"
        info = {**{k: v for k, v in info.items() if not of_estimate(k)}, **cv, "sigma": pilot.S.tolist(),
                "sigma_diag": np.diag(pilot.S).tolist(), "kappa": 0.0, "kappa_share": 0.0, "covariance_model": used,
                "estimated_covariance": {k: v for k, v in info.items() if of_estimate(k)}}
        common = self._common()
        if common["solver"] == "newton" and not common["solver_options"]:  # the pilot's fit is this very fit (the
            # same weighted problem, solver and options): returned under dm's name, not fitted a second time
            return dataclasses.replace(pilot.fit, method=self.name, info={**pilot.fit.info, **info})
        return fit_weighted(sensor, pilot.S[None], self.name, common, info, what="the pilot's weight covariance")
