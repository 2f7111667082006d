import csv
import json

import numpy as np
import pytest

from seaice_jax.cli import main
from seaice_jax.files import atomic_path, write_csv
from seaice_jax.outputs import foreign_output
from seaice_jax.workflows.demo import DEMO_COMMAND, run_demo


def read_csv(path):
    with open(path, newline="") as stream:
        return list(csv.DictReader(stream))


@pytest.mark.slow
def test_demo_writes_its_files_and_its_numbers_hold(tmp_path):
    """The quick demo (a shorter image sequence: the same steps, the same files, the same checks).

    Minutes and ~3 GB: outside `make test`, run by `make test-slow`."""
    result = run_demo(tmp_path / "out", quick=True)
    names = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert names == ["aidjex", "figure_3_3_stations.csv", "manifest.json", "map.png", "orbit_fit.json",
                     "orbit_fit_report.txt", "position_sigma.png", "radar_strip.csv", "satellite_image.csv", "sequence"]
    assert foreign_output(tmp_path / "out", DEMO_COMMAND) is None  # a rerun replaces it
    listed = json.loads((tmp_path / "out" / "manifest.json").read_text())["files"]
    assert f"wrote {len(listed)} files into" in result.summary  # every file the folder holds, the manifest too
    for name in ("film.gif", "drift/drift_IMG01_IMG02.nc", "remapped/IMG03.tif", "velocities/box_averages.png",
                 "adjusted/models.npz", "adjusted/ties.csv"):
        assert (tmp_path / "out" / "sequence" / name).stat().st_size > 0
    assert "tracked drift of the first pair against the truth" in result.summary
    assert "simultaneous adjustment of 3 images" in result.summary
    assert (tmp_path / "out" / "aidjex" / "sequential" / "drift.geojson").exists()
    assert (tmp_path / "out" / "aidjex" / "simultaneous" / "navigation_errors.png").exists()
    assert "general drift" in result.summary and "sequential (1979)" in result.summary
    assert result.fit_rms_km <= 1.25 and abs(result.fit_subtrack_pixel - 112) <= 5
    assert "SUBTRACK PIXEL" in (tmp_path / "out" / "orbit_fit_report.txt").read_text()
    assert (tmp_path / "out" / "map.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    radar = read_csv(tmp_path / "out" / "radar_strip.csv")
    assert len(radar) == result.radar_points
    lat = np.array([float(r["latitude_deg"]) for r in radar])
    assert np.all((lat > 74.0) & (lat < 76.0))
    assert result.radar_time_error_s < 1e-6 and result.radar_range_error_m < 1e-3
    assert result.image_round_trip_pixels < 1e-6
    assert result.station_dlat_difference_arcmin < 1.5 and result.station_dlon_difference_arcmin < 1.5
    stations = read_csv(tmp_path / "out" / "figure_3_3_stations.csv")
    assert [row["id"] for row in stations] == ["3030", "3031", "3032", "3034", "3035"]
    assert "Figure 3-3 stations" in result.summary


def test_cli_demo_and_usage_errors(tmp_path, capsys):
    """(The demo itself runs in the test above; here the CLI's error path.)"""
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    assert main(["demo", "--out", str(blocker)]) == 2
    assert "seaice demo: error" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["no-such-command"])


def test_csv_is_atomic_and_names_the_bad_column(tmp_path):
    target = tmp_path / "table.csv"
    with pytest.raises(ValueError, match=r"columns differ in length: \{'a': 2, 'b': 3\}"):
        write_csv(target, {"a": [1.0, 2.0], "b": [1.0, 2.0, 3.0]})
    assert list(tmp_path.iterdir()) == []
    write_csv(target, {"a": [0.5, 2.0], "name": ["x", "y"]})
    assert read_csv(target) == [{"a": "0.5", "name": "x"}, {"a": "2", "name": "y"}]
    with pytest.raises(RuntimeError), atomic_path(target) as temporary:
        temporary.write_text("half")
        raise RuntimeError("interrupted")
    assert read_csv(target)[0]["a"] == "0.5"  # the old complete file is untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["table.csv"]
