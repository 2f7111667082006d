"""Estimation: one weighted least-squares engine (:mod:`.engine`) and the models adjusted on it: :mod:`.orbit` (the
scan model of satellite images), :mod:`.radar` (radar blocks, Sentinel-1 timing), :mod:`.sequence` (image sequences)."""

from seaice_jax import _config  # noqa: F401  (float64 before any of this subpackage's code)
