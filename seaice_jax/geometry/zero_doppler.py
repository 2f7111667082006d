"""Zero-Doppler range-Doppler geolocation on the WGS84 ellipsoid: spaceborne radar (Sentinel-1, ERS, RADARSAT).

The sources' model (source 000, eq. A5; :mod:`seaice_jax.geometry.range_doppler`) intersects the range sphere and
the Doppler plane with a *sphere*, which is what 1970s airborne strips needed. A spaceborne image is geolocated on
the ellipsoid: the imaged point p at azimuth time t, slant range r and ellipsoidal height h satisfies

* |p − s(t)| = r,
* (p − s(t))·ṡ(t) = 0 (zero Doppler: focused products are in zero-Doppler geometry),
* the geodetic height of p is h.

The first two put p on a circle about the sensor in the plane normal to its velocity:
p(θ) = s + r (cos θ d + sin θ w), with d the downward direction in that plane and w = ṡ×s/|ṡ×s| to the right of the
flight direction. The third is one equation in θ, solved by Newton's method (fixed count, differentiable) from the
closed-form solution on the sphere through the sub-sensor point's ellipsoid radius (eq. A5). The inverse, a ground
point -> (t, r), solves the zero-Doppler condition along the orbit
(:func:`~seaice_jax.geometry.range_doppler.imaging_time_and_range`).
"""

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

from seaice_jax.geometry._checks import raise_where_nan
from seaice_jax.geometry.earth import WGS84_FLATTENING, WGS84_SEMI_MAJOR_AXIS, ecef_to_geodetic, geodetic_to_ecef
from seaice_jax.geometry.range_doppler import LookSide, imaging_time_and_range, look_sign
from seaice_jax.geometry.trajectory import Trajectory

SPEED_OF_LIGHT = 299_792_458.0
"""m/s: two-way slant range time τ -> slant range c τ / 2."""

NEWTON_STEPS = 3
"""Newton steps in the circle angle θ from the sphere start (within ~1 km of the ellipsoid point). On the nine
Sentinel-1 annotations of the tests one step leaves up to 0.63 m, two reach ESA's grid to its own rounding (14 mm at
most, the microsecond of its printed times), the third is margin."""

INVERSE_START_TIMES = 9
"""Times along the orbit's span (Sentinel-1: ~150 s, so ~19 s apart) where the inverse picks its Newton start."""
INVERSE_NEWTON_STEPS = 5
"""Newton steps of the inverse's zero-Doppler time from that start. On the nine Sentinel-1 annotations of the tests,
3, 5, 9, 17 or 65 start times with five or six steps give the same largest difference from ESA's grid times
(2.03 µs)."""


def ellipsoid_ground_point(
    trajectory: Trajectory,
    azimuth_time,
    slant_range,
    height: ArrayLike = 0.0,
    look_side: LookSide | ArrayLike = "right",
    semi_major_axis=WGS84_SEMI_MAJOR_AXIS,
    flattening=WGS84_FLATTENING,
    on_failure="raise",
):
    """Geodetic latitude, longitude (radians) of the point imaged at ``azimuth_time`` and ``slant_range``.

    Zero-Doppler range-Doppler intersection on the ellipsoid at ellipsoidal ``height`` (see the module docstring).
    Broadcasts over the batch shape of its arguments; works under jit, vmap and grad.

    Args:
        trajectory: the sensor orbit, e.g. :class:`~seaice_jax.geometry.state_vectors.StateVectorOrbit`
            (Earth-fixed positions and velocities).
        azimuth_time: ``(...)`` zero-Doppler time, s from the trajectory's epoch.
        slant_range: ``(...)`` m (c τ / 2 for a two-way range time τ).
        height: ``(...)`` ellipsoidal height of the imaged surface, m.
        look_side: ``"right"`` (Sentinel-1) or ``"left"``, or an array of +1 / −1.
        semi_major_axis, flattening: the ellipsoid (WGS84 by default).
        on_failure: ``"raise"`` or ``"nan"``: a range shorter than the sensor's height or beyond the horizon.

    Returns:
        ``(latitude, longitude)``, each ``(...)``, radians.
    """
    if on_failure not in ("raise", "nan"):
        raise ValueError(f"on_failure must be 'raise' or 'nan', got {on_failure!r}")
    latitude, longitude = _ellipsoid_ground_point(trajectory, azimuth_time, slant_range, height, look_sign(look_side),
                                                  semi_major_axis, flattening)
    if on_failure == "raise":
        raise_where_nan(latitude, "slant range", "the range sphere does not meet the surface at this height in the "
                        "zero-Doppler plane (range shorter than the sensor's height above it, or beyond the horizon)")
    return latitude, longitude


@jax.jit
def _ellipsoid_ground_point(trajectory, azimuth_time, slant_range, height, sign, semi_major_axis, flattening):
    time, slant, height, sign = jnp.broadcast_arrays(*(jnp.asarray(v, float)
                                                       for v in (azimuth_time, slant_range, height, sign)))
    position, velocity = trajectory(time)
    down, right = _circle_axes(position, velocity)
    sub_latitude, sub_longitude, _ = ecef_to_geodetic(position, semi_major_axis, flattening)
    sphere_radius = jnp.linalg.norm(geodetic_to_ecef(sub_latitude, sub_longitude, height, semi_major_axis,
                                                     flattening), axis=-1)
    distance = jnp.linalg.norm(position, axis=-1)
    # Eq. A5 in the zero-Doppler plane: the point at range r from s on the sphere of that radius.
    # (p − s)·(−ŝ) = r cos θ cos δ, δ the angle between −ŝ and ``down`` (in-plane: ``right`` ⟂ s).
    cos_nadir = (distance**2 + slant**2 - sphere_radius**2) / (2.0 * distance * slant)
    cos_angle = cos_nadir / (-jnp.sum(position * down, axis=-1) / distance)
    visible = (jnp.abs(cos_angle) <= 1.0) & (slant**2 <= distance**2 - sphere_radius**2)
    angle = sign * jnp.arccos(jnp.clip(cos_angle, -1.0, 1.0))

    def circle(theta):
        return position + slant[..., None] * (jnp.cos(theta)[..., None] * down + jnp.sin(theta)[..., None] * right)

    def height_error(theta):
        return ecef_to_geodetic(circle(theta), semi_major_axis, flattening)[2] - height

    def newton(theta, _):
        value, slope = jax.jvp(height_error, (theta,), (jnp.ones_like(theta),))
        return theta - value / slope, None

    angle, _ = jax.lax.scan(newton, angle, None, length=NEWTON_STEPS)
    latitude, longitude, _ = ecef_to_geodetic(circle(angle), semi_major_axis, flattening)
    return jnp.where(visible, latitude, jnp.nan), jnp.where(visible, longitude, jnp.nan)


def _circle_axes(position, velocity):
    """Unit vectors of the zero-Doppler plane: ``down`` (towards the Earth's centre, normal to the velocity) and
    ``right`` (ṡ×s normalised: right of the flight direction, the ``w`` of eq. A5)."""
    right = jnp.cross(velocity, position)
    right = right / jnp.linalg.norm(right, axis=-1, keepdims=True)
    down = jnp.cross(right, velocity)
    down = down / jnp.linalg.norm(down, axis=-1, keepdims=True)
    return down, right


def ellipsoid_imaging_time_and_range(
    trajectory: Trajectory, latitude, longitude, height: ArrayLike = 0.0, time_start=None, time_end=None,
    semi_major_axis=WGS84_SEMI_MAJOR_AXIS, flattening=WGS84_FLATTENING,
):
    """Inverse of :func:`ellipsoid_ground_point`: zero-Doppler azimuth time (s) and slant range (m) of ground points.

    Args:
        trajectory: the sensor orbit.
        latitude, longitude: ``(...)`` geodetic, radians. height: ``(...)`` ellipsoidal height, m.
        time_start, time_end: s, bracketing the imaging times (default: the state vectors' span of a
            :class:`~seaice_jax.geometry.state_vectors.StateVectorOrbit`).

    Returns:
        ``(azimuth_time, slant_range)``, each ``(...)``.
    """
    if time_start is None or time_end is None:
        span = getattr(trajectory, "time_span", None)
        if span is None:
            raise ValueError("time_start and time_end are needed for a trajectory without a time_span")
        time_start, time_end = span
    point = geodetic_to_ecef(latitude, longitude, height, semi_major_axis, flattening)
    # As arrays, not Python floats: one compilation serves every time span.
    return imaging_time_and_range(point, trajectory, jnp.asarray(time_start, float), jnp.asarray(time_end, float),
                                  grid_points=INVERSE_START_TIMES, iterations=INVERSE_NEWTON_STEPS)
