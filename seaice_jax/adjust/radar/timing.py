"""Azimuth-time and slant-range offsets of spaceborne radar images: the spaceborne sweep delay.

The airborne strips of source 000 carry a sweep delay c and a range scale f (r = (y + c) f, eqs A1-A4); a focused
spaceborne image's equivalents are a constant offset of its azimuth time (timing of the orbit against the image)
and of its slant range (the echo window's delay, atmosphere). Per image i:

    zero-Doppler time of a point = measured time + azimuth_offset[i],
    slant range                   = measured range + range_offset[i].

They are estimated from control points (image measurements of known ground points) and tie points (one unknown
ground point measured in several images) through the one engine (:func:`seaice_jax.adjust.engine.lsq.make_solver`): the
model is the zero-Doppler geolocation itself (:func:`seaice_jax.geometry.range_doppler.refined_imaging_time`,
differentiated by autodiff through its Newton steps), with covariance, σ̂0 and the w-test of every measurement.
With ties only, the offsets have no datum; priors (the orbit's stated accuracy) give it.
"""

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from seaice_jax.adjust.engine.lsq import Adjustment, Observations, Solver, checked_solve, make_solver
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.earth import geodetic_to_ecef
from seaice_jax.geometry.range_doppler import refined_imaging_time
from seaice_jax.geometry.state_vectors import StateVectorOrbit

NEWTON_STEPS = 4
"""Newton steps of the zero-Doppler time from the measured time (micro- to milliseconds away: converged in two)."""


@dataclass(frozen=True)
class RadarMeasurements:
    """Points measured in radar images: ``(k,)`` arrays.

    Attributes:
        image: index of the image (into the orbits) each measurement is in.
        point: index of the ground point (into the control or tie points).
        azimuth_time: measured zero-Doppler time, s from the images' common epoch.
        slant_range: measured slant range, m.
    """

    image: np.ndarray
    point: np.ndarray
    azimuth_time: np.ndarray
    slant_range: np.ndarray

    def __post_init__(self):
        arrays = [np.asarray(getattr(self, name)) for name in ("image", "point", "azimuth_time", "slant_range")]
        if len({a.shape for a in arrays}) != 1 or arrays[0].ndim != 1:
            raise SeaiceError(f"radar measurements: image, point, azimuth_time and slant_range must be 1-D arrays of "
                              f"one length, got shapes {[a.shape for a in arrays]}")
        for name, values in zip(("azimuth_time", "slant_range"), arrays[2:], strict=True):
            bad = np.flatnonzero(~np.isfinite(values.astype(float)))
            if bad.size:
                raise SeaiceError(f"radar measurements: {name} of measurement {int(bad[0])} is not finite")


@dataclass(frozen=True)
class GroundPoints:
    """Ground points: ``(p,)`` geodetic latitude, longitude (radians) and ellipsoidal height (m); for tie points the
    latitude and longitude are the start of the adjustment, for control points they are known."""

    latitude: np.ndarray
    longitude: np.ndarray
    height: np.ndarray


@dataclass(frozen=True)
class TimingOptions:
    """The stochastic model of :func:`adjust_radar_timing`.

    Attributes:
        time_sigma: σ of a measured azimuth time, s (pointing σ in lines × the line interval).
        range_sigma: σ of a measured slant range, m (pointing σ in pixels × the range pixel spacing).
        prior_time_sigma, prior_range_sigma: prior σ of every image's offsets (s, m) about zero, e.g. the orbit's
            stated along-track accuracy / ground speed and its radial accuracy; ``None``: no prior.
    """

    time_sigma: float = 1e-5
    range_sigma: float = 1.0
    prior_time_sigma: float | None = None
    prior_range_sigma: float | None = None


def _stacked(orbits):
    padded = [orbit.bucketed() for orbit in orbits]
    return jax.tree_util.tree_map(lambda *leaves: jnp.stack(leaves), *padded)


def _predicted(orbits, image, point_ecef, measured_time):
    """Zero-Doppler time and slant range of ECEF points ``(k, 3)`` in images ``(k,)``, Newton from the measured
    times."""

    def one(i, point, time):
        orbit = jax.tree_util.tree_map(lambda leaf: leaf[i], orbits)
        return refined_imaging_time(point, orbit, time, iterations=NEWTON_STEPS)

    return jax.vmap(one)(image, point_ecef, measured_time)


def _model(parameters, args):
    control_time, control_range = _predicted(args["orbits"], args["control"]["image"], args["control"]["ecef"],
                                             args["control"]["time"])
    tie = args["tie"]
    ecef = geodetic_to_ecef(parameters["tie_latitude"][tie["point"]], parameters["tie_longitude"][tie["point"]],
                            tie["height"])
    tie_time, tie_range = _predicted(args["orbits"], tie["image"], ecef, tie["time"])
    azimuth, slant = parameters["azimuth_offset"], parameters["range_offset"]
    return {"control_time": control_time - azimuth[args["control"]["image"]],
            "control_range": control_range - slant[args["control"]["image"]],
            "tie_time": tie_time - azimuth[tie["image"]], "tie_range": tie_range - slant[tie["image"]]}


def timing_solver(
    orbits: list[StateVectorOrbit],
    control: RadarMeasurements,
    control_points: GroundPoints,
    ties: RadarMeasurements | None = None,
    tie_points: GroundPoints | None = None,
    options: TimingOptions = TimingOptions(),
) -> tuple[Solver, dict, dict]:
    """Set up the offset adjustment: ``(solver, observed, args)``; ``checked_solve(solver, observed, args)`` adjusts
    (see :func:`adjust_radar_timing`); ``jax.vmap`` the solver over realizations of ``observed`` for Monte Carlo."""
    if not orbits:
        raise SeaiceError("radar timing: no image orbits given")
    ties = ties or RadarMeasurements(*(np.zeros(0, t) for t in (int, int, float, float)))
    tie_points = tie_points or GroundPoints(np.zeros(0), np.zeros(0), np.zeros(0))
    for name, measured, points in (("control", control, control_points), ("tie", ties, tie_points)):
        if measured.image.size and (measured.image.min() < 0 or measured.image.max() >= len(orbits)):
            raise SeaiceError(f"radar timing: a {name} measurement is in image {int(measured.image.max())}, but "
                              f"{len(orbits)} orbit(s) were given")
        if measured.point.size and (measured.point.min() < 0 or measured.point.max() >= points.latitude.size):
            raise SeaiceError(f"radar timing: a {name} measurement refers to point {int(measured.point.max())} of "
                              f"{points.latitude.size}")
    counts = np.bincount(ties.point, minlength=tie_points.latitude.size)
    if np.any(counts < 2) and tie_points.latitude.size:
        raise SeaiceError(f"radar timing: tie point {int(np.argmax(counts < 2))} is measured in {int(counts.min())} "
                          f"image(s); a tie needs two or more")
    n_images = len(orbits)
    control_ecef = geodetic_to_ecef(control_points.latitude[control.point], control_points.longitude[control.point],
                                    control_points.height[control.point])
    args = {"orbits": _stacked(orbits),
            "control": {"image": jnp.asarray(control.image), "ecef": control_ecef,
                        "time": jnp.asarray(control.azimuth_time, float)},
            "tie": {"image": jnp.asarray(ties.image), "point": jnp.asarray(ties.point),
                    "height": jnp.asarray(tie_points.height[ties.point], float),
                    "time": jnp.asarray(ties.azimuth_time, float)}}
    parameters = {"azimuth_offset": jnp.zeros(n_images), "range_offset": jnp.zeros(n_images),
                  "tie_latitude": jnp.asarray(tie_points.latitude, float),
                  "tie_longitude": jnp.asarray(tie_points.longitude, float)}
    observed = {"control_time": jnp.asarray(control.azimuth_time, float),
                "control_range": jnp.asarray(control.slant_range, float),
                "tie_time": jnp.asarray(ties.azimuth_time, float), "tie_range": jnp.asarray(ties.slant_range, float)}
    sigma = {"control_time": options.time_sigma, "control_range": options.range_sigma,
             "tie_time": options.time_sigma, "tie_range": options.range_sigma}
    observations = {group: Observations(values, sigma[group]) for group, values in observed.items()}
    prior_sigma = None
    if options.prior_time_sigma is not None or options.prior_range_sigma is not None:
        time_prior, range_prior = (np.inf if v is None else v for v in (options.prior_time_sigma,
                                                                          options.prior_range_sigma))
        prior_sigma = {"azimuth_offset": jnp.full(n_images, time_prior),
                       "range_offset": jnp.full(n_images, range_prior), "tie_latitude": None, "tie_longitude": None}
    solver = make_solver(_model, parameters, observations, prior_sigma=prior_sigma, args=args, max_steps=20)
    return solver, observed, args


def adjust_radar_timing(
    orbits: list[StateVectorOrbit],
    control: RadarMeasurements,
    control_points: GroundPoints,
    ties: RadarMeasurements | None = None,
    tie_points: GroundPoints | None = None,
    options: TimingOptions = TimingOptions(),
) -> Adjustment:
    """Estimate each image's azimuth-time offset (s) and slant-range offset (m), and the tie points' positions.

    Args:
        orbits: one orbit per image (times from one common epoch).
        control, control_points: measurements of known ground points.
        ties, tie_points: measurements of unknown ground points (two or more images each) and their start values.
        options: the measurements' σ and the offsets' priors.

    Returns:
        The engine's :class:`~seaice_jax.adjust.engine.Adjustment`: parameters ``azimuth_offset`` ``(images,)``,
        ``range_offset`` ``(images,)``, ``tie_latitude``, ``tie_longitude`` ``(ties,)`` radians, covariance,
        σ̂0 and the w-test of every measurement (groups ``control_time``, ``control_range``, ``tie_time``,
        ``tie_range``; residuals computed − observed).

    Raises:
        RankDeficiencyError: naming the offsets the measurements cannot determine (ties without control or priors).
    """
    solver, observed, args = timing_solver(orbits, control, control_points, ties, tie_points, options)
    return checked_solve(solver, observed, args)
