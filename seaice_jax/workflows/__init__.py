"""End-to-end jobs behind the ``seaice`` commands: each computes a typed result first, then writes its files
(radar block, satellite image sequence, demo)."""

from seaice_jax import _config  # noqa: F401  (float64 before any of this subpackage's code)
