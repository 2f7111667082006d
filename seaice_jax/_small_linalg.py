"""Closed-form linear algebra of 2 × 2 matrices, for use under ``vmap``.

XLA's CPU runtime runs a batched LAPACK kernel (what ``jnp.linalg`` becomes under ``vmap``) in parallel on its
own thread pool; two such kernels at once on a 2-thread pool wait on each other for ever (a 100-strip radar block
hung so on a 2-core machine). The small matrices of the project's models — a point's 2 × 2 normal block, the
2 × 2 Jacobian between image and map — are inverted here elementwise instead: no LAPACK call, and faster.
"""

import jax.numpy as jnp


def inverse_2x2(matrix):
    """Inverse of ``(..., 2, 2)`` matrices (inf/NaN where singular)."""
    a, b, c, d = matrix[..., 0, 0], matrix[..., 0, 1], matrix[..., 1, 0], matrix[..., 1, 1]
    determinant = a * d - b * c
    return jnp.stack([jnp.stack([d, -b], -1), jnp.stack([-c, a], -1)], -2) / determinant[..., None, None]


def symmetric_inverse_2x2(matrix):
    """Inverse of symmetric ``(..., 2, 2)`` matrices, NaN where not positive definite (as a Cholesky factor
    would fail)."""
    a, b, c = matrix[..., 0, 0], 0.5 * (matrix[..., 0, 1] + matrix[..., 1, 0]), matrix[..., 1, 1]
    positive = (a > 0) & (a * c - b * b > 0)
    symmetric = jnp.stack([jnp.stack([a, b], -1), jnp.stack([b, c], -1)], -2)
    return jnp.where(positive[..., None, None], inverse_2x2(symmetric), jnp.nan)
