"""Ice motion: drift vectors, transformation fits between point sets, deformation."""

from seaice_jax import _config  # noqa: F401  (float64 before any of this subpackage's code)
