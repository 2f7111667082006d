"""The written products read by the tools researchers use: the IOOS compliance checker (CF 1.8, ACDD 1.3),
xarray on the OSI SAF layout, rasterio on the GeoTIFF, GDAL/OGR (pyogrio) on the GeoJSON layers."""

import json

import numpy as np
import pytest

from seaice_jax.geometry.projections import (
    Equirectangular,
    LambertConformalConic,
    MapGrid,
    PolarStereographic,
    TangentPlane,
    nsidc_polar_stereographic,
)
from seaice_jax.imagery.tracking import GOOD, LOW_CORRELATION, NO_DATA, OUTLIER, STATUS
from seaice_jax.io.products import (
    OSISAF_STATUS,
    write_drift_netcdf,
    write_fixes_geojson,
    write_geotiff,
    write_osisaf_drift,
    write_trajectories_geojson,
)

EPOCH = "1983-03-08T00:00:00Z"
START, END = 3600.0, 90000.0
ACDD_BASICS = ("title", "summary", "keywords", "history", "date_created", "time_coverage_start", "time_coverage_end",
               "product_version", "institution", "source", "references")


def drift_fields(grid):
    rng = np.random.default_rng(4)
    fields = {"dX": rng.normal(1500.0, 300.0, grid.shape), "dY": rng.normal(-700.0, 300.0, grid.shape),
              "dX_uncertainty": rng.uniform(100.0, 300.0, grid.shape),
              "dY_uncertainty": rng.uniform(100.0, 300.0, grid.shape),
              "status_flag": np.full(grid.shape, GOOD), "u_east": np.zeros(grid.shape), "v_north": np.zeros(grid.shape)}
    for (row, column), code in (((2, 3), LOW_CORRELATION), ((0, 0), NO_DATA), ((5, 7), OUTLIER)):
        fields["dX"][row, column] = fields["dY"][row, column] = np.nan
        fields["status_flag"][row, column] = code
    return fields


@pytest.fixture(scope="module", name="grid")
def nsidc_grid():
    return MapGrid.centred(nsidc_polar_stereographic("north"), np.radians(74.0), np.radians(-85.0), 5000.0, 5000.0,
                           6, 8)


def failures(path, checker: str, weights: tuple[int, ...]) -> list:
    """``(weight, name, messages)`` of every failed check of the IOOS compliance checker with these weights
    (3 = highly recommended / required, 2 = recommended, 1 = suggested)."""
    from compliance_checker.suite import CheckSuite

    suite = CheckSuite()
    suite.load_all_available_checkers()
    ((results, errors),) = suite.run_all(suite.load_dataset(str(path)), [checker], [], []).values()
    assert not errors, errors
    found = []
    for result in results:
        passed, total = result.value if isinstance(result.value, tuple) else (bool(result.value), 1)
        if result.weight in weights and passed < total:
            found.append((result.weight, result.name, result.msgs))
    return found


@pytest.mark.filterwarnings("ignore:Problem fetching standard name table")
@pytest.mark.parametrize("layout", ["project", "osisaf"])
def test_drift_files_pass_the_cf_and_acdd_checks(tmp_path, grid, layout):
    path = tmp_path / f"{layout}.nc"
    if layout == "project":
        write_drift_netcdf(path, grid, drift_fields(grid), START, END, EPOCH, STATUS)
    else:
        write_osisaf_drift(path, grid, drift_fields(grid), START, END, EPOCH)
    assert failures(path, "cf:1.8", (1, 2, 3)) == []
    # OSI SAF's dt0/dt1 (time offsets) have no CF standard name: the only highly recommended item missing
    missing = [] if layout == "project" else [(3, f'variable "{name}" missing the following attributes:',
                                                ["standard_name"]) for name in ("dt0", "dt1")]
    assert failures(path, "acdd:1.3", (3,)) == missing
    # of the recommended ACDD attributes, those the brief names are present (the checker only warns)
    import netCDF4

    with netCDF4.Dataset(path) as ds:
        attrs = {name: ds.getncattr(name) for name in ds.ncattrs()}
        crs = {name: ds["crs"].getncattr(name) for name in ds["crs"].ncattrs()}
        flag = ds["status_flag"]
        assert flag.long_name and flag._FillValue == -1 and len(flag.flag_values) == len(flag.flag_meanings.split())
    assert attrs["Conventions"] == "CF-1.8, ACDD-1.3"
    assert all(str(attrs[name]).strip() for name in ACDD_BASICS), [n for n in ACDD_BASICS if n not in attrs]
    assert (attrs["time_coverage_start"], attrs["time_coverage_end"]) == ("1983-03-08T01:00:00Z",
                                                                          "1983-03-09T01:00:00Z")
    # the grid mapping: CF parameters and crs_wkt only, the WKT being the NSIDC north grid's (EPSG:3413)
    import pyproj

    assert "proj4_params" not in crs and "epsg_code" not in crs
    assert pyproj.CRS.from_wkt(crs["crs_wkt"]).equals(pyproj.CRS.from_epsg(3413))
    assert crs["grid_mapping_name"] == "polar_stereographic"


def test_osisaf_layout_read_back_with_that_products_names_and_units(tmp_path, grid):
    import xarray as xr

    fields = drift_fields(grid)
    write_drift_netcdf(tmp_path / "project.nc", grid, fields, START, END, EPOCH, STATUS)
    write_osisaf_drift(tmp_path / "osisaf.nc", grid, fields, START, END, EPOCH)
    with xr.open_dataset(tmp_path / "osisaf.nc") as osi, xr.open_dataset(tmp_path / "project.nc") as own:
        assert {"lat", "lon", "dt0", "lon1", "lat1", "dt1", "dX", "dY", "status_flag",
                "uncert_dX_and_dY", "time_bnds", "crs"} <= set(osi.variables)
        units = {name: osi[name].attrs["units"] for name in ("dX", "dY", "uncert_dX_and_dY", "dt0", "dt1", "lat1",
                                                              "lon1")}
        assert units == {"dX": "km", "dY": "km", "uncert_dX_and_dY": "km", "dt0": "s", "dt1": "s",
                         "lat1": "degrees_north", "lon1": "degrees_east"}
        assert osi["dX"].attrs["standard_name"] == "sea_ice_x_displacement"
        # the same vectors, in km, against the project's own file in metres
        np.testing.assert_allclose(osi["dX"].values * 1000.0, own["dX"].values, rtol=1e-6)
        np.testing.assert_allclose(osi["dY"].values * 1000.0, own["dY"].values, rtol=1e-6)
        np.testing.assert_allclose(osi["lat1"].values, own["lat1"].values, atol=1e-5)
        sigma = np.hypot(fields["dX_uncertainty"], fields["dY_uncertainty"]) / np.sqrt(2) / 1000.0
        good = fields["status_flag"] == GOOD
        np.testing.assert_allclose(osi["uncert_dX_and_dY"].values[0][good], sigma[good], rtol=1e-6)
        assert np.isnan(osi["uncert_dX_and_dY"].values[0, 0, 0]) and np.isnan(osi["dt0"].values[0, 2, 3])
        np.testing.assert_array_equal(osi["dt1"].values[0][good], 0.0)
        # OSI SAF's flag codes: 30 nominal, 0 missing input, 11 too low correlation, 13 filtered by neighbours
        status = osi["status_flag"].values[0]
        assert status[1, 1] == 30 and status[0, 0] == 0 and status[2, 3] == 11 and status[5, 7] == 13
        meanings = dict(zip(osi["status_flag"].attrs["flag_values"].tolist(),
                            osi["status_flag"].attrs["flag_meanings"].split(), strict=True))
        assert meanings == OSISAF_STATUS and meanings[30] == "nominal_quality"
    with pytest.raises(Exception, match="status codes \\[99\\] have no OSI SAF equivalent"):
        write_osisaf_drift(tmp_path / "bad.nc", grid, {**fields, "status_flag": np.full(grid.shape, 99)}, START,
                           END, EPOCH)


@pytest.mark.parametrize("kind", ["nsidc", "equirectangular", "tangent", "lambert", "polar_south_71"])
def test_geotiff_read_by_rasterio_with_crs_and_transform(tmp_path, kind):
    """GDAL (through rasterio) reads the grid's CRS and transform: the pixel centres it computes, projected back by
    the CRS it reads, land on the project's own inverse projection of the same pixels."""
    import pyproj
    import rasterio

    lat0, lon0 = np.radians(74.0), np.radians(-87.0)
    projection = {"nsidc": nsidc_polar_stereographic("north"), "equirectangular": Equirectangular(lat0, lon0),
                  "tangent": TangentPlane(lat0, lon0),
                  "lambert": LambertConformalConic(np.radians(70.0), np.radians(78.0), np.radians(74.0), lon0,
                                                   2.0e5, -1.0e5),
                  "polar_south_71": PolarStereographic(np.radians(-71.0), np.radians(0.0))}[kind]
    if kind == "polar_south_71":
        lat0, lon0 = np.radians(-70.0), np.radians(30.0)
    g = MapGrid.centred(projection, lat0, lon0, 1000.0, 1200.0, 6, 8)
    image = np.arange(48, dtype=float).reshape(6, 8)
    write_geotiff(tmp_path / "a.tif", image, g)
    with rasterio.open(tmp_path / "a.tif") as raster:
        np.testing.assert_array_equal(raster.read(1), image.astype(np.float32))
        rows, columns = np.mgrid[0:6, 0:8]
        x, y = raster.transform * (columns + 0.5, rows + 0.5)
        crs = pyproj.CRS.from_wkt(raster.crs.to_wkt())
        epsg = raster.crs.to_epsg()
    grid_x, grid_y = (np.asarray(a) for a in g.xy())
    np.testing.assert_allclose(x, grid_x, atol=1e-6)
    np.testing.assert_allclose(y, grid_y, atol=1e-6)
    inverse = pyproj.Transformer.from_crs(crs, crs.geodetic_crs, always_xy=True)
    lon, lat = inverse.transform(x, y)
    own_lat, own_lon = (np.degrees(np.asarray(a)) for a in projection.inverse(grid_x, grid_y))
    np.testing.assert_allclose(lat, own_lat, atol=1e-7)
    np.testing.assert_allclose(lon, own_lon, atol=1e-7)
    assert (epsg == 3413) == (kind == "nsidc")


def test_geojson_layers_have_one_geometry_type_each(tmp_path):
    import pyogrio

    floe = np.array(["F1", "F2", "F1", "F3", "F1", "F2"])
    time = np.array([0.0, 0.0, 86400.0, 86400.0, 172800.0, 86400.0])
    latitude, longitude = np.radians([74.0, 74.2, 74.05, 73.0, 74.1, 74.25]), np.radians([-85, -84, -84.9, -80,
                                                                                           -84.8, -83.95])
    write_trajectories_geojson(tmp_path / "t.geojson", floe, time, latitude, longitude, EPOCH)
    write_fixes_geojson(tmp_path / "f.geojson", floe, time, latitude, longitude, EPOCH)
    lines, points = (pyogrio.read_info(tmp_path / name) for name in ("t.geojson", "f.geojson"))
    assert lines["geometry_type"] == "LineString" and lines["features"] == 2  # F3 has one fix: not a line
    assert points["geometry_type"] == "Point" and points["features"] == 6
    assert "4326" in str(lines["crs"]) and "4326" in str(points["crs"])
    meta, _, geometry, field_data = pyogrio.raw.read(tmp_path / "f.geojson")
    assert len(geometry) == 6 and sorted(field_data[list(meta["fields"]).index("floe_id")]) == sorted(floe.tolist())
    collection = json.loads((tmp_path / "t.geojson").read_text())
    first = collection["features"][0]
    assert first["properties"]["floe_id"] == "F1" and first["properties"]["times"] == [
        "1983-03-08T00:00:00Z", "1983-03-09T00:00:00Z", "1983-03-10T00:00:00Z"]
    assert first["geometry"]["coordinates"][0] == pytest.approx([-85.0, 74.0])
    fixes = json.loads((tmp_path / "f.geojson").read_text())["features"]
    assert [f["properties"]["sequence"] for f in fixes if f["properties"]["floe_id"] == "F1"] == [0, 1, 2]
