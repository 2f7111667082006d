"""Pure geometric models (no I/O): the Earth, range-Doppler intersection, the great-circle scan model,
trajectories and map projections."""

from seaice_jax import _config  # noqa: F401  (float64 before any of this subpackage's code)
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

__all__ = [
    "EARTH_ROTATION_RATE", "MEAN_RADIUS", "SIDEREAL_DAY", "SOLAR_DAY", "WGS84_FLATTENING",
    "WGS84_SEMI_MAJOR_AXIS", "cartesian_to_sphere", "ecef_to_geodetic", "geodetic_to_ecef",
    "great_circle_distance", "latitude_longitude", "north_east", "sphere_to_cartesian", "unit_vector", "wrap_angle",
    "Equirectangular", "ImageGrid", "Projection", "LambertConformalConic", "MapGrid", "PolarStereographic",
    "TangentPlane",
    "nsidc_polar_stereographic",
    "LEFT", "RIGHT", "LookSide", "doppler_residual", "ground_point", "imaging_time_and_range", "incidence_angle",
    "SATELLITES", "SCAN_UNKNOWNS", "Orbit", "SatelliteOrbit", "ScanModel", "satellite_orbit", "CircularTrajectory",
    "Trajectory",
]
