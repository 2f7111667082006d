"""Small helpers shared by the geometry modules (explicit broadcasting, no rank promotion)."""

import jax.numpy as jnp


def as_float(value):
    """``value`` as a float64 JAX array (the converter of the modules' array fields)."""
    return jnp.asarray(value, float)


def along(scalar, vector):
    """``scalar (...)`` times a single ``vector (3,)`` -> ``(..., 3)``."""
    return scalar[..., None] * vector.reshape((1,) * scalar.ndim + (3,))
