"""GeoTIFFs written by the package carry the image's acquisition time: the TIFF DateTime tag and the GDAL metadata
item ACQUISITION_TIME, read back with rasterio (GDAL) and by ``seaice track``'s GeoTIFF reader."""

import numpy as np
import pytest
import rasterio

from seaice_jax.errors import SeaiceError
from seaice_jax.io.products import ACQUISITION_TIME, read_geotiff, write_geotiff
from seaice_jax.io.remapped import RemappedStack, geotiff_stack
from seaice_jax.io.sequence import make_grid
from seaice_jax.workflows.remap import write_remapped

SPEC = {"projection": "nsidc-north", "centre_deg": [74.0, -85.0], "pixel_m": [2500.0, 2500.0], "shape": [6, 8]}


def _grid():
    return make_grid(**SPEC)


def test_time_is_written_as_the_tiff_datetime_and_a_gdal_item(tmp_path):
    path = write_geotiff(tmp_path / "a.tif", np.ones((6, 8)), _grid(), "image A", time="2024-03-01T08:00:00.25+02:00")
    with rasterio.open(path) as source:
        tags = source.tags()
    assert tags["TIFFTAG_DATETIME"] == "2024:03:01 06:00:00"  # UTC, whole seconds
    assert tags[ACQUISITION_TIME] == "2024-03-01T06:00:00.250000Z"
    assert tags["TIFFTAG_IMAGEDESCRIPTION"] == "image A"
    assert read_geotiff(path)[2] == "2024-03-01T06:00:00.250000Z"


def test_without_a_time_neither_is_written_and_a_bad_time_writes_nothing(tmp_path):
    path = write_geotiff(tmp_path / "a.tif", np.ones((6, 8)), _grid())
    with rasterio.open(path) as source:
        tags = source.tags()
    assert "TIFFTAG_DATETIME" not in tags and ACQUISITION_TIME not in tags and read_geotiff(path)[2] is None
    with pytest.raises(SeaiceError, match=r"b.tif: acquisition time 'yesterday' is not an ISO 8601 date-time"):
        write_geotiff(tmp_path / "b.tif", np.ones((6, 8)), _grid(), time="yesterday")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.tif"]


def test_remapped_geotiffs_carry_their_image_times_into_tracking(tmp_path):
    grid = _grid()
    rng = np.random.default_rng(1)
    values = rng.normal(size=(2, 6, 8))
    stack = RemappedStack(values, np.ones(values.shape, bool), np.array([4520.0, 86400.0 + 3600.5]), ("A", "B"),
                          "1983-03-08T00:00:00Z", grid, SPEC, (), np.zeros((10, 10)), np.full(values.shape, np.nan))
    write_remapped(stack, [], tmp_path)
    with rasterio.open(tmp_path / "B.tif") as source:
        assert source.tags()["TIFFTAG_DATETIME"] == "1983:03:09 01:00:00"
        assert source.tags()[ACQUISITION_TIME] == "1983-03-09T01:00:00Z"
    tracked = geotiff_stack([tmp_path / "A.tif", tmp_path / "B.tif"])  # seaice track on GeoTIFFs: no --times needed
    np.testing.assert_allclose(tracked.times - tracked.times[0], [0.0, 86400.0 + 3600.0 - 4520.0])
    np.testing.assert_allclose(tracked.values, values.astype(np.float32))
