"""The WLS reference of the dual-metric fit's metric guard, solved by dualid's own interior-point method.

``DualMetric.fit`` certifies its θ̂ against a WLS fit (metric_guard.py). Through cvxpy that reference cost
more than the Newton fit itself at N = 1,000 (two conic problems compiled and solved: OLS for the residual
covariance, then WLS; 0.035 s of a 0.09 s fit on the benchmark Crazyflie, 0.12 of 0.24 s on arm7). Both are
p-sized quadratic problems on the sufficient statistics, which ``quadratic_newton.fit_quadratic_newton``
solves with the dual-metric solver's own iterations in a few milliseconds. The guard only compares
generalised eigenvalues against [1/c, c] with c = 100, so the reference need not be Clarabel's to its last
digits; it is the same convex problem (same H, g, c and constraints) solved to 1e-6 relative (TOL).
"""

from __future__ import annotations

import numpy as np

from dualid.errors import SolverError
from dualid.estimators.least_squares import WLS, residual_covariance
from dualid.estimators.quadratic_newton import fit_quadratic_newton
from dualid.estimators.statistics import statistics
from dualid.problem import IdentificationProblem

TOL = 1e-6  # relative: the guard compares eigenvalue ratios against [1/100, 100], far coarser than this …
MAX_ITER = 30  # … and a jam (rank-deficient arm7 at N = 100: stuck at a gap of 8.7e-7 after 100 iterations, 1e-6 not reached in 40)
# costs at most this many cheap iterations before cvxpy takes over


def wls_reference(problem: IdentificationProblem, constrained: bool) -> tuple[np.ndarray, str]:
    """(θ_wls, how it was solved): OLS → Σ̂ of its residuals → WLS with W = Σ̂⁻¹, both by dualid's interior-point
    method to TOL; if that fails, the cvxpy WLS estimator (recorded in the second element). Raises SolverError when
    both fail."""
    try:
        ols = statistics(problem)
        theta_ols, _ = fit_quadratic_newton(ols.H, ols.g, ols.c, problem.parameters, constrained=constrained,
                                            tol=TOL, max_iter=MAX_ITER)
        W = np.linalg.inv(residual_covariance(problem, theta_ols))
        wls = statistics(problem, 0.5 * (W + W.T))
        theta, _ = fit_quadratic_newton(wls.H, wls.g, wls.c, problem.parameters, constrained=constrained,
                                        tol=TOL, max_iter=MAX_ITER)
        return theta, f"newton (tol {TOL:g})"
    except (SolverError, np.linalg.LinAlgError) as exc:
        theta = WLS(constrained=constrained, allow_unidentifiable=True).fit(problem).theta
        return theta, f"cvxpy (dualid's interior point failed: {str(exc)[:120]})"
