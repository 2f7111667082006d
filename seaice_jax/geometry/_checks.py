"""Turning NaN markers of impossible geometry into clear errors at the public API."""

import numpy as np

from seaice_jax._shapes import is_traced
from seaice_jax.errors import GeometryError


def raise_where_nan(result, what: str, reason: str, vector_axes: int = 0):
    """Raise :class:`GeometryError` naming the indices where ``result`` is NaN, unless traced.

    Args:
        result: array ``(..., *vector)`` whose NaN entries mark impossible geometry.
        what: what the indices refer to (e.g. "slant range").
        reason: why such points have no solution.
        vector_axes: number of trailing axes that belong to one point (1 for ``(..., 3)`` vectors).
    """
    if is_traced(result):
        return
    bad = np.isnan(np.asarray(result))
    for _ in range(vector_axes):
        bad = bad.any(axis=-1)
    bad = np.atleast_1d(bad)
    if np.any(bad):
        indices = np.nonzero(bad)
        count = int(bad.sum())
        listed = list(zip(*(i.tolist() for i in indices), strict=True))[:10]
        more = "" if count <= 10 else f" and {count - 10} more"
        raise GeometryError(f"no solution for {what} at index {listed}{more}: {reason}", indices)
