"""The Earth: a sphere for the models, the WGS84 ellipsoid by explicit conversion, and its rotation.

Conventions (DESIGN.md): metres, seconds, radians; latitude/longitude are on the sphere of radius ``radius``
unless a function says it is geodetic (WGS84). Geocentric Earth-fixed axes: x towards (0°N, 0°E), z towards the
north pole.
"""

import functools

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

from seaice_jax import _config  # noqa: F401  (float64)

MEAN_RADIUS = 6_371_000.0
"""Mean Earth radius in metres (IUGG R1), the default sphere of the models."""

WGS84_SEMI_MAJOR_AXIS = 6_378_137.0
"""WGS84 semi-major axis a, metres."""

WGS84_FLATTENING = 1.0 / 298.257223563
"""WGS84 flattening f."""

SOLAR_DAY = 86_400.0
"""Mean solar day, seconds (1440 min; the Earth-rotation period the 1985 program evidently used)."""

SIDEREAL_DAY = 86_164.0905
"""Sidereal day, seconds (one rotation of the Earth relative to the stars, 1436.068 min)."""

EARTH_ROTATION_RATE = 7.292115e-5
"""Earth rotation rate, rad/s (WGS84 / IERS value, 2π / sidereal day)."""


@jax.jit
def unit_vector(latitude, longitude):
    """Unit vector of a point on the sphere.

    Args:
        latitude, longitude: radians, any broadcastable shapes ``(...)``.

    Returns:
        ``(..., 3)`` geocentric unit vector.
    """
    latitude, longitude = jnp.broadcast_arrays(jnp.asarray(latitude, float), jnp.asarray(longitude, float))
    cos_lat = jnp.cos(latitude)
    return jnp.stack([cos_lat * jnp.cos(longitude), cos_lat * jnp.sin(longitude), jnp.sin(latitude)], axis=-1)


@jax.jit
def latitude_longitude(vector):
    """Latitude and longitude (radians) of a geocentric vector of any length.

    Args:
        vector: ``(..., 3)``.

    Returns:
        ``(latitude, longitude)``, each ``(...)``; longitude in (-π, π].
    """
    vector = jnp.asarray(vector, float)
    x, y, z = vector[..., 0], vector[..., 1], vector[..., 2]
    return jnp.arctan2(z, jnp.hypot(x, y)), jnp.arctan2(y, x)


@jax.jit
def north_east(position):
    """Local north and east unit vectors ``(..., 3)`` at geocentric positions ``(..., 3)`` (any length)."""
    latitude, longitude = latitude_longitude(position)
    east = jnp.stack([-jnp.sin(longitude), jnp.cos(longitude), jnp.zeros_like(longitude)], axis=-1)
    north = jnp.stack([-jnp.sin(latitude) * jnp.cos(longitude), -jnp.sin(latitude) * jnp.sin(longitude),
                       jnp.cos(latitude)], axis=-1)
    return north, east


@jax.jit
def sphere_to_cartesian(latitude, longitude, height=0.0, radius=MEAN_RADIUS):
    """Geocentric position (m) of a point at ``height`` above the sphere of ``radius``.

    Returns:
        ``(..., 3)`` metres.
    """
    direction = unit_vector(latitude, longitude)
    distance = jnp.broadcast_to(radius + jnp.asarray(height, float), direction.shape[:-1])
    return direction * distance[..., None]


@jax.jit
def cartesian_to_sphere(position, radius=MEAN_RADIUS):
    """Inverse of :func:`sphere_to_cartesian`: ``(latitude, longitude, height)`` in radians and metres."""
    latitude, longitude = latitude_longitude(position)
    return latitude, longitude, jnp.linalg.norm(jnp.asarray(position, float), axis=-1) - radius


@jax.jit
def geodetic_to_ecef(latitude, longitude, height=0.0, a=WGS84_SEMI_MAJOR_AXIS, f=WGS84_FLATTENING):
    """WGS84 (or any ellipsoid ``a``, ``f``) geodetic coordinates to Earth-centred Earth-fixed (ECEF) metres.

    Args:
        latitude, longitude: geodetic, radians. height: ellipsoidal height, metres.

    Returns:
        ``(..., 3)`` ECEF metres.
    """
    latitude, longitude, height = jnp.broadcast_arrays(
        jnp.asarray(latitude, float), jnp.asarray(longitude, float), jnp.asarray(height, float)
    )
    e2 = f * (2.0 - f)
    sin_lat = jnp.sin(latitude)
    prime_vertical = a / jnp.sqrt(1.0 - e2 * sin_lat**2)
    horizontal = (prime_vertical + height) * jnp.cos(latitude)
    return jnp.stack(
        [
            horizontal * jnp.cos(longitude),
            horizontal * jnp.sin(longitude),
            (prime_vertical * (1.0 - e2) + height) * sin_lat,
        ],
        axis=-1,
    )


@functools.partial(jax.jit, static_argnames="iterations")
def ecef_to_geodetic(position, a=WGS84_SEMI_MAJOR_AXIS, f=WGS84_FLATTENING, iterations=4):
    """ECEF metres to geodetic latitude, longitude (radians) and ellipsoidal height (m).

    Bowring's parametric-latitude iteration with a fixed count (differentiable, jit-friendly); four iterations
    reach well below a micrometre for points from the Earth's centre region out to satellite altitudes.

    Args:
        position: ``(..., 3)`` ECEF metres.

    Returns:
        ``(latitude, longitude, height)``, each ``(...)``.
    """
    position = jnp.asarray(position, float)
    x, y, z = position[..., 0], position[..., 1], position[..., 2]
    b = a * (1.0 - f)
    e2 = f * (2.0 - f)
    ep2 = e2 / (1.0 - e2)
    horizontal = jnp.hypot(x, y)
    longitude = jnp.arctan2(y, x)
    parametric = jnp.arctan2(a * z, b * horizontal)
    latitude = parametric
    for _ in range(iterations):
        latitude = jnp.arctan2(
            z + ep2 * b * jnp.sin(parametric) ** 3, horizontal - e2 * a * jnp.cos(parametric) ** 3
        )
        parametric = jnp.arctan2((1.0 - f) * jnp.sin(latitude), jnp.cos(latitude))
    sin_lat = jnp.sin(latitude)
    prime_vertical = a / jnp.sqrt(1.0 - e2 * sin_lat**2)
    # Height along the normal, stable at all latitudes.
    height = horizontal * jnp.cos(latitude) + z * sin_lat - a * a / prime_vertical
    return latitude, longitude, height


@jax.jit
def wrap_angle(angle):
    """Angle (radians) wrapped into (-π, π]."""
    return jnp.pi - jnp.mod(jnp.pi - angle, 2.0 * jnp.pi)


@jax.jit
def great_circle_distance(lat1, lon1, lat2, lon2, radius: ArrayLike = MEAN_RADIUS):
    """Great-circle distance (m) on the sphere between points given in radians (haversine-free, atan2 form)."""
    u1 = unit_vector(lat1, lon1)
    u2 = unit_vector(lat2, lon2)
    cross = jnp.linalg.norm(jnp.cross(u1, u2), axis=-1)
    return radius * jnp.arctan2(cross, jnp.sum(u1 * u2, axis=-1))
