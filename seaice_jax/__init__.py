# ruff: noqa: F401, I001  (the names are re-exported lazily, in the order a user meets them, not alphabetically)
"""seaice_jax: sea-ice mapping and drift from radar strips and satellite images, in JAX (float64).

The user API, re-exported here (``import seaice_jax as sj; sj.fit_scan_model(...)``), in the order a user meets it:
readers (files in), models (geometry, sensors, observation and option types), verbs (fit, adjust, remap, track,
simulate), results, products (files out), the session (:func:`enable_compilation_cache`), errors. The list is
written once, as the type checker's imports below: the names, their modules and ``__all__`` are read from it. Each
name is imported on first use, so that ``import seaice_jax`` (and the ``seaice`` command's ``--help``) loads neither
JAX nor OpenCV. Deeper modules hold the rest (the documentation's module table). The library reports through
:mod:`logging` (the ``seaice_jax`` loggers: the workflows' stages at INFO, notes at WARNING); the ``seaice`` command
prints them.

Float64: geocentric coordinates are ~6.4e6 m and must keep millimetres. Every subpackage that runs JAX imports
:mod:`seaice_jax._config` (``jax_enable_x64``) before any of its code, so no seaice_jax function runs in float32.
Importing the package also makes JAX float64 for the caller: at once if JAX is already loaded, otherwise through
``JAX_ENABLE_X64`` (unless the caller set it), which JAX reads when it is first imported.
"""

import ast
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
    # readers
    from seaice_jax.drift.records import read_records
    from seaice_jax.io.products import read_geotiff
    from seaice_jax.io.sentinel1 import read_annotation
    from seaice_jax.io.sequence import read_sequence
    from seaice_jax.io.stations import read_agrid, read_measurements

    # models: the Earth, map projections, the radar and scan geometry, sensors, observations, options
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
    from seaice_jax.io.sentinel1 import Sentinel1Annotation
    from seaice_jax.sensors.control import ControlPoints, ImageObservations
    from seaice_jax.sensors.navigation import NavigationSpline
    from seaice_jax.adjust.engine import EngineOptions, Observations, Problem, ResidualBlock
    from seaice_jax.adjust.radar.options import BlockOptions
    from seaice_jax.adjust.radar.timing import GroundPoints, RadarMeasurements, TimingOptions
    from seaice_jax.adjust.sequence.adjustment import SequenceOptions
    from seaice_jax.imagery.tracking import TrackingOptions

    # verbs
    from seaice_jax.adjust.orbit.fit import fit_scan_model
    from seaice_jax.adjust.radar.block import simultaneous_block
    from seaice_jax.adjust.radar.timing import adjust_radar_timing
    from seaice_jax.adjust.sequence.adjustment import adjust_sequence
    from seaice_jax.adjust.sequence.control_test import control_test
    from seaice_jax.adjust.engine import least_squares, robust_adjustment, solve, variance_components
    from seaice_jax.imagery.remap import remap
    from seaice_jax.imagery.ties import find_ties
    from seaice_jax.imagery.tracking import track
    from seaice_jax.simulate.satellite import simulate_sequence

    # results
    from seaice_jax.adjust.engine import Adjustment
    from seaice_jax.adjust.orbit.fit import OrbitFit
    from seaice_jax.adjust.radar.block import BlockResult
    from seaice_jax.adjust.sequence.adjustment import SequenceAdjustment
    from seaice_jax.adjust.sequence.control_test import ControlTest
    from seaice_jax.imagery.ties import TiePoints
    from seaice_jax.imagery.tracking import Displacements
    from seaice_jax.drift.records import FloeRecords

    # products
    from seaice_jax.drift.records import write_records
    from seaice_jax.io.products import write_drift_netcdf, write_geotiff, write_osisaf_drift

    # the session: JAX's compilations kept on disk between sessions
    from seaice_jax._compilation_cache import enable_compilation_cache

__version__ = "0.1.0"


def _public_face() -> dict[str, str]:
    """``{name: module}`` of the public names in the order of the type checker's imports above (the one place they
    are written), the errors last."""
    with open(__file__, encoding="utf-8") as source:
        tree = ast.parse(source.read())
    imports = sorted((node for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)
                      and (node.module or "").startswith("seaice_jax.")),
                     key=lambda node: (node.module == "seaice_jax.errors", node.lineno))
    return {alias.name: str(node.module) for node in imports for alias in node.names}


_LAZY = _public_face()
"""The module each public name is imported from on first use."""
__all__ = list(_LAZY)  # pyright: ignore[reportUnsupportedDunderAll]


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'seaice_jax' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
