import jax
import jax.numpy as jnp
import numpy as np
import pyproj
import pytest
from hypothesis import given
from hypothesis import strategies as st

from seaice_jax.geometry import earth
from tests.helpers import assert_jacobian_matches


def test_float64_is_active():
    assert jax.config.jax_enable_x64
    assert jnp.asarray(1.0).dtype == jnp.float64
    assert earth.unit_vector(0.1, 0.2).dtype == jnp.float64


def test_day_lengths():
    assert earth.SOLAR_DAY == 1440 * 60
    # The WGS84 rate is given to 7 digits: it fixes the day to about 0.01 s.
    assert earth.SIDEREAL_DAY == pytest.approx(2 * np.pi / earth.EARTH_ROTATION_RATE, rel=2e-7)


@given(st.floats(-89.9, 89.9), st.floats(-179.9, 179.9))
def test_unit_vector_round_trip(lat_deg, lon_deg):
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    v = earth.unit_vector(lat, lon)
    assert float(jnp.linalg.norm(v)) == pytest.approx(1.0, abs=1e-15)
    back_lat, back_lon = earth.latitude_longitude(v * 7e6)
    assert float(back_lat) == pytest.approx(lat, abs=1e-14)
    assert float(back_lon) == pytest.approx(lon, abs=1e-14)


def test_geodetic_to_ecef_matches_proj(rng):
    lat = rng.uniform(-90, 90, 200)
    lon = rng.uniform(-180, 180, 200)
    h = rng.uniform(-1000, 1_000_000, 200)
    to_ecef = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    x, y, z = to_ecef.transform(lon, lat, h)
    ours = np.asarray(earth.geodetic_to_ecef(np.radians(lat), np.radians(lon), h))
    np.testing.assert_allclose(ours, np.stack([x, y, z], -1), atol=1e-3, rtol=0)


def test_ecef_to_geodetic_round_trip_to_a_millimetre(rng):
    lat = np.radians(rng.uniform(-90, 90, 500))
    lon = np.radians(rng.uniform(-180, 180, 500))
    h = rng.uniform(-5000, 1_000_000, 500)
    back_lat, back_lon, back_h = earth.ecef_to_geodetic(earth.geodetic_to_ecef(lat, lon, h))
    assert np.max(np.abs(np.asarray(back_lat) - lat)) * earth.WGS84_SEMI_MAJOR_AXIS < 1e-3
    np.testing.assert_allclose(np.cos(lat) * (np.asarray(back_lon) - lon), 0, atol=1e-3 / 6.4e6)
    np.testing.assert_allclose(back_h, h, atol=1e-3)


def test_sphere_round_trip_and_distance_against_proj(rng):
    lat1, lat2 = np.radians(rng.uniform(-80, 80, (2, 50)))
    lon1, lon2 = np.radians(rng.uniform(-180, 180, (2, 50)))
    position = earth.sphere_to_cartesian(lat1, lon1, 1234.5)
    back = earth.cartesian_to_sphere(position)
    np.testing.assert_allclose(back[2], 1234.5, atol=1e-6)
    geod = pyproj.Geod(a=earth.MEAN_RADIUS, f=0.0)
    _, _, expected = geod.inv(np.degrees(lon1), np.degrees(lat1), np.degrees(lon2), np.degrees(lat2))
    np.testing.assert_allclose(earth.great_circle_distance(lat1, lon1, lat2, lon2), expected, atol=1e-3)


def test_geodetic_jacobian_matches_finite_differences():
    def f(v):
        return jnp.stack(earth.ecef_to_geodetic(v)[::2])

    x0 = np.asarray(earth.geodetic_to_ecef(np.radians(75.0), np.radians(-140.0), 300.0))
    assert_jacobian_matches(f, x0, rtol=1e-6, relative_step=1e-7)
    assert_jacobian_matches(lambda v: earth.geodetic_to_ecef(v[0], v[1], v[2]),
                            np.array([1.2, -2.0, 500.0]), rtol=1e-6)
