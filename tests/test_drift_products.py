"""Velocities, deformation, floe records and the files other tools read."""

import json

import numpy as np
import pytest

from seaice_jax.drift.kinematics import box_averages, box_time_series, deformation, grid_to_east_north, velocities
from seaice_jax.drift.records import FloeRecords, read_records, write_records
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.projections import Equirectangular, MapGrid, nsidc_polar_stereographic

GRADIENT = np.array([[2e-7, 3e-7], [-1e-7, -0.5e-7]])  # 1/s


def affine_field(points):
    return np.array([0.05, -0.02]) + points @ GRADIENT.T


def test_deformation_of_an_affine_field_is_exact():
    rng = np.random.default_rng(0)
    points = rng.uniform(0, 100e3, (30, 2))
    result = deformation(points, affine_field(points), 0.002)
    assert len(result.triangles) > 30
    np.testing.assert_allclose(result.divergence, np.trace(GRADIENT), rtol=0, atol=1e-18)
    np.testing.assert_allclose(result.vorticity, GRADIENT[1, 0] - GRADIENT[0, 1], rtol=0, atol=1e-18)
    np.testing.assert_allclose(result.shear, np.hypot(GRADIENT[0, 0] - GRADIENT[1, 1],
                                                      GRADIENT[0, 1] + GRADIENT[1, 0]), rtol=1e-12)
    np.testing.assert_allclose(result.gradient, np.broadcast_to(GRADIENT, result.gradient.shape), atol=1e-18)
    clockwise = deformation(points, affine_field(points), 0.002, result.triangles[:, ::-1])
    np.testing.assert_allclose(clockwise.divergence, result.divergence, atol=1e-18)
    with pytest.raises(SeaiceError, match="at least 3 points"):
        deformation(points[:2], affine_field(points[:2]), 0.002)


def test_propagated_deformation_sigma_matches_monte_carlo():
    """First-order σ: exact for divergence and vorticity (linear in the velocities), and for the shear where the
    shear is well above its noise (the shear is a norm: near zero it is biased, Rice-distributed)."""
    rng = np.random.default_rng(1)
    points = rng.uniform(0, 200e3, (12, 2))
    velocity, sigma = affine_field(points), 0.0005
    predicted = deformation(points, velocity, sigma)
    runs = np.array([[getattr(deformation(points, velocity + rng.normal(0, sigma, velocity.shape), sigma,
                                          predicted.triangles), k) for k in ("divergence", "shear", "vorticity")]
                     for _ in range(600)])
    empirical = runs.std(axis=0)  # (3, t)
    for k, name in enumerate(("divergence", "shear", "vorticity")):
        ratio = np.sqrt(np.mean(getattr(predicted, f"sigma_{name}") ** 2) / np.mean(empirical[k] ** 2))
        assert abs(ratio - 1) < 0.1, (name, ratio)


def test_velocities_grid_and_east_north_and_box_averages():
    projection = nsidc_polar_stereographic("north")
    # on the central meridian (45°W) grid +y points to the pole: north
    x, y = (np.asarray(a) for a in projection.forward(np.radians(75.0), np.radians(-45.0)))
    east, north = grid_to_east_north(projection, x, y, 0.0, 1.0)
    np.testing.assert_allclose([float(east[0]), float(north[0])], [0.0, 1.0], atol=1e-9)
    # elsewhere: a small step along the vector changes latitude and longitude as its east/north parts say
    lat, lon = np.radians(74.0), np.radians(-85.0)
    x, y = (float(a) for a in projection.forward(lat, lon))
    east, north = grid_to_east_north(projection, x, y, 0.3, 0.4)
    lat2, lon2 = (float(a) for a in projection.inverse(x + 0.3, y + 0.4))
    e2 = float(projection.flattening) * (2 - float(projection.flattening))  # the projection is on WGS84
    w = 1 - e2 * np.sin(lat) ** 2
    step = np.array([(lon2 - lon) * np.cos(lat) / np.sqrt(w), (lat2 - lat) * (1 - e2) / w**1.5])  # N cos φ dλ, M dφ
    np.testing.assert_allclose(step / np.linalg.norm(step), np.array([east[0], north[0]]) / 0.5, atol=1e-6)

    floe = np.array(["A", "B", "A", "B", "A"])
    time = np.array([0.0, 0.0, 86400.0, 86400.0, 2 * 86400.0])
    px = np.array([0.0, 5000.0, 8640.0, 5000.0 + 4320.0, 8640.0 * 2]) + x
    py = np.full(5, y)
    v = velocities(floe, time, px, py, projection)
    np.testing.assert_allclose(np.sort(v.u_grid), [0.05, 0.1, 0.1])
    np.testing.assert_allclose(v.speed, np.hypot(v.u_east, v.v_north))
    boxes = box_averages(v.x, v.y, v.u_grid, v.v_grid, 1e6, origin=(x - 5e5, y - 5e5))
    assert boxes.count.tolist() == [3]
    np.testing.assert_allclose(boxes.u, [0.25 / 3]), np.testing.assert_allclose(boxes.sigma_u, [np.std(
        [0.05, 0.1, 0.1], ddof=1)])
    series = box_time_series(v, 1e6, origin=(x - 5e5, y - 5e5))
    (entry,) = series.values()
    np.testing.assert_allclose(entry["u"], [0.075, 0.1])  # day 0: both floes; day 1: floe A
    with pytest.raises(SeaiceError, match="floe A: two fixes at the same time"):
        velocities(np.array(["A", "A"]), np.zeros(2), np.zeros(2), np.zeros(2), projection)


def sample_records(tmp_path):
    records = FloeRecords(np.array(["F1", "F2", "F1", "F2"]), np.array([0.0, 0.0, 86400.0, 86400.0]),
                          np.array(["IMG01", "IMG01", "IMG02", "IMG02"]), np.array([10.5, 20.0, 12.25, 21.0]),
                          np.array([30.0, 40.0, 31.0, 41.0]), np.radians([74.0, 74.2, 74.05, 74.25]),
                          np.radians([-85.0, -84.0, -84.9, -83.95]), "1983-03-08T14:00:00Z")
    path = write_records(tmp_path / "floes.csv", records)
    return records, path


def test_records_round_trip(tmp_path):
    records, path = sample_records(tmp_path)
    back = read_records(path, images={"IMG01", "IMG02"})
    for name in ("floe", "image", "time", "pixel", "scan"):
        np.testing.assert_array_equal(getattr(back, name), getattr(records, name))
    np.testing.assert_allclose(back.latitude, records.latitude, atol=1e-12)
    assert back.epoch == records.epoch and back.lines.tolist() == [2, 3, 4, 5]


@pytest.mark.parametrize("line, replacement, message", [
    (3, "F2,1983-02-30T14:00:00Z,IMG01,20,40,74.2,-84", r"line 3: floe F2: invalid date '1983-02-30T14:00:00Z'"),
    (4, "F1,1983-03-09T14:00:00Z,IMG09,12.25,31,74.05,-84.9", r"line 4: floe F1: unknown image 'IMG09'"),
    (4, "F1,1983-03-09T14:00:00Z,IMG01,12.25,31,74.05,-84.9",
     r"line 4: floe F1 appears twice in image IMG01 \(first at line 2\): duplicate id"),
    (4, "F1,1983-03-08T13:00:00Z,IMG02,12.25,31,74.05,-84.9",
     r"line 4: floe F1: time 1983-03-08T13:00:00Z is not after its previous record \(line 2"),
    (5, "F2,1983-03-09T14:00:00Z,IMG02,21,41,94.25,-83.95", r"line 5: floe F2: position .* outside"),
    (5, "F2,1983-03-09T14:00:00Z,IMG02,x,41,74.25,-83.95", r"line 5: floe F2: pixel 'x' is not a number"),
])
def test_records_validation_names_the_record(tmp_path, line, replacement, message):
    _, path = sample_records(tmp_path)
    lines = path.read_text().splitlines()
    lines[line - 1] = replacement
    path.write_text("\n".join(lines) + "\n")
    before = path.read_bytes()
    with pytest.raises(SeaiceError, match=message):
        read_records(path, images={"IMG01", "IMG02"})
    assert path.read_bytes() == before  # input untouched


def test_records_missing_column_is_named(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("floe_id,time,image,pixel,scan,latitude\nF1,1983-03-08T00:00:00Z,A,1,1,74\n")
    with pytest.raises(SeaiceError, match=r"bad.csv: missing column\(s\) longitude"):
        read_records(path)


def test_geotiff_netcdf_geojson_are_read_back(tmp_path):
    import pyproj
    import tifffile
    import xarray as xr

    from seaice_jax.imagery.tracking import STATUS
    from seaice_jax.io.products import write_drift_netcdf, write_geotiff, write_trajectories_geojson

    projection = nsidc_polar_stereographic("north")
    grid = MapGrid.centred(projection, np.radians(74.0), np.radians(-85.0), 5000.0, 5000.0, 6, 8)
    image = np.arange(48, dtype=float).reshape(6, 8)
    image[0, 0] = np.nan
    write_geotiff(tmp_path / "a.tif", image, grid)
    with tifffile.TiffFile(tmp_path / "a.tif") as tif:
        page = tif.pages[0]
        np.testing.assert_array_equal(page.asarray()[1:], image[1:].astype(np.float32))
        assert np.isnan(page.asarray()[0, 0])
        assert tif.geotiff_metadata["ProjectedCSTypeGeoKey"] == 3413
        scale = page.tags["ModelPixelScaleTag"].value
        tie = page.tags["ModelTiepointTag"].value
    assert scale[:2] == (5000.0, 5000.0)
    assert tie[3] == pytest.approx(float(grid.x_first) - 2500.0) and tie[4] == pytest.approx(float(grid.y_first)
                                                                                              + 2500.0)
    # a projection without EPSG code: its PROJ string, checked against PROJ itself
    eqc = Equirectangular(np.radians(74.0), np.radians(-87.0))
    write_geotiff(tmp_path / "b.tif", image, MapGrid.centred(eqc, np.radians(74.0), np.radians(-87.0), 1000.0,
                                                             1200.0, 6, 8))
    with tifffile.TiffFile(tmp_path / "b.tif") as tif:
        citation = tif.geotiff_metadata["GTCitationGeoKey"]
    transformer = pyproj.Transformer.from_crs("+proj=longlat +R=6371000 +no_defs", citation.rstrip("|"),
                                              always_xy=True)
    np.testing.assert_allclose(transformer.transform(-80.0, 75.0), [float(v) for v in eqc.forward(
        np.radians(75.0), np.radians(-80.0))], atol=1e-6)
    assert projection.proj_string().startswith("+proj=stere +lat_0=90")

    fields = {"dX": np.full(grid.shape, 1500.0), "dY": np.full(grid.shape, -700.0),
              "dX_uncertainty": np.full(grid.shape, 200.0), "dY_uncertainty": np.full(grid.shape, 250.0),
              "status_flag": np.zeros(grid.shape, int), "u_east": np.zeros(grid.shape), "v_north": np.zeros(
                  grid.shape)}
    fields["dX"][2, 3] = np.nan
    fields["status_flag"][2, 3] = 3
    rates = deformation(np.stack([np.asarray(a).ravel() for a in grid.xy()], 1), np.full((48, 2), 0.01), 0.001)
    write_drift_netcdf(tmp_path / "drift.nc", grid, fields, 3600.0, 90000.0, "1983-03-08T00:00:00Z", STATUS,
                       deformation=rates)
    with xr.open_dataset(tmp_path / "drift.nc") as ds:
        assert ds["dX"].attrs["standard_name"] == "sea_ice_x_displacement" and ds["dX"].attrs["units"] == "m"
        assert "dX_uncertainty" in ds["dX"].attrs["ancillary_variables"]
        assert ds["crs"].attrs["grid_mapping_name"] == "polar_stereographic"
        assert ds["dY"].attrs["grid_mapping"] == "crs"
        np.testing.assert_allclose(ds["u_grid"].values[0, 0, 0], 1500.0 / 86400.0)
        assert np.isnan(ds["dX"].values[0, 2, 3]) and int(ds["status_flag"].values[0, 2, 3]) == 3
        assert str(ds["time_bnds"].values[0, 1])[:19] == "1983-03-09T01:00:00"
        np.testing.assert_allclose(ds["divergence"].values, 0.0, atol=1e-15)
        # the end position is the start moved by (dX, dY) in the projection
        x1, y1 = projection.forward(np.radians(ds["lat1"].values[0, 0, 0]), np.radians(ds["lon1"].values[0, 0, 0]))
        np.testing.assert_allclose([float(x1) - ds["xc"].values[0], float(y1) - ds["yc"].values[0]],
                                   [1500.0, -700.0], atol=1e-3)

    records, _ = sample_records(tmp_path)
    write_trajectories_geojson(tmp_path / "t.geojson", records.floe, records.time, records.latitude,
                               records.longitude, records.epoch)
    collection = json.loads((tmp_path / "t.geojson").read_text())
    first = collection["features"][0]
    assert first["geometry"]["type"] == "LineString" and first["properties"]["floe_id"] == "F1"
    assert first["geometry"]["coordinates"][0] == pytest.approx([-85.0, 74.0])
    assert first["properties"]["times"] == ["1983-03-08T14:00:00Z", "1983-03-09T14:00:00Z"]
