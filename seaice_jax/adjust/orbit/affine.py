"""AFFINE polynomials of source 001 (section 3.5, Table 3-1): a touch-up of an already rectified image.

Both target coordinates are polynomials in (x, y) with the terms of Table 3-1 taken in order:
1, x, y, xy, x², y², x³ (n = 3 … 7 as printed), continued "following the established pattern" with y³, x²y, xy²,
x²y² up to the program's 11 terms (the order of these four is our reading). With as many terms as points the
polynomial interpolates the control points exactly (the 1985 AFFINE program); with more points than terms it is a
least-squares fit.

The source warns that "enormous distortions can occur ... at even relatively moderate distances from the control
points"; :func:`trust_region` says where a correction is supported by the points and :func:`leave_one_out_errors`
how wrong it is at a point it was not fitted to.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from seaice_jax.errors import RankDeficiencyError, SeaiceError

AFFINE_TERMS = ("1", "x", "y", "xy", "x^2", "y^2", "x^3", "y^3", "x^2 y", "x y^2", "x^2 y^2")
_POWERS = ((0, 0), (1, 0), (0, 1), (1, 1), (2, 0), (0, 2), (3, 0), (0, 3), (2, 1), (1, 2), (2, 2))


def affine_design(x, y, n_terms: int):
    """``(..., n_terms)`` design matrix of the first ``n_terms`` Table 3-1 monomials at ``(x, y)``."""
    x, y = jnp.broadcast_arrays(jnp.asarray(x, float), jnp.asarray(y, float))
    return jnp.stack([x**i * y**j for i, j in _POWERS[:n_terms]], axis=-1)


class AffinePolynomial(eqx.Module):
    """(x, y) -> (x', y') by two polynomials of Table 3-1 terms, in coordinates centred and scaled for conditioning.

    Attributes:
        coefficients_x, coefficients_y: ``(n_terms,)`` on the normalised coordinates.
        centre: ``(2,)`` subtracted from (x, y); scale: divides them.
    """

    coefficients_x: Float[Array, " n"]
    coefficients_y: Float[Array, " n"]
    centre: Float[Array, "2"]
    scale: Float[Array, ""]

    @property
    def n_terms(self) -> int:
        return self.coefficients_x.shape[0]

    def __call__(self, x, y):
        """``(x', y')`` at ``(x, y)`` (any broadcastable shapes)."""
        design = affine_design((jnp.asarray(x, float) - self.centre[0]) / self.scale,
                               (jnp.asarray(y, float) - self.centre[1]) / self.scale, self.n_terms)
        return design @ self.coefficients_x, design @ self.coefficients_y


def fit_affine(x, y, x_target, y_target, n_terms: int | None = None) -> AffinePolynomial:
    """AFFINE polynomial through (exact) or nearest to (least squares) the control points.

    Args:
        x, y: ``(n,)`` control-point coordinates in the image to correct.
        x_target, y_target: ``(n,)`` where they must go.
        n_terms: 3 … 11; default ``min(n, 11)``: exact interpolation as in 1985 when n <= 11.

    Raises:
        SeaiceError: fewer than 3 points, or more terms than points.
        RankDeficiencyError: the points cannot determine the polynomial (e.g. collinear), naming the terms —
            the 1985 program's "AFFINE TRANSFORMATION MATRIX INVERSION FAILED".
    """
    x, y, x_target, y_target = (np.atleast_1d(np.asarray(a, float)) for a in (x, y, x_target, y_target))
    n = x.size
    n_terms = min(n, len(AFFINE_TERMS)) if n_terms is None else int(n_terms)
    if n < 3:
        raise SeaiceError(f"AFFINE needs at least 3 control points, got {n}")
    if not 3 <= n_terms <= len(AFFINE_TERMS):
        raise SeaiceError(f"AFFINE polynomials have 3 to {len(AFFINE_TERMS)} terms, got n_terms={n_terms}")
    if n_terms > n:
        raise SeaiceError(f"{n_terms} terms need at least {n_terms} control points, got {n}")
    centre = np.array([x.mean(), y.mean()])
    scale = max(float(np.max(np.hypot(x - centre[0], y - centre[1]))), 1e-12)
    design = np.asarray(affine_design((x - centre[0]) / scale, (y - centre[1]) / scale, n_terms))
    singular_values, vt = np.linalg.svd(design, full_matrices=False)[1:]
    if singular_values[-1] < 1e-9 * singular_values[0]:
        involved = np.nonzero(np.abs(vt[-1]) > 0.1)[0]
        terms = [AFFINE_TERMS[k] for k in involved]
        raise RankDeficiencyError(f"AFFINE transformation matrix inversion failed: the {n} control points cannot "
                                  f"determine the terms {', '.join(terms)} (collinear or symmetric points)", terms)
    coefficients = np.linalg.lstsq(design, np.stack([x_target, y_target], 1), rcond=None)[0]
    return AffinePolynomial(jnp.asarray(coefficients[:, 0]), jnp.asarray(coefficients[:, 1]), jnp.asarray(centre),
                            jnp.asarray(scale))


def leave_one_out_errors(x, y, x_target, y_target, n_terms: int):
    """Distance between each control point's target and the polynomial fitted without it, ``(n,)``.

    Needs ``n_terms < n``. Large values mean the correction cannot be trusted between the points.
    """
    x, y, x_target, y_target = (np.asarray(a, float) for a in (x, y, x_target, y_target))
    errors = np.empty(x.size)
    for k in range(x.size):
        keep = np.arange(x.size) != k
        polynomial = fit_affine(x[keep], y[keep], x_target[keep], y_target[keep], n_terms)
        px, py = polynomial(x[k], y[k])
        errors[k] = np.hypot(float(px) - x_target[k], float(py) - y_target[k])
    return errors


def trust_region(x, y, grid_x, grid_y):
    """Where a correction fitted to control points at ``(x, y)`` is supported by them.

    A grid point is trusted when it lies inside the convex hull of the control points and no farther from the
    nearest one than the points' mean nearest-neighbour spacing.

    Returns:
        ``(trusted, distance)``: boolean mask and distance to the nearest control point, shaped like the grid.
    """
    points = np.stack([np.asarray(x, float), np.asarray(y, float)], 1)
    grid = np.stack([np.ravel(grid_x), np.ravel(grid_y)], 1)
    distance = np.min(np.linalg.norm(grid[:, None, :] - points[None, :, :], axis=-1), axis=1)
    pairwise = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=-1)
    np.fill_diagonal(pairwise, np.inf)
    spacing = float(np.mean(np.min(pairwise, axis=1)))
    trusted = _inside_hull(points, grid) & (distance <= spacing)
    shape = np.shape(grid_x)
    return trusted.reshape(shape), distance.reshape(shape)


def _inside_hull(points, query):
    """Points of ``query`` inside (or on) the convex hull of ``points`` (monotone chain hull)."""
    order = np.lexsort((points[:, 1], points[:, 0]))
    ordered = points[order]

    def turn(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    def half(sequence):
        chain = []
        for p in sequence:
            while len(chain) >= 2 and turn(chain[-2], chain[-1], p) <= 0:
                chain.pop()
            chain.append(p)
        return chain

    hull = np.array(half(ordered)[:-1] + half(ordered[::-1])[:-1])
    if hull.shape[0] < 3:
        return np.zeros(query.shape[0], bool)
    edges = np.roll(hull, -1, axis=0) - hull
    relative = query[:, None, :] - hull[None, :, :]
    cross = edges[None, :, 0] * relative[..., 1] - edges[None, :, 1] * relative[..., 0]
    return np.all(cross >= -1e-9, axis=1)


def affine_touch_up(fit, n_terms: int | None = None) -> AffinePolynomial:
    """The 1985 two-level processing: an AFFINE correction in image space after the orbit fit.

    Maps measured (pixel, scan) to corrected (pixel, scan) so that ``fit.model.forward(*correction(p, s))`` meets
    the control points' known positions (exactly when ``n_terms`` equals the number of points, the default up to
    11). Apply it as ``fit.model.forward(*correction(pixel, scan))``; trust it only inside :func:`trust_region`.

    Args:
        fit: an :class:`~seaice_jax.adjust.orbit.fit.OrbitFit`.
    """
    control = fit.control
    pixel, scan = fit.model.inverse(control.latitude, control.longitude)
    return fit_affine(np.asarray(control.pixel), np.asarray(control.scan), np.asarray(pixel), np.asarray(scan),
                      n_terms)
