"""Bad control-point measurement files and ``seaice rectify`` options: refused before the fit, naming the file and
line or the option; random corruptions of a valid file read cleanly or fail with a SeaiceError."""

import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from seaice_jax.cli import main
from seaice_jax.errors import SeaiceError
from seaice_jax.io.stations import check_in_image, control_points, read_agrid, read_measurements

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
VALID = (EXAMPLES / "figure_3_3.csv").read_text()
RECTIFY = ["--satellite", "NOAA-7", "--altitude", "0", "--earth-day", "1440", "--direction", "south"]


def _bad(tmp_path, text, name="points.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize(("edit", "message"), [
    (lambda t: t.replace("-78.616667", "400", 1), r"points.csv, line 2: point 3030 longitude 400.0° is outside "
                                                  r"\[-180°, 360°\)"),
    (lambda t: t.replace("75.716667", "95", 1), r"points.csv, line 2: point 3030 latitude 95.0° is outside"),
    (lambda t: t.replace("75.716667", "nan", 1),
     r"points.csv, line 2: column 'latitude_deg' value 'nan' is not finite"),
    (lambda t: t.replace(",164,", ",inf,", 1), r"points.csv, line 2: column 'pixel' value 'inf' is not finite"),
    (lambda t: t + t.splitlines()[1] + "\n", r"points.csv, line 7: point 3030 already measured on line 2"),
    (lambda t: t.replace("id,name", "ident,name"), r"points.csv, line 1: missing column\(s\) id"),
])
def test_bad_measurements_name_file_and_line(tmp_path, edit, message):
    with pytest.raises(SeaiceError, match=message):
        read_measurements(_bad(tmp_path, edit(VALID)))


def test_points_outside_the_image_are_refused(tmp_path):
    path = _bad(tmp_path, VALID.replace(",164,123,", ",600,123,"))
    measurements = read_measurements(path)
    with pytest.raises(SeaiceError, match=r"points.csv, line 2: point 3030 at pixel 600.0, scan 123.0 is outside the "
                                          r"image of 512 pixels x 512 scan lines"):
        check_in_image(measurements, 512, 512, path)
    check_in_image(measurements, 600, 512, path)  # the same point inside a wider image


def test_encodings_are_named_and_a_byte_order_mark_is_read(tmp_path):
    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + VALID.encode())
    assert [m.id for m in read_measurements(bom)] == [m.id for m in read_measurements(EXAMPLES / "figure_3_3.csv")]
    latin = tmp_path / "latin.csv"
    latin.write_bytes(VALID.replace("COB IS", "CÔB IS").encode("latin-1"))
    with pytest.raises(SeaiceError, match=r"latin.csv: not UTF-8 text"):
        read_measurements(latin)
    with pytest.raises(SeaiceError, match=r"/dev/zero: not a regular file"):
        read_measurements("/dev/zero")
    with pytest.raises(SeaiceError, match=r"--sigma \(default_sigma_km\) must be > 0, got -1"):
        control_points(read_measurements(bom), -1.0)


@pytest.mark.parametrize(("options", "message"), [
    (["--period", "-100"], r"argument --period: must be > 0.0, got -100"),
    (["--earth-day", "-1440"], r"argument --earth-day: must be > 0.0, got -1440"),
    (["--earth-day", "nan"], r"argument --earth-day: 'nan' is not finite"),
    (["--max-latitude", "95"], r"argument --max-latitude: must be <= 90.0, got 95"),
    (["--sigma", "-1"], r"argument --sigma: must be > 0.0, got -1"),
    (["--pixels", "0"], r"argument --pixels: must be >= 2, got 0"),
    (["--altitude", "abc"], r"argument --altitude: 'abc' is not a number"),
])
def test_bad_rectify_options_are_usage_errors_naming_the_option(tmp_path, capsys, options, message):
    with pytest.raises(SystemExit) as exit_:
        main(["rectify", str(EXAMPLES / "figure_3_3.csv"), "--satellite", "NOAA-7", *options])
    assert exit_.value.code == 2
    assert re.search(message, capsys.readouterr().err)


def test_rectify_refuses_points_off_the_image_and_an_existing_json(tmp_path, capsys):
    off = _bad(tmp_path, VALID.replace(",165,400,", ",165,700,"))
    assert main(["rectify", str(off), *RECTIFY]) == 2
    assert "point 3032 at pixel 165.0, scan 700.0 is outside the image" in capsys.readouterr().err
    out = tmp_path / "fit.json"
    out.write_text("{}")
    assert main(["rectify", str(EXAMPLES / "figure_3_3.csv"), *RECTIFY, "--json", str(out)]) == 2
    assert "fit.json: the file exists; pass --overwrite" in capsys.readouterr().err and out.read_text() == "{}"
    assert main(["rectify", str(EXAMPLES / "figure_3_3.csv"), *RECTIFY, "--json", str(out), "--overwrite"]) == 0
    assert '"rms_km"' in out.read_text()


def test_agrid_catalogue_errors_name_the_line(tmp_path):
    lines = (EXAMPLES / "AGRID.STN").read_text().splitlines()
    with pytest.raises(SeaiceError, match=r"bad.stn, line 2: station \d+ already defined on line 1"):
        read_agrid(_bad(tmp_path, "\n".join([lines[0], lines[0]]) + "\n", "bad.stn"))


@settings(max_examples=80, deadline=None)
@given(cuts=st.lists(st.tuples(st.integers(0, len(VALID) - 1), st.sampled_from(["", "-", "9", ",", "\n", "é", "nan",
                                                                                 "\x00", '"', "1e999"])),
                     min_size=1, max_size=4))
def test_random_corruptions_read_cleanly_or_fail_with_a_seaice_error(tmp_path_factory, cuts):
    text = VALID
    for at, replacement in cuts:
        text = text[:at] + replacement + text[at + 1:]
    path = tmp_path_factory.mktemp("corrupt") / "points.csv"
    path.write_text(text)
    try:
        measurements = read_measurements(path)
        check_in_image(measurements, 512, 512, path)
        control = control_points(measurements)
    except SeaiceError as error:
        assert str(path) in str(error) or "no control-point measurements" in str(error)
        return
    assert np.all(np.isfinite(np.asarray(control.latitude))) and np.all(np.abs(np.asarray(control.latitude)) <= 1.58)
