"""``dm``: the dual-metric fit with a physical noise model, min_θ Σ r_iᵀ (Σ_τ + M_i(θ) Σ_a M_i(θ))⁻¹ r_i.

Torque noise (Σ_τ) and the acceleration noise that differentiated encoders put into the regressor (Σ_a) give the
residual at the true θ the covariance C_i(θ) = Σ_τ + M_i(θ) Σ_a M_i(θ) (``newton.noise_objective``). Minimising
Σ r_iᵀ C_i(θ)⁻¹ r_i with C depending on θ is weighted total least squares: least squares shrinks the inertia under
noise in the accelerations (errors-in-variables attenuation), the paper's Σ r_iᵀ M_i(θ)⁻¹ r_i inflates it under
torque noise; this objective is consistent under both when the noise levels are right. The weights frozen at a θ
(the fixed point "weights at θ_k, weighted LS, repeat") do not do it: the gain is the ∂C/∂θ term.

The fit, in the problem's sensor chart (so every chart the problem records, configuration-dependent ones too, gives
the same fit; the objective is invariant when Σ_τ, Σ_a are carried covariantly):
1. pilot: WLS under the physical-consistency constraints, moved strictly inside them;
2. ``rounds`` times: the noise levels from the residuals at the current θ (``noise_level.estimate_noise``: full
   covariances, regularised likelihood, equivariant), then θ by dualid's primal–dual interior point on f with those
   levels, under the same constraints (the objective's gradient and Hessian of ``newton.noise_objective``);
3. the result records the noise levels (sensor chart), their residual shares and the rounds in ``result.noise``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

import warnings

from dualid.errors import ConfigError, MetricError, OptimumAtInfinityWarning, SolverError
from dualid.estimators.base import check_identifiable
from dualid.estimators.least_squares import WLS
from dualid.estimators.metric_guard import reference_guard
from dualid.estimators.newton.fit import fit_dual_metric_newton
from dualid.estimators.newton.closure import on_closure
from dualid.estimators.newton.interior_point import run_interior_point
from dualid.estimators.newton.noise_objective import (
    noise_model_derivatives,
    noise_model_objective,
    noise_model_scale,
)
from dualid.estimators.newton.objective import CHUNK, NotPositiveDefinite
from dualid.estimators.newton.start import central_point
from dualid.estimators.noise_check import NoiseCheck, check_noise_model
from dualid.estimators.noise_level import PRIOR_SAMPLES, PRIOR_SHARE, NoiseLevels, estimate_noise
from dualid.estimators.result import IdentificationResult, NoiseRecord
from dualid.model.consistency import feasible_set
from dualid.problem import IdentificationProblem


CHECK_SAMPLES = 20_000  # streamed data: the noise levels and the held-out check from a strided subsample of this size


@dataclass(frozen=True)
class NoiseModelDM:
    """Σ r_iᵀ (Σ_τ + M_i(θ) Σ_a M_i(θ))⁻¹ r_i with Σ_τ, Σ_a estimated from the data (module doc).

    sigma_tau, sigma_a: fix the noise levels ((n, n), in the sensor chart: force² and acceleration² units) instead
    of estimating them; rounds: noise-level / θ alternations; prior_samples, prior_share: the noise-level prior
    (``noise_level``); tol, max_iter: the interior point's.
    """

    constrained: bool = True
    allow_unidentifiable: bool = False
    rounds: int = 3
    pilot: str = "dm-paper"  # "dm-paper" | "wls"
    sigma_tau: tuple | None = None
    sigma_a: tuple | None = None
    prior_samples: float = PRIOR_SAMPLES
    prior_share: float = PRIOR_SHARE
    check: bool = True  # the held-out check of the noise model against WLS (estimators.noise_check)
    structure: str = "pooled"  # "pooled" | "diagonal" | "highpass" | "full" (noise_level.estimate_noise)
    tol: float = 1e-9
    max_iter: int = 100
    chunk: int = field(default=CHUNK, kw_only=True)
    name = "dm"  # the result's method

    def __post_init__(self) -> None:
        if (self.sigma_tau is None) != (self.sigma_a is None):
            raise ConfigError("NoiseModelDM: give both sigma_tau and sigma_a, or neither")
        for key in ("sigma_tau", "sigma_a"):
            value = getattr(self, key)
            if value is not None:
                a = np.asarray(value, dtype=float)
                if a.ndim != 2 or a.shape[0] != a.shape[1] or not np.all(np.isfinite(a)):
                    raise ConfigError(f"NoiseModelDM: {key} must be a finite (n, n) matrix, got shape {a.shape}")
                object.__setattr__(self, key, tuple(tuple(float(x) for x in row) for row in a))
        if not (isinstance(self.rounds, (int, np.integer)) and self.rounds >= 1):
            raise ConfigError(f"NoiseModelDM: rounds must be a positive integer, got {self.rounds!r}")

    def fit(self, problem: IdentificationProblem) -> IdentificationResult:
        t0 = time.perf_counter()
        if not self.allow_unidentifiable:
            check_identifiable(problem)
        sensor = problem.in_sensor_chart()
        sample = _in_memory(sensor)  # the noise levels and the check read sample subsets
        cons = feasible_set(sensor.parameters, self.constrained)
        pilot, start = self._pilot(sensor)
        theta = np.asarray(pilot.theta)
        if self.constrained and not cons.margin(theta) > 0:
            theta = central_point(theta, cons)
        fixed = self.sigma_tau is not None
        noise = None
        if fixed:
            noise = NoiseLevels(np.asarray(self.sigma_tau), np.asarray(self.sigma_a), np.nan, np.nan, 0)
        iterations, history = 0, []
        for k in range(1 if fixed else self.rounds):
            if not fixed:
                noise = estimate_noise(sample, theta, prior_samples=self.prior_samples, prior_share=self.prior_share,
                                       start=noise, structure=self.structure)
            theta, info = self._solve(sensor, cons, theta, noise)
            iterations += info["iterations"]
            history.append((noise.torque_share, noise.acceleration_share, info["objective"]))
        f = noise_model_objective(sensor, theta, noise.sigma_tau, noise.sigma_a, self.chunk)
        wls = pilot if start.endswith("wls") else WLS(constrained=self.constrained, allow_unidentifiable=True).fit(sensor)
        check, choice = None, "noise model"
        if self.check:
            check = self._check(sample, cons, theta, noise, wls)
            if check is not None and check.rejected:
                theta, f = np.asarray(wls.theta), float(wls.objective)
                choice = (f"wls: the residual is not the modelled noise (held-out loss {check.excess:.3g} of WLS's "
                          f"beyond the noise model's prediction, standard error {check.standard_error:.2g})")
        record = NoiseRecord(noise.sigma_tau, noise.sigma_a, noise.torque_share, noise.acceleration_share,
                             "fixed" if fixed else "estimated", len(history), float(pilot.objective), choice,
                             np.nan if check is None else check.excess,
                             np.nan if check is None else check.measured_gap,
                             np.nan if check is None else check.predicted_gap)
        guard = reference_guard(sensor, theta, np.asarray(pilot.theta), f"pilot ({start})")
        closure = _closure_info(info if choice == "noise model" else wls.info)
        return IdentificationResult(self.name, theta, problem.parameters, f, "optimal", "newton",
                                    time.perf_counter() - t0, iterations, self.constrained,
                                    {"rounds": len(history), "start": start, **guard, **closure}, noise=record)

    def _check(self, sensor, cons, theta, noise, wls) -> NoiseCheck | None:
        Sigma = np.asarray(wls.info["covariance_matrix"])

        def fit_wls(train):
            return np.asarray(WLS(covariance=Sigma, constrained=self.constrained, allow_unidentifiable=True)
                              .fit(train).theta)

        def fit_dm(train, start):
            return self._solve(train, cons, start, noise)[0]

        try:
            return check_noise_model(sensor, theta, noise.sigma_tau, noise.sigma_a, np.linalg.inv(Sigma),
                                     fit_wls, fit_dm)
        except (SolverError, MetricError, NotPositiveDefinite):
            return None

    def _pilot(self, problem) -> tuple[IdentificationResult, str]:
        """The paper's dual-metric optimum (the same θ in every chart, hand-made ones too); WLS where it fails."""
        if self.pilot == "dm-paper":
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", OptimumAtInfinityWarning)
                    return fit_dual_metric_newton(problem, constrained=self.constrained, chunk=self.chunk), "dm-paper"
            except (SolverError, MetricError) as exc:
                why = f"dm-paper pilot failed ({str(exc)[:120]}); "
        else:
            why = ""
        return WLS(constrained=self.constrained, allow_unidentifiable=True).fit(problem), why + "wls"

    def _solve(self, problem, cons, theta, noise: NoiseLevels):
        """θ minimising f with the noise levels fixed, from θ, on the closed feasible set: a parameter that neither Y
        nor M(θ) sees (f's row of it vanishes) only loosens its consistency block, so f's infimum would be approached
        as it grows without bound; it is projected out and completed to the smallest consistent value
        (``newton.closure``), as the quadratic fits do."""
        S, A = noise.sigma_tau, noise.sigma_a

        def objective(th, order):
            return noise_model_derivatives(problem, th, S, A, order, self.chunk)

        try:
            scale = noise_model_scale(problem, theta, S, A, self.chunk)
            der = objective(theta, 2)
        except NotPositiveDefinite:
            raise MetricError("dm: the noise model's covariance is not positive definite at the start") from None
        closed, done = on_closure(cons, 0.5 * der.hess, scale, problem.parameters.names, enabled=self.constrained)
        theta, _, _, info = run_interior_point(problem, closed, theta, None, None, self.tol, self.max_iter, self.chunk,
                                               False, der=der, objective=objective, f_scale=scale, convex=False)
        return done(theta, info)


def _in_memory(problem, samples: int = CHECK_SAMPLES):
    """The problem itself when it is in memory; for data streamed from disk (``streaming.ChunkedProblem``), an evenly
    strided in-memory subsample of at most ``samples`` samples, in time order (one pass)."""
    if isinstance(problem, IdentificationProblem):
        return problem
    return problem.subset(slice(0, None, max(1, -(-problem.N // samples))))


def _closure_info(info: dict) -> dict:
    """What the closed-set completion said of the parameters the data do not determine (``newton.closure``)."""
    return {k: info[k] for k in ("projected_parameters", "projected_names", "projected_note") if k in info}


__all__ = ["NoiseModelDM"]
