"""Sentinel-1 on the real Earth: the zero-Doppler model on the WGS84 ellipsoid against ESA's own geolocation grids.

Nine real annotation files (EW SLC over Smith Sound, IW SLC of three sub-swaths, IW GRDH, stripmap). Every grid
point of every file: forward (azimuth time, slant range, height -> lat/lon) within 0.05 m horizontally, inverse
(lat/lon/height -> time, range) within 5 µs and 0.01 m, and image line/pixel -> radar coordinates (bursts, GRD
polynomials, bistatic shift) within 5 µs and 0.01 m. All files share one compiled forward and one compiled inverse
(grids padded to 1024 points, orbits to 32 state vectors).
"""

import shutil
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from seaice_jax._shapes import pad
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.earth import geodetic_to_ecef, north_east
from seaice_jax.geometry.state_vectors import ORBIT_BUCKET, StateVectorOrbit
from seaice_jax.geometry.zero_doppler import ellipsoid_ground_point, ellipsoid_imaging_time_and_range
from seaice_jax.io.sentinel1 import read_annotation
from tests.helpers import assert_jacobian_matches

DATA = Path(__file__).with_name("data") / "sentinel1"
FILES = sorted(DATA.glob("*.xml"))
GRID_POINTS = 1024


def _padded(values):
    return jnp.asarray(pad(np.asarray(values, float), GRID_POINTS, values[0]))


def _geolocated(annotation):
    """Our forward and inverse on the file's grid: horizontal error (m), time error (s), range error (m)."""
    grid, orbit = annotation.grid, annotation.orbit()
    n = grid.line.size
    padded = orbit.padded(ORBIT_BUCKET)
    latitude, longitude = (np.asarray(v)[:n] for v in ellipsoid_ground_point(
        padded, _padded(grid.azimuth_time), _padded(grid.slant_range), _padded(grid.height)))
    ours = np.asarray(geodetic_to_ecef(latitude, longitude, grid.height))
    esa = np.asarray(geodetic_to_ecef(np.radians(grid.latitude), np.radians(grid.longitude), grid.height))
    north, east = (np.asarray(v) for v in north_east(esa))
    horizontal = np.hypot(np.sum((ours - esa) * north, -1), np.sum((ours - esa) * east, -1))
    time, slant = (np.asarray(v)[:n] for v in ellipsoid_imaging_time_and_range(
        padded, _padded(np.radians(grid.latitude)), _padded(np.radians(grid.longitude)), _padded(grid.height),
        *orbit.time_span))
    return horizontal, np.abs(time - grid.azimuth_time), np.abs(slant - grid.slant_range)


@pytest.mark.parametrize("path", FILES, ids=[p.name[:14] + p.name[-7:-4] for p in FILES])
def test_every_grid_point_of_every_file(path):
    annotation = read_annotation(path)
    horizontal, time_error, range_error = _geolocated(annotation)
    assert annotation.grid.line.size >= 200
    assert horizontal.max() <= 0.05, f"forward: {horizontal.max():.4f} m"
    assert time_error.max() <= 5e-6, f"inverse: {time_error.max():.2e} s"
    assert range_error.max() <= 0.01, f"inverse: {range_error.max():.2e} m"
    time, slant = annotation.radar_coordinates(annotation.grid.line, annotation.grid.pixel)
    assert np.abs(time - annotation.grid.azimuth_time).max() <= 5e-6
    assert np.abs(slant - annotation.grid.slant_range).max() <= 0.01


def test_without_the_bistatic_shift_the_line_times_miss_the_grid():
    """The shift matters: image line times alone are off the grid's zero-Doppler times by up to ~0.5 ms."""
    annotation = read_annotation(FILES[0])
    grid = annotation.grid
    shift = np.abs(annotation.line_time(grid.line) - grid.azimuth_time)
    assert shift.max() > 1e-4


def test_bistatic_reference_from_the_middle_sub_swath():
    """The IW1 file's τ_ref from its own grid equals the IW2 annotation's mid-swath range time (same product) to
    well under a microsecond of azimuth shift; stripmap and IW2 state it themselves."""
    iw1 = read_annotation(DATA / "s1b-iw1-slc-vv-20210401t052624-20210401t052649-026269-032297-004.xml")
    iw2_path = DATA / "s1b-iw2-slc-vh-20210401t052622-20210401t052650-026269-032297-002.xml"
    assert iw1.bistatic_reference_source == "geolocation grid"
    referenced = read_annotation(iw1.path, reference=iw2_path)
    assert referenced.bistatic_reference_source.startswith("reference annotation")
    assert abs(referenced.bistatic_reference_time - iw1.bistatic_reference_time) / 2 < 1e-6
    time, _ = referenced.radar_coordinates(iw1.grid.line, iw1.grid.pixel)
    assert np.abs(time - iw1.grid.azimuth_time).max() <= 5e-6
    assert read_annotation(iw2_path).bistatic_reference_source == "mid-swath"
    with pytest.raises(SeaiceError, match="middle sub-swath"):
        read_annotation(iw2_path, reference=iw1.path)


def test_grd_uses_the_nearest_polynomial():
    """Blending the two neighbouring ground-to-slant polynomials instead of taking the nearest misses the grid."""
    annotation = read_annotation(next(p for p in FILES if "-grd-" in p.name))
    table = annotation.ground_to_slant
    assert table is not None and table.azimuth_time.size > 2
    grid = annotation.grid
    time = annotation.line_time(grid.line)
    nearest = annotation.slant_range_time(grid.pixel, time)
    assert np.abs(nearest - grid.slant_range_time).max() * 299_792_458.0 / 2 < 0.01


def test_velocity_from_the_position_curve_costs_metres_along_track():
    """Interpolating the annotated velocities separately matters: the derivative of the position polynomial is off
    by centimetres per second, which moves the zero-Doppler point by metres."""
    annotation = read_annotation(FILES[0])
    orbit = annotation.orbit()
    times = annotation.grid.azimuth_time
    _, velocity = orbit(times)
    differentiated = jax.vmap(jax.jacfwd(lambda t: orbit(t)[0]))(jnp.asarray(times))
    difference = np.linalg.norm(np.asarray(differentiated) - np.asarray(velocity), axis=-1)
    assert 0.002 < difference.max() < 0.1
    position, _ = orbit(times)
    point = geodetic_to_ecef(np.radians(annotation.grid.latitude), np.radians(annotation.grid.longitude),
                             annotation.grid.height)
    along_track = np.sum((np.asarray(point) - np.asarray(position)) * np.asarray(differentiated), -1) / \
        np.linalg.norm(np.asarray(differentiated), axis=-1)
    assert np.abs(along_track).max() > 0.5


def test_orbit_reproduces_its_state_vectors_and_padding_changes_nothing():
    annotation = read_annotation(FILES[0])
    orbit = annotation.orbit()
    position, velocity = orbit(annotation.orbit_times)
    np.testing.assert_allclose(position, annotation.orbit_positions, atol=1e-6)
    np.testing.assert_allclose(velocity, annotation.orbit_velocities, atol=1e-9)
    times = np.linspace(*orbit.time_span, 57)
    for a, b in zip(orbit(times), orbit.padded(ORBIT_BUCKET)(times), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_round_trip_and_jacobian():
    """Forward then inverse returns the time and range (repeated 20 times: no drift); the forward's derivatives
    match central differences."""
    annotation = read_annotation(FILES[0])
    orbit = annotation.orbit().padded(ORBIT_BUCKET)
    grid = annotation.grid
    time, slant, height = _padded(grid.azimuth_time), _padded(grid.slant_range), _padded(grid.height + 300.0)
    for _ in range(20):
        latitude, longitude = ellipsoid_ground_point(orbit, time, slant, height)
        time, slant = ellipsoid_imaging_time_and_range(orbit, latitude, longitude, height,
                                                       *annotation.orbit().time_span)
    assert np.abs(np.asarray(time) - _padded(grid.azimuth_time)).max() < 1e-7
    assert np.abs(np.asarray(slant) - _padded(grid.slant_range)).max() < 1e-4

    def forward(x):
        return jnp.stack(ellipsoid_ground_point(orbit, x[0], x[1], x[2], on_failure="nan"))

    assert_jacobian_matches(forward, np.array([grid.azimuth_time[7], grid.slant_range[7], 100.0]), rtol=1e-5,
                            steps=np.array([1e-4, 1.0, 1.0]))


def test_impossible_range_is_an_error_naming_the_index():
    annotation = read_annotation(FILES[0])
    orbit = annotation.orbit()
    t = annotation.grid.azimuth_time[:3]
    with pytest.raises(SeaiceError, match=r"index \[\(1,\)\]"):
        ellipsoid_ground_point(orbit, t, np.array([9e5, 5e5, 9e5]), 0.0)


def test_state_vectors_must_increase():
    with pytest.raises(ValueError, match="must increase"):
        StateVectorOrbit(np.r_[0.0, 10, 20, 20, 40, 50, 60, 70, 80], np.zeros((9, 3)), np.ones((9, 3)))
    with pytest.raises(ValueError, match="at least 8"):
        StateVectorOrbit(np.arange(5.0), np.zeros((5, 3)), np.ones((5, 3)))


@pytest.mark.parametrize(("edit", "message"), [
    (lambda text: text[: len(text) // 2], "not well-formed XML at line"),
    (lambda text: text.replace("<numberOfLines>", "<numberOfLinesX>", 1).replace("</numberOfLines>",
                                                                                 "</numberOfLinesX>", 1),
     "<imageAnnotation/imageInformation/numberOfLines> is missing"),
    (lambda text: text.replace("<rangeSamplingRate>2.502314816000000e+07", "<rangeSamplingRate>fast", 1),
     "rangeSamplingRate> is not a number: 'fast'"),
    (lambda text: text.replace("<time>2021-04-03T12:24:46.000000", "<time>2021-04-03T12:24:26.000000", 1),
     r"orbit\[2\]/time> does not follow"),
    (lambda text: text.replace("<latitude>7.926742931108166e+01", "<latitude>9.926742931108166e+01", 1),
     r"geolocationGridPoint\[1\]> has a latitude outside"),
    (lambda text: text.replace("<product>", "<products>", 1).replace("</product>", "</products>"),
     "not a Sentinel-1 annotation"),
])
def test_malformed_annotation_names_file_and_element(tmp_path, edit, message):
    source = FILES[0]
    broken = tmp_path / source.name
    broken.write_text(edit(source.read_text()))
    before = source.read_bytes()
    with pytest.raises(SeaiceError, match=message) as raised:
        read_annotation(broken)
    assert str(broken) in str(raised.value)
    assert source.read_bytes() == before


def test_missing_file_is_named(tmp_path):
    with pytest.raises(SeaiceError, match="cannot be read"):
        read_annotation(tmp_path / "absent.xml")
    shutil.copy(FILES[0], tmp_path / "copy.xml")
    assert read_annotation(tmp_path / "copy.xml").swath == "EW1"
