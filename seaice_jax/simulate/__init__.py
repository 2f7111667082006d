"""Synthetic but physically faithful scenarios whose truth is known."""

from seaice_jax import _config  # noqa: F401  (float64 before any of this subpackage's code)
