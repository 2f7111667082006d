"""seaice_jax: sea-ice mapping and drift from radar strips and satellite images, in JAX (float64).

The user API, re-exported here: ``import seaice_jax as sj; sj.fit_scan_model(...)``, ``sj.remap``,
``sj.simultaneous_block``, ``sj.least_squares``, ``sj.track``, the geometry and projections. Deeper modules hold the
rest (see the README's module table). Each name is imported on first use, so that ``import seaice_jax`` (and the
``seaice`` command's ``--help``) loads neither JAX nor OpenCV.

Float64: geocentric coordinates are ~6.4e6 m and must keep millimetres. Every subpackage that runs JAX imports
:mod:`seaice_jax._config` (``jax_enable_x64``) before any of its code, so no seaice_jax function runs in float32.
Importing the package also makes JAX float64 for the caller: at once if JAX is already loaded, otherwise through
``JAX_ENABLE_X64`` (unless the caller set it), which JAX reads when it is first imported.
"""

import importlib
import os
import sys
from typing import TYPE_CHECKING

from seaice_jax.errors import GeometryError, NotConvergedError, RankDeficiencyError, SeaiceError

if "jax" in sys.modules:
    from seaice_jax import _config  # noqa: F401  (float64 now)
else:
    os.environ.setdefault("JAX_ENABLE_X64", "1")

if TYPE_CHECKING:
    from seaice_jax.adjust.engine import Adjustment, EngineOptions, solve
    from seaice_jax.adjust.engine.lsq import Observations, least_squares
    from seaice_jax.adjust.engine.problem import Problem, ResidualBlock
    from seaice_jax.adjust.engine.variance import robust_adjustment, variance_components
    from seaice_jax.adjust.orbit.fit import fit_scan_model
    from seaice_jax.adjust.radar.block import BlockOptions, simultaneous_block
    from seaice_jax.adjust.radar.timing import GroundPoints, RadarMeasurements, TimingOptions, adjust_radar_timing
    from seaice_jax.adjust.sequence.adjustment import adjust_sequence
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
    from seaice_jax.geometry.state_vectors import StateVectorOrbit
    from seaice_jax.geometry.trajectory import CircularTrajectory, Trajectory
    from seaice_jax.geometry.zero_doppler import ellipsoid_ground_point, ellipsoid_imaging_time_and_range
    from seaice_jax.imagery.remap import remap
    from seaice_jax.imagery.ties import find_ties
    from seaice_jax.imagery.tracking import TrackingOptions, track
    from seaice_jax.io.sentinel1 import Sentinel1Annotation, read_annotation
    from seaice_jax.sensors.control import ControlPoints, ImageObservations
    from seaice_jax.sensors.navigation import NavigationSpline
    from seaice_jax.simulate.satellite import simulate_sequence

__version__ = "0.1.0"

_SOURCES = {
    "seaice_jax.adjust.radar.block": ("BlockOptions", "simultaneous_block"),
    "seaice_jax.adjust.engine": ("Adjustment", "EngineOptions", "solve"),
    "seaice_jax.adjust.engine.lsq": ("Observations", "least_squares"),
    "seaice_jax.adjust.orbit.fit": ("fit_scan_model",),
    "seaice_jax.adjust.engine.problem": ("Problem", "ResidualBlock"),
    "seaice_jax.adjust.radar.timing": ("GroundPoints", "RadarMeasurements", "TimingOptions", "adjust_radar_timing"),
    "seaice_jax.adjust.sequence.adjustment": ("adjust_sequence",),
    "seaice_jax.adjust.engine.variance": ("variance_components", "robust_adjustment"),
    "seaice_jax.geometry.earth": ("EARTH_ROTATION_RATE", "MEAN_RADIUS", "SIDEREAL_DAY", "SOLAR_DAY", "WGS84_FLATTENING",
                                  "WGS84_SEMI_MAJOR_AXIS", "cartesian_to_sphere", "ecef_to_geodetic",
                                  "geodetic_to_ecef", "great_circle_distance", "latitude_longitude", "north_east",
                                  "sphere_to_cartesian", "unit_vector", "wrap_angle"),
    "seaice_jax.geometry.projections": ("Equirectangular", "ImageGrid", "LambertConformalConic", "MapGrid",
                                        "PolarStereographic", "Projection", "TangentPlane",
                                        "nsidc_polar_stereographic"),
    "seaice_jax.geometry.range_doppler": ("LEFT", "RIGHT", "LookSide", "doppler_residual", "ground_point",
                                          "imaging_time_and_range", "incidence_angle"),
    "seaice_jax.geometry.scan": ("SATELLITES", "SCAN_UNKNOWNS", "Orbit", "SatelliteOrbit", "ScanModel",
                                 "satellite_orbit"),
    "seaice_jax.geometry.state_vectors": ("StateVectorOrbit",),
    "seaice_jax.geometry.trajectory": ("CircularTrajectory", "Trajectory"),
    "seaice_jax.geometry.zero_doppler": ("ellipsoid_ground_point", "ellipsoid_imaging_time_and_range"),
    "seaice_jax.io.sentinel1": ("Sentinel1Annotation", "read_annotation"),
    "seaice_jax.sensors.control": ("ControlPoints", "ImageObservations"),
    "seaice_jax.sensors.navigation": ("NavigationSpline",),
    "seaice_jax.simulate.satellite": ("simulate_sequence",),
    "seaice_jax.imagery.remap": ("remap",),
    "seaice_jax.imagery.ties": ("find_ties",),
    "seaice_jax.imagery.tracking": ("track", "TrackingOptions"),
}
_LAZY = {name: module for module, names in _SOURCES.items() for name in names}
"""The module each public name is imported from on first use."""


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'seaice_jax' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


__all__ = [
    # errors
    "SeaiceError", "GeometryError", "RankDeficiencyError", "NotConvergedError",
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
    # spaceborne radar: zero-Doppler on the WGS84 ellipsoid, Sentinel-1 annotations, timing offsets
    "StateVectorOrbit", "ellipsoid_ground_point", "ellipsoid_imaging_time_and_range", "Sentinel1Annotation",
    "read_annotation", "GroundPoints", "RadarMeasurements", "TimingOptions", "adjust_radar_timing",
    # satellite images: the great-circle scan model
    "SATELLITES", "SCAN_UNKNOWNS", "Orbit", "SatelliteOrbit", "ScanModel", "satellite_orbit",
    # observations and estimation
    "ControlPoints", "ImageObservations", "Observations", "least_squares", "fit_scan_model", "BlockOptions",
    "simultaneous_block", "adjust_sequence",
    # the adjustment engine
    "Problem", "ResidualBlock", "solve", "EngineOptions", "Adjustment", "variance_components", "robust_adjustment",
    # rasters and drift
    "remap", "track", "TrackingOptions", "find_ties",
    # simulation
    "simulate_sequence",
]
