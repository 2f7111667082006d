"""CLI habits: -q/-v and --overwrite on every command, defaults in --help, exit codes 0/1/2, `seaice examples`, and
`rectify --json` complete enough to rebuild the model and its covariance."""

import argparse
import json
import re
import shlex
from importlib.resources import files
from pathlib import Path

import numpy as np
import pytest

from seaice_jax.adjust.orbit.fit import fit_scan_model
from seaice_jax.cli import build_parser, main
from seaice_jax.errors import ComputationError, GeometryError, RankDeficiencyError, SeaiceError, exit_code
from seaice_jax.geometry.earth import SIDEREAL_DAY
from seaice_jax.geometry.scan import SCAN_UNKNOWNS, satellite_orbit
from seaice_jax.io.stations import control_points, read_measurements
from seaice_jax.report.text import scan_model_from_json

README = Path(__file__).resolve().parents[1] / "README.md"
PACKAGED = files("seaice_jax") / "examples"


def _verbs(parser, prefix=""):
    """``{"name": parser}`` of every command, a group's verbs as ``"group verb"`` (``seaice sar geolocate``)."""
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    found = {}
    for name, command in action.choices.items():
        if any(isinstance(a, argparse._SubParsersAction) for a in command._actions):
            found |= _verbs(command, f"{prefix}{name} ")
        else:
            found[f"{prefix}{name}"] = command
    return found


def _commands():
    return _verbs(build_parser())


@pytest.mark.parametrize("name", sorted(_commands()))
def test_every_command_takes_quiet_verbose_overwrite_and_shows_its_defaults(name):
    command = _commands()[name]
    text = " ".join(command.format_help().split())  # unwrapped
    for flag in ("-q, --quiet", "-v, --verbose", "--overwrite"):
        assert flag in text
    for action in command._actions:
        if action.option_strings and action.nargs != 0 and action.default not in (None, argparse.SUPPRESS):
            # every option with a value and a default says it, in the formatter's words or its own
            shown = " ".join(command._get_formatter()._format_action(action).split())
            assert "default" in shown, f"seaice {name} {action.option_strings[0]}: no default shown"
            assert str(action.default) in shown or "default:" in shown


def test_help_explains_the_jargon():
    rectify = " ".join(_commands()["rectify"].format_help().split())
    assert "Very High Resolution Radiometer" in rectify and "AGRID station catalogue (the 1985" in rectify
    assert "w-tests (Baarda's data snooping" in rectify
    track = " ".join(_commands()["track"].format_help().split())
    assert "OSI SAF (EUMETSAT Ocean and Sea Ice Satellite Application Facility)" in track


def test_verbosity_options_work_before_and_after_the_command():
    parser = build_parser()
    assert parser.parse_args(["-v", "examples"]).verbosity == 2
    assert parser.parse_args(["examples", "-q"]).verbosity == 0
    assert parser.parse_args(["examples"]).verbosity == 1
    with pytest.raises(SystemExit) as stop:
        parser.parse_args(["examples", "-q", "-v"])
    assert stop.value.code == 2


def test_exit_code_table():
    assert exit_code(ComputationError("no convergence")) == 1
    assert exit_code(PermissionError(13, "Permission denied")) == 1
    assert exit_code(RuntimeError("a bug")) == 1
    for error in (SeaiceError("bad"), GeometryError("bad"), RankDeficiencyError("bad"), ValueError("bad"),
                  FileNotFoundError(2, "No such file")):
        assert exit_code(error) == 2


def test_exit_codes_of_the_command(tmp_path, capsys):
    examples = Path(str(PACKAGED))
    fit = ["rectify", str(examples / "figure_3_3.csv"), "--satellite", "NOAA-7", "--altitude", "0"]
    with pytest.raises(SystemExit) as stop:
        main([*fit, "--sigma", "-1"])  # usage: a value out of range
    assert stop.value.code == 2
    assert main(["rectify", str(tmp_path / "absent.csv"), "--satellite", "NOAA-7"]) == 2  # bad input
    assert "absent.csv: file not found" in capsys.readouterr().err
    assert main([*fit, "--json", "/sys/seaice-test.json"]) == 1  # runtime: the output cannot be written
    error = capsys.readouterr().err
    assert error.startswith("seaice rectify: error:") and "Permission denied" in error and "Traceback" not in error
    assert main([*fit, "-v", "--json", "/sys/seaice-test.json"]) == 1
    assert "Traceback" in capsys.readouterr().err
    assert main([*fit, "-q"]) == 0  # quiet: nothing on stdout
    assert capsys.readouterr().out == ""
    assert main(["-v", "examples", str(tmp_path / "examples")]) == 0
    captured = capsys.readouterr()
    packaged = sum(1 for path in PACKAGED.iterdir() if path.is_file())
    assert f"wrote {packaged} example files" in captured.out
    assert re.search(r"seaice examples: done in \d+\.\d s", captured.err)


def _readme_commands(needing: str) -> list[list[str]]:
    """The README's shell commands (``seaice ...`` or ``.venv/bin/seaice ...``) that name ``needing``."""
    commands = []
    for block in re.findall(r"```(?:bash|sh|shell)?\n(.*?)```", README.read_text(), re.S):
        for line in block.splitlines():
            if re.match(r"(\.venv/bin/)?seaice ", line):
                words = shlex.split(line, comments=True)
                if any(needing in w for w in words):
                    commands.append(words[1:])
    return commands


def test_examples_copies_the_packaged_files_and_the_readme_commands_run_from_an_empty_folder(tmp_path, capsys,
                                                                                              monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["examples"]) == 0
    packaged = sorted(p.name for p in PACKAGED.iterdir() if p.is_file())
    assert {"figure_3_3.csv", "figure_3_3_measured.csv", "AGRID.STN"} <= set(packaged)
    assert sorted(p.name for p in (tmp_path / "examples").iterdir()) == packaged
    for name in packaged:
        assert (tmp_path / "examples" / name).read_bytes() == (PACKAGED / name).read_bytes()
    assert main(["examples"]) == 2  # an existing folder is kept unless --overwrite
    assert main(["examples", "--overwrite", "-q"]) == 0
    commands = _readme_commands("examples/")
    assert len(commands) >= 2
    for words in commands:
        assert main(words) == 0, words
    assert "COB IS ICE" in capsys.readouterr().out


def test_rectify_json_rebuilds_the_model_and_its_covariance(tmp_path):
    examples = Path(str(PACKAGED))
    out = tmp_path / "fit.json"
    assert main(["rectify", str(examples / "figure_3_3.csv"), "--satellite", "NOAA-7", "--altitude", "0",
                 "--earth-day", "1440", "--direction", "south", "--json", str(out), "-q"]) == 0
    document = json.loads(out.read_text())
    assert document["version"] and document["format"] and "model.covariance" in document["units"]
    model, covariance = scan_model_from_json(document)
    # the same fit made here, from the same file and options
    orbit = satellite_orbit("NOAA-7", altitude=0.0, earth_day=1440 * 60.0)
    assert float(orbit.earth_day) != SIDEREAL_DAY
    fit = fit_scan_model(control_points(read_measurements(examples / "figure_3_3.csv"), 1.0), orbit,
                         direction="south", n_pixels=512, n_scans=512)
    pixel, scan = np.meshgrid(np.linspace(1, 512, 9), np.linspace(1, 512, 9))
    expected = np.stack([np.asarray(a) for a in fit.model.forward(pixel, scan)])
    rebuilt = np.stack([np.asarray(a) for a in model.forward(pixel, scan)])
    assert np.max(np.abs(rebuilt - expected)) < 1e-12  # radians: the same positions to ~6 µm
    assert (model.n_pixels, model.n_scans, model.direction) == (512, 512, "south")
    assert fit.adjustment is not None and covariance is not None
    order = [SCAN_UNKNOWNS.index(name) for name in fit.adjustment.parameter_names]
    np.testing.assert_allclose(covariance[np.ix_(order, order)], np.asarray(fit.adjustment.covariance), rtol=1e-9,
                               atol=0)
    with pytest.raises(SeaiceError, match="format"):
        scan_model_from_json({**document, "format": "something else"})


def test_long_commands_say_each_stage_unless_quiet(tmp_path, capsys):
    project = tmp_path / "absent.toml"
    assert main(["block", str(project), "--out", str(tmp_path / "out")]) == 2
    error = capsys.readouterr().err
    assert re.search(rf"seaice block \[ *\d+ s\]: reading {re.escape(str(project))}\n", error)
    assert "absent.toml: file not found" in error
    assert main(["block", str(project), "--out", str(tmp_path / "out"), "-q"]) == 2
    assert "reading" not in capsys.readouterr().err


def test_the_block_commands_defaults_are_the_librarys():
    """`seaice --help` must not import JAX, so the parser spells out `BlockOptions`' defaults: they must agree."""
    from seaice_jax.adjust.radar.block import BlockOptions

    args = build_parser().parse_args(["block", "project.toml", "--out", "out"])
    defaults = BlockOptions()
    for name in ("navigation_model", "navigation_scope", "knot_spacing", "radar_constants", "take_off_time",
                 "time_mark_sigma", "variance_components", "robust"):
        assert getattr(args, name) == getattr(defaults, name), name
    assert tuple(args.image_sigma) == tuple(defaults.image_sigma)
