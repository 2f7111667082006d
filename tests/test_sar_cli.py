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
