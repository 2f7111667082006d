"""The sequential method of 1979 (source 000, section 2 and Appendix B) — building blocks.

Internal adjustment models the tie-point discrepancies between a strip and the previous one (eq. B1) as piecewise
cubic polynomials of the along-track coordinate (eq. B2), each piece fixed by the function values and tangents at
its two joints (eqs B3, B4); values and tangents at the joints come from a local regression of the discrepancies
around each joint.

Eq. B4 as printed holds for a unit interval (Δ = 1) and its a₃ has e where e′ belongs; this module uses the
cubic Hermite form valid for any Δ:
a₀ = e_{k−1}, a₁ = e′_{k−1}, a₂ = [3(e_k − e_{k−1})/Δ − 2e′_{k−1} − e′_k]/Δ,
a₃ = [e′_{k−1} + e′_k − 2(e_k − e_{k−1})/Δ]/Δ².
"""

from dataclasses import dataclass

import numpy as np

from seaice_jax.errors import SeaiceError


def piece_coefficients(value_start, slope_start, value_end, slope_end, length):
    """Coefficients (a₀, a₁, a₂, a₃) of one cubic piece in the local coordinate x − x_{k−1} (eqs B3, B4)."""
    chord = (value_end - value_start) / length
    return (value_start, slope_start, (3.0 * chord - 2.0 * slope_start - slope_end) / length,
            (slope_start + slope_end - 2.0 * chord) / length**2)


@dataclass(frozen=True)
class PiecewiseCubic:
    """A C¹ piecewise cubic through values and tangents at the joints (eq. B2).

    Attributes:
        joints: ``(p + 1,)`` increasing along-track coordinates x_k.
        values, slopes: ``(p + 1, c)`` function values e_k and tangents e′_k at the joints (c components, e.g.
            Δx and Δy of eq. B1).
    """

    joints: np.ndarray
    values: np.ndarray
    slopes: np.ndarray

    def __call__(self, x):
        """``(n, c)`` values at ``x`` ``(n,)``; beyond the end joints the end pieces extend."""
        x = np.atleast_1d(np.asarray(x, float))
        k = np.clip(np.searchsorted(self.joints, x, side="right") - 1, 0, self.joints.size - 2)
        length = (self.joints[k + 1] - self.joints[k])[:, None]
        a0, a1, a2, a3 = piece_coefficients(self.values[k], self.slopes[k], self.values[k + 1], self.slopes[k + 1],
                                            length)
        u = (x - self.joints[k])[:, None]
        return a0 + u * (a1 + u * (a2 + u * a3))


def local_regression(x, values, at, half_width, degree=2):
    """Value and tangent at ``at`` of a polynomial of ``degree`` fitted to the points within ±half_width.

    Args:
        x: ``(n,)``; values: ``(n, c)``.

    Returns:
        ``(value (c,), tangent (c,))``.

    Raises:
        SeaiceError: naming the joint when too few points lie near it.
    """
    near = np.abs(np.asarray(x) - at) <= half_width
    if near.sum() <= degree:
        raise SeaiceError(f"joint at x = {at:g}: only {int(near.sum())} tie points within ±{half_width:g} for a "
                          f"degree-{degree} local regression")
    design = np.vander(np.asarray(x)[near] - at, degree + 1, increasing=True)
    coefficients, *_ = np.linalg.lstsq(design, np.asarray(values)[near], rcond=None)
    return coefficients[0], coefficients[1]


def fit_piecewise_cubic(x, discrepancies, joints, half_width=None, degree=2) -> PiecewiseCubic:
    """Piecewise cubic model of tie-point discrepancies along a strip (source 000, Appendix B).

    Args:
        x: ``(n,)`` along-track coordinates of the tie points.
        discrepancies: ``(n, c)`` their discrepancies with the previous strip (eq. B1).
        joints: ``(p + 1,)`` increasing joint positions x_k.
        half_width: of the local regression window at each joint (default: the joint spacing).
        degree: of the local regression.
    """
    joints = np.asarray(joints, float)
    if joints.ndim != 1 or joints.size < 2 or np.any(np.diff(joints) <= 0):
        raise SeaiceError("joints must be at least two increasing along-track positions")
    values = np.asarray(discrepancies, float)
    values = values[:, None] if values.ndim == 1 else values
    half_width = float(np.max(np.diff(joints))) if half_width is None else float(half_width)
    pairs = [local_regression(x, values, at, half_width, degree) for at in joints]
    return PiecewiseCubic(joints, np.stack([v for v, _ in pairs]), np.stack([s for _, s in pairs]))
