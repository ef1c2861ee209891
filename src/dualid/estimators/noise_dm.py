"""``dm``: the dual-metric fit with a physical noise model, min_θ Σ r_iᵀ (Σ_τ + M_i(θ) Σ_a M_i(θ))⁻¹ r_i.

Torque noise (Σ_τ) and the acceleration noise that differentiated encoders put into the regressor (Σ_a) give the
residual at the true θ the covariance C_i(θ) = Σ_τ + M_i(θ) Σ_a M_i(θ) (``noise_model``). Minimising
Σ r_iᵀ C_i(θ)⁻¹ r_i with C depending on θ is weighted total least squares: least squares shrinks the inertia under
noise in the accelerations (errors-in-variables attenuation), the paper's Σ r_iᵀ M_i(θ)⁻¹ r_i inflates it under
torque noise; this objective is consistent under both when the noise levels are right. The weights frozen at a θ
(the fixed point "weights at θ_k, weighted LS, repeat") do not do it: the gain is the ∂C/∂θ term.

The fit, in the problem's sensor chart (so every chart the problem records, configuration-dependent ones too, gives
the same fit; the noise levels are covariant per coordinate, so a coordinate or the forces in other units by hand too):
1. two pilots, least squares unconstrained (constrained where M(θ) is not positive definite): on each coordinate's
   own force scale (the start, the levels, the check's and the guard's reference), and whitened by mean τ_i τ_iᵀ (its
   residual covariance is the fallback's weight: the same in every constant linear chart); with a passive coordinate
   (τ_j ≡ 0), both the paper's dual-metric optimum;
2. the noise levels from the pilot's residuals (``noise_model.estimate_noise``: Σ_τ per joint, Σ_a = σ_a² diag(mean
   v²): the sensors are independent); where the likelihood does not support acceleration noise, step 4's fallback;
3. ROUNDS times: θ by dualid's primal–dual interior point on f (gradient and Hessian of ``noise_model``) under the
   physical-consistency constraints, from the pilot moved strictly inside them, then from the last θ with the levels
   re-estimated at it; before the first, step 4's check at CHECK_STEPS damped Newton steps from the pilot (none of
   the rounds when it rejects by Z_DECISIVE standard errors: the fallback does not depend on them); a solve whose θ
   only feeds the levels (the pilot's, the first round's) stops at LEVELS_TOL;
4. the held-out check (``noise_model.check_noise_model``) and the metric guard against the pilot: when the residual
   is not the modelled noise, or the fit is degenerate (a ghost), ``dm`` returns WLS in the whitened pilot's residual
   covariance (full: correlated residuals, which model error makes, are weighed as WLS weighs them; one quadratic fit
   from its sufficient statistics, same constraints), or, where the pilot is the paper's optimum, that optimum;
5. the result records the noise levels (sensor chart), their residual shares and the rounds in ``result.noise``.

On streamed data, and in memory above 4 × CHECK_SAMPLES samples, steps 1–2 (the closure included), the check and the
first round (whose θ only feeds the levels: a few numbers) use an evenly strided subsample of CHECK_SAMPLES; the last
round and the fallback use every sample. So there (and up to CHECK_SAMPLES) a problem in memory and the same one
streamed give the same fit, and a large fit pays one round's interior point over all samples instead of two.

solver="cvxpy" makes step 3's θ-solves by majorize–minimize instead, each step one conic problem (a batched SDP):
the reference the interior point is checked against (``noise_cvxpy.solve_noise_model_cvxpy``; tests/test_dm_cvxpy.py).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from dualid.errors import ConfigError, MetricError, OptimumAtInfinityWarning, SolverError
from dualid.estimators.base import check_solver
from dualid.estimators.least_squares import residual_covariance
from dualid.estimators.newton.fit import fit_dual_metric_newton
from dualid.estimators.newton.interior_point import run_interior_point
from dualid.estimators.newton.objective import CHUNK, objective_value, statistics, stopping_scale, value_or_inf
from dualid.estimators.noise_cvxpy import solve_noise_model_cvxpy
from dualid.estimators.noise_model import (NoiseCheck, NoiseLevels, check_noise_model, estimate_noise, given_levels,
                                           newton_refit, noise_model_derivatives, noise_model_objective,
                                           noise_model_scale)
from dualid.estimators.newton.start import run_quadratic, toward_start
from dualid.estimators.quadratic_fit import fit_weighted
from dualid.estimators.quadratic_newton import quadratic_objective
from dualid.estimators.result import IdentificationResult, NoiseRecord
from dualid.identifiability import check_identifiable
from dualid.linalg import NotPositiveDefinite, triangular_factor
from dualid.metric_guard import reference_guard
from dualid.model.closure import on_closure
from dualid.model.consistency import central_point, feasible_set
from dualid.problem import IdentificationProblem, sample_blocks, strided_rows

ACCEPTABLE = 1e-6  # a solve that reaches max_iter within this relative gap ends "optimal_inaccurate", not an error
CHUNK_QR = 8192  # samples per block of the pilot's QR
CHECK_SAMPLES = 20_000  # streamed data, and data in memory above 4× this: the pilot, levels, check and first round from
# a strided subsample of this size (Panda, 10⁵ samples: half the CPU of all samples', the same clean error to 0.5 %)
ROUNDS = 2  # noise levels at the pilot, θ; the levels at that θ, θ again (unless the first round finds Σ_a = 0)
LEVELS_TOL = 1e-6  # gap of the solves whose θ only feeds the levels (pilot, first round; saves 5–20 %). θ̂ follows the
# levels: 4 re-charted fits moved (clean error / f) ≤ 5e-6 / 1e-4 at 1e-4, ≤ 2e-7 / 5e-6 at 1e-6, ≤ 1e-5 / 2e-6 at 1e-9
SINGULAR_TORQUES = 1e-10  # mean ττᵀ as a correlation matrix with an eigenvalue below this: singular (``torque_scale``)
CHECK_STEPS = 4  # damped Newton steps from the pilot give the first round's check its θ (DFKI: 2e-6 from the
# constrained solve's in predictions, the same check to 4 digits); a decisive rejection there skips that solve
LEVELS_MAX_ITER = 60  # first round's budget from a least-squares pilot, then from the paper's optimum: on the noise
# benchmark such solves converged in 15–50 iterations (46) or not in 300 (14, all xArm7); statistical benchmark ≤ 32


def torque_scale(problem) -> np.ndarray:
    """(n, n) mean τ_i τ_iᵀ (covariant under constant linear charts); where singular (a passive coordinate, torques
    linearly dependent) its diagonal, a passive coordinate's entry its regressor rows' mean square (alike covariant)."""
    T = problem.tau.T @ problem.tau / problem.N
    if np.all(np.linalg.eigvalsh(T / np.sqrt(np.outer(np.diag(T), np.diag(T)) + 1e-300)) > SINGULAR_TORQUES):
        return T
    scale = np.diag(T)
    rows = np.einsum("ijk,ijk->j", problem.Y, problem.Y) / problem.N
    return np.diag(np.where(scale > 0, scale, np.where(rows > 0, rows, 1.0)))


@dataclass(frozen=True)
class NoiseModelDM:
    """Σ r_iᵀ (Σ_τ + M_i(θ) Σ_a M_i(θ))⁻¹ r_i with Σ_τ, Σ_a estimated from the data (module doc).

    sigma_tau, sigma_a: fix the noise levels ((n, n), in the sensor chart: force² and acceleration² units) instead
    of estimating them; tol, max_iter: the interior point's (solver="newton"), or for solver="cvxpy" (majorize–minimize,
    ``solve_noise_model_cvxpy``, each step a conic problem for ``cvxpy_solver``: the reference, slow for large N) the
    relative decrease of f that ends it and the number of conic solves."""

    constrained: bool = True
    allow_unidentifiable: bool = False
    sigma_tau: tuple | None = None
    sigma_a: tuple | None = None
    tol: float = 1e-9
    max_iter: int = 300  # per solve: the non-convex fit converges linearly (Crazyflie, 21,000 samples: 265)
    chunk: int = field(default=CHUNK, kw_only=True)
    solver: str = field(default="newton", kw_only=True)
    cvxpy_solver: str = field(default="CLARABEL", kw_only=True)
    name = "dm"  # the result's method

    def __post_init__(self) -> None:
        check_solver(self.solver, self.cvxpy_solver, "NoiseModelDM")
        if (self.sigma_tau is None) != (self.sigma_a is None):
            raise ConfigError("NoiseModelDM: give both sigma_tau and sigma_a, or neither")
        for key in ("sigma_tau", "sigma_a"):
            value = getattr(self, key)
            if value is not None:
                a = np.asarray(value, dtype=float)
                if a.ndim != 2 or a.shape[0] != a.shape[1] or not np.all(np.isfinite(a)):
                    raise ConfigError(f"NoiseModelDM: {key} must be a finite (n, n) matrix, got shape {a.shape}")
                object.__setattr__(self, key, tuple(tuple(float(x) for x in row) for row in a))

    def fit(self, problem: IdentificationProblem) -> IdentificationResult:
        t0 = time.perf_counter()
        if not self.allow_unidentifiable:
            check_identifiable(problem)
        sensor = problem.in_sensor_chart()
        # pilot, closure, levels, check and first round: a strided subsample of streamed or large data (module doc)
        sample = (sensor if isinstance(sensor, IdentificationProblem) and sensor.N <= 4 * CHECK_SAMPLES else
                  sensor.subset(strided_rows(sensor.N, CHECK_SAMPLES)))
        cons, done, whitened = self.closed_set(sample)
        theta_pilot, pilot, weighing = self._pilot(sample, cons, *whitened)
        start, paper = self._inside(theta_pilot, cons), None  # paper: the paper's optimum of every sample, once made
        try:
            budget = None if pilot == "dm-paper" else LEVELS_MAX_ITER
            theta, noise, run = self._rounds(sensor, sample, cons, start, theta_pilot, budget)
            run.update(start=pilot, pilot=pilot)
        except SolverError as first:  # unseen parameters drifting outward, or over the budget: from the paper's optimum
            try:  # instead, unless the fit started there (the same solve would fail the same way)
                if pilot == "dm-paper" and sample is sensor:
                    raise first
                paper = self._paper_optimum(sensor)  # (the early check would repeat itself)
                theta, noise, run = self._rounds(sensor, sample, cons, self._inside(paper, cons), theta_pilot,
                                                 early=False)
                run.update(start=f"dm-paper (the fit from the {pilot} pilot failed)", pilot=pilot)
            except SolverError as exc:  # no noise-model fit: the pilot's estimator, as when the check rejects it
                return self._without_noise_model(problem, sensor, sample, cons, done, start, (theta_pilot, weighing),
                                                 pilot, f"its noise-model fit did not converge ({exc.status})", t0,
                                                 paper)
        if not noise.acceleration_share > 0:  # torque noise alone: WLS (the given Σ_τ, or the pilot's residuals')
            why = ("given" if self.sigma_tau is not None else f"2 log-likelihood ratio {noise.likelihood_ratio:.3g}"
                   if np.isfinite(noise.likelihood_ratio) else "the velocities are 0: Σ_a has no shape")
            note = ""
            if self.sigma_tau is None:  # recorded: the covariance the fit used
                theta, f, run["status"], note, S = self._wls(sensor, cons, start, weighing)
                noise = replace(noise, sigma_tau=S)
            else:
                f = noise_model_objective(sensor, theta, noise.sigma_tau, noise.sigma_a, self.chunk)
            return self._result(problem, sensor, done, theta, f, noise, run, theta_pilot, None,
                                f"no acceleration noise ({why}): WLS{note}", t0,
                                extra={"covariance_matrix": np.asarray(noise.sigma_tau).tolist()})
        check, guard, why, choice = run.pop("check", None) or self._check(sample, theta, noise), {}, None, "noise model"
        if check is not None and check.rejected:
            why = (f"the residual is not the modelled noise (held-out loss {check.excess:.3g} of WLS's beyond the noise "
                   f"model's prediction, standard error {check.standard_error:.2g})")
        elif (guard := reference_guard(sensor, done(theta, {})[0], theta_pilot, f"pilot ({pilot})")).get("degenerate"):
            why = (f"its fit is degenerate against its pilot (generalised eigenvalues of M(θ̂) against M(pilot) "  # a ghost
                   f"{guard.get('metric_ratio_min', np.nan):.2g}…{guard.get('metric_ratio_max', np.nan):.3g})")
        extra = {}
        if why:
            theta, f, status, choice, extra = self._pilots_estimator(sensor, sample, cons, start,
                                                                     (theta_pilot, weighing), pilot, why, paper)
            run["status"] = status or run["status"]
        else:
            f = noise_model_objective(sensor, theta, noise.sigma_tau, noise.sigma_a, self.chunk)
        return self._result(problem, sensor, done, theta, f, noise, run, theta_pilot, check, choice, t0,
                            None if why else guard, extra)

    def closed_set(self, sample):
        """(cons closed over what f cannot see (model.closure), done completing θ, (R, r, T = ``torque_scale``))."""
        T = torque_scale(sample)
        R, r = _scaled(sample, T)  # ‖r‖² = Σ τw_iᵀτw_i: f(0) of the whitened least squares, the closure's scale
        cons, done = on_closure(feasible_set(sample.parameters, self.constrained), R.T @ R, float(r @ r),
                                sample.parameters.names, enabled=self.constrained)
        return cons, done, (R, r, T)

    def _without_noise_model(self, problem, sensor, sample, cons, done, start, pilots, pilot, why, t0, paper):
        """``_pilots_estimator`` when no noise-model fit exists (``paper``: the paper's optimum of every sample, if made);
        the result records the levels at the pilot and why."""
        theta_pilot, run = pilots[0], {"iterations": 0, "rounds": 0, "status": "optimal", "start": pilot, "pilot": pilot}
        noise = (estimate_noise(sample, theta_pilot) if self.sigma_tau is None else
                 given_levels(sample, theta_pilot, np.asarray(self.sigma_tau), np.asarray(self.sigma_a)))
        theta, f, status, choice, extra = self._pilots_estimator(sensor, sample, cons, start, pilots, pilot, why, paper)
        run["status"] = status or run["status"]
        return self._result(problem, sensor, done, theta, f, noise, run, theta_pilot, None, choice, t0, extra=extra)

    def _pilots_estimator(self, sensor, sample, cons, start, pilots, pilot, why, paper=None):
        """dm's fallback: the paper's optimum where that is the pilot, else WLS in the whitened pilot's residual covariance
        (``pilots``: the pilot's θ, the whitened pilot's). (θ, f, status (None: the pilot's), choice, extra: its weight)."""
        theta_pilot, weighing = pilots
        if pilot == "dm-paper":  # a pilot from a subsample (``fit``) is the subsample's optimum, the fallback the whole data's
            theta = theta_pilot if sample is sensor else self._paper_optimum(sensor) if paper is None else paper
            return theta, objective_value(sensor, theta, self.chunk), None, f"dm-paper: {why}", {}
        theta, f, status, note, S = self._wls(sensor, cons, start, weighing)
        return theta, f, status, f"wls: {why}{note}", {"covariance_matrix": S.tolist()}  # its weight (sensor chart)

    def _wls(self, sensor, cons, start, weighing):
        """WLS in the residual covariance at ``weighing`` (the whitened pilot), constrained, from ``start`` (or where those
        steps stall from WLS's own): (θ, f, status, a note of the exact-data floor or the other start if used, Σ̂)."""
        S, fallback = residual_covariance(sensor, weighing)
        note, levels = "" if fallback is None else f"; {fallback}", NoiseLevels(S, np.zeros_like(S), 1.0, 0.0, 0)
        try:
            theta, info = self._solve(sensor, cons, start, levels, convex_only=True)
            status = _status(info)
        except SolverError as exc:  # its steps from a start barely inside a block stalled (5 of the 10 xArm7 data sets
            # with 1 mrad of encoder noise; the general path then failed after 300 iterations): WLS's fit from its own start
            if self.solver != "newton":  # the conic reference's own failure is its caller's to see
                raise
            fit = fit_weighted(sensor, S, "wls", {"constrained": self.constrained, "solver": "newton", "solver_options":
                                                  {"tol": self.tol, "max_iter": self.max_iter, "chunk": self.chunk},
                                                  "allow_unidentifiable": True}, {})
            theta, status = np.asarray(fit.theta), fit.status
            note += f"; fitted from WLS's own start (from dm's: {exc.status})"
            note += f"; {fit.info['solver_fallback']}" if fit.info.get("solver_fallback") else ""
        f = noise_model_objective(sensor, theta, S, np.zeros_like(S), self.chunk)
        return theta, f, status, note, S

    def _inside(self, theta, cons):  # θ, or (constrained, θ not strictly inside cons) its central point: a start
        return central_point(theta, cons) if self.constrained and not cons.margin(theta) > 0 else theta

    def _rounds(self, sensor, sample, cons, theta, theta_pilot, budget=None, early: bool = True):
        """The levels / θ alternations from θ (module doc, step 3): (θ, levels, {iterations, rounds, status: ``_status``
        of the last solve}); the levels and the first round's θ from ``sample`` (``fit``: the problem, or a strided subsample);
        ``budget``: the levels-only solves' iteration limit (None: max_iter). ``early``: the check at Newton steps from
        the pilot first; a decisive rejection returns (θ as given, its levels, {…, check}) without a solve."""
        noise, run = None, {"iterations": 0, "rounds": 0, "status": "optimal"}
        fixed = self.sigma_tau is not None
        if fixed:
            noise = given_levels(sample, theta, np.asarray(self.sigma_tau), np.asarray(self.sigma_a))
        for k in range(1 if fixed else ROUNDS):
            if not fixed:
                noise = estimate_noise(sample, theta_pilot if k == 0 else theta, start=noise if k else None)
                if not noise.acceleration_share > 0:  # no acceleration noise: ``fit`` returns WLS
                    break
            last = fixed or k == ROUNDS - 1
            if early and not last and (check := self._early_check(sample, theta_pilot, noise)) is not None \
                    and check.decisive:
                run.update(check=check, rounds=1)  # clearly not the modelled noise already: ``fit`` falls back
                return theta, noise, run  # (the start: inside the constraints, where the Newton θ need not be)
            # a θ that only feeds the levels (not the last round's) from their sample
            theta, info = self._solve(sensor if last else sample, cons, theta, noise,
                                      *((None, None) if last else (LEVELS_TOL, budget)))
            run.update(iterations=run["iterations"] + info["iterations"], rounds=run["rounds"] + 1, status=_status(info))
        return theta, noise, run

    def _result(self, problem, sensor, done, theta, f, noise, run, theta_pilot, check, choice, t0, guard=None,
                extra=None):
        """The result of θ (completed by ``done``); ``guard``: θ's metric guard against the pilot, if already made;
        ``extra``: more info (the covariance of a WLS fit)."""
        theta, completed = done(theta, {})
        gaps = (np.nan,) * 3 if check is None else (check.excess, check.measured_gap, check.predicted_gap)
        record = NoiseRecord(noise.sigma_tau, noise.sigma_a, noise.torque_share, noise.acceleration_share,
                             "fixed" if self.sigma_tau is not None else "estimated", run["rounds"], np.nan, choice, *gaps)
        if guard is None:
            guard = reference_guard(sensor, theta, theta_pilot, f"pilot ({run['pilot']})")
        solver = "newton" if self.solver == "newton" else f"cvxpy-mm/{self.cvxpy_solver}"
        return IdentificationResult(self.name, theta, problem.parameters, f, run["status"], solver,
                                    time.perf_counter() - t0, run["iterations"], self.constrained,
                                    {"rounds": run["rounds"], "start": run["start"], **guard, **completed, **(extra or {})},
                                    noise=record)

    def _paper_optimum(self, problem) -> np.ndarray:
        """The paper's dual-metric optimum (the same θ in every chart); where its infimum is at infinity, where the
        solver stopped (its warning is not this fit's to raise)."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", OptimumAtInfinityWarning)
            return np.asarray(fit_dual_metric_newton(problem, constrained=self.constrained, chunk=self.chunk).theta)

    def _pilot(self, sensor, cons, R, r, T) -> tuple[np.ndarray, str, np.ndarray]:
        """(θ, its name, the whitened pilot's θ): least squares on each coordinate's own force scale, and in the weight
        T⁻¹ (T = mean τ_i τ_iᵀ; R, r), whose residual covariance only weighs the fallback. Whitening amplifies combinations in
        which the torques nearly cancel and the regressor is mostly velocity noise, where least squares attenuates
        (LandSalp's lateral wheel directions: lateral drags 0–30 % of the truth, ``dm`` 0.07 behind WLS from there).
        With a passive coordinate (τ_j ≡ 0) the paper's optimum for both: there f has several basins, and from least
        squares the Crazyflie's fit could not predict its pendulum."""
        if np.any(np.all(sensor.tau == 0, axis=0)):
            return (paper := self._paper_optimum(sensor)), "dm-paper", paper
        own = np.diag(np.diag(T))  # each coordinate's own mean τ_j²
        return (self._least_squares(sensor, cons, *_scaled(sensor, own), own), "unit-free least squares",
                self._least_squares(sensor, cons, R, r, T))

    def _least_squares(self, sensor, cons, R, r, weight) -> np.ndarray:
        """argmin ‖Rθ − r‖ (the equations whitened by ``weight``), or where some M_i(θ) is not ≻ 0 that fit constrained."""
        theta = np.linalg.lstsq(R, r, rcond=np.finfo(float).eps * max(sensor.N * sensor.n, sensor.p))[0]
        if np.isfinite(objective_value(sensor, theta, self.chunk)):
            return theta
        return self._solve(sensor, cons, central_point(theta, cons) if self.constrained else theta,
                           NoiseLevels(weight, np.zeros_like(weight), 1.0, 0.0, 0), LEVELS_TOL)[0]

    def _early_check(self, sample, theta_pilot, noise) -> NoiseCheck | None:
        """The check at CHECK_STEPS damped Newton steps of f from the pilot (unconstrained); None where they fail."""
        try:  # (``_check`` catches its own failures)
            return self._check(sample, newton_refit(sample, theta_pilot, noise.sigma_tau, noise.sigma_a, self.chunk,
                                                    CHECK_STEPS), noise)
        except (NotPositiveDefinite, np.linalg.LinAlgError):
            return None

    def _check(self, sensor, theta, noise) -> NoiseCheck | None:
        r = sensor.residual(theta)
        try:  # WLS's weight: the inverse residual covariance at θ̂ (singular: no check)
            W = np.linalg.inv(r.T @ r / sensor.N)
            return check_noise_model(sensor, theta, noise.sigma_tau, noise.sigma_a, W, self.chunk)
        except (MetricError, NotPositiveDefinite, np.linalg.LinAlgError):
            return None

    def _solve(self, problem, cons, theta, noise: NoiseLevels, tol: float | None = None, max_iter: int | None = None,
               convex_only: bool = False):
        """θ minimising f with the levels fixed, from θ, on the closed set ``cons``, to ``tol`` in at most ``max_iter``
        iterations (None: the estimator's): with Σ_a = 0 WLS's quadratic in Σ_τ⁻¹ from its sufficient statistics (one
        pass; where its steps stall, the general path, or with convex_only the SolverError); else f is not convex:
        the interior point's non-convex mode."""
        S, A = noise.sigma_tau, noise.sigma_a
        tol = self.tol if tol is None else max(tol, self.tol)
        max_iter = self.max_iter if max_iter is None else min(max_iter, self.max_iter)
        if self.solver == "cvxpy":
            return solve_noise_model_cvxpy(problem, cons, theta, S, A, tol, max_iter, self.cvxpy_solver)
        if not np.any(A):
            stats = statistics(problem, np.linalg.inv(S), self.chunk)
            objective, theta_ls = quadratic_objective(stats.H, stats.g, stats.c, problem.parameters)
            try:
                fit, info = run_quadratic(cons, theta, tol, max_iter, objective,
                                          stopping_scale(stats.c - stats.g @ theta_ls, stats.c))
                return toward_start(fit, theta, stats.H, cons, lambda th: value_or_inf(objective, th)), info
            except SolverError:  # the convex-mode steps stalled (arms near a block's boundary): the general path
                if convex_only:
                    raise

        def objective(th, order):
            return noise_model_derivatives(problem, th, S, A, order, self.chunk)

        try:
            scale = noise_model_scale(problem, theta, S, A, self.chunk)
        except NotPositiveDefinite:
            raise MetricError("dm: the noise model's covariance is not positive definite at the start") from None
        theta, _, _, info = run_interior_point(problem, cons, theta, None, None, tol, max_iter, self.chunk,
                                               False, objective=objective, f_scale=scale, convex=False,
                                               acceptable=ACCEPTABLE)
        return theta, info


def _status(info: dict) -> str:  # "optimal_inaccurate": the interior point stopped at max_iter within ACCEPTABLE
    return "optimal_inaccurate" if info.get("status") == "optimal_inaccurate" else "optimal"


def _scaled(problem, weight) -> tuple[np.ndarray, np.ndarray]:
    """(R, r): the triangular factor of [Yw τw], RᵀR = [Yw τw]ᵀ[Yw τw], split into its first p columns and its last, so
    that ‖Yw θ − τw‖² = ‖R θ − r‖² (and ‖r‖² = ‖τw‖²); Yw, τw the equations whitened by ``weight`` = L Lᵀ (Yw_i = L⁻¹Y_i,
    τw_i = L⁻¹τ_i), stacked: the pilots' least squares and the closure's statistics, by a QR over blocks of samples (the
    singular values of Yw, without a copy of Y)."""
    L, p = np.linalg.cholesky(weight), problem.p
    augmented = (np.linalg.solve(L, np.concatenate([block.Y[rows], block.tau[rows][:, :, None]], axis=2))
                 for block, rows, _ in sample_blocks(problem, CHUNK_QR))  # L⁻¹[Y_i τ_i]
    R = triangular_factor((A.reshape(-1, p + 1) for A in augmented), p + 1)
    return R[:, :p], R[:, p]


__all__ = ["NoiseModelDM"]
