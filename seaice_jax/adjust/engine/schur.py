"""The Schur-complement backend: points eliminated block by block, the reduced system by Cholesky.

Normal equations of the whitened problem, split into global unknowns θ and points p (each point's ``d × d``
block V_p independent of the others):

    [N   B] [Δθ]   [−g ]        S = N − Σ_p B_p V_p⁻¹ B_pᵀ   (reduced, Cholesky-factored)
    [Bᵀ  V] [Δp] = [−g_p]       Δθ = S⁻¹ (−g + Σ_p B_p V_p⁻¹ g_p),  Δp = V_p⁻¹ (−g_p − B_pᵀ Δθ)

B_p = Σ over the rows o of point p of C_o = J_θ,oᵀ J_p,o, so every product B_p … B_pᵀ is a sum over *pairs* of
rows measuring the same point (each point is seen by a few rows: the work grows linearly with the points).
Covariance blocks come from the same factors (cho_solve, no inverse of a normal matrix):
Q_θθ = S⁻¹, Q_θp = −S⁻¹ B_p V_p⁻¹, Q_pp = V_p⁻¹ + V_p⁻¹ B_pᵀ S⁻¹ B_p V_p⁻¹, and for two points p ≠ q
Q_pq = V_p⁻¹ B_pᵀ S⁻¹ B_q V_q⁻¹. Damping (Levenberg-Marquardt) adds λ·diag to N and V.
"""

from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.linalg import cho_factor, cho_solve
from jaxtyping import Array, Float, Int

from seaice_jax._shapes import bucket, pad
from seaice_jax._small_linalg import symmetric_inverse_2x2
from seaice_jax.adjust.engine.problem import Problem


class SchurLayout(eqx.Module):
    """Host-built index tables of the rows that touch both θ and a point (the *coupling rows*).

    Attributes:
        blocks: static names of the coupling blocks, in order; k_max, c_max: static padded sizes.
        first, second: ``(r,)`` pairs of coupling rows measuring the same point (both orders, and o = o′).
        pair_weight: ``(r,)`` 1, or 0 for padding pairs.
        flat: ``(Mc,)`` flat observation index of each coupling row's component 0.
        cross_first, cross_second, cross_group: pairs of rows of two requested points p ≠ q (``cross_points``).
        cross_points: ``(R, 2)`` the requested point pairs, padded to a bucket with ``(-1, -1)``.
    """

    blocks: tuple = eqx.field(static=True)
    k_max: int = eqx.field(static=True)
    c_max: int = eqx.field(static=True)
    first: Int[Array, " r"]
    second: Int[Array, " r"]
    pair_weight: Float[Array, " r"]
    flat: Int[Array, " mc"]
    cross_first: Int[Array, " s"]
    cross_second: Int[Array, " s"]
    cross_weight: Float[Array, " s"]
    cross_group: Int[Array, " s"]
    cross_points: Int[Array, "R 2"]


def _pairs(point):
    """``(first, second)``: every ordered pair of rows of one point (a row with itself included), point by point in
    ascending order, rows in their order within the point."""
    order = np.argsort(point, kind="stable")
    ordered = point[order]
    starts = np.flatnonzero(np.r_[True, ordered[1:] != ordered[:-1]]) if point.size else np.zeros(0, int)
    counts = np.diff(np.r_[starts, point.size])
    start_of, count_of = np.repeat(starts, counts), np.repeat(counts, counts)  # per sorted row, its point's run
    within = np.arange(int(count_of.sum())) - np.repeat(np.cumsum(count_of) - count_of, count_of)
    return np.repeat(order, count_of), order[np.repeat(start_of, count_of) + within]


def _cross_pairs(point, cross_points):
    """``(s, 3)`` rows ``(o, o′, g)``: every coupling row o of point a and o′ of point b of each requested pair
    ``g = (a, b)``."""
    order = np.argsort(point, kind="stable")
    ordered = point[order]
    lo_a, hi_a = np.searchsorted(ordered, cross_points[:, 0]), np.searchsorted(ordered, cross_points[:, 0], "right")
    lo_b, hi_b = np.searchsorted(ordered, cross_points[:, 1]), np.searchsorted(ordered, cross_points[:, 1], "right")
    count_a, count_b = hi_a - lo_a, hi_b - lo_b
    group = np.repeat(np.arange(cross_points.shape[0]), count_a * count_b)
    within = np.arange(group.size) - np.repeat(np.cumsum(count_a * count_b) - count_a * count_b, count_a * count_b)
    first = order[lo_a[group] + within // np.maximum(count_b[group], 1)]
    second = order[lo_b[group] + within % np.maximum(count_b[group], 1)]
    return np.stack([first, second, group], axis=1).astype(int)


def schur_layout(problem: Problem, cross_points=None) -> SchurLayout:
    """The pair tables of ``problem`` (host side; sizes padded to buckets so similar problems share a compile)."""
    names, points, flats = [], [], []
    offset = 0
    k_max = c_max = 1
    for name, block in problem.blocks.items():
        m, c = block.sigma.shape
        if block.point_index is not None and block.global_index.shape[1] > 0:
            names.append(name)
            # padding rows (σ = inf) pair with nothing
            real = np.isfinite(np.asarray(block.sigma)).any(axis=1)
            points.append(np.where(real, np.asarray(block.point_index), -1 - np.arange(m)))
            flats.append(offset + np.arange(m) * c)
            k_max, c_max = max(k_max, block.global_index.shape[1]), max(c_max, c)
        offset += m * c
    point = np.concatenate(points) if points else np.zeros(0, int)
    first, second = _pairs(point)
    keep = point[first] >= 0
    first, second = first[keep], second[keep]
    size = bucket(first.size)
    cross_points = np.zeros((0, 2), int) if cross_points is None else np.asarray(cross_points, int).reshape(-1, 2)
    cross = _cross_pairs(point, cross_points)
    cross_size = bucket(cross.shape[0])
    # the requested pairs padded with (-1, -1) too (their blocks are computed and dropped by the engine's solve)
    requested = pad(cross_points, bucket(cross_points.shape[0]), -1)
    return SchurLayout(tuple(names), k_max, c_max, jnp.asarray(pad(first, size, 0)), jnp.asarray(pad(second, size, 0)),
                       jnp.asarray(pad(np.ones(first.size), size, 0.0)),
                       jnp.asarray(np.concatenate(flats) if flats else np.zeros(0, int)),
                       jnp.asarray(pad(cross[:, 0], cross_size, 0)), jnp.asarray(pad(cross[:, 1], cross_size, 0)),
                       jnp.asarray(pad(np.ones(cross.shape[0]), cross_size, 0.0)),
                       jnp.asarray(pad(cross[:, 2], cross_size, 0)), jnp.asarray(requested))


def _padded(array, axis, size):
    widths = [(0, 0)] * array.ndim
    widths[axis] = (0, size - array.shape[axis])
    return jnp.pad(array, widths)


@dataclass
class Coupling:
    """The coupling rows, concatenated: index ``(Mc, k)``, point ``(Mc,)``, J_θ ``(Mc, c, k)``, J_p ``(Mc, c, d)``,
    C = J_θᵀ J_p ``(Mc, k, d)`` (padded entries are zero)."""

    index: Array
    point: Array
    theta: Array
    jac_point: Array
    matrix: Array


def coupling(problem: Problem, linear: dict, layout: SchurLayout) -> Coupling:
    d = problem.points.shape[1]
    if not layout.blocks:
        zero = jnp.zeros((0, layout.c_max, layout.k_max))
        return Coupling(jnp.zeros((0, layout.k_max), int), jnp.zeros(0, int), zero,
                        jnp.zeros((0, layout.c_max, d)), jnp.zeros((0, layout.k_max, d)))
    blocks = [problem.blocks[n] for n in layout.blocks]
    index = jnp.concatenate([_padded(b.global_index, 1, layout.k_max) for b in blocks])
    point = jnp.concatenate([b.point_index for b in blocks])
    theta = jnp.concatenate([_padded(_padded(linear[n].theta, 2, layout.k_max), 1, layout.c_max)
                             for n in layout.blocks])
    jac_point = jnp.concatenate([_padded(linear[n].point, 1, layout.c_max) for n in layout.blocks])
    return Coupling(index, point, theta, jac_point, jnp.einsum("mck,mcd->mkd", theta, jac_point))


def normal_equations(problem: Problem, linear: dict):
    """``(N, g, V, g_p)``: the global normal matrix and gradient Jᵀe, the point blocks and gradients."""
    n = problem.start.shape[0]
    points, d = problem.points.shape
    normal, gradient = jnp.zeros((n, n)), jnp.zeros(n)
    point_normal, point_gradient = jnp.zeros((points, d, d)), jnp.zeros((points, d))
    for name, block in problem.blocks.items():
        lin = linear[name]
        index = block.global_index
        if index.shape[1]:
            normal = normal.at[index[:, :, None], index[:, None, :]].add(
                jnp.einsum("mck,mcl->mkl", lin.theta, lin.theta))
            gradient = gradient.at[index].add(jnp.einsum("mck,mc->mk", lin.theta, lin.e))
        if block.point_index is not None:
            point_normal = point_normal.at[block.point_index].add(jnp.einsum("mca,mcb->mab", lin.point, lin.point))
            point_gradient = point_gradient.at[block.point_index].add(jnp.einsum("mca,mc->ma", lin.point, lin.e))
    return normal, gradient, point_normal, point_gradient


def _point_inverse(point_normal, damping):
    """V_p⁻¹ of every point's (damped) ``d × d`` block ``(P, d, d)``; NaN where a block is not positive definite
    (plane points, d = 2, in closed form: :mod:`seaice_jax._small_linalg`)."""
    d = point_normal.shape[-1]
    eye = jnp.eye(d)
    diagonal = jnp.diagonal(point_normal, axis1=1, axis2=2)
    unobserved = jnp.sum(diagonal, axis=1) <= 0  # padding points: no rows, no step
    damped = point_normal + (damping * diagonal)[:, :, None] * eye[None] + unobserved[:, None, None] * eye[None]
    if d == 2:
        return symmetric_inverse_2x2(damped)
    factor = jnp.linalg.cholesky(damped)
    return jax.vmap(lambda f: cho_solve((f, True), eye))(factor)


def _reduced(normal, gradient, point_inverse, point_gradient, couple: Coupling, layout: SchurLayout, damping):
    first, second, weight = layout.first, layout.second, layout.pair_weight
    pair_point = couple.point[first]
    products = jnp.einsum("rka,rab,rlb->rkl", couple.matrix[first], point_inverse[pair_point], couple.matrix[second])
    reduced = normal + jnp.diag(damping * jnp.diagonal(normal))
    reduced = reduced.at[couple.index[first][:, :, None], couple.index[second][:, None, :]].add(
        -products * weight[:, None, None])
    right = (-gradient).at[couple.index].add(jnp.einsum("mka,mab,mb->mk", couple.matrix, point_inverse[couple.point],
                                                        point_gradient[couple.point]))
    return reduced, right


def reduced_system(problem: Problem, linear: dict, layout: SchurLayout, damping=0.0):
    """``(S, right, V⁻¹, g_p, coupling)``: the reduced system of the global unknowns and the point blocks."""
    normal, gradient, point_normal, point_gradient = normal_equations(problem, linear)
    couple = coupling(problem, linear, layout)
    point_inverse = _point_inverse(point_normal, damping)
    reduced, right = _reduced(normal, gradient, point_inverse, point_gradient, couple, layout, damping)
    return reduced, right, point_inverse, point_gradient, couple


def step(problem: Problem, linear: dict, layout: SchurLayout, damping):
    """``(Δθ, Δp)`` of the damped Gauss-Newton step (NaN where the reduced matrix is not positive definite)."""
    reduced, right, point_inverse, point_gradient, couple = reduced_system(problem, linear, layout, damping)
    step_theta = cho_solve(cho_factor(reduced), right)
    back = jnp.zeros_like(point_gradient).at[couple.point].add(
        jnp.einsum("mka,mk->ma", couple.matrix, step_theta[couple.index]))
    return step_theta, jnp.einsum("pab,pb->pa", point_inverse, -point_gradient - back)


class Cofactors(eqx.Module):
    """Cofactor blocks at the solution: Q_θθ ``(n, n)``, Q_pp ``(P, d, d)``, the Q_θp rows of each coupling row
    ``(Mc, k, d)``, the requested point-pair blocks ``(R, d, d)``."""

    theta: Float[Array, "n n"]
    point: Float[Array, "P d d"]
    theta_point: Float[Array, "mc k d"]
    cross: Float[Array, "R d d"]


def cofactors(problem: Problem, linear: dict, layout: SchurLayout):
    """:class:`Cofactors` and the coupling rows, from one Cholesky factor of the reduced matrix."""
    reduced, _, point_inverse, _, couple = reduced_system(problem, linear, layout)
    theta = cho_solve(cho_factor(reduced), jnp.eye(reduced.shape[0]))
    first, second, weight = layout.first, layout.second, layout.pair_weight
    block = theta[couple.index[first][:, :, None], couple.index[second][:, None, :]] * weight[:, None, None]
    inner = jnp.zeros_like(point_inverse).at[couple.point[first]].add(
        jnp.einsum("rka,rkl,rlb->rab", couple.matrix[first], block, couple.matrix[second]))
    point = point_inverse + point_inverse @ inner @ point_inverse
    mixed = jnp.zeros_like(couple.matrix).at[first].add(jnp.einsum("rkl,rlb->rkb", block, couple.matrix[second]))
    theta_point = -jnp.einsum("mka,mab->mkb", mixed, point_inverse[couple.point])
    cross_block = theta[couple.index[layout.cross_first][:, :, None], couple.index[layout.cross_second][:, None, :]]
    groups = layout.cross_points.shape[0]
    inner = jnp.zeros((groups,) + point_inverse.shape[1:]).at[layout.cross_group].add(
        layout.cross_weight[:, None, None] * jnp.einsum("rka,rkl,rlb->rab", couple.matrix[layout.cross_first],
                                                         cross_block, couple.matrix[layout.cross_second]))
    a, b = layout.cross_points[:, 0], layout.cross_points[:, 1]
    cross = point_inverse[a] @ inner @ jnp.swapaxes(point_inverse[b], 1, 2)
    return Cofactors(theta, point, theta_point, cross), couple


def hat_diagonals(problem: Problem, linear: dict, layout: SchurLayout, q: Cofactors) -> dict:
    """``{block: (m, c)}`` diagonal of J Q Jᵀ (1 − redundancy numbers) from the local cofactor blocks."""
    out, start = {}, 0
    for name, block in problem.blocks.items():
        lin = linear[name]
        index = block.global_index
        local_theta = q.theta[index[:, :, None], index[:, None, :]]
        hat = jnp.einsum("mck,mkl,mcl->mc", lin.theta, local_theta, lin.theta)
        if block.point_index is not None:
            hat = hat + jnp.einsum("mca,mab,mcb->mc", lin.point, q.point[block.point_index], lin.point)
        if name in layout.blocks:
            m, k = index.shape
            mixed = q.theta_point[start:start + m, :k]
            hat = hat + 2.0 * jnp.einsum("mck,mka,mca->mc", lin.theta, mixed, lin.point)
            start += m
        out[name] = hat
    return out


def residual_correlation(couple: Coupling, layout: SchurLayout, q: Cofactors, redundancy):
    """Largest |correlation| of each coupling row's w-statistics with those of another row of the same point
    ``(Mc, c)``, and that row's flat observation index, from the pair table (rows of other points are
    uncorrelated only approximately; the pairs hold the rows that can be confounded)."""
    first, second = layout.first, layout.second
    block = q.theta[couple.index[first][:, :, None], couple.index[second][:, None, :]]
    upper = jnp.concatenate([block, q.theta_point[first]], axis=2)
    lower = jnp.concatenate([jnp.swapaxes(q.theta_point[second], 1, 2), q.point[couple.point[first]]], axis=2)
    cross = jnp.concatenate([upper, lower], axis=1)
    jac_first = jnp.concatenate([couple.theta[first], couple.jac_point[first]], axis=2)
    jac_second = jnp.concatenate([couple.theta[second], couple.jac_point[second]], axis=2)
    covariance = -jnp.einsum("rau,ruv,rbv->rab", jac_first, cross, jac_second)
    root = jnp.sqrt(jnp.maximum(redundancy, 1e-300))
    correlation = jnp.abs(covariance) / (root[first][:, :, None] * root[second][:, None, :])
    usable = ((first != second) & (layout.pair_weight > 0))[:, None, None] & (
        redundancy[first] > 1e-9)[:, :, None] & (redundancy[second] > 1e-9)[:, None, :]
    correlation = jnp.where(usable, correlation, 0.0)
    best = jnp.max(correlation, axis=2)  # (r, c): over the other row's components
    which = layout.flat[second][:, None] + jnp.argmax(correlation, axis=2)
    top = jnp.zeros(redundancy.shape).at[first].max(best)
    partner = jnp.full(redundancy.shape, -1).at[first].max(jnp.where((best >= top[first]) & (best > 0), which, -1))
    return top, partner


def coupling_redundancy(problem: Problem, layout: SchurLayout, redundancy: dict):
    """The redundancy numbers of the coupling rows, concatenated and padded like :class:`Coupling` ``(Mc, c)``."""
    if not layout.blocks:
        return jnp.zeros((0, layout.c_max))
    return jnp.concatenate([_padded(redundancy[n], 1, layout.c_max) for n in layout.blocks])
