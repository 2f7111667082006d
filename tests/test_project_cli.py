import csv
import json
import re
import shutil

import numpy as np
import pytest

from seaice_jax.cli import main
from seaice_jax.io.project import read_project, write_project
from seaice_jax.sensors.strips import strip_ground_points
from seaice_jax.simulate.aircraft import FlightPlan, aidjex_scenario


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sim")
    assert main(["simulate", "aidjex", "--out", str(folder), "--strips", "3", "--features", "200", "--seed", "2"]) == 0
    return folder


def test_simulate_then_block_writes_the_products(project, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["block", str(project / "project.toml"), "--method", "sequential", "--out", str(out)]) == 0
    report = capsys.readouterr().out
    assert "general drift" in report
    names = {p.name for p in out.iterdir()}
    assert {"adjusted_points.csv", "drift.csv", "drift.geojson", "report.txt", "drift_c1.png",
            "relative_motion_c1.png", "tie_discrepancies_c1.png", "control_discrepancies_c1.png"} <= names
    geojson = json.loads((out / "drift.geojson").read_text())
    assert geojson["type"] == "FeatureCollection" and geojson["features"]
    lon, lat = geojson["features"][0]["geometry"]["coordinates"][0]
    assert 70 < lat < 80 and -160 < lon < -135  # [longitude, latitude] degrees (RFC 7946)
    with open(out / "drift.csv", newline="") as stream:
        rows = list(csv.DictReader(stream))
    dx = np.median([float(r["dx_m"]) for r in rows])
    assert dx == pytest.approx(-1900.0 * 16, abs=2000.0)  # the simulated 1.9 km/day westward drift


@pytest.mark.slow
def test_simultaneous_block_writes_covariances_ellipses_and_quality(project, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["block", str(project / "project.toml"), "--out", str(out)]) == 0
    report = capsys.readouterr().out
    assert "method simultaneous" in report and "σ̂0" in report and "w-test" in report
    names = {p.name for p in out.iterdir()}
    assert {"adjusted_points.csv", "drift.csv", "drift.geojson", "strips.csv", "navigation_errors.csv",
            "navigation_errors.png", "observations.csv", "report.txt", "drift_c1.png"} <= names
    with open(out / "adjusted_points.csv", newline="") as stream:
        points = list(csv.DictReader(stream))
    sigma = np.array([[float(r["sigma_x_m"]), float(r["sigma_y_m"])] for r in points])
    major = np.array([float(r["ellipse_major_m"]) for r in points])
    assert np.all(sigma > 0) and np.all(major >= 2.4 * sigma.max(axis=1) - 1e-6)  # 95 %: 2.45 σ or more
    with open(out / "drift.csv", newline="") as stream:
        rows = list(csv.DictReader(stream))
    assert all(float(r["sigma_dx_m"]) > 0 for r in rows)
    truth = {}
    with open(project / "truth.csv", newline="") as stream:
        for r in csv.DictReader(stream):
            truth.setdefault(r["point"], []).append((float(r["x_m"]), float(r["y_m"])))
    errors = [(float(r["dx_m"]) - (truth[r["point"]][1][0] - truth[r["point"]][0][0])) / float(r["sigma_dx_m"])
              for r in rows]
    assert np.sqrt(np.mean(np.square(errors))) < 3.0  # drift errors of the size of their σ


def test_project_round_trip_keeps_the_strips(project):
    loaded = read_project(project / "project.toml")
    assert [c.name for c in loaded.coverages] == ["day 0", "day 16"]
    strip = loaded.coverages[0].strips[0]
    assert strip.record_positions.shape[1] == 3 and strip.mark_x.size == strip.mark_times.size
    assert set(loaded.coverages[0].control) and len(loaded.point_ids) > 100


def test_comparator_coordinates_and_kinds_round_trip(tmp_path):
    """A project written with films placed on the comparator at an angle reads back to the same image
    coordinates: rectifying the read project gives the simulated strips' ground points to < 1 mm."""
    scenario = aidjex_scenario(seed=4, plan=FlightPlan(strips=2), features=60)
    write_project(scenario, tmp_path)
    loaded = read_project(tmp_path / "project.toml")
    with open(tmp_path / "c1_measurements.csv", newline="") as stream:
        rows = list(csv.DictReader(stream))
    assert {"drift", "control", "nadir"} <= {r["kind"] for r in rows}
    coverage, original = loaded.coverages[0], scenario.coverages[0]
    raw = np.array([[float(r["x_mm"]), float(r["y_mm"])] for r in rows if r["kind"] != "nadir"])
    assert np.abs(raw - np.stack([original.measurements.x, original.measurements.y], 1)).max() > 1.0  # not image
    np.testing.assert_allclose(coverage.measurements.y, original.measurements.y, atol=1e-9)
    for read, simulated in zip(coverage.strips, original.strips, strict=True):
        np.testing.assert_allclose(read.nadir_y, simulated.nadir_y, atol=1e-9)
        np.testing.assert_allclose(np.diff(read.mark_x), np.diff(simulated.mark_x), atol=1e-9)
    ours = strip_ground_points(coverage.strips, coverage.measurements)
    theirs = strip_ground_points(original.strips, original.measurements)
    assert np.nanmax(np.linalg.norm(ours - theirs, axis=1)) < 1e-3
    kinds = dict(zip(loaded.point_ids, loaded.point_kinds, strict=True))
    assert [kinds[f"P{i:04d}"] for i in (1, 2, 3)] == ["control"] * 3


def corrupt(project, tmp_path, filename, edit):
    copy = tmp_path / "bad"
    shutil.copytree(project, copy)
    path = copy / filename
    path.write_text(edit(path.read_text()))
    return copy


@pytest.mark.parametrize("filename, edit, message", [
    ("c1_measurements.csv", lambda t: t.replace("x_mm", "x"), r"c1_measurements.csv, line 1: missing column\(s\) x_mm"),
    ("c1_S01_marks.csv", lambda t: t.replace(t.splitlines()[3].split(",")[2], "0.5", 1),
     r"c1_S01_marks.csv, line 4: time mark does not increase"),
    ("c1_S01_marks.csv", lambda t: t.replace(t.splitlines()[3].split(",")[0], "-40", 1),
     r"c1_S01_marks.csv, line 4: time mark does not increase"),
    ("c1_measurements.csv", lambda t: t.replace(",tie,", ",tye,", 1),
     r"c1_measurements.csv, line \d+: point P\d+: kind 'tye' is not one of tie, drift, control, nadir"),
    ("c1_measurements.csv", lambda t: t.replace(",drift,", ",tie,", 1),
     r"c2_measurements.csv, line \d+: point P\d+ is 'drift' here but 'tie' at .*c1_measurements.csv, line 4"),
    ("project.toml", lambda t: t.replace("far_range_mm", "far_range", 1), r"strip 'S01': missing far_range_mm"),
    ("c1_measurements.csv", lambda t: t.replace(",S02,", ",S99,", 1),
     r"c1_measurements.csv, line \d+: unknown strip 'S99'"),
    ("c1_measurements.csv", lambda t: t + t.splitlines()[1] + "\n",
     r"c1_measurements.csv, line \d+: point P\d+ already measured on strip S\d+ \(line 2\)"),
    ("c1_measurements.csv", lambda t: "\n".join(re.sub(r",[^,]*$", ",40.0", line) if line.startswith("P0001,")
                                                else line for line in t.splitlines()) + "\n",
     r"coverage 'day 0': control point P0001 is measured \(strip S0\d\) but has no ground solution"),
])
def test_bad_projects_name_file_and_line_and_write_nothing(project, tmp_path, capsys, filename, edit, message):
    bad = corrupt(project, tmp_path, filename, edit)
    out = tmp_path / "out"
    assert main(["block", str(bad / "project.toml"), "--out", str(out)]) == 2
    assert re.search(message, capsys.readouterr().err)
    assert not out.exists()


@pytest.mark.slow
def test_block_that_does_not_converge_exits_1_and_writes_nothing(project, tmp_path, capsys):
    """A strip's range scale given as 1 m/mm instead of 250 (a valid number: its slant ranges 250 times too short):
    the Gauss-Newton iterations do not converge within the block's limit, and the command says so and exits 1 (a
    runtime failure, as its --help says), leaving no output."""
    bad = corrupt(project, tmp_path, "project.toml",
                  lambda t: t.replace("range_scale_m_per_mm = 250.0", "range_scale_m_per_mm = 1.0", 1))
    out = tmp_path / "out"
    assert main(["block", str(bad / "project.toml"), "--out", str(out)]) == 1
    assert re.search(r"the block adjustment did not converge in \d+ steps \(σ̂0 = [0-9.]+\): its last step moved .+ "
                     r"by ", capsys.readouterr().err)
    assert not out.exists()

@pytest.mark.slow
def test_block_variance_components_are_reported_near_one_on_a_simulation_with_the_stated_errors(project, tmp_path,
                                                                                               capsys):
    """The simulation draws its image and altimeter errors with the default σ: each estimated variance factor is
    within 4 of its own σ of 1, and the report prints one line per group; robust and variance components together
    are refused as a usage error."""
    out = tmp_path / "vc"
    assert main(["block", str(project / "project.toml"), "--variance-components", "--out", str(out)]) == 0
    report = capsys.readouterr().out
    rows = re.findall(r"^ {4}(image x \(along track\)|image y \(slant range\)|nadir returns): ([0-9.]+) ±([0-9.]+)",
                      report, flags=re.MULTILINE)
    assert len(rows) == 3, report
    for _, value, sigma in rows:
        assert abs(float(value) - 1.0) < 4.0 * float(sigma), rows
    assert main(["block", str(project / "project.toml"), "--variance-components", "--robust", "huber",
                 "--out", str(tmp_path / "both")]) == 2
    assert not (tmp_path / "both").exists()
