"""Archives on Dask (issue 17): a local Dask cluster writes the files of the single-process run (same numbers, bit
for bit), and a worker killed during the run has its task run again and the job completes. (Monte Carlo
realizations sharded over devices: tests/test_sharded_vmap.py.)"""

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
import tomllib
from dataclasses import replace
from pathlib import Path
from typing import cast

import numpy as np
import pytest
import xarray as xr
from distributed import Client, LocalCluster

from seaice_jax.cli import main
from seaice_jax.errors import EXIT_USAGE, SeaiceError
from seaice_jax.geometry.scan import SCAN_UNKNOWNS
from seaice_jax.imagery.tracking import GOOD, ON_LAND
from seaice_jax.io.remapped import load_remapped, save_stack
from seaice_jax.io.sequence import make_grid, read_sequence, write_sequence
from seaice_jax.outputs import output_folder
from seaice_jax.simulate.satellite import simulate_sequence
from seaice_jax.timefmt import time_after
from seaice_jax.workflows.archive import remap_archive, run_remap_archive, run_track_archive
from seaice_jax.workflows.remap import OVERVIEW_PANELS, run_remap, write_overview
from seaice_jax.workflows.simulated_sequence import SIMULATED_GRID
from seaice_jax.workflows.track import run_track

IMAGES = 6
NO_DASHBOARD = cast(str, None)  # typed str; None starts no web server


def _archive(root: Path, images: int) -> Path:
    """A project of ``images`` daily entries cycling through the two images of a small simulated sequence (each
    with its control points) on an 80 x 80 grid: an archive as the remap sees it."""
    source = write_sequence(simulate_sequence(3, n_images=2, size=64), root / "source", SIMULATED_GRID)
    document = tomllib.loads(source.read_text())
    grid = {**document["grid"], "shape": [80, 80]}
    lines = [f'epoch = "{document["epoch"]}"', "[grid]", *(f"{key} = {json.dumps(value)}" for key, value in
                                                            grid.items())]
    for k in range(images):
        entry = {**document["image"][k % 2], "name": f"A{k:03d}", "time": time_after(document["epoch"],
                                                                                      86400.0 * k + 3600.0)}
        lines += ["[[image]]", *(f"{key} = {json.dumps(value)}" for key, value in entry.items())]
    project = root / "source" / "archive.toml"
    project.write_text("\n".join(lines) + "\n")
    return project


@pytest.fixture(scope="module")
def archive(tmp_path_factory):
    root = tmp_path_factory.mktemp("archive")
    project = _archive(root, IMAGES)
    single = run_remap(project, root / "single", progress=False)
    return project, root / "single", single


def _same_outputs(expected: Path, actual: Path):
    names = sorted(p.name for p in expected.iterdir())
    assert sorted(p.name for p in actual.iterdir()) == names
    for name in names:
        if name == "remapped.npz":
            with np.load(expected / name) as a, np.load(actual / name) as b:
                assert sorted(a.files) == sorted(b.files)
                for key in a.files:
                    assert a[key].dtype == b[key].dtype and a[key].shape == b[key].shape, key
                    assert np.array_equal(a[key], b[key], equal_nan=a[key].dtype.kind == "f"), key
        else:  # GeoTIFFs, rectification.csv and the figure: the same bytes
            assert (expected / name).read_bytes() == (actual / name).read_bytes(), name


def test_archive_project_is_a_sequence_of_distinct_images(archive):
    project, _, single = archive
    read = read_sequence(project)
    assert len(read.images) == IMAGES and len({im.name for im in read.images}) == IMAGES
    assert np.all(np.diff([im.time for im in read.images]) > 0)
    assert single.result.values.shape == (IMAGES, 80, 80) and single.result.valid.mean() > 0.3


def test_two_worker_cluster_writes_the_single_process_files(archive, tmp_path):
    project, single_dir, _ = archive
    with (LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=NO_DASHBOARD) as cluster,
          Client(cluster) as client, output_folder(tmp_path / "dask") as folder):
        result, files = remap_archive(client, project, folder.path)
        files = folder.final(files)
    assert result.workers == 2 and [image.index for image in result.images] == list(range(IMAGES))
    assert [f.name for f in files] == [f"{name}.tif" for name in read_sequence_names(project)] + [
        "remapped.npz", "rectification.csv", "remapped.png"]
    _same_outputs(single_dir, tmp_path / "dask")


def read_sequence_names(project):
    return [im.name for im in read_sequence(project).images]


@pytest.mark.slow
def test_killed_worker_is_retried_and_the_job_completes(archive, tmp_path):
    project, single_dir, single = archive
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=NO_DASHBOARD)
    with cluster, Client(cluster) as client:
        outcome = {}

        def job():
            try:
                outcome["step"] = run_remap_archive(project, tmp_path / "dask", progress=False,
                                                    scheduler=str(cluster.scheduler_address))
            except BaseException as error:  # reported below
                outcome["error"] = error

        runner = threading.Thread(target=job)
        runner.start()
        deadline = time.monotonic() + 120
        busy = {}
        while not busy and time.monotonic() < deadline:  # a worker with a task of the job in hand
            busy = {worker: keys for worker, keys in cast(dict, client.processing()).items() if keys}
            time.sleep(0.05)
        assert busy, "no task started"
        victim = next(iter(busy))
        worker_pid = cast(dict, client.run(os.getpid, workers=[victim]))[victim]
        os.kill(worker_pid, signal.SIGKILL)  # as the kernel's out-of-memory killer would
        runner.join(timeout=240)
        assert not runner.is_alive(), "the job did not complete after the kill"
        assert "error" not in outcome, outcome.get("error")
        assert victim not in client.scheduler_info(n_workers=-1)["workers"]  # it died (its nanny started another)
    # every image of the archive, the killed worker's too, remapped once and reported in project order
    images = outcome["step"].result.images
    assert [image.index for image in images] == list(range(len(single.result.names)))
    _same_outputs(single_dir, tmp_path / "dask")


def test_bad_archive_is_refused_before_the_cluster_starts(tmp_path):
    (tmp_path / "p.toml").write_text('epoch = "1983-03-08T00:00:00Z"\n[grid]\ncentre_deg = [74.0, -85.0]\n'
                                     'pixel_m = [2500.0, 2500.0]\nshape = [10, 10]\n')
    with pytest.raises(SeaiceError, match=r"p.toml: no \[\[image\]\] entries"):
        run_remap_archive(tmp_path / "p.toml", tmp_path / "out", workers=2)
    with pytest.raises(SeaiceError, match="--workers must be at least 1"):
        run_remap_archive(tmp_path / "p.toml", tmp_path / "out", workers=0)
    assert not (tmp_path / "out").exists()


def test_bad_image_fails_its_task_naming_the_file_and_writes_nothing(archive, tmp_path):
    project = archive[0]
    copy = tmp_path / "project"
    shutil.copytree(project.parent, copy)
    first = tomllib.loads((copy / project.name).read_text())["image"][0]["file"]
    pixels = np.load(copy / first)
    pixels[3, 4] = np.nan
    np.save(copy / first, pixels)
    text = (copy / project.name).read_text()
    (copy / "names.toml").write_text(text.replace('name = "A001"', 'name = "A000"'))
    with pytest.raises(SeaiceError, match=r"names.toml: image 'A000': duplicate image name"):
        run_remap_archive(copy / "names.toml", tmp_path / "out", workers=1)  # before the cluster starts
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=NO_DASHBOARD)
    with cluster, pytest.raises(SeaiceError, match=rf"{first}: 1 pixel values are not finite"):
        run_remap_archive(copy / project.name, tmp_path / "out", progress=False,
                          scheduler=str(cluster.scheduler_address))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["project"]  # no output, no staging folder left


def test_cli_dask_options_are_checked_before_anything_runs(archive, tmp_path, capsys):
    project = str(archive[0])
    for options, message in ((["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "--workers and --scheduler: "
                              "give one"),
                             (["--workers", "2", "--models", str(tmp_path / "m.npz")], "--models: the scan models of "
                              "`seaice adjust` are adopted by the single-process remap")):
        assert main(["remap", project, "--out", str(tmp_path / "out"), *options]) == EXIT_USAGE
        assert message in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["remap", project, "--out", str(tmp_path / "out"), "--workers", "0"])
    assert not (tmp_path / "out").exists()


def test_default_remap_path_does_not_import_dask():
    code = ("import sys\nfrom seaice_jax.cli import build_parser\n"
            "build_parser().parse_args(['remap', 'p.toml', '--out', 'o'])\n"
            "build_parser().parse_args(['track', 'remapped', '--out', 'o'])\n"
            "from seaice_jax.workflows import remap, track\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('dask', 'distributed')))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    assert run.stdout.strip() == "[]"


def _same_drift_outputs(expected: Path, actual: Path):
    """NetCDF files: every variable and attribute equal (bit for bit) but the creation time; others: the same
    bytes."""
    names = sorted(p.name for p in expected.iterdir())
    assert sorted(p.name for p in actual.iterdir()) == names
    for name in names:
        if name.endswith(".nc"):
            with (xr.open_dataset(expected / name, decode_cf=False) as a,
                  xr.open_dataset(actual / name, decode_cf=False) as b):
                for stamped in ("history", "date_created"):
                    a.attrs.pop(stamped, None)
                    b.attrs.pop(stamped, None)
                assert a.identical(b), name
        else:  # figures, floes.csv, GeoJSON
            assert (expected / name).read_bytes() == (actual / name).read_bytes(), name


TRACKED_IMAGES = 3
"""Images of the archive tracked on the cluster: two pairs, one per worker, and floes followed past the first pair
(each pair writes its NetCDF files and figure: the 5 pairs of the whole archive cost 2.5 times as much)."""


def _first_images(remapped: Path, count: int, folder: Path) -> Path:
    """A `seaice remap` folder holding the first ``count`` images of the stack in ``remapped``."""
    stack = load_remapped(remapped)
    unknowns = len(SCAN_UNKNOWNS) * count
    folder.mkdir()
    save_stack(folder / "remapped.npz", replace(
        stack, values=stack.values[:count], valid=stack.valid[:count], times=stack.times[:count],
        names=stack.names[:count], models=stack.models[:count], covariance=stack.covariance[:unknowns, :unknowns],
        sigma=stack.sigma[:count]))
    return folder


@pytest.mark.slow
def test_two_worker_cluster_tracks_as_the_single_process_run(archive, tmp_path):
    """Pairs as tasks on 2 worker processes, with a land mask and the OSI SAF layout: the files and every tracked
    array of the single-process ``run_track``, bit for bit."""
    remapped = _first_images(archive[1], TRACKED_IMAGES, tmp_path / "remapped")
    land = np.zeros((80, 80), bool)
    land[:, :20] = True
    np.save(tmp_path / "land.npy", land)
    options = {"progress": False, "layout": "osisaf", "land": tmp_path / "land.npy"}
    single = run_track(remapped, tmp_path / "single", **options)
    dask = run_track_archive(remapped, tmp_path / "dask", workers=2, **options)
    assert [f.name for f in dask.files] == [f.name for f in single.files]
    _same_drift_outputs(tmp_path / "single", tmp_path / "dask")
    assert len(dask.result.pairs) == TRACKED_IMAGES - 1 and dask.report == single.report
    for a, b in zip(single.result.pairs, dask.result.pairs, strict=True):
        assert a.first == b.first and a.interval == b.interval
        for field in ("status", "x", "y", "dx", "dy", "sigma", "tracking_sigma", "correlation", "u_east", "v_north"):
            assert np.array_equal(getattr(a, field), getattr(b, field), equal_nan=True), field
        assert np.any(b.status == GOOD) and np.any(b.status == ON_LAND)  # vectors at sea, none from land
    for field in ("floe", "image", "time", "latitude", "longitude", "pixel", "scan"):
        assert np.array_equal(getattr(single.result.records, field), getattr(dask.result.records, field)), field
    for field in ("tracking_sigma", "correlation"):  # NaN at each floe's first fix
        assert np.array_equal(getattr(single.result.records, field), getattr(dask.result.records, field),
                              equal_nan=True), field
    assert len(set(dask.result.records.image.tolist())) == TRACKED_IMAGES  # floes followed past the first pair


def test_bad_track_input_is_refused_before_the_cluster_starts(archive, tmp_path):
    remapped = archive[1]
    tifs = [str(remapped / "A000.tif"), str(remapped / "A001.tif")]
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "remapped.npz").write_bytes(b"not a zip archive")
    np.save(tmp_path / "land.npy", np.zeros((3, 3), bool))
    for source, land, workers, message in (
            (tifs, None, 2, "GeoTIFF files are tracked by the single-process run"),
            (tmp_path / "none", None, 2, r"none/remapped.npz: file not found"),
            (tmp_path / "broken", None, 2, r"broken/remapped.npz: truncated or not a remapped stack"),
            (remapped, tmp_path / "land.npy", 2, r"land.npy: a land mask must be a bool array of the grid's"),
            (remapped, None, 0, "--workers must be at least 1")):
        with pytest.raises(SeaiceError, match=message):
            run_track_archive(source, tmp_path / "out", progress=False, land=land, workers=workers)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["broken", "land.npy"]  # no output, no staging folder
    assert main(["track", str(remapped), "--out", str(tmp_path / "out"), "--workers", "2", "--scheduler",
                 "tcp://127.0.0.1:1"]) == EXIT_USAGE
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_the_overview_of_a_long_archive_shows_and_reads_twelve_images(tmp_path):
    """``remapped.png`` of a 30-image sequence: 12 images evenly spaced, the first and the last among them, each
    read once (an archive's overview does not hold every image's pixels)."""
    grid = make_grid(**SIMULATED_GRID)
    read = []

    def image(k):
        read.append(k)
        return np.full(grid.shape, float(k))

    names = [f"IMG{k:02d}" for k in range(30)]
    path = write_overview(tmp_path / "remapped.png", names, np.arange(30) * 86400.0, "1983-03-08T00:00:00Z", grid,
                          image)
    assert path.read_bytes()[:4] == b"\x89PNG"
    assert len(read) == len(set(read)) == OVERVIEW_PANELS == 12 and read[0] == 0 and read[-1] == 29
    assert np.all(np.diff(read) >= 2) and np.ptp(np.diff(read)) <= 1
