"""Bad image-sequence projects, remapped stacks and film options: refused before any computation or writing, with an
error naming the file, key, line or option (and the memory figure for grids and films over the budget)."""

import re

import numpy as np
import pytest

from seaice_jax.cli import main
from seaice_jax.errors import SeaiceError
from seaice_jax.io.remapped import RemappedStack, load_remapped, save_stack
from seaice_jax.io.sequence import MEMORY_BUDGET, make_grid, read_sequence
from seaice_jax.memory import remap_peak
from seaice_jax.simulate.satellite import noaa_pass
from seaice_jax.workflows.movie import run_movie
from seaice_jax.workflows.sequence_adjust import run_adjust
from seaice_jax.workflows.simulated_sequence import SIMULATED_GRID
from seaice_jax.workflows.track import run_track

HEAD = ('epoch = "1983-03-08T00:00:00Z"\n[grid]\ncentre_deg = [74.0, -85.0]\npixel_m = [2500.0, 2500.0]\n'
        'shape = [10, 10]\n')
IMAGE = '[[image]]\nname = "A"\ntime = "1983-03-08T01:00:00Z"\nfile = "a.npy"\ncontrol = "c.csv"\n'
CONTROL = "id,pixel,scan,latitude,longitude,sigma_m\nP1,1,1,74,-85,500\nP2,8,8,73,-84,500\n"


def _project(tmp_path, head=HEAD, image=IMAGE, control=CONTROL, pixels=None):
    np.save(tmp_path / "a.npy", np.zeros((8, 8)) if pixels is None else pixels)
    (tmp_path / "c.csv").write_text(control)
    path = tmp_path / "sequence.toml"
    path.write_text(head + image)
    return path


@pytest.mark.parametrize(("change", "message"), [
    ({"head": HEAD.replace("pixel_m = [2500.0, 2500.0]", "pixel_m = [0.0, 2500.0]")},
     r"sequence.toml: \[grid\] pixel_m must be > 0, got \[0.0, 2500.0\]"),
    ({"head": HEAD.replace("centre_deg = [74.0, -85.0]", 'centre_deg = ["a", "b"]')},
     r"sequence.toml: \[grid\] centre_deg must be two numbers, got \['a', 'b'\]"),
    ({"head": HEAD.replace("centre_deg = [74.0, -85.0]", "centre_deg = [74.0, 400.0]")},
     r"\[grid\] centre_deg \[74.0, 400.0\]: latitude .* longitude within \[-180°, 360°\)"),
    ({"head": HEAD.replace("centre_deg = [74.0, -85.0]", "centre_deg = [-74.0, -85.0]")},
     r"sequence.toml: \[grid\] centre_deg latitude -74.0 lies outside the nsidc-north grid's hemisphere; use "
     r"nsidc-south"),
    ({"head": HEAD.replace("[grid]", '[grid]\nprojection = "equirectangular"').replace("[74.0, -85.0]", "[89.9, 0.0]")},
     r"\[grid\] an equirectangular grid centred at latitude 89.9 with 12500 m north and south reaches latitude "
     r"90.012°, beyond the pole"),
    ({"head": HEAD.replace("shape = [10, 10]", "shape = [30000, 30000]")},
     r"\[grid\] shape \[30000, 30000\]: remapping one image on it needs about 243.9 GiB of memory at its peak, more "
     r"than the 4 GiB budget \(\$SEAICE_MEMORY_GIB sets another\)"),
    ({"head": HEAD.replace("shape = [10, 10]", "shape = [1000000, 1000000]")},
     r"remapping one image on it needs about 270084.3 GiB"),
    ({"head": HEAD.replace("shape = [10, 10]", "shape = [3000, 3000]"), "image": IMAGE * 6},
     r"6 images on a 3000 x 3000 grid needs about 5.3 GiB of memory at its peak, more than the 4 GiB budget"),
    ({"head": HEAD.replace("shape = [10, 10]", "shape = [10.5, 10]")}, r"\[grid\] shape must be two positive integers"),
    ({"image": IMAGE.replace('file = "a.npy"', "file = 5")},
     r"image 'A': file must be a file name \(a string\), got 5"),
    ({"image": IMAGE.replace('file = "a.npy"', 'file = "../a.npy"')},
     r"image 'A': file = '../a.npy' is outside the project's folder"),
    ({"pixels": np.where(np.eye(8) > 0, np.nan, 0.0)}, r"a.npy: 8 pixel values are not finite"),
    ({"control": CONTROL.replace("P2,8,8,", "P2,8,9,")},
     r"c.csv, line 3: point P2 at pixel 8.0, scan 9.0 is outside the image of 8 pixels x 8 scan lines"),
    ({"control": CONTROL.replace("P2,", "P1,")}, r"c.csv, line 3: point P1 already measured on line 2"),
    ({"control": CONTROL.replace("-84,", "400,")},
     r"c.csv, line 3: point P2 longitude 400.0° is outside \[-180°, 360°\)"),
    ({"control": CONTROL.replace("73,", "nan,")}, r"c.csv, line 3: column 'latitude' value 'nan' is not finite"),
])
def test_bad_sequence_project_is_refused_naming_the_culprit(tmp_path, change, message):
    with pytest.raises(SeaiceError, match=message):
        read_sequence(_project(tmp_path, **change))


def test_budget_figures_are_the_measured_peaks():
    """The estimates are lines through measured peaks (seaice_jax.memory; benchmarks/bench_memory.py checks the
    largest accepted jobs): one image on a 3000² grid fits the 4 GiB budget, six do not."""
    assert MEMORY_BUDGET == 4 * 2**30
    assert remap_peak(3000 * 3000, 1) / 2**30 == pytest.approx(3.23, abs=0.01)
    assert remap_peak(3000 * 3000, 6) / 2**30 == pytest.approx(5.33, abs=0.01)


@pytest.fixture(scope="module")
def remapped(tmp_path_factory):
    """A folder with the ``remapped.npz`` of two NOAA passes on the simulated projects' 150 x 150 grid, written by
    the remap's own writer (:func:`save_stack`; the errors below are about the file and the film's size, not
    about its pixels, so no rectification and remap is run for it)."""
    folder = tmp_path_factory.mktemp("sequence") / "remapped"
    folder.mkdir()
    grid = make_grid(**SIMULATED_GRID)
    models = tuple(noaa_pass(direction, 48, np.radians(74.0), np.radians(-85.0)) for direction in ("south", "north"))
    values = np.random.default_rng(1).uniform(0.0, 1.0, (2, *grid.shape))
    save_stack(folder / "remapped.npz", RemappedStack(
        values, np.ones(values.shape, bool), np.array([3600.0, 90000.0]), ("A", "B"), "1983-03-08T00:00:00Z", grid,
        SIMULATED_GRID, models, np.zeros((10, 10)), np.full(values.shape, 2500.0)))
    assert load_remapped(folder).values.shape == (2, 150, 150)
    return folder


def test_truncated_remapped_stack_is_named(remapped, tmp_path, capsys):
    copy = tmp_path / "remapped"
    copy.mkdir()
    data = (remapped / "remapped.npz").read_bytes()
    (copy / "remapped.npz").write_bytes(data[:len(data) // 2])
    with pytest.raises(SeaiceError, match=r"remapped.npz: truncated or not a remapped stack"):
        run_track(copy, tmp_path / "drift", progress=False)
    assert not (tmp_path / "drift").exists()
    assert main(["movie", str(copy), "--out", str(tmp_path / "film.gif")]) == 2
    error = capsys.readouterr().err
    assert "truncated or not a remapped stack" in error and "Traceback" not in error


def test_a_film_over_the_budget_is_refused_with_its_size(remapped, tmp_path):
    with pytest.raises(SeaiceError, match=r"--scale 200: a film of 2 frames of 30000 x 30000 pixels needs about 69.0 "
                                          r"GiB of memory at its peak, more than the 4 GiB budget"):
        run_movie(remapped, tmp_path / "film.gif", scale=200)
    with pytest.raises(SeaiceError, match=r"fps must be > 0"):
        run_movie(remapped, tmp_path / "film.gif", fps=0.0)
    assert list(tmp_path.iterdir()) == []


def test_a_film_with_a_land_mask_not_of_bools_on_its_grid_is_refused(remapped, tmp_path):
    """A mask of 0/1 floats (or of another grid) would fill the wrong cells: refused naming the file, nothing
    written."""
    for name, mask in (("floats.npy", np.zeros((150, 150))), ("other.npy", np.zeros((10, 10), bool))):
        np.save(tmp_path / name, mask)
        with pytest.raises(SeaiceError, match=rf"{name}: a land mask must be a bool array of the grid's shape "
                                              r"\(150, 150\)"):
            run_movie(remapped, tmp_path / "film.gif", land_mask=tmp_path / name)
    (tmp_path / "text.npy").write_text("not an array")
    with pytest.raises(SeaiceError, match=r"text.npy: not a .npy array"):
        run_movie(remapped, tmp_path / "film.gif", land_mask=tmp_path / "text.npy")
    assert not (tmp_path / "film.gif").exists()


def test_a_static_mask_not_of_bools_on_the_grid_is_refused_before_anything_is_written(tmp_path):
    project = _project(tmp_path)
    np.save(tmp_path / "static.npy", np.ones((10, 10)))
    with pytest.raises(SeaiceError, match=r"static.npy: a static-surface mask must be a bool array of the grid's "
                                          r"shape \(10, 10\), got float64"):
        run_adjust(project, tmp_path / "adjusted", static=tmp_path / "static.npy", progress=False)
    assert not (tmp_path / "adjusted").exists()


@pytest.mark.parametrize(("argv", "message"), [
    (["movie", "R", "--out", "f.gif", "--fps", "0"], r"argument --fps: must be > 0.0, got 0"),
    (["movie", "R", "--out", "f.gif", "--scale", "0"], r"argument --scale: must be >= 1, got 0"),
    (["movie", "R", "--out", "f.gif", "--scale", "100000"], r"argument --scale: must be <= 64, got 100000"),
    (["track", "R", "--out", "d", "--spacing", "0"], r"argument --spacing: must be >= 1, got 0"),
    (["track", "R", "--out", "d", "--patch", "3"], r"argument --patch: patch must be an odd number of pixels >= 5, "
                                                   r"got 3"),  # the rule of TrackingOptions, checked by it
    (["track", "R", "--out", "d", "--patch", "16"], r"argument --patch: patch must be an odd number"),
    (["track", "R", "--out", "d", "--search", "0"], r"argument --search: search must be at least 1 pixel, got 0"),
    (["track", "R", "--out", "d", "--tracking-sigma", "-0.2"], r"argument --tracking-sigma: must be > 0.0"),
    (["remap", "P", "--out", "d", "--fill", "1000000"], r"argument --fill: must be <= 1000, got 1000000"),
    (["velocities", "F", "--out", "d", "--velocity-sigma", "-1"], r"argument --velocity-sigma: must be > 0.0"),
    (["velocities", "F", "--out", "d", "--box-km", "0"], r"argument --box-km: must be > 0.0, got 0"),
    (["block", "P", "--out", "d", "--knot-spacing", "0"], r"argument --knot-spacing: must be > 0.0, got 0"),
    (["simulate", "lancaster", "--out", "d", "--size", "30000"], r"argument --size: must be <= 4096"),
])
def test_bad_options_are_usage_errors_naming_the_option(capsys, argv, message):
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    assert re.search(message, capsys.readouterr().err)
