"""Guards that hold (issue 31): inputs that used to run silently to a wrong result, or stop with a traceback, are
refused with an error naming the file, point, image or grid (before anything is written), or run with a note saying
what was left out."""

import os
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import xarray as xr

from seaice_jax.adjust.orbit.fit import check_point_errors, fit_scan_model
from seaice_jax.adjust.radar.block import BlockOptions
from seaice_jax.adjust.radar.layout import layout_block
from seaice_jax.cli import main
from seaice_jax.drift.kinematics import deformation
from seaice_jax.errors import RankDeficiencyError, SeaiceError
from seaice_jax.geometry.earth import MEAN_RADIUS
from seaice_jax.geometry.scan import ScanModel, satellite_orbit
from seaice_jax.imagery.tracking import GOOD, OUTLIER, Displacements, TrackingOptions, median_test
from seaice_jax.io.products import write_geotiff
from seaice_jax.io.project import read_project, write_project
from seaice_jax.io.remapped import RemappedStack, save_stack
from seaice_jax.io.sequence import MODEL_KEYS, make_grid, read_sequence
from seaice_jax.memory import check_disk, simulate_disk
from seaice_jax.sensors.control import ControlPoints
from seaice_jax.simulate.aircraft import FlightPlan, aidjex_scenario
from seaice_jax.simulate.satellite import noaa_pass
from seaice_jax.workflows.radar_block import block_unknowns
from seaice_jax.workflows.remap import run_remap
from seaice_jax.workflows.simulated_sequence import SIMULATED_GRID
from seaice_jax.workflows.track import run_track

SIZE = 32
HEAD = 'epoch = "1983-03-08T00:00:00Z"\n[grid]\ncentre_deg = {centre}\npixel_m = [5000.0, 5000.0]\nshape = [12, 12]\n'


def _given_model(name: str, model: ScanModel, hour: int, file: str) -> str:
    """An ``[[image]]`` table giving ``model`` (no control points: nothing is fitted)."""
    values = [float(getattr(model, f)) for f in ("scanner_angle_span", "subtrack_pixel", "orbital_angle_first",
                                                  "orbital_angle_span", "ascending_node")]
    keys = "\n".join(f"{key} = {value if key == 'subtrack_pixel' else float(np.degrees(value))!r}"
                     for key, value in zip(MODEL_KEYS, values, strict=True))
    return (f'[[image]]\nname = "{name}"\ntime = "1983-03-08T{hour:02d}:00:00Z"\nfile = "{file}"\n'
            f'satellite = "NOAA-7"\naltitude_m = 0.0\ndirection = "{model.direction}"\n{keys}\n')


def _project(folder, centre="[74.0, -85.0]", image_file="a.npy"):
    """Two small images near 74° N 85° W with given scan models, and a 60 km grid centred on ``centre``."""
    rng = np.random.default_rng(5)
    for name in ("a.npy", "b.npy"):
        np.save(folder / name, rng.uniform(0.0, 1.0, (SIZE, SIZE)))
    models = [noaa_pass(direction, SIZE, np.radians(74.0), np.radians(-85.0)) for direction in ("south", "north")]
    path = folder / "sequence.toml"
    path.write_text(HEAD.format(centre=centre) + _given_model("A", models[0], 1, image_file)
                    + _given_model("B", models[1], 22, "b.npy"))
    return path


def test_a_grid_that_misses_every_image_is_named_with_the_images(tmp_path, capsys):
    project = _project(tmp_path, centre="[80.0, 100.0]")
    out = tmp_path / "remapped"
    with pytest.raises(SeaiceError, match=r"sequence.toml: \[grid\] \(nsidc-north, centre_deg \[80.0, 100.0\], 12 x 12 "
                                          r"pixels of 5000.0 x 5000.0 m\) misses every image: no pixel of A, B falls "
                                          r"in it"):
        run_remap(project, out, progress=False)
    assert main(["remap", str(project), "--out", str(out), "-q"]) == 2
    assert "misses every image" in capsys.readouterr().err
    assert not out.exists()


def test_truncated_models_and_image_files_are_named(tmp_path, capsys):
    project = _project(tmp_path)
    (tmp_path / "models.npz").write_bytes(b"PK\x03\x04 a zip cut short")
    with pytest.raises(SeaiceError, match=r"models.npz: truncated or not a models file of `seaice adjust`"):
        run_remap(project, tmp_path / "out", progress=False, models_path=tmp_path / "models.npz")
    assert not (tmp_path / "out").exists()
    grid = make_grid(**{**SIMULATED_GRID, "shape": [SIZE, SIZE]})
    write_geotiff(tmp_path / "full.tif", np.zeros((SIZE, SIZE)), grid)
    (tmp_path / "a.tif").write_bytes((tmp_path / "full.tif").read_bytes()[:-1000])
    with pytest.raises(SeaiceError, match=r"a.tif: truncated or not a TIFF image"):
        read_sequence(_project(tmp_path, image_file="a.tif"))
    assert main(["remap", str(tmp_path / "sequence.toml"), "--out", str(tmp_path / "out")]) == 2
    error = capsys.readouterr().err
    assert "a.tif: truncated or not a TIFF image" in error and "Traceback" not in error


def _two_geotiffs(folder):
    grid = make_grid(**{**SIMULATED_GRID, "shape": [40, 40]})
    image = np.random.default_rng(2).uniform(0.0, 1.0, (40, 40))
    return [write_geotiff(folder / f"{name}.tif", image, grid) for name in ("first", "second")]


def test_images_too_close_in_time_to_measure_drift_are_refused(tmp_path):
    """Two images 1 ms apart gave drift speeds of ~6e8 km/day: refused, naming both images and the interval."""
    with pytest.raises(SeaiceError, match=r"images first and second are 0.001 s apart: the smallest displacement the "
                                          r"tracking resolves \(0.1 px of 2500 m\) would already be 2.16e\+07 km/day, "
                                          r"beyond the fastest sea-ice drift \(173 km/day\)"):
        run_track(_two_geotiffs(tmp_path), tmp_path / "drift", times=["2024-03-01T06:00:00.000Z",
                                                                      "2024-03-01T06:00:00.001Z"], progress=False)
    assert not (tmp_path / "drift").exists()


def test_a_drift_netcdf_given_to_track_is_named(tmp_path, capsys):
    """The tool's own drift NetCDF (an IndexError from GDAL's band 1) is named as not a GeoTIFF."""
    path = tmp_path / "drift_A_B.nc"
    xr.Dataset({"dX": (("y", "x"), np.zeros((3, 3))), "dY": (("y", "x"), np.zeros((3, 3)))}).to_netcdf(path)
    with pytest.raises(SeaiceError, match=r"drift_A_B.nc: not a GeoTIFF \(GDAL reads it as netCDF\)"):
        run_track([path, path], tmp_path / "out", progress=False)
    assert main(["track", str(path), "--out", str(tmp_path / "out")]) == 2
    error = capsys.readouterr().err
    assert "drift_A_B.nc: a file, not the folder written by `seaice remap`" in error and "Traceback" not in error
    assert not (tmp_path / "out").exists()


RECORDS = "floe_id,time,image,pixel,scan,latitude,longitude\n"


def _records(path, fixes):
    path.write_text(RECORDS + "".join(f"F{floe},{time},I{image},1,1,{lat},{lon}\n"
                                      for floe, time, image, lat, lon in fixes))
    return path


def test_velocities_of_floes_on_a_line_are_kept_with_a_note(tmp_path, capsys):
    """Floes on one line (the EPSG:3413 grid's meridian, 45° W, is a straight line) give no deformation triangles:
    the velocities and boxes are written, with a note, instead of the whole command failing."""
    fixes = [(k, time, image, 74 + k / 10 + image / 100, -45.0) for k in range(1, 5)
             for image, time in ((1, "1983-03-08T12:00:00Z"), (2, "1983-03-09T12:00:00Z"))]
    out = tmp_path / "velocities"
    assert main(["velocities", str(_records(tmp_path / "line.csv", fixes)), "--out", str(out)]) == 0
    report = capsys.readouterr().out
    assert "4 velocities of 4 floes" in report and "0 deformation triangles" in report
    assert "note: deformation at 1983-03-09T00:00:00Z: the 4 points lie on one line (or coincide): no triangles" \
        in report
    assert (out / "velocities.csv").is_file() and not (out / "deformation.csv").exists()
    rates = deformation(np.array([[0.0, 0.0], [1000.0, 0.0], [0.0, 1000.0], [500.0, 1e-7]]), np.ones((4, 2)), 0.01)
    assert rates.note == "1 of 3 triangles left out: their corners lie on one line" and len(rates.area) == 2


def test_implausible_velocities_are_left_out_with_a_note_or_refused(tmp_path, capsys):
    day, next_day = "1983-03-08T12:00:00Z", "1983-03-09T12:00:00Z"
    fixes = [(k, t, i, 74 + k / 10, -80.0 - k / 10 - i / 100) for k in range(1, 4) for i, t in ((1, day),
                                                                                               (2, next_day))]
    fixes.append((3, "1983-03-09T12:00:00.001Z", 3, 74.4, -80.0))  # 1 ms after its previous fix, 20 km away
    assert main(["velocities", str(_records(tmp_path / "one.csv", fixes)), "--out", str(tmp_path / "v1")]) == 0
    assert ("note: 1 of 4 velocities beyond the fastest sea-ice drift (173 km/day) left out (a wrong time or "
            "position); the fastest: floe F3:") in capsys.readouterr().out
    close = [(k, f"1983-03-08T12:00:00.00{i}Z", i, 74 + k / 10, -80.0 - i / 100) for k in range(1, 4) for i in (1, 2)]
    assert main(["velocities", str(_records(tmp_path / "all.csv", close)), "--out", str(tmp_path / "v2")]) == 2
    assert "all 3 velocities are beyond the fastest sea-ice drift (173 km/day)" in capsys.readouterr().err
    assert not (tmp_path / "v2").exists()


FIGURE_3_3_ORBIT = satellite_orbit("NOAA-7", altitude=0.0, earth_day=1440 * 60.0)


def _control(model, pixel, scan):
    lat, lon = (np.asarray(a) for a in model.forward(np.asarray(pixel, float), np.asarray(scan, float)))
    return ControlPoints(np.asarray(pixel, float), np.asarray(scan, float), lat, lon, 500.0,
                         [f"S{k}" for k in range(len(pixel))])


@pytest.mark.parametrize(("pixel", "scan", "message", "undetermined"), [
    ([50, 150, 250, 350, 450], [200.2] * 5, r"lie on one scan line \(200.2\)", {"orbital_angle_span"}),
    ([120] * 4, [50, 150, 300, 450], r"lie on one pixel column \(120\)", {"scanner_angle_span", "subtrack_pixel"}),
    ([100, 200, 300, 400], [100, 200.3, 300, 400], r"lie on one line of the image \(pixel, scan\)",
     {"scanner_angle_span", "orbital_angle_span"}),
])
@pytest.mark.parametrize("method", ["gauss-newton", "appendix_c"])
def test_control_points_on_one_line_are_refused_by_both_methods(pixel, scan, message, undetermined, method):
    """Appendix C answered a wrong span and Gauss-Newton a NumPy division warning (or σ of 1677°) for these."""
    truth = noaa_pass("south", 512, np.radians(74.0), np.radians(-80.0))
    with pytest.raises(RankDeficiencyError, match=rf"control points S0, S1, S2, S3.* {message}, within 0.5 px: they "
                                                  r"cannot determine .* apart") as info:
        fit_scan_model(_control(truth, pixel, scan), truth.orbit, method=method,
                       n_pixels=truth.n_pixels, n_scans=truth.n_scans)
    assert undetermined <= set(info.value.parameters)


def test_rectify_refuses_collinear_points_without_a_warning(tmp_path, capsys):
    path = tmp_path / "column.csv"
    path.write_text("id,name,pixel,scan,lat,lon\n1,A,100,100,75.0,-80.0\n2,B,100,200,74.5,-80.5\n"
                    "3,C,100,300,74.0,-81.0\n4,D,100,400,73.5,-81.5\n")
    assert main(["rectify", str(path), "--satellite", "NOAA-7", "--altitude", "0"]) == 2
    error = capsys.readouterr().err
    assert "control points 1, 2, 3, 4 lie on one pixel column (100)" in error
    assert "Warning" not in error and "Traceback" not in error


def test_an_image_across_the_orbits_apex_over_the_pole_is_fitted():
    """A pass whose image straddles the orbit's northernmost point, the pole inside its swath, was refused ("no
    southbound pass puts all control points on one side of the orbit's apex"); it is fitted to its points."""
    truth = ScanModel(np.radians(30.0), 16.0, np.radians(85.0), np.radians(10.0), 0.0, FIGURE_3_3_ORBIT, "south", 32,
                      32)
    rng = np.random.default_rng(3)
    control = _control(truth, rng.uniform(1, 32, 12), rng.uniform(1, 32, 12))
    pole = np.array([float(a) for a in truth.inverse(np.radians(89.999), 0.0)])
    assert np.all((pole > 1) & (pole < 32))  # the pole lies inside the image (pixel 6.8, scan line 16.5)
    fit = fit_scan_model(control, FIGURE_3_3_ORBIT, direction="south", n_pixels=32, n_scans=32)
    assert fit.rms_km < 1e-3
    check = _control(truth, rng.uniform(1, 32, 20), rng.uniform(1, 32, 20))
    assert np.max(check_point_errors(fit.model, check)) < 1e-3  # km: the whole image, not only its points


def test_local_workers_are_capped_by_the_cores_and_the_open_file_limit():
    """`remap --workers 10000` hung with "Too many open files": the workers started are capped, saying why."""
    script = ("import resource, sys\nfrom seaice_jax.workflows.archive import cores, local_workers\n"
              "print(local_workers(10_000)[0] == cores(), local_workers(10_000)[1])\n"
              "resource.setrlimit(resource.RLIMIT_NOFILE, (280, resource.getrlimit(resource.RLIMIT_NOFILE)[1]))\n"
              "print(local_workers(4))\n")
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    capped, limited = run.stdout.splitlines()
    assert capped.startswith("True --workers 10000: starting ") and "core(s), the open-file limit" in capped
    assert limited == "(1, '--workers 4: starting 1 worker process(es) (this machine gives " \
        f"{len(os.sched_getaffinity(0))} core(s), the open-file limit 280 allows 1)')"


def _interrupt(command, ready, timeout=120.0):
    """Run ``seaice command`` in its own process group, send SIGINT to the group (as Ctrl-C in a terminal does) once
    ``ready(pid)`` holds; ``(exit code, seconds from the signal to the exit, stderr)``."""
    process = subprocess.Popen([sys.executable, "-m", "seaice_jax.cli", *command], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, start_new_session=True)
    end = time.monotonic() + timeout
    while not ready(process.pid) and process.poll() is None and time.monotonic() < end:
        time.sleep(0.01)
    sent = time.monotonic()
    os.killpg(process.pid, signal.SIGINT)
    try:
        _, error = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
    return process.returncode, time.monotonic() - sent, error


def test_ctrl_c_stops_remap_on_local_workers_promptly_and_leaves_nothing(tmp_path):
    """Ctrl-C during `remap --workers`: each worker took the interrupt for itself (tracebacks, restarted by its
    nanny), the run went on or took 5-18 s to stop, and a staging folder was left. Now the workers never see it,
    the command exits 130 within seconds and the folder is as before."""
    project = _project(tmp_path)
    out = tmp_path / "remapped"
    code, seconds, error = _interrupt(["remap", str(project), "--out", str(out), "--workers", "10000"],
                                      lambda _: any((p / ".parts").is_dir() for p in tmp_path.glob(".remapped.*")))
    assert code == 130, error
    assert seconds < 10, seconds  # measured 1.0-1.3 s on 2 cores
    assert "seaice: --workers 10000: starting" in error  # capped, saying so, before the cluster starts
    assert "interrupted by SIGINT; the output was left as it was before the run" in error
    assert "Traceback" not in error and "KeyboardInterrupt" not in error
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npy", "b.npy", "sequence.toml"]


def _catches_sigterm(pid: int) -> bool:
    """Whether process ``pid`` has a handler for SIGTERM (the ``seaice`` command's, installed first thing in its
    ``main``; Python's own catches SIGINT only)."""
    with open(f"/proc/{pid}/status") as status:
        caught = next(line for line in status if line.startswith("SigCgt:"))
    return bool(int(caught.split()[1], 16) & (1 << (signal.SIGTERM - 1)))


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_ctrl_c_while_the_command_starts_is_not_lost(tmp_path):
    """A Ctrl-C in the first second (while JAX loads) was swallowed by a garbage-collection callback and the run
    went on to the end with exit 0; or it printed a traceback. Sent as soon as the command's handler is in place."""
    project = _project(tmp_path)
    code, seconds, error = _interrupt(["remap", str(project), "--out", str(tmp_path / "remapped")], _catches_sigterm)
    assert code == 130, error
    assert seconds < 10, seconds
    assert error.rstrip().endswith("interrupted by SIGINT; the output was left as it was before the run")
    assert not (tmp_path / "remapped").exists() and not list(tmp_path.glob(".remapped*"))


def test_jobs_beyond_the_memory_budget_are_refused_before_they_start(tmp_path, capsys, monkeypatch):
    """Estimates from the measured peaks (seaice_jax.memory; benchmarks/bench_memory.py runs the largest accepted
    jobs): `simulate --size 4096 --images 1000` was accepted; now refused before anything is simulated or written."""
    out = tmp_path / "simulated"
    assert main(["simulate", "lancaster", "--size", "4096", "--images", "1000", "--out", str(out)]) == 2
    assert ("--size 4096 --images 1000: simulating 1000 images of 4096 x 4096 pixels needs about 55.4 GiB of memory "
            "at its peak, more than the 4 GiB budget ($SEAICE_MEMORY_GIB sets another)") in capsys.readouterr().err
    assert simulate_disk(4096, 1000, 150 * 150) / 2**30 == pytest.approx(126.2, abs=0.1)  # the images' .npy files
    with pytest.raises(SeaiceError, match=rf"--size 4096 needs about 931322574.6 GiB of disk, \d+\.\d GiB free in "
                                          rf"{re.escape(str(tmp_path))}"):
        check_disk(1e18, out, "--size 4096")  # (memory enough: the disk is the limit then)
    monkeypatch.setenv("SEAICE_MEMORY_GIB", "plenty")
    assert main(["simulate", "lancaster", "--out", str(out)]) == 2
    assert "$SEAICE_MEMORY_GIB: the memory budget must be a positive number of GiB, got 'plenty'" in \
        capsys.readouterr().err
    assert not out.exists()


def test_tracking_every_pixel_of_a_large_grid_is_refused(tmp_path):
    """`track --spacing 1` reached 6 GB (20 GB on a 337² grid: the median test's distance matrix, now in blocks of
    rows): 15 kB per lattice point, measured."""
    spec = {**SIMULATED_GRID, "shape": [600, 600]}
    grid = make_grid(**spec)
    folder = tmp_path / "remapped"
    folder.mkdir()
    values = np.random.default_rng(1).uniform(0.0, 1.0, (2, *grid.shape))
    save_stack(folder / "remapped.npz", RemappedStack(values, np.ones(values.shape, bool), np.array([0.0, 86400.0]),
                                                      ("A", "B"), "1983-03-08T00:00:00Z", grid, spec, (),
                                                      np.zeros((0, 0)), np.full(values.shape, np.nan)))
    with pytest.raises(SeaiceError, match=r"--spacing 1: tracking 329476 lattice points needs about 5.7 GiB of "
                                          r"memory"):
        run_track(folder, tmp_path / "drift", TrackingOptions(spacing=1), progress=False, land=None)
    assert not (tmp_path / "drift").exists()


@pytest.fixture(scope="module")
def radar_project(tmp_path_factory):
    folder = tmp_path_factory.mktemp("radar") / "project"
    write_project(aidjex_scenario(seed=1, plan=FlightPlan(strips=2), features=40), folder)
    return folder / "project.toml"


def test_a_block_with_knots_every_millisecond_is_refused(radar_project, tmp_path, capsys):
    """`block --knot-spacing 1e-3` reached 6.3 GB: refused from the count of its unknowns, before anything runs."""
    out = tmp_path / "block"
    assert main(["block", str(radar_project), "--out", str(out), "--navigation-model", "spline",
                 "--navigation-scope", "strip", "--knot-spacing", "1e-3"]) == 2
    assert re.search(r"the simultaneous adjustment of 7200032 unknowns \(navigation model spline, --knot-spacing 0.001 "
                     r"s\) needs about \d+\.\d GiB of memory at its peak, more than the 4 GiB budget",
                     capsys.readouterr().err)
    assert not out.exists()


@pytest.mark.parametrize("options", [
    {}, {"navigation_model": "linear"}, {"take_off_time": 3000.0},
    {"navigation_model": "spline", "navigation_scope": "strip", "knot_spacing": 30.0},
    {"navigation_model": "constant", "navigation_scope": "strip"},
])
def test_the_block_guard_counts_the_layouts_unknowns(radar_project, options):
    project = read_project(radar_project)
    block = BlockOptions(**options)
    layout = layout_block(project.coverages, len(project.point_ids), project.plane, block, MEAN_RADIUS,
                          project.point_ids)
    assert block_unknowns(project.coverages, block) == len(layout.names)


@pytest.mark.slow
def test_the_median_test_of_many_vectors_keeps_its_memory_linear_and_its_answer():
    """Beyond 2048 good vectors the neighbours come from blocks of rows (the g x g distance matrix of 97 000 vectors
    took 20 GB): the same flags as the test written out on the whole matrix."""
    rng = np.random.default_rng(4)
    n = 3000
    row, column = rng.uniform(0.0, 400.0, n), rng.uniform(0.0, 400.0, n)
    d_row, d_column = 0.01 * row + rng.normal(0.0, 0.1, n), -0.02 * column + rng.normal(0.0, 0.1, n)
    d_row[:40] += 5.0  # outliers
    nan = np.full(n, np.nan)
    vectors = Displacements(row, column, d_row, d_column, nan, nan, np.full(n, GOOD), nan, nan)
    flagged = median_test(vectors).status == OUTLIER
    position, vector = np.stack([row, column], 1), np.stack([d_row, d_column], 1)
    distance = np.linalg.norm(position[:, None] - position[None], axis=-1)
    np.fill_diagonal(distance, np.inf)
    neighbours = vector[np.argsort(distance, axis=1)[:, :8]]
    median = np.median(neighbours, axis=1)
    spread = np.median(np.abs(neighbours - median[:, None]), axis=1)
    expected = (np.abs(vector - median) / (spread + 0.1) > 3.0).any(axis=1)
    np.testing.assert_array_equal(flagged, expected)
    assert flagged[:40].all() and flagged.sum() < 60
