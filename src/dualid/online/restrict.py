"""The identification problem in a subset of the parameters, the others held at known values.

    τ_i − Y_i,fixed θ_fixed = Y_i,free θ_free,     M_i(θ) = (M_i0 + Σ_fixed θ_k M_ik) + Σ_free θ_k M_ik

Tracking a payload or a tool means re-identifying the last link's block while the arm's other parameters stay at a
previous fit: the free block is identifiable from all joints' torques even where its mass alone is not in the full
problem (there it is regrouped into the parent links' parameters). The free set is a union of whole constraint
blocks, so the physical-consistency constraints of the free parameters are their own blocks' (``free_space``).
"""

from __future__ import annotations

import numpy as np

from dualid.errors import ModelError
from dualid.model.metric import AffineMetric, MetricTerm
from dualid.model.parameters import ParameterBlock, ParameterSpace
from dualid.problem import IdentificationProblem, owned


def free_indices(parameters: ParameterSpace, free) -> np.ndarray:
    """Sorted indices of ``free``: None (every parameter), names of blocks or parameters, or indices. Every
    constrained block is either wholly free or wholly fixed (ModelError otherwise)."""
    if free is None:
        return np.arange(parameters.p)
    block_names = {b.name: b.indices for b in parameters.blocks}
    idx: set[int] = set()
    for item in free:
        if isinstance(item, (int, np.integer)):
            idx.add(int(item))
        elif item in block_names:
            idx.update(block_names[item])
        else:
            idx.add(parameters.index(str(item)))
    out = np.array(sorted(idx), dtype=int)
    if out.size == 0 or out[0] < 0 or out[-1] >= parameters.p:
        raise ModelError(f"free parameters: expected indices in 0..{parameters.p - 1} or names, got {list(free)}")
    chosen = set(out.tolist())
    for b in parameters.blocks:
        inside = chosen.intersection(b.indices)
        if inside and len(inside) != len(b.indices):
            raise ModelError(f"free parameters: block {b.name!r} is partly free; free whole blocks")
    return out


def free_space(parameters: ParameterSpace, idx: np.ndarray) -> ParameterSpace:
    """The parameter space of θ[idx]: its names, units, bounds and the blocks inside idx (re-indexed)."""
    if len(idx) == parameters.p:
        return parameters
    where = {int(i): k for k, i in enumerate(idx)}
    blocks = tuple(ParameterBlock(b.name, b.kind, tuple(where[i] for i in b.indices))
                   for b in parameters.blocks if b.indices and b.indices[0] in where)
    names = tuple(parameters.names[i] for i in idx)
    units = tuple(parameters.units[i] for i in idx)
    lower = None if parameters.lower is None else tuple(parameters.lower[i] for i in idx)
    upper = None if parameters.upper is None else tuple(parameters.upper[i] for i in idx)
    return ParameterSpace(names, units, blocks, lower, upper)


def restrict(problem: IdentificationProblem, idx: np.ndarray, theta_fixed: np.ndarray,
             metric: bool = True) -> IdentificationProblem:
    """The problem in θ[idx], every other parameter held at theta_fixed's value (module doc). metric=False: the
    metric of the result is a placeholder (the identity), for callers that do not read it (cheaper)."""
    if len(idx) == problem.p:
        return problem
    theta_fixed = np.asarray(theta_fixed, dtype=float)
    if theta_fixed.shape != (problem.p,):
        raise ModelError(f"restrict: expected theta_fixed of shape ({problem.p},), got {theta_fixed.shape}")
    held = theta_fixed.copy()
    held[idx] = 0.0
    tau = problem.tau - problem.Y @ held
    if not metric:
        placeholder = AffineMetric(len(idx), (), np.broadcast_to(np.eye(problem.n), (problem.N, problem.n, problem.n)))
        return IdentificationProblem(owned(problem.Y[:, :, idx]), tau, placeholder, problem.v,
                                     free_space(problem.parameters, idx), problem.kind, problem.coordinates,
                                     problem.sensor_chart)
    M0 = problem.metric.evaluate(held)  # M_i0 + Σ_fixed θ_k M_ik
    where = {int(i): k for k, i in enumerate(idx)}
    terms = []
    for t in problem.metric.terms:
        keep = [k for k, i in enumerate(t.indices) if i in where]
        if keep:
            E = t.E[..., keep, :, :]
            terms.append(MetricTerm(tuple(where[t.indices[k]] for k in keep), E, t.J))
    metric = AffineMetric(len(idx), tuple(terms), M0)
    return IdentificationProblem(owned(problem.Y[:, :, idx]), tau, metric, problem.v,
                                 free_space(problem.parameters, idx), problem.kind, problem.coordinates,
                                 problem.sensor_chart)
