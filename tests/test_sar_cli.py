"""``seaice sar geolocate`` on the real Smith Sound EW scene: every grid point in the CSV with differences within the
tolerances, the figure clean, bad input named before anything is written."""

import csv
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pytest

from seaice_jax.cli import main
from seaice_jax.io.sentinel1 import read_annotation
from seaice_jax.report.figures import sar_geolocation_figure
from seaice_jax.workflows.sar import check_geolocation
from tests.test_figures import assert_no_text_overprints

EW = Path(__file__).with_name("data") / "sentinel1" / \
    "s1a-ew1-slc-hh-20210403t122536-20210403t122628-037286-046484-001.xml"


def test_geolocate_writes_every_grid_point(tmp_path, capsys):
    out = tmp_path / "ew"
    assert main(["sar", "geolocate", str(EW), "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["geolocation.csv", "geolocation.png", "report.txt"]
    with open(out / "geolocation.csv") as handle:
        rows = list(csv.DictReader(handle))
    grid = read_annotation(EW).grid
    assert len(rows) == grid.line.size
    horizontal = np.array([float(r["horizontal_difference_m"]) for r in rows])
    assert horizontal.max() <= 0.05
    assert max(abs(float(r["inverse_time_difference_us"])) for r in rows) <= 5.0
    assert max(abs(float(r["image_time_difference_us"])) for r in rows) <= 5.0
    # independent of our model: the CSV's ESA columns are the file's grid, and ours lie within 1e-6 degrees of them
    esa = np.array([[float(r["esa_latitude_deg"]), float(r["esa_longitude_deg"])] for r in rows])
    ours = np.array([[float(r["latitude_deg"]), float(r["longitude_deg"])] for r in rows])
    np.testing.assert_allclose(esa, np.c_[grid.latitude, grid.longitude], rtol=0, atol=1e-11)
    np.testing.assert_allclose(ours, esa, rtol=0, atol=1e-6)
    assert rows[0]["azimuth_time_utc"].startswith("2021-04-03T12:25:36.5055")
    assert "horizontal difference from ESA max" in capsys.readouterr().out


def test_geolocation_figure_has_no_overprinted_text():
    fig = sar_geolocation_figure(check_geolocation(read_annotation(EW)))
    try:
        assert_no_text_overprints(fig)
        assert "EPSG:3413" in fig.axes[0].get_xlabel()
    finally:
        plt.close(fig)


def test_bad_annotation_is_named_and_nothing_written(tmp_path, capsys):
    broken = tmp_path / "broken.xml"
    broken.write_text(EW.read_text().replace("<orbitList", "<orbitListX", 1).replace("</orbitList>",
                                                                                       "</orbitListX>", 1))
    out = tmp_path / "out"
    assert main(["sar", "geolocate", str(broken), "--out", str(out)]) == 2
    assert not out.exists()
    message = capsys.readouterr().err
    assert str(broken) in message and "orbitList/orbit" in message


@pytest.mark.parametrize("reference", ["iw1", "missing"])
def test_reference_must_be_the_middle_sub_swath(tmp_path, capsys, reference):
    iw1 = next(EW.parent.glob("s1b-iw1-slc-vv-*.xml"))
    path = iw1 if reference == "iw1" else tmp_path / "absent.xml"
    assert main(["sar", "geolocate", str(iw1), "--reference", str(path), "--out", str(tmp_path / "o")]) == 2
    assert not (tmp_path / "o").exists()
    assert str(path.name) in capsys.readouterr().err


GRD = EW.parent / "s1b-iw-grd-vv-20210401t052623-20210401t052648-026269-032297-001.xml"


def _pattern(latitude_deg, longitude_deg):
    """A smooth ground pattern (waves of ~50 km) to paint on an image and find again on the map."""
    return np.sin(np.radians(latitude_deg) * 400.0) + np.cos(np.radians(longitude_deg) * 300.0)


def test_remap_puts_the_ground_pattern_where_it_belongs(tmp_path):
    """An image painted from ESA's geolocation grid alone (lat/lon bilinear in line/pixel between its points,
    independent of our model) comes back on the polar grid where the pattern says, and the σ grows with range."""
    import tifffile

    decimation = 40
    annotation = read_annotation(GRD).decimated(decimation)
    grid = annotation.grid
    lines, pixels = np.unique(grid.line), np.unique(grid.pixel)
    order = np.lexsort((grid.pixel, grid.line))
    table_lat = grid.latitude[order].reshape(lines.size, pixels.size)
    table_lon = grid.longitude[order].reshape(lines.size, pixels.size)
    line, pixel = np.meshgrid(np.arange(annotation.lines), np.arange(annotation.samples), indexing="ij")

    def bilinear(table):
        i = np.clip(np.searchsorted(lines, line, side="right") - 1, 0, lines.size - 2)
        j = np.clip(np.searchsorted(pixels, pixel, side="right") - 1, 0, pixels.size - 2)
        u = (line - lines[i]) / (lines[i + 1] - lines[i])
        v = (pixel - pixels[j]) / (pixels[j + 1] - pixels[j])
        return ((1 - u) * (1 - v) * table[i, j] + u * (1 - v) * table[i + 1, j] + (1 - u) * v * table[i, j + 1]
                + u * v * table[i + 1, j + 1])

    image = _pattern(bilinear(table_lat), bilinear(table_lon)).astype(np.float32)
    tifffile.imwrite(tmp_path / "quicklook.tif", image)
    out = tmp_path / "remap"
    assert main(["sar", "remap", str(GRD), str(tmp_path / "quicklook.tif"), "--out", str(out), "--spacing", "2000",
                 "--decimation", str(decimation)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["position_sigma.tif", "remapped.png", "remapped.tif",
                                                     "report.txt"]
    from seaice_jax.io.products import read_geotiff

    remapped, map_grid, _ = read_geotiff(out / "remapped.tif")
    sigma, _, _ = read_geotiff(out / "position_sigma.tif")
    latitude, longitude = (np.degrees(np.asarray(v)) for v in map_grid.latitude_longitude())
    inside = np.isfinite(remapped)
    assert inside.sum() > 5000
    error = remapped[inside] - _pattern(latitude, longitude)[inside]
    assert np.sqrt(np.mean(error**2)) < 0.01
    assert np.isfinite(sigma[inside]).all() and np.all(sigma[inside] > 0)


def test_remap_refuses_a_tops_slc_and_a_wrong_image_size(tmp_path, capsys):
    np.save(tmp_path / "small.npy", np.zeros((10, 10)))
    assert main(["sar", "remap", str(GRD), str(tmp_path / "small.npy"), "--out", str(tmp_path / "a")]) == 2
    assert "describes 16685 lines x 25788 samples" in capsys.readouterr().err
    assert main(["sar", "remap", str(EW), str(tmp_path / "small.npy"), "--out", str(tmp_path / "b")]) == 2
    assert "bursts" in capsys.readouterr().err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
