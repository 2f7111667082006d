"""seaice_jax: sea-ice mapping and drift from radar strips and satellite images, in JAX (float64).

Importing the package enables ``jax_enable_x64``: geocentric coordinates are ~6.4e6 m and must keep millimetres.
"""

from seaice_jax import _config  # noqa: F401  (float64 on import)
from seaice_jax.errors import GeometryError, SeaiceError
from seaice_jax.geometry import *  # noqa: F403
from seaice_jax.geometry import __all__ as _geometry_all
from seaice_jax.sensors.navigation import NavigationSpline

__version__ = "0.1.0"
__all__ = ["GeometryError", "SeaiceError", "NavigationSpline", *_geometry_all]
