"""The dense backend: the whole whitened Jacobian, QR of its column-scaled form, SVD of the triangle.

With J D⁻¹ = Q R (D the column norms: units drop out) and R = U S Vᵀ, the damped step is
Δ = −D⁻¹ V S (S² + λ)⁻¹ (QU)ᵀ e, the cofactor of the unknowns (JᵀJ)⁻¹ = D⁻¹ V S⁻² Vᵀ D⁻¹ and the hat matrix's
diagonal ‖(QU)_i‖², all from the factors: the normal matrix is never formed (its condition is the square of
J's), so a problem with cond(J) = 1e8 keeps its digits. Singular values below ``RANK_TOLERANCE`` · s_max are
dropped (a minimum-norm step in an undetermined direction; the engine then names the parameters involved).
"""

import jax.numpy as jnp

from seaice_jax.adjust.problem import Problem

RANK_TOLERANCE = 1e-12
"""Relative singular value of the column-scaled Jacobian below which a direction counts as undetermined: about
100 × the float64 roundoff of a Jacobian computed to full precision (κ > 1e12 leaves no digit in σ)."""


def columns(problem: Problem, block):
    """``(m, k + d)`` column of the dense Jacobian for each row's global unknowns then its point coordinates."""
    n = problem.start.shape[0]
    if block.point_index is None:
        return block.global_index
    d = problem.points.shape[1]
    point_columns = n + block.point_index[:, None] * d + jnp.arange(d)[None, :]
    return jnp.concatenate([block.global_index, point_columns], axis=1)


def assemble(problem: Problem, linear: dict):
    """Whitened residual vector ``(M,)`` and Jacobian ``(M, N)``, blocks in order, rows then components."""
    size = problem.unknowns
    residuals, jacobians = [], []
    for name, block in problem.blocks.items():
        lin = linear[name]
        m, c = lin.e.shape
        local = lin.theta if block.point_index is None else jnp.concatenate([lin.theta, lin.point], axis=2)
        where = columns(problem, block)
        rows = jnp.arange(m * c).reshape(m, c)
        matrix = jnp.zeros((m * c, size)).at[rows[:, :, None], where[:, None, :]].add(local)
        residuals.append(lin.e.reshape(-1))
        jacobians.append(matrix)
    return jnp.concatenate(residuals), jnp.concatenate(jacobians)


def column_norms(jacobian):
    """``(N,)`` the Euclidean norms of the Jacobian's columns (the scales D)."""
    return jnp.linalg.norm(jacobian, axis=0)


class Factors:
    """Column scales, left singular vectors ``(M, N)`` of J D⁻¹, singular values ``(N,)``, right vectors."""

    def __init__(self, jacobian, scale=None):
        scale = column_norms(jacobian) if scale is None else scale
        self.scale = jnp.where(scale > 0, scale, 1.0)
        q, r = jnp.linalg.qr(jacobian / self.scale[None, :])
        u, self.singular, self.vt = jnp.linalg.svd(r)
        self.left = q @ u
        self.kept = self.singular > RANK_TOLERANCE * self.singular[0]

    def step(self, residuals, damping):
        """Δ ``(N,)`` minimising ‖e + JΔ‖² + λ‖DΔ‖²."""
        s = self.singular
        gain = jnp.where(self.kept, s / jnp.where(self.kept, s**2 + damping, 1.0), 0.0)
        return -(self.vt.T @ (gain * (self.left.T @ residuals))) / self.scale

    def gauss_newton_decrease(self, residuals):
        """‖J Δ_GN‖²: the decrease of the square sum the undamped step predicts (e's part in J's range)."""
        return jnp.sum(jnp.where(self.kept, self.left.T @ residuals, 0.0) ** 2)

    def cofactor(self):
        """(JᵀJ)⁻¹ ``(N, N)`` (a pseudo-inverse over the kept directions)."""
        inverse = jnp.where(self.kept, 1.0 / jnp.where(self.kept, self.singular, 1.0) ** 2, 0.0)
        scaled = (self.vt.T * inverse[None, :]) @ self.vt
        return scaled / jnp.outer(self.scale, self.scale)

    def undetermined(self):
        """``(N,)`` each unknown's largest |component| in a dropped (undetermined) direction of the scaled problem:
        above 0.1, the unknown takes part in a combination the observations cannot determine."""
        return jnp.max(jnp.where(self.kept[:, None], 0.0, jnp.abs(self.vt)), axis=0)

    def hat_diagonal(self):
        """``(M,)`` diagonal of J (JᵀJ)⁻¹ Jᵀ: 1 − redundancy number."""
        return jnp.sum(jnp.where(self.kept[None, :], self.left, 0.0) ** 2, axis=1)

    def residual_correlation(self, redundancy):
        """``(max |ρ|, partner)`` ``(M,)`` each: the largest correlation of an observation's w-statistic with
        another's, and which (flat index), from the residual cofactor I − J (JᵀJ)⁻¹ Jᵀ."""
        left = jnp.where(self.kept[None, :], self.left, 0.0)
        covariance = -(left @ left.T)
        size = redundancy.shape[0]
        root = jnp.sqrt(jnp.maximum(redundancy, 1e-300))
        correlation = jnp.abs(covariance) / jnp.outer(root, root)
        controlled = redundancy > 1e-9
        correlation = jnp.where(controlled[:, None] & controlled[None, :] & ~jnp.eye(size, dtype=bool),
                                correlation, 0.0)
        return jnp.max(correlation, axis=1), jnp.argmax(correlation, axis=1)
