"""Small vector helpers shared by the geometry modules (explicit broadcasting, no rank promotion)."""


def along(scalar, vector):
    """``scalar (...)`` times a single ``vector (3,)`` -> ``(..., 3)``."""
    return scalar[..., None] * vector.reshape((1,) * scalar.ndim + (3,))
