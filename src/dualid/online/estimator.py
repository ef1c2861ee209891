"""Recursive identification: θ updated with every batch of samples, from forgotten sufficient statistics.

The fit keeps the statistics of Σ_i w_i r_iᵀ W_i r_i over the samples seen (r_i = Y_i θ − τ_i, in the free
parameters of ``restrict``):

    H = Σ w_i Y_iᵀ W_i Y_i,   g = Σ w_i Y_iᵀ W_i τ_i,   c = Σ w_i τ_iᵀ W_i τ_i,   N_eff = Σ w_i

with exponential forgetting (w_i = λ^(age of sample i), λ = 1 − 1/T for a time constant of T samples) or a sliding
window (the last batches holding ``window`` samples, each batch's statistics subtracted when it leaves). A batch of
B samples costs O(B n p²) for the statistics and one p×p Cholesky solve (p³/3) for the unconstrained estimate

    θ̂ = θ₀ + (H + ρ I)⁻¹ (g − H θ₀)        (ρ = ridge · mean diag H toward the start θ₀; ρ = 0: least squares),

i.e. O(n p²) per sample once B ≥ p / (3n). Every ``project_every`` samples the physically consistent estimate is the
minimiser of the same quadratic over the feasible set (pseudo-inertia ⪰ 0, …): the unconstrained estimate itself
where it is strictly consistent, else dualid's interior point on the statistics (``estimators.quadratic_newton``);
between projections the unconstrained θ̂ is the fast estimate and the consistent one is held.

Weights W_i: ``"ols"`` the identity; ``"wls"`` a given covariance's inverse, or the inverse of the running innovation
covariance Ŝ of the change detector, frozen for each batch (the identity until Ŝ exists); ``"dm"`` the noise model of
``estimators.noise_dm``, C_i(θ) = Σ_τ + M_i(θ) Σ_a M_i(θ), with θ **frozen at the latest consistent estimate (θ₀
before the first projection) for each batch**: the batch fit minimises Σ r_iᵀ C_i(θ)⁻¹ r_i with C depending on θ; here each batch is weighted with C_i at the
estimate before it and never re-weighted (iteratively reweighted recursive least squares). The ∂C/∂θ term of the
batch fit and the re-weighting of old samples at the final θ are both left out; the cost of that approximation is
measured in docs/online.md. Σ_τ and Σ_a are given ((n, n), the sensor chart of the forces).

Change detection: ``detector.ChiSquareDetector`` on the innovations of each batch before it updates the fit (with
``"dm"`` whitened by C_i, whose variation with the configuration would otherwise fatten the χ² tail); at the
start of an alarm event the memory is cut to ``reset_samples`` effective samples (the statistics scaled down), so
the fit re-converges on the data after the change at the speed of a fresh fit; no second cut follows within one
memory length (the time constant or the window) of the last.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from dualid.errors import ConfigError, DataError, SolverError
from dualid.estimators.quadratic_newton import fit_quadratic_newton
from dualid.linalg import solve_psd
from dualid.model.base import Model
from dualid.model.consistency import feasible_set
from dualid.model.metric import AffineMetric
from dualid.model.parameters import ParameterSpace
from dualid.online.detector import ChiSquareDetector
from dualid.online.restrict import free_indices, free_space, restrict
from dualid.problem import IdentificationProblem, owned

WEIGHTS = ("ols", "wls", "dm")


@dataclass(frozen=True)
class Step:
    """What one batch did: the samples seen after it, the estimates (full θ), the detector's windows."""

    samples: int
    theta: np.ndarray  # (p,) unconstrained recursive estimate
    consistent: np.ndarray | None  # (p,) latest projection, None before the first
    projected: bool  # a projection ran in this batch
    windows: tuple[tuple[int, float, bool], ...]  # (sample index, z, new alarm event) per tested window
    reset: bool  # the memory was cut in this batch


class RecursiveFit:
    """Online least squares with forgetting or a window, a consistent projection and a change detector (module doc).

    parameters, theta0: the parameter space and the start (also the value of every parameter not in ``free``, and
    the ridge's centre); model: builds each batch's regressor and metric in ``update`` (``update_problem`` takes a
    built problem instead). forgetting: λ in (0, 1] per sample, or time_constant T in samples (λ = 1 − 1/T);
    window: samples in a sliding window (whole batches; exclusive with forgetting < 1).
    """

    def __init__(self, parameters: ParameterSpace, theta0, *, model: Model | None = None, free=None,
                 forgetting: float = 1.0, time_constant: float | None = None, window: int | None = None,
                 weight: str = "ols", covariance=None, sigma_tau=None, sigma_a=None, project_every: int = 0,
                 ridge: float = 0.0, detector: ChiSquareDetector | None = None, reset_on_alarm: bool = True,
                 reset_samples: float = 200.0, projection_tol: float = 1e-9):
        self.parameters, self.model = parameters, model
        self.theta0 = np.asarray(theta0, dtype=float).copy()
        if self.theta0.shape != (parameters.p,):
            raise ConfigError(f"RecursiveFit: theta0 has shape {self.theta0.shape}, expected ({parameters.p},)")
        self.idx = free_indices(parameters, free)
        self.space = free_space(parameters, self.idx)
        self._feasible = feasible_set(self.space)
        self.lam = _forgetting(forgetting, time_constant, window)
        self.window = window
        if weight not in WEIGHTS:
            raise ConfigError(f"RecursiveFit: weight must be one of {WEIGHTS}, got {weight!r}")
        self.weight = weight
        n = len(model.coordinates) if model is not None else None
        self.W = None if covariance is None else np.linalg.inv(_spd(covariance, "covariance"))
        self.sigma = None
        if weight == "dm":
            if sigma_tau is None or sigma_a is None:
                raise ConfigError("RecursiveFit: weight 'dm' needs the noise levels sigma_tau and sigma_a ((n, n))")
            self.sigma = (_spd(sigma_tau, "sigma_tau"), np.asarray(sigma_a, dtype=float))
            n = self.sigma[0].shape[0]
        self.project_every, self.ridge, self.projection_tol = int(project_every), float(ridge), float(projection_tol)
        self.detector, self._n = detector, n
        self.reset_on_alarm, self.reset_samples = reset_on_alarm, float(reset_samples)
        # no second cut within one memory length of the last: the data after a cut re-converge the fit, and their
        # larger innovations (a short memory) would otherwise alarm and cut again
        self.refractory = window if window is not None else (1.0 / (1.0 - self.lam) if self.lam < 1.0 else 0.0)
        self._last_reset = -np.inf
        pf = len(self.idx)
        self.H, self.g, self.c, self.count = np.zeros((pf, pf)), np.zeros(pf), 0.0, 0.0
        self._batches: deque = deque()
        self._free = self.theta0[self.idx].copy()
        self._consistent: np.ndarray | None = None
        self.samples, self._since_projection, self.projections, self.projection_failures = 0, 0, 0, 0
        self.projection_seconds: list[float] = []  # wall time of every projection
        self.projections_interior = 0  # projections that found the unconstrained estimate strictly consistent

    # --- estimates ------------------------------------------------------------------------------
    @property
    def theta(self) -> np.ndarray:
        """(p,) the unconstrained recursive estimate (θ₀ where the data have not arrived yet)."""
        return self._full(self._free)

    @property
    def consistent(self) -> np.ndarray | None:
        """(p,) the latest physically consistent estimate, None before the first projection."""
        return None if self._consistent is None else self._full(self._consistent)

    def _full(self, free: np.ndarray) -> np.ndarray:
        out = self.theta0.copy()
        out[self.idx] = free
        return out

    # --- updates --------------------------------------------------------------------------------
    def update(self, q, v, a, tau) -> Step:
        """One batch of raw samples (q (B, nq), v, a, τ (B, n)): its regressor and metric by the model."""
        if self.model is None:
            raise ConfigError("RecursiveFit.update needs a model; give one, or call update_problem")
        q, v, tau = (np.atleast_2d(np.asarray(x, dtype=float)) for x in (q, v, tau))
        a = None if a is None else np.atleast_2d(np.asarray(a, dtype=float))
        if self.model.kind == "inertia" and a is None:
            raise DataError("RecursiveFit.update: an inertia-dominated model needs accelerations")
        metric = self.model.metric(q) if self.weight == "dm" else _no_metric(len(q), tau.shape[1], self.parameters.p)
        block = IdentificationProblem(owned(self.model.regressor(q, v, a)), tau, metric, v, self.parameters,
                                      self.model.kind, tuple(self.model.coordinates))
        return self.update_problem(block)

    def update_problem(self, block: IdentificationProblem) -> Step:
        """One batch given as a problem in the full parameters (its samples in time order)."""
        sub = restrict(block, self.idx, self.theta0, metric=False)
        A, t = self._whitened(sub, block)
        windows, reset = (), False
        if self.detector is not None:  # dm: innovations whitened by C_i (their modelled covariance varies with q)
            r = t - A @ self._free if self.weight == "dm" else sub.tau - sub.Y @ self._free
            windows = tuple(self.detector.push(r))
            if self.reset_on_alarm and any(w[2] for w in windows) and self.samples >= self._last_reset + self.refractory:
                self.reset(self.reset_samples)
                self._last_reset, reset = self.samples, True
        B = len(t)
        w = np.sqrt(self.lam ** np.arange(B - 1, -1, -1.0))  # sample weights: λ^(age) within the batch
        A, t = A * w[:, None, None], t * w[:, None]
        Af, tf = A.reshape(-1, A.shape[2]), t.reshape(-1)
        terms = (Af.T @ Af, Af.T @ tf, float(tf @ tf), float(np.sum(w * w)))
        self._accumulate(terms, self.lam ** B)
        self.samples += B
        self._free = self._solve()
        self._since_projection += B
        projected = False
        if self.project_every and self._since_projection >= self.project_every:
            projected = self.project()
        return Step(self.samples, self.theta, self.consistent, projected, windows, reset)

    def _whitened(self, sub: IdentificationProblem, block: IdentificationProblem) -> tuple[np.ndarray, np.ndarray]:
        """(L_i⁻¹ Y_i, L_i⁻¹ τ_i) of sub (block restricted) with W_i = L_i⁻ᵀ L_i⁻¹ the batch's frozen weight."""
        Y, tau = sub.Y, sub.tau
        if self.weight == "ols":
            return Y, tau
        if self.weight == "wls":
            W = self.W
            if W is None and self.detector is not None and self.detector.S is not None:
                W = np.linalg.inv(self.detector.S)
            if W is None:
                return Y, tau
            F = np.linalg.cholesky(0.5 * (W + W.T))  # W = F Fᵀ: r ᵀ W r = ‖Fᵀ r‖²
            return np.matmul(F.T, Y), tau @ F
        sigma_tau, sigma_a = self.sigma
        at = self._consistent if self._consistent is not None else self.theta0[self.idx]
        M = block.metric.evaluate(self._full(at))
        C = sigma_tau + M @ sigma_a @ M
        L = np.linalg.cholesky(0.5 * (C + np.swapaxes(C, 1, 2)))
        return np.linalg.solve(L, Y), np.linalg.solve(L, tau[..., None])[..., 0]

    def _accumulate(self, terms, decay: float) -> None:
        H, g, c, count = terms
        if self.window is None:
            self.H, self.g = decay * self.H + H, decay * self.g + g
            self.c, self.count = decay * self.c + c, decay * self.count + count
            return
        self._batches.append(terms)
        self.H, self.g, self.c, self.count = self.H + H, self.g + g, self.c + c, self.count + count
        while self.count - self._batches[0][3] >= self.window - 1e-9 and len(self._batches) > 1:
            oH, og, oc, on = self._batches.popleft()
            self.H, self.g, self.c, self.count = self.H - oH, self.g - og, self.c - oc, self.count - on
        if len(self._batches) % 256 == 0:  # re-sum now and then: subtraction accumulates rounding
            self.H, self.g = sum(b[0] for b in self._batches), sum(b[1] for b in self._batches)
            self.c, self.count = sum(b[2] for b in self._batches), sum(b[3] for b in self._batches)

    def _ridged(self) -> tuple[np.ndarray, np.ndarray, float]:
        """(H + ρI, g + ρθ₀, c + ρ‖θ₀‖²): the statistics with the ridge toward θ₀."""
        rho = self.ridge * float(np.mean(np.diag(self.H))) if self.ridge else 0.0
        t0 = self.theta0[self.idx]
        return self.H + rho * np.eye(len(t0)), self.g + rho * t0, self.c + rho * float(t0 @ t0)

    def _solve(self) -> np.ndarray:
        H, g, _ = self._ridged()
        t0 = self.theta0[self.idx]
        rhs = g - H @ t0
        try:
            return t0 + cho_solve(cho_factor(H), rhs)
        except (np.linalg.LinAlgError, ValueError):  # not yet identifiable: the least-norm step from θ₀
            return t0 + solve_psd(H, rhs) if np.any(H) else t0

    def project(self) -> bool:
        """The consistent estimate from the current statistics now (module doc); False when the
        solver fails (the previous one is kept and ``projection_failures`` counts it)."""
        self._since_projection = 0
        if self.count == 0:
            return False
        t0 = time.perf_counter()
        if self._feasible.margin(self._free) > 0:  # strictly consistent: it is the constrained minimiser (convex)
            self._consistent = self._free.copy()
            self.projection_seconds.append(time.perf_counter() - t0)
            self.projections_interior += 1
            self.projections += 1
            return True
        H, g, c = self._ridged()
        try:
            # a cold start from the unconstrained minimiser: warm starts at the previous projection (on the boundary
            # of the feasible set) took a median 44 interior-point iterations on benchmarks/online_payload.py, cold 11
            theta, _ = fit_quadratic_newton(H, g, c, self.space, constrained=True, tol=self.projection_tol)
        except SolverError:
            self.projection_failures += 1
            return False
        finally:
            self.projection_seconds.append(time.perf_counter() - t0)
        self._consistent = theta
        self.projections += 1
        return True

    def reset(self, samples: float) -> None:
        """Cut the memory to ``samples`` effective samples (every statistic scaled by samples / N_eff)."""
        s = min(1.0, float(samples) / self.count) if self.count > 0 else 1.0
        self.H, self.g, self.c, self.count = s * self.H, s * self.g, s * self.c, s * self.count
        self._batches = deque(tuple(s * x for x in b) for b in self._batches)


def _forgetting(forgetting: float, time_constant: float | None, window: int | None) -> float:
    lam = float(forgetting) if time_constant is None else 1.0 - 1.0 / float(time_constant)
    if time_constant is not None and not float(time_constant) >= 1.0:
        raise ConfigError(f"RecursiveFit: time_constant must be ≥ 1 sample, got {time_constant!r}")
    if not 0.0 < lam <= 1.0:
        raise ConfigError(f"RecursiveFit: forgetting must be in (0, 1], got {forgetting!r}")
    if window is not None and (lam < 1.0 or not (isinstance(window, (int, np.integer)) and window >= 1)):
        raise ConfigError(f"RecursiveFit: window must be a positive integer and excludes forgetting, got {window!r}")
    return lam


def _spd(x, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.ndim != 2 or a.shape[0] != a.shape[1] or not np.all(np.isfinite(a)):
        raise ConfigError(f"RecursiveFit: {name} must be a finite (n, n) matrix, got shape {a.shape}")
    try:
        np.linalg.cholesky(0.5 * (a + a.T))
    except np.linalg.LinAlgError:
        raise ConfigError(f"RecursiveFit: {name} must be positive definite") from None
    return 0.5 * (a + a.T)


def _no_metric(N: int, n: int, p: int):
    """A placeholder metric (the identity) for the weights that do not read M_i."""
    return AffineMetric(p, (), np.broadcast_to(np.eye(n), (N, n, n)))
