"""Any target grid by EPSG code or PROJ string (pyproj), and `seaice track` on GeoTIFFs made elsewhere."""

import numpy as np
import pyproj
import pytest

from seaice_jax.cli import main
from seaice_jax.drift.kinematics import east_north_axes
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.crs import CrsProjection, projection_from_definition
from seaice_jax.geometry.projections import PolarStereographic, nsidc_polar_stereographic

LAEA = "+proj=laea +lat_0=90 +lon_0=-85 +datum=WGS84 +units=m +no_defs"


def test_crs_projection_is_proj_inside_jit_and_its_derivatives_are_the_native_ones():
    import jax

    latitude = np.radians([66.0, 72.5, 80.0, 89.0])
    longitude = np.radians([-150.0, -85.0, 10.0, 170.0])
    laea = CrsProjection(LAEA)
    x, y = (np.asarray(a) for a in jax.jit(laea.forward)(latitude, longitude))
    expected = pyproj.Transformer.from_crs("EPSG:4326", LAEA, always_xy=True).transform(np.degrees(longitude),
                                                                                      np.degrees(latitude))
    np.testing.assert_allclose(np.stack([x, y]), np.stack(expected), rtol=0, atol=1e-6)
    back = np.stack([np.asarray(a) for a in laea.inverse(x, y)])
    np.testing.assert_allclose(back, np.stack([latitude, longitude]), rtol=0, atol=1e-10)  # PROJ: < 1 mm
    # EPSG:3413 through PROJ against the JAX polar stereographic (Snyder's equations): values and grid convergence
    proj, native = CrsProjection("EPSG:3413"), nsidc_polar_stereographic("north")
    grid_x, grid_y = (np.asarray(a) for a in native.forward(latitude, longitude))
    np.testing.assert_allclose(np.stack([np.asarray(a) for a in proj.forward(latitude, longitude)]),
                               np.stack([grid_x, grid_y]), rtol=0, atol=1e-6)
    for a, b in zip(east_north_axes(proj, grid_x, grid_y), east_north_axes(native, grid_x, grid_y), strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-8)
    assert isinstance(projection_from_definition("EPSG:3413"), PolarStereographic)  # the JAX one where there is one
    assert laea.cf_parameters()["grid_mapping_name"] == "lambert_azimuthal_equal_area"
    assert pyproj.CRS.from_wkt(laea.cf_grid_mapping()["crs_wkt"]).equals(pyproj.CRS.from_user_input(LAEA))
    for bad, message in (("EPSG:4326", "not a projected CRS"), ("EPSG:999999", "pyproj does not know"),
                         ("+proj=stere +lat_0=90 +units=us-ft", "metres are needed")):
        with pytest.raises(SeaiceError, match=message):
            CrsProjection(bad)


def _texture(rng, size):
    import cv2

    return cv2.GaussianBlur(rng.normal(size=(size, size)), (0, 0), 2.0) * 40.0 + 100.0


def _write_geotiff(path, values, crs, left, top, pixel, moment=None):
    import rasterio
    from affine import Affine

    with rasterio.open(path, "w", driver="GTiff", width=values.shape[1], height=values.shape[0], count=1,
                       dtype="float32", crs=crs, transform=Affine(pixel, 0.0, left, 0.0, -pixel, top),
                       nodata=-9999.0) as out:
        out.write(values.astype(np.float32), 1)
        if moment is not None:
            out.update_tags(TIFFTAG_DATETIME=moment)
    return path


PIXEL, LEFT, TOP = 1000.0, -600_000.0, -900_000.0


@pytest.fixture(scope="module")
def tracked(tmp_path_factory):
    """Two GeoTIFFs written by rasterio in EPSG:3995 (the ice moves 2 rows down, 3 columns right in one day),
    tracked by `seaice track`, then `seaice velocities` on its floes."""
    root = tmp_path_factory.mktemp("geotiffs")
    big = _texture(np.random.default_rng(5), 140)
    first, second = big[10:130, 10:130], big[8:128, 7:127].copy()
    second[:4, :4] = -9999.0  # no data there
    a = _write_geotiff(root / "a.tif", first, "EPSG:3995", LEFT, TOP, PIXEL, "2024:03:01 06:00:00")
    b = _write_geotiff(root / "b.tif", second, "EPSG:3995", LEFT, TOP, PIXEL, "2024:03:02 06:00:00")
    # the grid lies on Greenland's land (GSHHG): without --land none every vector would be flagged "on land"
    assert main(["track", str(a), str(b), "--out", str(root / "drift"), "--land", "none", "-q"]) == 0
    assert main(["velocities", str(root / "drift" / "floes.csv"), "--out", str(root / "velocities"), "--projection",
                 "EPSG:3995", "--box-km", "40", "-q"]) == 0
    return root


def test_track_reads_geotiffs_made_elsewhere_and_finds_their_shift(tracked):
    import xarray as xr

    pixel, left, out = PIXEL, LEFT, tracked / "drift"
    with xr.open_dataset(out / "drift_a_b.nc") as ds:
        dx, dy = ds["dX"].values[0], ds["dY"].values[0]
        crs = pyproj.CRS.from_wkt(ds["crs"].attrs["crs_wkt"])
        x = ds["xc"].values
        u = ds["u_grid"].values[0]
    assert crs.equals(pyproj.CRS.from_epsg(3995))
    column = (x - (left + 0.5 * pixel)) / pixel  # the lattice is on the files' pixel centres
    np.testing.assert_allclose(column, np.round(column), rtol=0, atol=1e-9)
    good = np.isfinite(dx)
    assert good.mean() > 0.8
    for measured, shift in ((dx[good], 3 * pixel), (dy[good], -2 * pixel)):  # sub-pixel peaks: ~0.05 px rms
        assert abs(np.median(measured) - shift) < 0.02 * pixel and np.max(np.abs(measured - shift)) < 0.25 * pixel
    np.testing.assert_allclose(u[good], 3 * pixel / 86400.0, rtol=0.05)
    floes = np.genfromtxt(out / "floes.csv", delimiter=",", names=True, dtype=None, encoding=None)
    start = {f: (p, s) for f, i, p, s in zip(floes["floe_id"], floes["image"], floes["pixel"], floes["scan"],
                                             strict=True) if i == "a"}
    moved = [(p - start[f][0], s - start[f][1]) for f, i, p, s in zip(floes["floe_id"], floes["image"],
                                                                       floes["pixel"], floes["scan"], strict=True)
             if i == "b"]
    assert len(moved) > 50
    np.testing.assert_allclose(np.median(moved, axis=0), [3.0, 2.0], atol=0.1)
    # velocities along the EPSG:3995 grid's axes: the same 3 km east-ward (x) and 2 km south-ward (y) per day
    speeds = np.genfromtxt(tracked / "velocities" / "velocities.csv", delimiter=",", names=True, dtype=None,
                           encoding=None)
    np.testing.assert_allclose(np.median(speeds["u_grid_m_s"]), 3 * pixel / 86400.0, rtol=0.03)
    np.testing.assert_allclose(np.median(speeds["v_grid_m_s"]), -2 * pixel / 86400.0, rtol=0.03)


UNITLESS = {"pixel", "scan", "count", "tie", "reference", "removed", "correlation"}
"""Numeric CSV columns that are their own unit (pixels, scan lines, counts), flags or dimensionless."""
UNIT_SUFFIXES = ("_m", "_km", "_s", "_per_s", "_m_s", "_deg", "_arcmin", "_mm", "_m2", "_m_per_mm")


def _numeric_columns_without_unit(path):
    import csv

    with open(path, newline="") as stream:
        rows = list(csv.DictReader(stream))
    names = list(rows[0]) if rows else []

    def numeric(name):
        try:
            return all(np.isfinite(float(r[name])) or r[name] == "nan" for r in rows)
        except ValueError:
            return False

    return [n for n in names if numeric(n) and n not in UNITLESS and not n.endswith(UNIT_SUFFIXES)
            and not n.startswith(("w_", "redundancy_", "sigma_pixel", "sigma_scan"))]


def test_every_csv_names_the_unit_of_its_numbers(tracked, tmp_path):
    written = sorted(tracked.rglob("*.csv"))
    assert {p.name for p in written} >= {"floes.csv", "velocities.csv", "box_averages.csv", "deformation.csv"}
    for path in written:
        assert _numeric_columns_without_unit(path) == [], path
    header = (tracked / "drift" / "floes.csv").read_text().splitlines()[0]
    assert header == ("floe_id,time,image,pixel,scan,latitude_deg,longitude_deg,tracking_sigma_x_m,tracking_sigma_y_m,"
                      "correlation")
    # the readers take degree columns with or without the unit: the same records either way
    from seaice_jax.drift.records import read_records

    bare = tmp_path / "bare.csv"
    bare.write_text((tracked / "drift" / "floes.csv").read_text().replace("latitude_deg,longitude_deg",
                                                                         "latitude,longitude", 1))
    with_unit, without = read_records(tracked / "drift" / "floes.csv"), read_records(bare)
    np.testing.assert_array_equal(with_unit.latitude, without.latitude)
    np.testing.assert_array_equal(with_unit.longitude, without.longitude)


def test_track_refuses_geotiffs_of_different_grids_or_without_times(tmp_path, rng, capsys):
    image = _texture(rng, 40)
    a = _write_geotiff(tmp_path / "a.tif", image, "EPSG:3995", 0.0, 0.0, 1000.0)
    b = _write_geotiff(tmp_path / "b.tif", image, "EPSG:3995", 0.0, 0.0, 500.0)
    c = _write_geotiff(tmp_path / "c.tif", image, "EPSG:3413", 0.0, 0.0, 1000.0)
    times = ["--times", "2024-03-01T06:00:00Z", "2024-03-02T06:00:00Z"]
    for other in (b, c):
        assert main(["track", str(a), str(other), *times, "--out", str(tmp_path / "out")]) == 2
        assert "differs from that of" in capsys.readouterr().err
    assert main(["track", str(a), str(a), "--out", str(tmp_path / "out")]) == 2
    assert "no TIFF DateTime tag" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_remap_into_a_proj_string_grid(tmp_path):
    """An image of a given scan model whose values are linear in pixel and scan (bilinear remapping is then exact)
    remapped into a Lambert azimuthal grid: every remapped value is the image's value at the point PROJ and the scan
    model put under that grid pixel, and GDAL reads the grid's CRS back."""
    import rasterio

    from seaice_jax.geometry.scan import ScanModel, satellite_orbit
    from seaice_jax.io.remapped import load_remapped

    size = 64
    model = ScanModel(np.radians(7.0), 30.0, np.radians(99.0), np.radians(5.6), np.radians(66.0),
                      satellite_orbit("NOAA-7", altitude=0.0), "south", n_pixels=size, n_scans=size)
    scan, pixel = np.mgrid[1:size + 1, 1:size + 1].astype(float)
    np.save(tmp_path / "IMG.npy", 3.0 * pixel + 7.0 * scan)
    centre_lat, centre_lon = (float(np.degrees(v)) for v in model.forward(size / 2 + 0.5, size / 2 + 0.5))
    unknowns = {"scanner_angle_span_deg": 7.0, "subtrack_pixel": 30.0, "orbital_angle_first_deg": 99.0,
                "orbital_angle_span_deg": 5.6, "ascending_node_deg": 66.0}
    (tmp_path / "sequence.toml").write_text(
        f'epoch = "1983-03-08T00:00:00Z"\n[grid]\nprojection = "{LAEA}"\ncentre_deg = [{centre_lat!r}, '
        f"{centre_lon!r}]\npixel_m = [10000.0, 10000.0]\nshape = [40, 40]\n[[image]]\nname = \"IMG\"\n"
        'time = "1983-03-08T01:00:00Z"\nfile = "IMG.npy"\nsatellite = "NOAA-7"\naltitude_m = 0.0\n'
        'direction = "south"\n' + "".join(f"{k} = {v!r}\n" for k, v in unknowns.items()))
    assert main(["remap", str(tmp_path / "sequence.toml"), "--out", str(tmp_path / "remapped"), "--fill", "0",
                 "-q"]) == 0
    stack = load_remapped(tmp_path / "remapped")
    assert isinstance(stack.grid.projection, CrsProjection)
    x, y = (np.asarray(v) for v in stack.grid.xy())
    longitude, latitude = pyproj.Transformer.from_crs(LAEA, "EPSG:4326", always_xy=True).transform(x, y)
    expected_pixel, expected_scan = (np.asarray(v) for v in model.inverse(np.radians(latitude),
                                                                           np.radians(longitude)))
    inside = ((expected_pixel > 2) & (expected_pixel < size - 1) & (expected_scan > 2)
              & (expected_scan < size - 1))
    assert inside.mean() > 0.3
    assert np.all(stack.valid[0][inside])
    np.testing.assert_allclose(stack.values[0][inside], (3.0 * expected_pixel + 7.0 * expected_scan)[inside],
                               rtol=0, atol=0.6)  # the approximate transformer's 0.05 px, 10 value units per px
    with rasterio.open(tmp_path / "remapped" / "IMG.tif") as tif:  # GDAL reads the user-defined CRS as LAEA
        crs = pyproj.CRS.from_wkt(tif.crs.to_wkt())
        assert crs.coordinate_operation is not None
        assert crs.coordinate_operation.method_name.startswith("Lambert Azimuthal Equal Area")
        read_lon, read_lat = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(x, y)
        np.testing.assert_allclose(np.stack([read_lat, read_lon]), np.stack([latitude, longitude]), rtol=0,
                                   atol=1e-9)
        assert tif.transform.c == pytest.approx(float(x[0, 0]) - 5000.0)
        np.testing.assert_array_equal(tif.read(1), stack.values[0].astype(np.float32))


@pytest.mark.parametrize("projection, message", [
    ("EPSG:4326", "not a projected CRS"),
    ("+proj=nonsense", "pyproj does not know it"),
    ("+proj=ortho +lat_0=-90 +lon_0=0 +datum=WGS84 +units=m", "outside the domain of projection"),
])
def test_a_grid_projection_that_cannot_serve_is_named_with_its_file(tmp_path, capsys, projection, message):
    project = tmp_path / "sequence.toml"
    project.write_text(f'epoch = "1983-03-08T00:00:00Z"\n[grid]\nprojection = "{projection}"\n'
                       "centre_deg = [74.0, -85.0]\npixel_m = [2500.0, 2500.0]\nshape = [10, 10]\n")
    assert main(["remap", str(project), "--out", str(tmp_path / "out")]) == 2
    error = capsys.readouterr().err
    assert f"{project}: [grid]" in error and message in error
    assert not (tmp_path / "out").exists()
