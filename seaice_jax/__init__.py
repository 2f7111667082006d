"""seaice_jax: sea-ice mapping and drift from radar strips and satellite images, in JAX (float64).

The user API, re-exported here: ``import seaice_jax as sj; sj.fit_scan_model(...)``, ``sj.remap``,
``sj.simultaneous_block``, ``sj.least_squares``, ``sj.track``, the geometry and projections. Deeper modules hold the
rest (see the README's module table). Importing the package enables ``jax_enable_x64``: geocentric coordinates are
~6.4e6 m and must keep millimetres. OpenCV (``remap``, ``track``, ``TrackingOptions``) is imported only when first used.
"""

import importlib
from typing import TYPE_CHECKING

from seaice_jax import _config  # noqa: F401  (float64 on import)
from seaice_jax.adjust.block import BlockOptions, simultaneous_block
from seaice_jax.adjust.lsq import Observations, least_squares
from seaice_jax.adjust.orbit_fit import fit_scan_model
from seaice_jax.errors import GeometryError, RankDeficiencyError, SeaiceError
from seaice_jax.geometry.earth import (
    EARTH_ROTATION_RATE,
    MEAN_RADIUS,
    SIDEREAL_DAY,
    SOLAR_DAY,
    WGS84_FLATTENING,
    WGS84_SEMI_MAJOR_AXIS,
    cartesian_to_sphere,
    ecef_to_geodetic,
    geodetic_to_ecef,
    great_circle_distance,
    latitude_longitude,
    north_east,
    sphere_to_cartesian,
    unit_vector,
    wrap_angle,
)
from seaice_jax.geometry.projections import (
    Equirectangular,
    ImageGrid,
    LambertConformalConic,
    MapGrid,
    PolarStereographic,
    Projection,
    TangentPlane,
    nsidc_polar_stereographic,
)
from seaice_jax.geometry.range_doppler import (
    LEFT,
    RIGHT,
    LookSide,
    doppler_residual,
    ground_point,
    imaging_time_and_range,
    incidence_angle,
)
from seaice_jax.geometry.scan import SATELLITES, SCAN_UNKNOWNS, Orbit, SatelliteOrbit, ScanModel, satellite_orbit
from seaice_jax.geometry.trajectory import CircularTrajectory, Trajectory
from seaice_jax.sensors.control import ControlPoints, ImageObservations
from seaice_jax.sensors.navigation import NavigationSpline
from seaice_jax.simulate.satellite import simulate_sequence

if TYPE_CHECKING:
    from seaice_jax.imagery.remap import remap
    from seaice_jax.imagery.tracking import TrackingOptions, track

__version__ = "0.1.0"

_LAZY = {"remap": "seaice_jax.imagery.remap", "track": "seaice_jax.imagery.tracking",
         "TrackingOptions": "seaice_jax.imagery.tracking"}
"""Names re-exported on first use (their modules import OpenCV)."""


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'seaice_jax' has no attribute {name!r}")


__all__ = [
    # errors
    "SeaiceError", "GeometryError", "RankDeficiencyError",
    # the Earth
    "EARTH_ROTATION_RATE", "MEAN_RADIUS", "SIDEREAL_DAY", "SOLAR_DAY", "WGS84_FLATTENING", "WGS84_SEMI_MAJOR_AXIS",
    "cartesian_to_sphere", "ecef_to_geodetic", "geodetic_to_ecef", "great_circle_distance", "latitude_longitude",
    "north_east", "sphere_to_cartesian", "unit_vector", "wrap_angle",
    # projections and map grids
    "Projection", "Equirectangular", "ImageGrid", "LambertConformalConic", "MapGrid", "PolarStereographic",
    "TangentPlane", "nsidc_polar_stereographic",
    # radar: range-Doppler and trajectories
    "LEFT", "RIGHT", "LookSide", "doppler_residual", "ground_point", "imaging_time_and_range", "incidence_angle",
    "Trajectory", "CircularTrajectory", "NavigationSpline",
    # satellite images: the great-circle scan model
    "SATELLITES", "SCAN_UNKNOWNS", "Orbit", "SatelliteOrbit", "ScanModel", "satellite_orbit",
    # observations and estimation
    "ControlPoints", "ImageObservations", "Observations", "least_squares", "fit_scan_model", "BlockOptions",
    "simultaneous_block",
    # rasters and drift
    "remap", "track", "TrackingOptions",
    # simulation
    "simulate_sequence",
]
