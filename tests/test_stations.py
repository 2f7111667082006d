import numpy as np
import pytest

from seaice_jax.errors import SeaiceError
from seaice_jax.io.stations import (
    Station,
    control_points,
    read_agrid,
    read_measurements,
    write_agrid,
)

# The Figure 3-3 stations in the AGRID layout, typed column by column as the manual describes.
AGRID = (
    " 3030     COB IS ICE                       75   43  -78   37\n"
    " 3031     N DEV PT                         75   51  -81   55\n"
    "\n"
    "   12     HALF DEGREE WEST                 74   30   -0   30\n"
)


def test_read_agrid_columns(tmp_path):
    path = tmp_path / "AGRID.STN"
    path.write_text(AGRID)
    stations = read_agrid(path)
    assert [s.number for s in stations] == [3030, 3031, 12]
    assert stations[0].name == "COB IS ICE"
    assert stations[0].latitude_deg == pytest.approx(75 + 43 / 60)
    assert stations[1].longitude_deg == pytest.approx(-(81 + 55 / 60))
    assert stations[2].longitude_deg == pytest.approx(-0.5)


def test_agrid_round_trip(tmp_path):
    stations = [Station(7, "CAPE SHERARD", 74.5833, -80.4167), Station(99, "X", -0.25, 120.5)]
    path = write_agrid(tmp_path / "out.stn", stations)
    back = read_agrid(path)
    for a, b in zip(stations, back, strict=True):
        assert (a.number, a.name) == (b.number, b.name)
        assert b.latitude_deg == pytest.approx(a.latitude_deg, abs=0.01 / 60)
        assert b.longitude_deg == pytest.approx(a.longitude_deg, abs=0.01 / 60)
    line = path.read_text().splitlines()[0]
    assert line[:5] == "    7" and line[10:40].rstrip() == "CAPE SHERARD" and len(line) == 60


@pytest.mark.parametrize("line, message", [
    ("  abc     NAME                             75   43  -78   37", r"line 2: station number 'abc'"),
    (" 3030     AGAIN                            75   43  -78   37", r"line 2: station 3030 already defined on line 1"),
    (" 3040     BAD MINUTE                       75   73  -78   37", r"line 2: latitude minute 73.0"),
    (" 3041     SHORT                            75", r"line 2: too short"),
])
def test_agrid_errors_name_file_and_line(tmp_path, line, message):
    path = tmp_path / "bad.stn"
    path.write_text(" 3030     COB IS ICE                       75   43  -78   37\n" + line + "\n")
    with pytest.raises(SeaiceError, match=f"bad.stn, {message}"):
        read_agrid(path)


def test_measurements_with_positions_and_joined_to_a_catalogue(tmp_path):
    direct = tmp_path / "direct.csv"
    direct.write_text("id,name,pixel,scan,lat,lon,sigma_km\nA,Alpha,10,20,75.5,-80.25,0.5\nB,Beta,30,40,74,-79,\n")
    ms = read_measurements(direct)
    assert [(m.id, m.pixel, m.scan, m.sigma_m) for m in ms] == [("A", 10, 20, 500.0), ("B", 30, 40, None)]
    catalogue = tmp_path / "AGRID.STN"
    catalogue.write_text(AGRID)
    joined = tmp_path / "joined.csv"
    joined.write_text("id,pixel,scan\n3030,164,123\n3031,114,172\n")
    ms = read_measurements(joined, read_agrid(catalogue))
    assert ms[0].name == "COB IS ICE" and ms[1].latitude_deg == pytest.approx(75 + 51 / 60)
    control = control_points(ms, default_sigma_km=2.0)
    assert control.ids == ("3030", "3031")
    np.testing.assert_allclose(control.sigma, 2000.0)


@pytest.mark.parametrize("content, message", [
    ("id,pixel,lat,lon\nA,1,70,0\n", r"line 1: missing column\(s\) scan"),
    ("id,pixel,scan,lat,lon\nA,1,2,70,0\nA,3,4,71,0\n", r"line 3: point A already measured on line 2"),
    ("id,pixel,scan,lat,lon\nA,one,2,70,0\n", r"line 2: column 'pixel' value 'one' is not a number"),
    ("id,pixel,scan,lat,lon\nA,1,2,95,0\n", r"line 2: point A latitude 95.0° is outside"),
    ("id,pixel,scan,lat,lon\nA,1,2,,\n", r"line 2: point A has no lat/lon and is not in the station catalogue"),
])
def test_measurement_errors_name_file_and_line(tmp_path, content, message):
    path = tmp_path / "m.csv"
    path.write_text(content)
    with pytest.raises(SeaiceError, match=f"m.csv, {message}"):
        read_measurements(path)
