"""Rasters: remapping images into a map grid (VHR2/VHR3), camera-distortion correction (OPT), automatic tracking
by cross-correlation, time-lapse films (MOVIE)."""

from seaice_jax import _config  # noqa: F401  (float64 before any of this subpackage's code)
