"""Bad radar block projects (TOML + CSV): each is refused before any computation or writing, with an error naming
the file, line, column or key; random corruptions of a valid project read cleanly or fail with a SeaiceError."""

import re
import shutil

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from seaice_jax.cli import main
from seaice_jax.errors import SeaiceError
from seaice_jax.io.project import read_project, write_project
from seaice_jax.simulate.aircraft import FlightPlan, aidjex_scenario


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    folder = tmp_path_factory.mktemp("valid") / "project"
    write_project(aidjex_scenario(seed=1, plan=FlightPlan(strips=2), features=40), folder)
    return folder


def _copy(project, tmp_path):
    copy = tmp_path / "bad"
    shutil.copytree(project, copy)
    return copy


def _edit(folder, filename, edit):
    path = folder / filename
    path.write_text(edit(path.read_text()))


def _replace_cell(text, line, column, value):
    """``text`` (CSV) with the cell at 1-based ``line`` and header ``column`` replaced by ``value``."""
    lines = text.splitlines()
    index = lines[0].split(",").index(column)
    cells = lines[line - 1].split(",")
    cells[index] = value
    lines[line - 1] = ",".join(cells)
    return "\n".join(lines) + "\n"


CASES = [
    ("project.toml", lambda t: re.sub(r"map_centre_deg = .*", 'map_centre_deg = ["a", "b"]', t),
     r"project.toml: \[project\] map_centre_deg must be \[latitude, longitude\] in degrees, got \['a', 'b'\]"),
    ("project.toml", lambda t: re.sub(r"map_centre_deg = .*", "map_centre_deg = [74.0, 400.0]", t),
     r"map_centre_deg \[74.0, 400.0\]: latitude must be within .* longitude within \[-180°, 360°\)"),
    ("project.toml", lambda t: t.replace('navigation = "c1_S01_navigation.csv"', "navigation = 5"),
     r"coverage 'day 0' strip 'S01': navigation must be a file name \(a string\), got 5"),
    ("project.toml", lambda t: t.replace('navigation = "c1_S01_navigation.csv"', 'navigation = "../../etc/passwd"'),
     r"strip 'S01': navigation = '../../etc/passwd' is outside the project's folder"),
    ("project.toml", lambda t: t.replace("sweep_delay_mm = 10.0", "sweep_delay_mm = -1000", 1),
     r"strip 'S01': sweep_delay_mm must be >= 0, got -1000"),
    ("project.toml", lambda t: t.replace("range_scale_m_per_mm = 250.0", "range_scale_m_per_mm = 0.0", 1),
     r"strip 'S01': range_scale_m_per_mm must be > 0, got 0.0"),
    ("project.toml", lambda t: t.replace("sweep_delay_mm = 10.0", 'sweep_delay_mm = "ten"', 1),
     r"strip 'S01': sweep_delay_mm must be a finite number, got 'ten'"),
    ("project.toml", lambda t: re.sub(r"epoch_s = [1-9][0-9.]*", "epoch_s = -5.0", t),
     r"coverage 'day 16' epoch_s -5.0 is not after coverage 'day 0' epoch_s 0.0"),
    ("project.toml", lambda t: t.replace('name = "S02"', 'name = "S01"', 1),
     r"coverage 'day 0'.*strip 'S01' defined twice"),
    ("c1_S01_navigation.csv", lambda t: _replace_cell(t, 3, "x_m", "nan"),
     r"c1_S01_navigation.csv, line 3: column 'x_m' value 'nan' is not finite"),
    ("c1_S01_navigation.csv", lambda t: _replace_cell(t, 4, "time_s", "0"),
     r"c1_S01_navigation.csv, line 4: time_s 0.0 does not increase"),
    ("c1_S01_navigation.csv", lambda t: "\n".join(t.splitlines()[:4]) + "\n",
     r"c1_S01_marks.csv: time marks .* reach outside the navigation records' span"),
    ("c1_measurements.csv", lambda t: _replace_cell(t, len(t.splitlines()), "y_mm", "inf"),
     r"c1_measurements.csv, line \d+: column 'y_mm' value 'inf' is not finite"),
    ("c1_measurements.csv", lambda t: _replace_cell(t, 2, "y_mm", "80.0,7"),
     r"c1_measurements.csv, line 2: more values than the header's 5 columns"),
    ("c1_control.csv", lambda t: t + t.splitlines()[1] + "\n", r"c1_control.csv, line \d+: control point P0001 already "
                                                               r"defined on line 2"),
    ("c1_control.csv", lambda t: _replace_cell(t, 2, "lon_deg", "400"),
     r"c1_control.csv, line 2: point P0001: .*longitude within \[-180°, 360°\).* lon 400.0"),
    ("c1_control.csv", lambda t: _replace_cell(t, 2, "sigma_m", "-100"), r"c1_control.csv, line 2: .*sigma_m -100.0"),
    ("c1_control.csv", lambda t: "".join(t.splitlines(keepends=True)[:1] + t.splitlines(keepends=True)[2:]),
     r"c1_measurements.csv, line \d+: control point P0001 is not in the coverage's control file .*c1_control.csv: "
     r"give its position there, or measure it as a 'tie' or 'drift' point"),
    ("project.toml", lambda t: t.replace('control = "c1_control.csv"', ""),
     r"c1_measurements.csv, line \d+: control point P0001 is not in a control file \(.*coverage 'day 0' gives none\)"),
]


@pytest.mark.parametrize(("filename", "edit", "message"), CASES)
def test_bad_project_is_refused_naming_the_culprit(project, tmp_path, filename, edit, message):
    bad = _copy(project, tmp_path)
    _edit(bad, filename, edit)
    with pytest.raises(SeaiceError, match=message):
        read_project(bad / "project.toml")


def test_cli_refuses_a_bad_project_with_exit_code_2_and_writes_nothing(project, tmp_path, capsys):
    bad = _copy(project, tmp_path)
    _edit(bad, "project.toml", lambda t: t.replace("sweep_delay_mm = 10.0", "sweep_delay_mm = -1000", 1))
    out = tmp_path / "out"
    assert main(["block", str(bad / "project.toml"), "--out", str(out)]) == 2
    error = capsys.readouterr().err
    assert "sweep_delay_mm must be >= 0" in error and "Traceback" not in error
    assert not out.exists() and [p.name for p in tmp_path.iterdir()] == ["bad"]


def test_a_byte_order_mark_is_read_and_other_encodings_are_named(project, tmp_path):
    good = read_project(project / "project.toml")
    bad = _copy(project, tmp_path)
    for name in ("project.toml", "c1_measurements.csv"):
        (bad / name).write_bytes(b"\xef\xbb\xbf" + (bad / name).read_bytes())
    read = read_project(bad / "project.toml")
    np.testing.assert_array_equal(read.coverages[0].measurements.x, good.coverages[0].measurements.x)
    (bad / "c1_control.csv").write_bytes((bad / "c1_control.csv").read_bytes().replace(b"P0001", b"P\xe9001", 1))
    with pytest.raises(SeaiceError, match=r"c1_control.csv: not UTF-8 text"):
        read_project(bad / "project.toml")


def test_a_device_or_folder_is_not_read_as_a_table(project, tmp_path):
    bad = _copy(project, tmp_path)
    _edit(bad, "project.toml", lambda t: t.replace('measurements = "c1_measurements.csv"',
                                                   'measurements = "/dev/zero"'))
    with pytest.raises(SeaiceError, match=r"measurements = '/dev/zero' is outside the project's folder"):
        read_project(bad / "project.toml")
    with pytest.raises(SeaiceError, match=r"/dev/zero: not a regular file"):
        read_project(bad / "project.toml", allow_outside=True)


def test_paths_are_resolved_relative_to_the_project_file(project, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert len(read_project(project / "project.toml").coverages) == 2


_MUTATIONS = st.sampled_from(["delete", "replace", "duplicate_line", "delete_line", "nan"])


def _mutate(text: str, kind: str, where: float, char: str) -> str:
    lines = text.splitlines(keepends=True)
    at = int(where * len(text))
    line = int(where * len(lines))
    if kind == "delete":
        return text[:at] + text[at + 1:]
    if kind == "replace":
        return text[:at] + char + text[at + 1:]
    if kind == "duplicate_line":
        return "".join(lines[:line + 1] + lines[line:])
    if kind == "delete_line":
        return "".join(lines[:line] + lines[line + 1:])
    return re.sub(r"-?\d+\.\d+", "nan", text, count=1 + line % 3)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(filename=st.sampled_from(["project.toml", "c1_measurements.csv", "c1_control.csv", "c2_S01_navigation.csv",
                                 "c1_S02_marks.csv"]),
       mutations=st.lists(st.tuples(_MUTATIONS, st.floats(0, 0.999), st.characters(codec="utf-8")), min_size=1,
                          max_size=3))
def test_random_corruptions_read_cleanly_or_fail_with_a_seaice_error(project, tmp_path_factory, filename, mutations):
    bad = _copy(project, tmp_path_factory.mktemp("corrupt"))
    text = (bad / filename).read_text()
    for kind, where, char in mutations:
        text = _mutate(text, kind, where, char)
    (bad / filename).write_text(text)
    try:
        read = read_project(bad / "project.toml")
    except SeaiceError as error:
        assert str(error)
        return
    for coverage in read.coverages:
        for strip in coverage.strips:
            assert np.all(np.isfinite(strip.record_positions)) and np.all(np.diff(strip.record_times) > 0)
        assert np.all(np.isfinite(coverage.measurements.x)) and np.all(np.isfinite(coverage.measurements.y))
