"""An adjustment problem declared as residual blocks over variable groups, and its linearization.

Unknowns come in two kinds: a vector θ of *global* unknowns (per image, per strip, calibration constants: every
name in ``names``) and an optional table of *points*, ``(P, d)`` (ground positions), each touched by few
observations, which the Schur-complement backend eliminates point by point.

A :class:`ResidualBlock` is one observation group: ``m`` rows of ``c`` components, row ``i`` touching the
global unknowns ``θ[global_index[i]]`` and (if the block has ``point_index``) point ``point_index[i]``. Its
``function(theta_k, point_d, row) -> (c,)`` returns computed − observed, in observation units; ``row`` is the
block's ``data`` sliced at ``i``. The engine whitens by ``sigma`` (``inf`` marks padding rows: weight 0) and
takes the Jacobians per row by ``vmap(jacfwd)``: no Python loop over observations.
"""

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int, PyTree


class ResidualBlock(eqx.Module):
    """One observation group of ``m`` rows and ``c`` components.

    Attributes:
        function: ``function(theta_k (k,), point (d,) or (0,), row) -> (c,)`` computed − observed
            (observation units); pure JAX.
        data: pytree of arrays with leading axis ``m`` (whatever the function needs per row; observed values).
        sigma: ``(m, c)`` a priori standard deviations (``inf`` for padding rows).
        global_index: ``(m, k)`` indices into θ of the global unknowns each row touches (``k`` may be 0).
        point_index: ``(m,)`` the point each row touches, or ``None``.
    """

    function: Callable = eqx.field(static=True)
    data: PyTree
    sigma: Float[Array, "m c"]
    global_index: Int[Array, "m k"]
    point_index: Int[Array, " m"] | None = None

    @property
    def rows(self) -> int:
        return self.sigma.shape[0]

    @property
    def components(self) -> int:
        return self.sigma.shape[1]


class Problem(eqx.Module):
    """Residual blocks over the global unknowns θ and the points.

    Attributes:
        blocks: ``{group name: ResidualBlock}`` (the names key the results).
        start: ``(n,)`` initial θ.
        points: ``(P, d)`` initial points (``(0, 0)`` when there are none).
    """

    blocks: dict
    start: Float[Array, " n"]
    points: Float[Array, "P d"]

    def __init__(self, blocks, start, points=None):
        self.blocks = dict(sorted(blocks.items()))  # the order of the flat observation index (and of jit)
        self.start = jnp.asarray(start, float)
        self.points = jnp.zeros((0, 0)) if points is None else jnp.asarray(points, float)

    @property
    def unknowns(self) -> int:
        return int(self.start.shape[0]) + int(np.prod(self.points.shape))


class Linearization(eqx.Module):
    """Whitened residuals and Jacobians of one block: ``e (m, c)``, ``theta (m, c, k)``, ``point (m, c, d)``."""

    e: Float[Array, "m c"]
    theta: Float[Array, "m c k"]
    point: Float[Array, "m c d"]


def weights(block: ResidualBlock):
    """``(m, c)`` 1/σ (0 for padding rows, σ = inf)."""
    return jnp.where(jnp.isfinite(block.sigma), 1.0 / block.sigma, 0.0)


def _row_points(block: ResidualBlock, points):
    if block.point_index is None:
        return jnp.zeros((block.rows, 0))
    return points[block.point_index]


def block_residuals(block: ResidualBlock, theta, points):
    """``(m, c)`` whitened residuals (computed − observed)/σ of one block."""
    values = jax.vmap(block.function)(theta[block.global_index], _row_points(block, points), block.data)
    return values * weights(block)


def linearize(block: ResidualBlock, theta, points) -> Linearization:
    """Whitened residuals and their Jacobians per row (``vmap(jacfwd)``)."""

    def value_and_jacobian(t, p, row):
        return block.function(t, p, row), jax.jacfwd(block.function, argnums=(0, 1))(t, p, row)

    values, (j_theta, j_point) = jax.vmap(value_and_jacobian)(theta[block.global_index], _row_points(block, points),
                                                               block.data)
    weight = weights(block)
    return Linearization(values * weight, j_theta * weight[..., None], j_point * weight[..., None])


def unlinearized(problem: Problem) -> dict:
    """Zero linearizations of the shapes :func:`linearize_all` returns (a loop's state before its first
    linearization)."""
    width = problem.points.shape[1]
    return {name: Linearization(jnp.zeros(b.sigma.shape), jnp.zeros(b.sigma.shape + b.global_index.shape[1:]),
                                jnp.zeros(b.sigma.shape + (width if b.point_index is not None else 0,)))
            for name, b in problem.blocks.items()}


def linearize_all(problem: Problem, theta, points) -> dict:
    return {name: linearize(block, theta, points) for name, block in problem.blocks.items()}


def square_sum(problem: Problem, theta, points):
    """Σ of the squared whitened residuals (NaN if any is NaN)."""
    return sum(jnp.sum(block_residuals(b, theta, points) ** 2) for b in problem.blocks.values())


def predicted_decrease(problem: Problem, linear: dict, step_theta, step_points):
    """−(2 eᵀJΔ + ‖JΔ‖²): the decrease of the square sum the linearized model predicts for the step (formed
    without subtracting two square sums, so it keeps its digits when it is 1e-20 of them)."""
    total = 0.0
    for name, block in problem.blocks.items():
        lin = linear[name]
        change = jnp.einsum("mck,mk->mc", lin.theta, step_theta[block.global_index])
        if block.point_index is not None:
            change = change + jnp.einsum("mcd,md->mc", lin.point, step_points[block.point_index])
        total = total - jnp.sum(change * (2.0 * lin.e + change))
    return total


def observation_count(problem: Problem) -> int:
    """Number of real (non-padding) scalar observations."""
    return int(sum(int(np.sum(np.isfinite(np.asarray(b.sigma)))) for b in problem.blocks.values()))
