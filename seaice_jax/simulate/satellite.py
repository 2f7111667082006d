"""Simulated satellite images with known truth (grows into full image sequences)."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from seaice_jax.adjust.multi_image import ImageObservations
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


def overlapping_pair(rng: np.random.Generator, primary_first: int = 6, primary_second: int = 1,
                     secondary: int = 6, sigma_m: float = 500.0, pointing_m: float = 300.0):
    """Two overlapping southbound NOAA-7 images (the second's node 2° east, 0.8° earlier in the orbit).

    The first has ``primary_first`` control points, the second only ``primary_second`` (too few on its own);
    ``secondary`` points inside the overlap are measured on both. Known positions carry N(0, σ) noise; pointing
    at the secondary points is exact (add noise to the adjustment's observations to simulate it).

    Returns:
        ``(images, truths)``: two :class:`ImageObservations` and the two true :class:`ScanModel`.
    """
    first = noaa_image("south")
    second = eqx.tree_at(lambda m: (m.ascending_node, m.orbital_angle_first), first,
                         replace=(first.ascending_node + 2.0 * _DEG, first.orbital_angle_first - 0.8 * _DEG))
    primary_a, _, _ = simulate_control_points(first, primary_first, rng, sigma_m)
    primary_b, _, _ = simulate_control_points(second, primary_second, rng, sigma_m)
    pixel = rng.uniform(150.0, 400.0, secondary)
    scan = rng.uniform(150.0, 400.0, secondary)
    pixel_b, scan_b = (np.asarray(a) for a in second.inverse(*first.forward(pixel, scan)))
    ids = tuple(f"S{k + 1}" for k in range(secondary))
    images = [ImageObservations("A", first.orbit, "south", primary_a, ids, pixel, scan, pointing_m),
              ImageObservations("B", second.orbit, "south", primary_b, ids, pixel_b, scan_b, pointing_m)]
    return images, (first, second)
