import jax
import jax.numpy as jnp
import numpy as np
import pyproj
import pytest
from hypothesis import given
from hypothesis import strategies as st

from seaice_jax.geometry.earth import MEAN_RADIUS
from seaice_jax.geometry.projections import (
    ImageGrid,
    LambertConformalConic,
    PolarStereographic,
    TangentPlane,
    nsidc_polar_stereographic,
)
from tests.helpers import assert_jacobian_matches

DEG = np.pi / 180.0
HUGHES_1980 = dict(semi_major_axis=6378273.0, flattening=1.0 - 6356889.449 / 6378273.0)

# (our projection, the same definition in PROJ, latitude range, longitude range) in degrees
CASES = {
    "tangent_plane": (TangentPlane(72.0 * DEG, -150.0 * DEG), "+proj=ortho +lat_0=72 +lon_0=-150 +R=6371000",
                      (55.0, 89.0), (-190.0, -110.0)),
    "lcc_wgs84_two_parallels": (
        LambertConformalConic(60 * DEG, 80 * DEG, 70 * DEG, -100 * DEG, 500_000.0, -200_000.0),
        "+proj=lcc +lat_1=60 +lat_2=80 +lat_0=70 +lon_0=-100 +x_0=500000 +y_0=-200000 +ellps=WGS84",
        (45.0, 88.0), (-170.0, -30.0)),
    "lcc_sphere_one_parallel": (
        LambertConformalConic(75 * DEG, 75 * DEG, 75 * DEG, -80 * DEG, semi_major_axis=MEAN_RADIUS,
                              flattening=0.0),
        "+proj=lcc +lat_1=75 +lat_0=75 +lon_0=-80 +R=6371000", (50.0, 89.0), (-150.0, -10.0)),
    "nsidc_north_epsg3413": (nsidc_polar_stereographic("north"), "EPSG:3413", (30.0, 90.0), (-180.0, 180.0)),
    "nsidc_south_epsg3976": (nsidc_polar_stereographic("south"), "EPSG:3976", (-90.0, -40.0), (-180.0, 180.0)),
    "nsidc_north_hughes_epsg3411": (
        PolarStereographic(70 * DEG, -45 * DEG, **HUGHES_1980),
        "+proj=stere +lat_0=90 +lat_ts=70 +lon_0=-45 +a=6378273 +b=6356889.449", (30.0, 90.0), (-180.0, 180.0)),
    "stereographic_true_at_pole_sphere": (
        PolarStereographic(90 * DEG, 0.0, 0.0, 0.0, MEAN_RADIUS, 0.0),
        "+proj=stere +lat_0=90 +lat_ts=90 +lon_0=0 +R=6371000", (20.0, 90.0), (-180.0, 180.0)),
}


def sample(lat_range, lon_range, rng, n=400):
    return rng.uniform(*lat_range, n), rng.uniform(*lon_range, n)


@pytest.mark.parametrize("name", CASES)
def test_forward_agrees_with_proj_to_a_millimetre(name, rng):
    projection, definition, lat_range, lon_range = CASES[name]
    lat, lon = sample(lat_range, lon_range, rng)
    x, y = projection.forward(lat * DEG, lon * DEG)
    proj_x, proj_y = pyproj.Proj(definition)(lon, lat)
    np.testing.assert_allclose(x, proj_x, atol=1e-3, rtol=0)
    np.testing.assert_allclose(y, proj_y, atol=1e-3, rtol=0)


@pytest.mark.parametrize("name", CASES)
def test_inverse_agrees_with_proj_and_round_trips_to_a_millimetre(name, rng):
    projection, definition, lat_range, lon_range = CASES[name]
    lat, lon = sample(lat_range, lon_range, rng)
    x, y = pyproj.Proj(definition)(lon, lat)
    back_lat, back_lon = (np.asarray(a) / DEG for a in projection.inverse(x, y))
    proj_lon, proj_lat = pyproj.Proj(definition)(x, y, inverse=True)
    metres = MEAN_RADIUS * DEG
    np.testing.assert_allclose(back_lat * metres, proj_lat * metres, atol=1e-3, rtol=0)
    east_error = np.angle(np.exp(1j * (back_lon - proj_lon) * DEG)) / DEG * metres * np.cos(lat * DEG)
    np.testing.assert_allclose(east_error, 0.0, atol=1e-3)
    # repeated round trips (PROJ's "roundtrip 100") do not drift
    xx, yy = x, y
    for _ in range(100):
        xx, yy = projection.forward(*projection.inverse(xx, yy))
    np.testing.assert_allclose(xx, x, atol=1e-3, rtol=0)
    np.testing.assert_allclose(yy, y, atol=1e-3, rtol=0)


def test_image_grid_matches_proj_eqc_and_source_001_layout():
    grid = ImageGrid(74.0 * DEG, -80.0 * DEG, 256.0, 256.0, 1100.0, 1400.0)
    lat = np.array([74.0, 75.0, 73.0, 74.5])
    lon = np.array([-80.0, -80.0, -85.0, -75.0])
    pixel, line = grid.forward(lat * DEG, lon * DEG)
    x, y = pyproj.Proj("+proj=eqc +lat_ts=74 +lat_0=74 +lon_0=-80 +R=6371000")(lon, lat)
    np.testing.assert_allclose(pixel, 256.0 + np.asarray(x) / 1100.0, atol=1e-6)
    np.testing.assert_allclose(line, 256.0 - np.asarray(y) / 1400.0, atol=1e-6)
    assert float(pixel[0]) == 256.0 and float(line[0]) == 256.0
    assert float(line[1]) < 256.0 and float(pixel[3]) > 256.0  # north is up, east to the right
    back_lat, back_lon = grid.inverse(pixel, line)
    np.testing.assert_allclose(np.asarray(back_lat) * MEAN_RADIUS, lat * DEG * MEAN_RADIUS, atol=1e-3)
    np.testing.assert_allclose(np.asarray(back_lon) * MEAN_RADIUS, lon * DEG * MEAN_RADIUS, atol=1e-3)


def test_tangent_plane_far_side_is_nan():
    plane = TangentPlane(72.0 * DEG, -150.0 * DEG)
    x, _ = plane.forward(np.array([72.0, -72.0]) * DEG, np.array([-150.0, 30.0]) * DEG)
    assert abs(float(x[0])) < 1e-9 and np.isnan(x[1])
    lat, _ = plane.inverse(np.array([0.0, 7e6]), np.array([0.0, 0.0]))
    assert float(lat[0]) == pytest.approx(72.0 * DEG) and np.isnan(lat[1])


@given(st.floats(35.0, 89.99), st.floats(-180.0, 180.0))
def test_round_trip_property_polar_and_conic(lat, lon):
    for projection in (nsidc_polar_stereographic("north"), CASES["lcc_wgs84_two_parallels"][0]):
        if projection is not CASES["nsidc_north_epsg3413"][0] and lat < 46.0:
            continue
        back_lat, back_lon = projection.inverse(*projection.forward(lat * DEG, lon * DEG))
        assert abs(float(back_lat) - lat * DEG) * MEAN_RADIUS < 1e-3
        assert abs(np.angle(np.exp(1j * (float(back_lon) - lon * DEG)))) * MEAN_RADIUS * np.cos(lat * DEG) < 1e-3


@pytest.mark.parametrize("name", CASES)
def test_jacobians_match_finite_differences(name):
    projection, _, lat_range, lon_range = CASES[name]
    point = np.array([np.mean(lat_range) * DEG, (lon_range[0] * 0.3 + lon_range[1] * 0.7) * DEG])
    assert_jacobian_matches(lambda v: jnp.stack(projection.forward(v[0], v[1])), point, steps=np.full(2, 1e-7))
    xy = np.array([float(a) for a in projection.forward(point[0], point[1])])
    assert_jacobian_matches(lambda v: jnp.stack(projection.inverse(v[0], v[1])), xy, steps=np.full(2, 0.5))


def test_jit_vmap_grad():
    projection = nsidc_polar_stereographic("north")
    lat = jnp.linspace(60.0, 85.0, 5) * DEG
    eager = projection.forward(lat, 0.3)
    jitted = jax.jit(lambda p, la: p.forward(la, 0.3))(projection, lat)
    mapped = jax.vmap(lambda la: projection.forward(la, 0.3))(lat)
    np.testing.assert_allclose(jitted[0], eager[0], atol=1e-9)
    np.testing.assert_allclose(mapped[1], eager[1], atol=1e-9)
    # scale along the meridian at the standard parallel is the ellipsoid's meridional radius factor k = 1
    dy = jax.grad(lambda la: projection.forward(la, projection.central_meridian)[1])(70.0 * DEG)
    e2 = projection.flattening * (2 - projection.flattening)
    meridional = projection.semi_major_axis * (1 - e2) / (1 - e2 * np.sin(70 * DEG) ** 2) ** 1.5
    assert abs(float(dy)) == pytest.approx(float(meridional), rel=1e-12)


@pytest.mark.parametrize("name", CASES)
def test_proj_string_and_crs_wkt_describe_the_same_projection(name, rng):
    """The PROJ definition and the WKT of the CF grid mapping, each read by pyproj, map points where our forward
    does (to a millimetre); the NSIDC grids carry their EPSG codes."""
    projection, _, lat_range, lon_range = CASES[name]
    lat, lon = sample(lat_range, lon_range, rng, 50)
    x, y = (np.asarray(a) for a in projection.forward(lat * DEG, lon * DEG))
    mapping = projection.cf_grid_mapping()
    geographic = pyproj.CRS.from_proj4(projection.proj_string()).geodetic_crs
    for definition in (projection.proj_string(), mapping["crs_wkt"]):
        crs = pyproj.CRS.from_user_input(definition)
        px, py = pyproj.Transformer.from_crs(crs.geodetic_crs or geographic, crs, always_xy=True).transform(lon, lat)
        np.testing.assert_allclose(px, x, atol=1e-3, rtol=0)
        np.testing.assert_allclose(py, y, atol=1e-3, rtol=0)
    assert mapping["proj4_params"] == projection.proj_string()
    expected_code = {"nsidc_north_epsg3413": "EPSG:3413", "nsidc_south_epsg3976": "EPSG:3976"}.get(name)
    assert mapping.get("epsg_code") == expected_code
    if expected_code is not None:
        assert pyproj.CRS.from_wkt(mapping["crs_wkt"]).to_epsg() == int(expected_code[5:])
        assert mapping["grid_mapping_name"] == "polar_stereographic"


def test_every_projection_is_a_projection_and_the_base_is_abstract():
    import inspect

    from seaice_jax.geometry import projections

    family = [c for _, c in inspect.getmembers(projections, inspect.isclass)
              if c.__module__ == projections.__name__ and hasattr(c, "forward") and hasattr(c, "inverse")
              and c not in (projections.Projection, projections.ImageGrid)]
    assert {c.__name__ for c in family} == {"TangentPlane", "Equirectangular", "LambertConformalConic",
                                            "PolarStereographic"}
    assert all(issubclass(c, projections.Projection) for c in family)
    with pytest.raises(TypeError):
        projections.Projection()
