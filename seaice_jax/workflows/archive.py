"""Image archives on Dask (``dask.distributed``): ``seaice remap`` and ``seaice track`` with ``--workers N`` or
``--scheduler ADDRESS``.

The single-process :func:`~seaice_jax.workflows.remap.run_remap` holds every image of a sequence in memory.
Here every image is one task: a worker reads it (:func:`~seaice_jax.io.sequence.read_sequence_image`), fits its scan
model to its control points, remaps it, writes its GeoTIFF and its pixels into the run's staging folder and returns
only the small rest (model, covariance block, control-point deviations). A worker's memory is thus bounded by the
images it works on at once (one per thread), not by the archive. Dask schedules the tasks, reports progress, and runs
again the tasks of a worker that dies. The client then streams the per-image pixels into ``remapped.npz`` one image
at a time and writes the summary files; every file equals the single-process one (same numbers, bit for bit: the
per-image computation is the same code on the same data).

``seaice track`` likewise makes every consecutive pair of images one task (:func:`track_image_pair`): the client
unpacks the pixels of ``remapped.npz`` once into ``.npy`` files in the staging folder (streamed), a task reads the
two images it needs from them (memory-mapped), tracks the pair and writes its drift files. Following the floes is a
chain through the whole sequence (each step starts where the last ended), so it stays in the client, reading the
images one pair at a time from the same memory maps while the tasks run; the client then writes the sequence-wide
files (``floes.csv``, the GeoJSON).

The output folder policy holds (:func:`~seaice_jax.outputs.output_folder`): the staging folder lies beside the
target and becomes it only when the run is complete; a failed or interrupted run cancels its tasks and waits for the
running ones to end before the staging folder is removed. With ``--scheduler`` the workers must therefore see the
project and the target's parent folder at the same paths (a shared file system, as on a batch system's cluster).

Dask is imported only here; the default single-machine path never loads it.
"""

import contextlib
import json
import logging
import os
import shutil
import signal
import sys
import threading
import time
import weakref
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import cast

import numpy as np
from distributed import Client, LocalCluster, as_completed
from tqdm.auto import tqdm

from seaice_jax.drift.kinematics import check_tracking_interval
from seaice_jax.errors import SeaiceError
from seaice_jax.files import atomic_path
from seaice_jax.geometry.scan import SCAN_UNKNOWNS, ScanModel
from seaice_jax.imagery.tracking import TrackingOptions, grid_points
from seaice_jax.io.products import write_geotiff
from seaice_jax.io.remapped import RemappedStack, load_remapped, model_arrays
from seaice_jax.io.sequence import SequenceProject, read_sequence_image, read_sequence_outline
from seaice_jax.memory import check_memory, track_peak
from seaice_jax.outputs import check_interrupted, check_output, output_folder
from seaice_jax.timefmt import time_after
from seaice_jax.workflows.remap import (
    Rectification,
    check_grid_reached,
    remap_sequence,
    write_overview,
    write_rectification,
)
from seaice_jax.workflows.step import Step
from seaice_jax.workflows.track import (
    TrackedPair,
    TrackedSequence,
    follow_floes,
    land_of_grid,
    make_lattice,
    track_pair,
    track_report,
    write_pair,
    write_tracked,
)

_UNKNOWNS = len(SCAN_UNKNOWNS)
PARTS = ".parts"
"""The staging folder's sub-folder of per-image pixels (removed before the run completes)."""


@dataclass(frozen=True)
class RemappedImage:
    """What the task of one image returns (its pixels stay in the staging folder: :func:`remap_image`).

    Attributes:
        index: the image's place in the project. time: s since the project's epoch. rectification: its scan model
        and fit. covariance: ``(5, 5)`` of the model's unknowns (zero for a given model). worker: the process id
        that ran the task. seconds: its wall time. peak_memory: bytes, the worker process's peak resident memory
        when the task ended (:func:`peak_memory`). pixels: its valid pixels on the grid (0: it misses the grid).
    """

    index: int
    time: float
    rectification: Rectification
    covariance: np.ndarray
    worker: int
    seconds: float
    peak_memory: int
    pixels: int = 0


@dataclass(frozen=True)
class ArchiveRemap:
    """An archive remapped on Dask: everything of a :class:`~seaice_jax.io.remapped.RemappedStack` but
    its pixels (in the written ``remapped.npz``).

    Attributes:
        project: the project (its grid; no images). images: per image, in project order. workers: the number of
        Dask workers when the run ended.
    """

    project: SequenceProject
    images: tuple[RemappedImage, ...]
    workers: int

    @property
    def models(self) -> tuple[ScanModel, ...]:
        return tuple(image.rectification.model for image in self.images)


def peak_memory() -> int:
    """Bytes: this process's peak resident memory (Linux ``VmHWM``; ``ru_maxrss`` elsewhere — not on Linux, where
    it also holds the peak of the process that started this one)."""
    status = Path("/proc/self/status")
    if status.exists():
        for line in status.read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * (1 if sys.platform == "darwin" else 1024)


def _part_path(staging: Path, index: int) -> Path:
    return staging / PARTS / f"{index:08d}.npz"


def remap_image(project: SequenceProject, entry: dict, index: int, staging: str | os.PathLike, method: str,
                fill: int) -> RemappedImage:
    """The task of one image: read it, fit its scan model to its control points (or take the given one), remap it
    into the project's grid, and write ``<name>.tif`` and its pixels (values, valid, geolocation σ) into
    ``staging``, as :func:`~seaice_jax.workflows.remap.run_remap` computes and writes each image.
    Idempotent (files written atomically), so Dask may run it again after a worker died."""
    start = time.perf_counter()
    staging = Path(staging)
    image = read_sequence_image(project, entry, index)
    alone = SequenceProject(project.path, project.epoch, project.grid, project.grid_spec, (image,))
    stack, (rectification,) = remap_sequence(alone, method, fill, check_reached=False)
    moment = time_after(project.epoch, image.time)
    write_geotiff(staging / f"{image.name}.tif", stack.values[0], project.grid, f"{image.name} {moment}", time=moment)
    with atomic_path(_part_path(staging, index)) as temporary, open(temporary, "wb") as stream:
        np.savez(stream, values=stack.values[0], valid=stack.valid[0], sigma=stack.sigma[0])
    return RemappedImage(index, float(image.time), rectification, stack.covariance, os.getpid(),
                         time.perf_counter() - start, peak_memory(), int(stack.valid[0].sum()))


def check_cluster_options(workers: int | None, scheduler: str | None) -> None:
    """Refuse ``--workers`` and ``--scheduler`` together, or fewer than one worker.

    Raises:
        SeaiceError: ``workers`` below 1, or both ``workers`` and ``scheduler`` given.
    """
    if workers is not None and scheduler is not None:
        raise SeaiceError("--workers and --scheduler: give one (--workers starts a local cluster, --scheduler "
                          "connects to a running one)")
    if workers is not None and workers < 1:
        raise SeaiceError(f"--workers must be at least 1, got {workers}")


FILES_PER_WORKER = 16
"""Open files (sockets, pipes) a local Dask worker costs this process: about 10 measured (25 for one worker, 95 for
eight), with a margin."""
FILES_KEPT = 256
"""Open files kept for the rest of this process (JAX, the images, the outputs) when the workers are counted."""


def cores() -> int:
    """The CPU cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def local_workers(requested: int | None = None) -> tuple[int, str]:
    """How many local worker processes to start for ``requested`` (None: one per core): at most one per core (each
    runs one image at a time on one thread) and no more than the open-file limit (``RLIMIT_NOFILE``) allows
    (:data:`FILES_PER_WORKER`, :data:`FILES_KEPT`; 10 000 workers stopped with "Too many open files").

    Returns:
        ``(count, note)``: the note says why fewer than ``requested`` are started (empty when none are left out).
    """
    import resource

    limit = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    by_files = (max(1, (limit - FILES_KEPT) // FILES_PER_WORKER) if limit != resource.RLIM_INFINITY
                else requested or cores())
    count = max(1, min(requested or cores(), cores(), by_files))
    if requested is None or count == requested:
        return count, ""
    files = "" if limit == resource.RLIM_INFINITY else f", the open-file limit {limit} allows {by_files}"
    return count, (f"--workers {requested}: starting {count} worker process(es) (this machine gives {cores()} "
                   f"core(s){files})")


_LOCAL: "weakref.WeakSet[Client]" = weakref.WeakSet()
"""Clients of the local clusters :func:`dask_client` started: closing the cluster ends every task."""


@contextlib.contextmanager
def _sigint_held() -> Iterator[None]:
    """SIGINT blocked in this thread while the block runs: threads and processes started in it inherit the block
    (delivered here when it ends)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


@contextlib.contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None) -> Iterator[Client]:
    """A Dask client: of the cluster at ``scheduler`` (an address, e.g. ``tcp://host:8786``), or of a local cluster of
    worker processes (:func:`local_workers` of ``workers``; default: one per CPU core) with one thread each, closed
    when the block ends. The local workers inherit the environment and share this process's persistent JAX
    compilation cache, if it has one (the ``seaice`` command's: a second run's workers skip XLA's compilations).

    The local cluster's threads and worker processes start with SIGINT blocked: a Ctrl-C (SIGINT to the terminal's
    process group) reaches this process alone, which stops the run and closes the cluster (before, each worker took
    the interrupt for itself, printed a traceback and was restarted by its nanny, and the run went on or took many
    seconds to stop).

    Raises:
        SeaiceError: as :func:`check_cluster_options`.
    """
    check_cluster_options(workers, scheduler)
    if scheduler is not None:
        with Client(scheduler) as client:
            yield client
        return
    import jax

    folder = jax.config.values.get("jax_compilation_cache_dir")
    cache = {"JAX_COMPILATION_CACHE_DIR": str(folder), "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
             "JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES": "0"} if folder else {}
    no_dashboard = cast(str, None)  # typed str; None starts no web server
    from multiprocessing import resource_tracker

    # started now, outside the block: starting it from the cluster's thread would unblock SIGINT there (it blocks
    # and then unblocks SIGINT and SIGTERM around its own start)
    resource_tracker.ensure_running()
    cluster = None
    with _distributed_logs(logging.WARNING) as quiet:
        try:
            with _sigint_held():
                cluster = LocalCluster(n_workers=local_workers(workers)[0], threads_per_worker=1, processes=True,
                                       dashboard_address=no_dashboard, env=cache)
                client = Client(cluster)
                _LOCAL.add(client)
            check_interrupted()
            with client:
                yield client
        finally:
            if cluster is not None:
                with _sigint_held():  # a second Ctrl-C does not cut the closing short (it is delivered after)
                    if sys.exc_info()[0] is not None:  # stopped (an interrupt, an error): no running task is wanted
                        quiet.setLevel(logging.CRITICAL)  # the scheduler's notes on the workers it lost
                        _end_workers(cluster)
                    cluster.close()


@contextlib.contextmanager
def _distributed_logs(level: int) -> Iterator[logging.Logger]:
    """Dask's ``distributed`` logger at ``level`` while the block runs, the level it had after. Around the whole
    life of a local cluster: Dask's own ``silence_logs`` gives back the level it found inside ``close``, and that
    was INFO, at which the scheduler's note on a connection closed by the killed workers printed a traceback after
    a Ctrl-C (a race: seen on CI)."""
    logger = logging.getLogger("distributed")
    before = logger.level
    logger.setLevel(level)
    try:
        yield logger
    finally:
        logger.setLevel(before)


def _end_workers(cluster: LocalCluster) -> None:
    """End the worker processes of a local cluster at once (a running task cannot be interrupted, and its nanny
    would wait 4 s for it to close): their nannies told not to start them again, then SIGKILL."""
    for nanny in list(cluster.workers.values()):
        pid = getattr(nanny, "pid", None)
        with contextlib.suppress(Exception):
            nanny.close_gracefully("the run stopped")
        if pid:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


def _npy_header(stream, dtype, shape) -> None:
    np.lib.format.write_array_header_1_0(stream, {"descr": np.lib.format.dtype_to_descr(np.dtype(dtype)),
                                                  "fortran_order": False, "shape": tuple(shape)})


def _write_npz(path: Path, small: dict, stacked: dict, parts: list[Path]) -> Path:
    """``path``, an ``.npz`` as :func:`numpy.savez_compressed` writes it: the ``small`` arrays whole, and each
    ``stacked`` array (name -> (dtype, shape of one image)) streamed image by image from the ``parts`` files, so
    that one image at a time is in memory."""
    with atomic_path(path) as temporary, zipfile.ZipFile(temporary, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, value in small.items():
            with archive.open(f"{name}.npy", "w", force_zip64=True) as stream:
                np.lib.format.write_array(stream, np.asanyarray(value), allow_pickle=False)
        for name, (dtype, shape) in stacked.items():
            with archive.open(f"{name}.npy", "w", force_zip64=True) as stream:
                _npy_header(stream, dtype, (len(parts), *shape))
                for part in parts:
                    with np.load(part) as data:
                        stream.write(np.ascontiguousarray(data[name], dtype).tobytes())
    return path


def write_archive_summary(result: ArchiveRemap, staging: Path) -> list[Path]:
    """``remapped.npz`` (streamed from the per-image parts), ``rectification.csv`` and ``remapped.png``, as
    :func:`~seaice_jax.workflows.remap.write_remapped` writes them."""
    project, images = result.project, result.images
    names = [image.rectification.name for image in images]
    covariance = np.zeros((_UNKNOWNS * len(images),) * 2)
    for k, image in enumerate(images):
        covariance[_UNKNOWNS * k:_UNKNOWNS * (k + 1), _UNKNOWNS * k:_UNKNOWNS * (k + 1)] = image.covariance
    times = np.array([image.time for image in images])
    parts = [_part_path(staging, image.index) for image in images]
    shape = project.grid.shape
    small = {"times": times, "names": np.array(names), "epoch": project.epoch, "grid": json.dumps(project.grid_spec),
             "covariance": covariance, **model_arrays(result.models)}
    files = [_write_npz(staging / "remapped.npz", small, {"values": (np.float64, shape), "valid": (np.bool_, shape),
                                                           "sigma": (np.float64, shape)}, parts)]
    files += write_rectification(staging / "rectification.csv", [image.rectification for image in images])

    def values(k):
        with np.load(parts[k]) as data:
            return data["values"]

    files.append(write_overview(staging / "remapped.png", names, times, project.epoch, project.grid, values))
    return files


def _executing(keys: set, dask_worker=None) -> int:
    """How many of the tasks ``keys`` the worker (``dask_worker``, given by ``Client.run``) is running, cancelled
    ones included."""
    assert dask_worker is not None
    return sum(task.key in keys for task in dask_worker.state.executing)


def _stop(client: Client, futures, timeout: float = 60.0) -> None:
    """Cancel the run's tasks and wait (up to ``timeout`` s) until none still runs, so that none writes into the
    staging folder once it is removed (a running task cannot be interrupted, only forgotten); on a local cluster of
    :func:`dask_client`, closed before the staging folder is removed (its workers end with it), not waiting."""
    client.cancel(futures)
    if client in _LOCAL:
        return
    keys = {future.key for future in futures}
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and sum(cast(dict, client.run(_executing, keys, on_error="ignore")).values()):
        time.sleep(0.1)


def remap_archive(client: Client, project_path: str | os.PathLike, staging: str | os.PathLike,
                  method: str = "bilinear", fill: int = 1,
                  progress: bool = False) -> tuple[ArchiveRemap, tuple[Path, ...]]:
    """Remap every image of the project as one Dask task (:func:`remap_image`) into ``staging`` and write the
    summary files there (:func:`write_archive_summary`).

    Returns:
        ``(result, files)``: the files those of :func:`~seaice_jax.workflows.remap.write_remapped`, in its
        order.

    Raises:
        SeaiceError: the project's outline is bad (before any task runs), or an image is (from its task, naming
            its file).
    """
    project, entries = read_sequence_outline(project_path)
    staging = Path(staging)
    (staging / PARTS).mkdir(exist_ok=True)
    count = len(entries)
    futures = client.map(remap_image, [project] * count, entries, range(count), [str(staging)] * count,
                         method=method, fill=fill, pure=False)
    images: list[RemappedImage | None] = [None] * count
    try:
        with tqdm(total=count, desc="remap (dask)", disable=not progress, leave=False) as bar:
            for future in as_completed(futures):
                image = future.result()
                images[image.index] = image
                future.release()
                bar.update()
                check_interrupted()
    except BaseException:  # a task's error, or an interrupt: no task may write into the staging folder after this
        _stop(client, futures)
        raise
    result = ArchiveRemap(project, tuple(image for image in images if image is not None),
                          len(client.scheduler_info(n_workers=-1)["workers"]))
    check_grid_reached(project.path, project.grid_spec, [image.rectification.name for image in result.images],
                       [image.pixels for image in result.images])
    files = [staging / f"{image.rectification.name}.tif" for image in result.images]
    files += write_archive_summary(result, staging)
    for part in (staging / PARTS).iterdir():
        part.unlink()
    (staging / PARTS).rmdir()
    return result, tuple(files)


def archive_report(result: ArchiveRemap, method: str, fill: int) -> str:
    fitted = [image.rectification for image in result.images if image.rectification.control]
    rows, columns = result.project.grid.shape
    lines = [f"remapped {len(result.images)} images into a {rows} x {columns} grid ({method}, fill {fill}) on "
             f"{result.workers} Dask workers"]
    if fitted:
        sigma0 = np.array([r.sigma0 for r in fitted])
        lines.append(f"  {len(fitted)} scan models fitted to control points: σ̂0 median {np.median(sigma0):.2f}, "
                     f"max {sigma0.max():.2f}")
    missing = [image.rectification.name for image in result.images if not image.pixels]
    if missing:
        lines.append(f"  note: no pixel of {', '.join(missing)} falls in the grid (their remapped images are empty)")
    seconds = np.array([image.seconds for image in result.images])
    lines.append(f"  per image: median {np.median(seconds):.2f} s of a worker (max {seconds.max():.1f} s, with the "
                 f"compilations); peak memory of a worker {max(i.peak_memory for i in result.images) / 2**20:.0f} MiB")
    return "\n".join(lines)


def run_remap_archive(project_path: str | os.PathLike, out_dir: str | os.PathLike, method: str = "bilinear",
                      fill: int = 1, progress: bool = True, overwrite: bool = False, workers: int | None = None,
                      scheduler: str | None = None, models_path: str | os.PathLike | None = None) -> Step[ArchiveRemap]:
    """:func:`~seaice_jax.workflows.remap.run_remap` on Dask (:func:`dask_client`: ``workers`` local
    processes, or the cluster at ``scheduler``): the same files in ``out_dir``, written as one run (the project's
    outline and the target are checked before the cluster starts).

    Raises:
        SeaiceError: ``models_path`` given (the models of ``seaice adjust`` are adopted by the single-process run
            only), or as :func:`dask_client` and :func:`remap_archive`.
    """
    if models_path is not None:
        raise SeaiceError("--models: the scan models of `seaice adjust` are adopted by the single-process remap; "
                          "drop --workers/--scheduler (or --models)")
    check_cluster_options(workers, scheduler)
    read_sequence_outline(project_path)
    check_output(out_dir, overwrite, inputs=(project_path,))
    note = workers_note(workers, scheduler, progress)
    # the staging folder outlives the cluster: no task writes into it once it is removed
    with output_folder(out_dir, overwrite, inputs=(project_path,)) as folder, dask_client(workers,
                                                                                          scheduler) as client:
        result, files = remap_archive(client, project_path, folder.path, method, fill, progress)
        files = folder.final(files)
    return Step(files, "\n".join(filter(None, [archive_report(result, method, fill), note and f"  note: {note}"])),
                result)


def workers_note(workers: int | None, scheduler: str | None, progress: bool) -> str:
    """The note of :func:`local_workers` for a local cluster, logged at once (``seaice_jax.workflows.archive``,
    WARNING; with ``progress``, before the cluster starts: the command line prints it then)."""
    note = local_workers(workers)[1] if scheduler is None else ""
    if note:
        logging.getLogger(__name__).warning(note)
    return note


# ------------------------------------------------------------------------------------------------ track

PIXELS = ("values", "valid", "sigma")
"""The per-image arrays of ``remapped.npz`` that a tracking run unpacks into its staging folder's :data:`PARTS`."""


def staged_stack(remapped_dir: str | os.PathLike, parts: str | os.PathLike) -> RemappedStack:
    """The stack written by ``seaice remap`` into ``remapped_dir``, its :data:`PIXELS` unpacked from
    ``remapped.npz`` into ``.npy`` files in ``parts`` (streamed: a few MB in memory whatever the archive's size) and
    memory-mapped from there.

    Raises:
        SeaiceError: naming ``remapped.npz``: missing, truncated, or not a remapped stack of two or more images.
    """
    path, parts = Path(remapped_dir) / "remapped.npz", Path(parts)
    if Path(remapped_dir).is_file():
        raise SeaiceError(f"{remapped_dir}: a file, not the folder written by `seaice remap`; give that folder")
    if not path.exists():
        raise SeaiceError(f"{path}: file not found (run `seaice remap` first)")
    parts.mkdir(exist_ok=True)
    try:
        with zipfile.ZipFile(path) as archive:
            for name in PIXELS:
                with archive.open(f"{name}.npy") as source, open(parts / f"{name}.npy", "wb") as target:
                    shutil.copyfileobj(source, target, 1 << 24)
        pixels = {name: np.load(parts / f"{name}.npy", mmap_mode="r") for name in PIXELS}
    except (KeyError, zipfile.BadZipFile, EOFError, ValueError, OSError) as error:
        raise SeaiceError(f"{path}: truncated or not a remapped stack ({error}); run `seaice remap` again") from None
    stack = load_remapped(remapped_dir, pixels)
    if len(stack.names) < 2:
        raise SeaiceError(f"{path}: tracking needs at least two images, got {len(stack.names)}")
    return stack


def _pair_outline(stack: RemappedStack, first: int) -> RemappedStack:
    """Images ``first`` and ``first + 1`` of ``stack`` without their pixels (zero images: the task reads them), with
    the ``(10, 10)`` covariance of their unknowns: what the client sends a task."""
    none = np.zeros((0, *stack.grid.shape))
    return RemappedStack(none, none.astype(bool), np.array(stack.times[first:first + 2]),
                         stack.names[first:first + 2], stack.epoch, stack.grid, stack.grid_spec,
                         stack.models[first:first + 2], np.array(stack.pair_covariance(first)), none)


def track_image_pair(outline: RemappedStack, first: int, parts: str | os.PathLike, staging: str | os.PathLike,
                     lattice, options: TrackingOptions, land=None,
                     layout: str = "project") -> tuple[TrackedPair, list[Path]]:
    """The task of one pair: read images ``first`` and ``first + 1`` from the unpacked pixels (``parts``:
    :func:`staged_stack`) into ``outline`` (:func:`_pair_outline`), track them
    (:func:`~seaice_jax.workflows.track.track_pair`) and write the pair's files into ``staging``
    (:func:`~seaice_jax.workflows.track.write_pair`). Idempotent (files written atomically).

    Returns:
        ``(pair, files)``: the tracked pair (``first`` its index in the sequence) and the files written.
    """
    pixels = {name: np.array(np.load(Path(parts) / f"{name}.npy", mmap_mode="r")[first:first + 2])
              for name in PIXELS}
    pair_stack = replace(outline, **pixels)
    pair = track_pair(pair_stack, 0, options, land)
    files = write_pair(pair_stack, lattice, pair, Path(staging), layout)
    return replace(pair, first=first), files


def track_archive(client: Client, stack: RemappedStack, staging: str | os.PathLike,
                  options: TrackingOptions | None = None, layout: str = "project", land=None,
                  progress: bool = False) -> tuple[TrackedSequence, tuple[Path, ...]]:
    """Track every pair of consecutive images of ``stack`` (from :func:`staged_stack` into ``staging``) as one Dask
    task (:func:`track_image_pair`), follow the floes through the sequence in this process meanwhile
    (:func:`~seaice_jax.workflows.track.follow_floes`: a chain), and write the sequence-wide files;
    arguments as :func:`~seaice_jax.workflows.track.track_sequence` and
    :func:`~seaice_jax.workflows.track.write_tracked`.

    Returns:
        ``(tracked, files)``: the files those of :func:`~seaice_jax.workflows.track.write_tracked`, in its
        order.
    """
    options = options or TrackingOptions()
    staging = Path(staging)
    rows, columns = grid_points(stack.grid.shape, options)
    lattice = make_lattice(stack.grid, rows, columns, (np.unique(rows).size, np.unique(columns).size))
    count = len(stack.names) - 1
    futures = client.map(track_image_pair, [_pair_outline(stack, k) for k in range(count)], range(count),
                         parts=str(staging / PARTS), staging=str(staging), lattice=lattice, options=options,
                         land=land, layout=layout, pure=False)
    pairs: list[TrackedPair | None] = [None] * count
    written: list[list[Path]] = [[] for _ in range(count)]
    try:
        records = follow_floes(stack, rows, columns, options, progress, land)
        with tqdm(total=count, desc="track (dask)", disable=not progress, leave=False) as bar:
            for future in as_completed(futures):
                pair, files = future.result()
                pairs[pair.first], written[pair.first] = pair, files
                future.release()
                bar.update()
    except BaseException:  # a task's error, or an interrupt: no task may write into the staging folder after this
        _stop(client, futures)
        raise
    tracked = TrackedSequence(tuple(pair for pair in pairs if pair is not None), lattice, records, options)
    files = [path for pair_files in written for path in pair_files]
    files += write_tracked(stack, replace(tracked, pairs=()), staging, layout)
    shutil.rmtree(staging / PARTS)
    return tracked, tuple(files)


def run_track_archive(remapped_dir, out_dir: str | os.PathLike, options: TrackingOptions | None = None,
                      progress: bool = True, overwrite: bool = False, layout: str = "project",
                      land: str | os.PathLike | None = "coastline", workers: int | None = None,
                      scheduler: str | None = None) -> Step[TrackedSequence]:
    """:func:`~seaice_jax.workflows.track.run_track` on Dask (:func:`dask_client`: ``workers`` local
    processes, or the cluster at ``scheduler``) for the folder of ``seaice remap``: the same files in ``out_dir``,
    written as one run (the stack, the land mask and the target are checked before the cluster starts).

    Raises:
        SeaiceError: ``remapped_dir`` a list of GeoTIFF files (tracked by the single-process run only), or as
            :func:`dask_client`, :func:`staged_stack` and
            :func:`~seaice_jax.workflows.track.land_of_grid`.
    """
    if isinstance(remapped_dir, list | tuple):
        raise SeaiceError("--workers/--scheduler: give the folder of `seaice remap`; GeoTIFF files are tracked by "
                          "the single-process run (drop --workers/--scheduler)")
    check_cluster_options(workers, scheduler)
    note = workers_note(workers, scheduler, progress)
    with output_folder(out_dir, overwrite, inputs=(remapped_dir,)) as folder:
        stack = staged_stack(remapped_dir, folder.path / PARTS)
        check_tracking_interval(stack.names, stack.times, float(stack.grid.pixel_width))
        points = grid_points(stack.grid.shape, options or TrackingOptions())[0].size
        check_memory(track_peak(points, stack.grid.shape[0] * stack.grid.shape[1], 2),  # a pair per worker
                     f"--spacing {(options or TrackingOptions()).spacing}: tracking {points} lattice points")
        mask = None if land is None else land_of_grid(land, stack.grid)
        with dask_client(workers, scheduler) as client:
            tracked, files = track_archive(client, stack, folder.path, options, layout, mask, progress)
        files = folder.final(files)
    return Step(files, "\n".join(filter(None, [track_report(stack, tracked), note and f"  note: {note}"])), tracked)
