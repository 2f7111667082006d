"""Shared test tools: central finite differences as the independent check of autodiff Jacobians; a tie table; a
vmapped batch of orbit fits."""

import jax
import jax.numpy as jnp
import numpy as np

from seaice_jax.adjust.engine.problem import block_residuals, linearize
from seaice_jax.imagery.ties import TiePoints


def central_difference_jacobian(function, x, relative_step=1e-6, absolute_step=1e-9, steps=None):
    """Jacobian of ``function`` (R^n -> R^m, numpy in/out) at ``x`` by central differences, shape (m, n).

    ``steps`` (n,) overrides the step per variable (needed where outputs of ~6e6 m meet inputs of ~10 m/s).
    """
    x = np.asarray(x, float)
    columns = []
    for j in range(x.size):
        h = max(abs(x[j]) * relative_step, absolute_step) if steps is None else steps[j]
        plus, minus = x.copy(), x.copy()
        plus[j] += h
        minus[j] -= h
        columns.append((np.asarray(function(plus)) - np.asarray(function(minus))) / (2 * h))
    return np.stack(columns, axis=-1)


def assert_jacobian_matches(function, x, rtol=1e-6, atol_scale=1e-9, **steps):
    """``jax.jacfwd`` and ``jax.jacrev`` of ``function`` agree with central differences to ``rtol`` relative.

    The absolute tolerance is ``atol_scale`` times the largest Jacobian entry (zero entries have no relative
    error to speak of).
    """
    x = np.asarray(x, float)
    compiled = jax.jit(function)  # one program, not one per operation (each would compile on its own)
    numeric = central_difference_jacobian(lambda v: np.asarray(compiled(v)), x, **steps)
    forward = np.asarray(jax.jit(jax.jacfwd(function))(x))
    reverse = np.asarray(jax.jit(jax.jacrev(function))(x))
    atol = atol_scale * np.max(np.abs(numeric))
    np.testing.assert_allclose(forward, numeric, rtol=rtol, atol=atol)
    np.testing.assert_allclose(reverse, forward, rtol=1e-12, atol=1e-12 * np.max(np.abs(forward)))


FIT_LANES = 40
"""Realizations per call of :func:`vmapped_fits` in the tests: batches of one control layout and this many lanes share
one compiled program across test files (the session's persistent compilation cache serves the other processes)."""


@jax.jit
def vmapped_fits(solver, args, lats, lons):
    """An orbit solver (:func:`~seaice_jax.adjust.orbit.fit.orbit_solver`) vmapped over realizations ``(runs, n)`` of
    the known latitudes and longitudes (compiled once per solver structure and number of realizations)."""
    return jax.vmap(lambda a, b: solver({"latitude": a, "longitude": b}, args))(lats, lons)


def lattice_ties(models, latitude, longitude, size, sigma_pixel, sigma_scan):
    """Exact tie observations of ground points ``(n,)`` radians in every image of ``models`` (size x size) that
    sees them, kept where two or more images do: a :class:`~seaice_jax.imagery.ties.TiePoints` table with the
    given pointing σ (pixels)."""
    rows = []
    for i, model in enumerate(models):
        pixel, scan = (np.asarray(a) for a in model.inverse(latitude, longitude))
        inside = (pixel > 1) & (pixel < size) & (scan > 1) & (scan < size)
        rows += [(i, t, pixel[t], scan[t]) for t in np.nonzero(inside)[0]]
    table = np.array(rows)
    counts = np.bincount(table[:, 1].astype(int), minlength=latitude.size)
    table = table[counts[table[:, 1].astype(int)] >= 2]
    kept, tie = np.unique(table[:, 1].astype(int), return_inverse=True)
    ones = np.ones(len(table))
    return TiePoints.measured(table[:, 0].astype(int), tie, table[:, 2], table[:, 3], sigma_pixel * ones,
                              sigma_scan * ones, latitude[kept], longitude[kept])


def sequence_rows(block):
    """``(images (m,), ties (m,) or None)`` of the rows of a sequence's residual block (image ``i``'s unknowns are
    θ_flat[5 i: 5 i + 5]; tie ``t`` is point ``t``)."""
    images = np.asarray(block.global_index)[:, 0] // block.global_index.shape[1]
    return images, None if block.point_index is None else np.asarray(block.point_index)


def whitened(block, theta, points):
    """``(m, c)`` whitened residuals of a sequence's block at θ ``(n_images, 5)`` and points ``(n_ties, 2)``."""
    return np.asarray(block_residuals(block, jnp.ravel(jnp.asarray(theta)), points))


def whitened_jacobians(block, theta, points):
    """Whitened residuals ``(m, c)`` and Jacobians ``(m, c, 5)``, ``(m, c, d)`` of a sequence's block (the engine's
    ``vmap(jacfwd)``)."""
    lin = linearize(block, jnp.ravel(jnp.asarray(theta)), points)
    return np.asarray(lin.e), np.asarray(lin.theta), np.asarray(lin.point)
