"""Simulated satellite images with known truth (grows into full image sequences)."""

import jax.numpy as jnp
import numpy as np

from seaice_jax.adjust.orbit_fit import ControlPoints
from seaice_jax.geometry.earth import MEAN_RADIUS
from seaice_jax.geometry.scan import ScanModel, satellite_orbit

_DEG = np.pi / 180.0


def noaa_image(direction: str = "south", altitude: float = 0.0, earth_day=None) -> ScanModel:
    """A NOAA-7-like 512 x 512 blow-up image over Baffin Bay / Lancaster Sound (like source 001's).

    Southbound: orbital angle 99° to 104.6°, node 66°; northbound: the mirrored geometry (η from 81° down to
    75.4°, node chosen so the image covers the same area).
    """
    options = {} if earth_day is None else {"earth_day": earth_day}
    orbit = satellite_orbit("NOAA-7", altitude=altitude, **options)
    if direction == "south":
        return ScanModel(7.0 * _DEG, 110.0, 99.0 * _DEG, 5.6 * _DEG, 66.0 * _DEG, orbit, "south")
    return ScanModel(7.0 * _DEG, 400.0, 81.0 * _DEG, 5.6 * _DEG, -126.0 * _DEG, orbit, "north")


def simulate_control_points(model: ScanModel, count: int, rng: np.random.Generator, sigma_m: float = 1000.0,
                            margin: float = 20.0):
    """Control points spread over the image with known positions perturbed by N(0, σ) metres per coordinate.

    Returns:
        ``(control, truth_latitude, truth_longitude)``: the noisy control points and the true positions.
    """
    pixel = rng.uniform(1.0 + margin, model.n_pixels - margin, count)
    scan = rng.uniform(1.0 + margin, model.n_scans - margin, count)
    latitude, longitude = (np.asarray(a) for a in model.forward(jnp.asarray(pixel), jnp.asarray(scan)))
    radius = float(model.orbit.radius)
    noisy_lat = latitude + rng.normal(0.0, sigma_m, count) / radius
    noisy_lon = longitude + rng.normal(0.0, sigma_m, count) / (radius * np.cos(latitude))
    control = ControlPoints(pixel, scan, noisy_lat, noisy_lon, sigma_m, [f"P{i + 1}" for i in range(count)])
    return control, latitude, longitude


def perturb_known_positions(latitude, longitude, sigma_m, rng, runs, radius=MEAN_RADIUS):
    """``runs`` Monte Carlo realizations of known positions: arrays ``(runs, n)`` of latitude and longitude."""
    latitude, longitude = np.asarray(latitude), np.asarray(longitude)
    noise = rng.normal(0.0, 1.0, (2, runs, latitude.size)) * np.asarray(sigma_m)
    return latitude + noise[0] / radius, longitude + noise[1] / (radius * np.cos(latitude))
