"""How raw measurements become geometry inputs (navigation records, radar image coordinates)."""

from seaice_jax import _config  # noqa: F401  (float64 before any of this subpackage's code)
