"""Estimation: one weighted least-squares engine and its quality control."""

from seaice_jax import _config  # noqa: F401  (float64 before any of this subpackage's code)
