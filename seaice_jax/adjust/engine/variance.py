"""Variance components and robust reweighting, both by repeated solves of the engine with rescaled σ.

Variance components (Förstner 1979; Koch, *Parameter Estimation and Hypothesis Testing*, ch. 3.6): for each
observation group g, σ̂g² = vgᵀ Pg vg / rg with rg = Σ of the group's redundancy numbers; the group's σ are
multiplied by σ̂g and the adjustment repeated until every σ̂g² is 1 within ``tolerance`` (iterated
Förstner/Helmert: at convergence the estimates are the Helmert estimates). The component (relative to the a
priori σ) has approximately the standard deviation σ̂g² √(2/rg); the test statistic vgᵀPgvg (a priori σ) / rg is
compared with χ²(rg)/rg.

Robust reweighting (iteratively reweighted least squares): after each solve every observation's a priori σ is
divided by √f(u) with u = v/(σ0 √r) its standardized residual with the a priori σ and the current redundancy:
Huber f = min(1, c/|u|) (c = 1.5 by default), Danish f = 1 for |u| ≤ c else exp(1 − (u/c)²) (Krarup; c = 2.5).
A blunder's weight falls towards 0, its redundancy towards 1, and its |u| stays large. The w-tests of the result
are those of the final weights.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax.scipy.stats import chi2

from seaice_jax.adjust.engine import gauss_newton
from seaice_jax.adjust.engine.problem import Problem
from seaice_jax.errors import SeaiceError

ROBUST = {"huber": 1.5, "danish": 2.5}
"""Robust weight functions and their default tuning constants c (in σ of the standardized residual)."""


class VarianceComponent(eqx.Module):
    """One group's estimated variance factor (relative to its a priori σ²).

    Attributes:
        value: σ̂g². sigma: its approximate σ, σ̂g² √(2/rg). redundancy: rg. p_value: two-sided χ² test of
            σ̂g² = 1 (the a priori σ of the group are right).
    """

    value: float
    sigma: float
    redundancy: float
    p_value: float


def _groups(problem: Problem, split_components):
    """``[(block, component or None)]``: one group per block, or per component for blocks in ``split_components``."""
    return [(name, c) for name, block in problem.blocks.items()
            for c in (range(block.components) if name in split_components else [None])]


def _sums(adjustment: gauss_newton.Adjustment, problem: Problem, group):
    name, component = group
    sigma = problem.blocks[name].sigma
    whitened = jnp.where(jnp.isfinite(sigma), adjustment.residuals[name] / jnp.where(jnp.isfinite(sigma), sigma, 1.0),
                         0.0)
    redundancy = adjustment.redundancy[name]
    if component is not None:
        whitened, redundancy = whitened[:, component], redundancy[:, component]
    return float(jnp.sum(whitened**2)), float(jnp.sum(redundancy))


def variance_components(problem: Problem, options=None, names=(), groups=None, split_components=(), pooled=(),
                        tolerance: float = 1e-3, max_rounds: int = 20, **solve_options):
    """Iterated Förstner/Helmert variance-component estimation.

    Args:
        groups: block names (or ``(block, component)``) whose variance factors are estimated; default every group
            with a redundancy ≥ 1; the others (e.g. priors) keep their σ.
        split_components: blocks estimated per component (e.g. an image's along-track and range coordinates).
        pooled: tuples of block names (not split) that share one factor, σ̂² = Σ vᵀPv / Σ r over the blocks. Groups
            whose observations only ever meet in differences (each tie of a two-image sequence has one
            observation in each image) determine the sum of their variances but not its split: estimated
            separately, the split drifts round after round towards one factor 0 and never settles.

    Returns:
        The final :class:`~seaice_jax.adjust.engine.Adjustment` (σ of the estimated groups rescaled) with
        ``variance_components = {group label: VarianceComponent}`` (label ``"block"`` or ``"block[c]"``; pooled
        blocks: their names joined by ``"+"``).
    """
    candidates = _groups(problem, split_components)
    for pool in pooled:
        bad = [n for n in pool if n not in problem.blocks or n in split_components]
        if bad:
            raise SeaiceError(f"pooled: {', '.join(map(repr, bad))} not an unsplit block of the problem")
    shared = sorted({n for pool in pooled for n in pool if sum(n in other for other in pooled) > 1})
    if shared:
        raise SeaiceError(f"pooled: {', '.join(map(repr, shared))} in more than one pool (one factor per block)")
    factors = {g: 1.0 for g in candidates}
    first = result = gauss_newton.solve(problem, options, names, throw=False, **solve_options)
    chosen = [g for g in candidates if (groups is None and _sums(first, problem, g)[1] >= 1.0)
              or (groups is not None and (g[0] in groups or g in groups))]
    units = [unit for pool in pooled if (unit := [g for g in chosen if g[0] in pool])]
    units += [[g] for g in chosen if not any(g in unit for unit in units)]
    for _ in range(max_rounds):
        scaled = gauss_newton.rescaled(problem, _scale_arrays(problem, factors), result)
        result = gauss_newton.solve(scaled, options, names, throw=False, **solve_options)
        change = 0.0
        for unit in units:
            square, redundancy = np.sum([_sums(result, scaled, g) for g in unit], axis=0)
            ratio = square / redundancy if redundancy > 0 else 1.0
            for g in unit:
                factors[g] *= np.sqrt(ratio)
            change = max(change, abs(ratio - 1.0))
        if change < tolerance:
            break
    else:
        raise SeaiceError(f"variance components did not settle in {max_rounds} rounds (largest change of a factor "
                          f"{change:.2g}); a group may have too little redundancy, or groups that only meet in "
                          f"differences may need pooling")
    out = {}
    for unit in units:
        value = factors[unit[0]] ** 2
        redundancy = float(np.sum([_sums(result, scaled, g)[1] for g in unit]))
        statistic = value * redundancy
        lower = float(chi2.cdf(statistic, redundancy))
        label = "+".join(g[0] if g[1] is None else f"{g[0]}[{g[1]}]" for g in unit)
        out[label] = VarianceComponent(value, value * np.sqrt(2.0 / max(redundancy, 1e-12)), redundancy,
                                       2.0 * min(lower, 1.0 - lower))
    return eqx.tree_at(lambda r: r.variance_components, result, out, is_leaf=lambda x: x is None)


def _scale_arrays(problem: Problem, factors):
    scale = {name: jnp.ones_like(block.sigma) for name, block in problem.blocks.items()}
    for (name, component), factor in factors.items():
        if component is None:
            scale[name] = scale[name] * factor
        else:
            scale[name] = scale[name].at[:, component].multiply(factor)
    return scale


def robust_weights(standardized, kind: str, constant: float | None = None):
    """Weight factors f(u) ∈ (0, 1] of standardized residuals ``u`` (any shape)."""
    if kind not in ROBUST:
        raise SeaiceError(f"robust must be one of {', '.join(ROBUST)}, got {kind!r}")
    c = ROBUST[kind] if constant is None else constant
    u = jnp.abs(standardized)
    if kind == "huber":
        return jnp.minimum(1.0, c / jnp.maximum(u, 1e-300))
    return jnp.where(u <= c, 1.0, jnp.exp(1.0 - (u / c) ** 2))


def robust_adjustment(problem: Problem, kind: str = "danish", options=None, names=(), groups=None,
                      constant: float | None = None, tolerance: float = 1e-3, max_rounds: int = 30,
                      **solve_options):
    """Iteratively reweighted adjustment; ``groups``: the blocks reweighted (default all but ``"prior"``).

    Returns:
        The final :class:`~seaice_jax.adjust.engine.Adjustment` (w-tests with the final weights) with
        ``robust_weights = {block: (m, c) factors}``.
    """
    groups = [n for n in problem.blocks if n != "prior"] if groups is None else list(groups)
    weights = {n: jnp.ones_like(problem.blocks[n].sigma) for n in groups}
    result = gauss_newton.solve(problem, options, names, throw=False, **solve_options)
    for _ in range(max_rounds):
        new = {}
        for n in groups:
            sigma = problem.blocks[n].sigma
            finite = jnp.isfinite(sigma)
            whitened = jnp.where(finite, result.residuals[n] / jnp.where(finite, sigma, 1.0), 0.0)
            redundancy = result.redundancy[n]
            # standardized with the a priori σ and the current redundancy (a down-weighted blunder keeps its |u|)
            u = jnp.where(redundancy > 1e-9, whitened / jnp.sqrt(jnp.maximum(redundancy, 1e-300)), 0.0)
            new[n] = robust_weights(u, kind, constant)
        change = max(float(jnp.max(jnp.abs(new[n] - weights[n]))) for n in groups)
        weights = new
        scaled = gauss_newton.rescaled(problem, {n: 1.0 / jnp.sqrt(w) for n, w in weights.items()}, result)
        result = gauss_newton.solve(scaled, options, names, throw=False, **solve_options)
        if change < tolerance:
            break
    return eqx.tree_at(lambda r: r.robust_weights, result, weights, is_leaf=lambda x: x is None)
