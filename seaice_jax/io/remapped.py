"""A sequence remapped into one grid (:class:`RemappedStack`: what ``seaice remap`` writes and ``seaice track``
reads) and the scan models of a sequence (``models.npz``): saving and loading, GeoTIFF stacks made elsewhere."""

import json
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import cast

import numpy as np

from seaice_jax.errors import SeaiceError
from seaice_jax.files import atomic_path
from seaice_jax.geometry.crs import CrsProjection
from seaice_jax.geometry.projections import MapGrid
from seaice_jax.geometry.scan import SCAN_UNKNOWNS, Direction, Orbit, ScanModel
from seaice_jax.io.products import read_geotiff
from seaice_jax.io.sequence import SequenceProject, make_grid
from seaice_jax.timefmt import format_time, parse_time

_UNKNOWNS = len(SCAN_UNKNOWNS)


@dataclass(frozen=True)
class RemappedStack:
    """A sequence remapped into one grid (what ``remapped.npz`` holds).

    Attributes:
        values: ``(images, n_rows, n_columns)`` remapped pixels (NaN outside the swath). valid: same shape, bool.
        times: ``(images,)`` s since ``epoch`` (ISO 8601 UTC). names: the images' names.
        grid: the map grid; grid_spec: its definition (projection, centre_deg, pixel_m, shape).
        models: the scan model of each image (empty for GeoTIFFs made elsewhere: :func:`geotiff_stack`).
        covariance: ``(5·images, 5·images)`` of their unknowns (:data:`~seaice_jax.geometry.scan.SCAN_UNKNOWNS`,
        block-diagonal: one fit per image; zero for given models). sigma: ``(images, n_rows, n_columns)`` m,
        geolocation σ of every grid pixel (NaN: unknown).
    """

    values: np.ndarray
    valid: np.ndarray
    times: np.ndarray
    names: tuple[str, ...]
    epoch: str
    grid: MapGrid
    grid_spec: dict
    models: tuple[ScanModel, ...]
    covariance: np.ndarray
    sigma: np.ndarray

    def pair_covariance(self, k: int) -> np.ndarray:
        """``(10, 10)`` joint covariance of the unknowns of images ``k`` and ``k + 1``."""
        return self.covariance[_UNKNOWNS * k:_UNKNOWNS * (k + 2), _UNKNOWNS * k:_UNKNOWNS * (k + 2)]


_STORED = ("values", "valid", "times", "names", "epoch", "grid", "sigma", "covariance", "parameters", "orbits",
           "directions", "shapes")


def model_arrays(models) -> dict:
    """The scan models as arrays (unknowns, directions, shapes, orbits) for an ``.npz``."""
    return {"parameters": np.array([[float(getattr(m, f)) for f in SCAN_UNKNOWNS] for m in models]),
            "directions": np.array([m.direction for m in models]),
            "shapes": np.array([[m.n_scans, m.n_pixels] for m in models]),
            "orbits": np.array([[float(m.orbit.inclination), float(m.orbit.period), float(m.orbit.altitude),
                                 float(m.orbit.earth_day), float(m.orbit.radius)] for m in models])}


def _stored_models(stored: dict) -> tuple[ScanModel, ...]:
    return tuple(ScanModel(**dict(zip(SCAN_UNKNOWNS, p, strict=True)), orbit=Orbit(*o),
                           direction=cast(Direction, str(d)), n_pixels=int(s[1]), n_scans=int(s[0]))
                 for p, o, d, s in zip(stored["parameters"], stored["orbits"], stored["directions"], stored["shapes"],
                                       strict=True))


def save_stack(path: str | os.PathLike, stack: RemappedStack) -> Path:
    """Write ``stack`` as a compressed ``.npz`` (atomically), with its grid and scan models."""
    with atomic_path(path) as temporary, open(temporary, "wb") as stream:
        np.savez_compressed(
            stream, values=stack.values, valid=stack.valid, times=stack.times, names=np.array(stack.names),
            epoch=stack.epoch, grid=json.dumps(stack.grid_spec), sigma=stack.sigma, covariance=stack.covariance,
            **model_arrays(stack.models))
    return Path(path)


_MODEL_FILE = ("names", "covariance", "sigma0", "method", "parameters", "orbits", "directions", "shapes")


def save_models(path: str | os.PathLike, names, models, covariance, sigma0: float, method: str) -> Path:
    """Write the scan models of a sequence with the joint covariance ``(5·images, 5·images)`` of their unknowns
    (:data:`~seaice_jax.geometry.scan.SCAN_UNKNOWNS`, cross-covariances between images included), σ̂0 and the
    method that found them, as an ``.npz`` (atomically) that ``seaice remap --models`` adopts."""
    with atomic_path(path) as temporary, open(temporary, "wb") as stream:
        np.savez_compressed(stream, names=np.array(names), covariance=np.asarray(covariance, float),
                            sigma0=float(sigma0), method=method, **model_arrays(models))
    return Path(path)


def load_models(path: str | os.PathLike, project: SequenceProject):
    """``(models, covariance, sigma0)`` from a file of :func:`save_models`, checked against ``project``.

    Raises:
        SeaiceError: naming the file and what does not match the project (image names, image sizes, the
            covariance's shape).
    """
    path = Path(path)
    if not path.exists():
        raise SeaiceError(f"{path}: file not found (run `seaice adjust` first)")
    try:
        with np.load(path, allow_pickle=False) as data:
            stored = {k: data[k] for k in data.files}
    except (zipfile.BadZipFile, EOFError, ValueError, OSError) as error:
        raise SeaiceError(f"{path}: truncated or not a models file of `seaice adjust` ({error}); run `seaice adjust` "
                          "again") from None
    missing = [k for k in _MODEL_FILE if k not in stored]
    if missing:
        raise SeaiceError(f"{path}: no {', '.join(missing)}: not a models file of `seaice adjust`")
    names = tuple(str(n) for n in stored["names"])
    expected = tuple(im.name for im in project.images)
    if names != expected:
        raise SeaiceError(f"{path}: images {list(names)} differ from the project's {list(expected)}")
    models = _stored_models(stored)
    for image, model in zip(project.images, models, strict=True):
        if image.data.shape != (model.n_scans, model.n_pixels):
            raise SeaiceError(f"{path}: image {image.name!r}: model of {model.n_scans} x {model.n_pixels} for an "
                              f"image of {image.data.shape[0]} x {image.data.shape[1]}")
    covariance = np.asarray(stored["covariance"], float)
    if covariance.shape != (_UNKNOWNS * len(models),) * 2:
        raise SeaiceError(f"{path}: covariance of shape {covariance.shape} for {len(models)} images")
    return models, covariance, float(stored["sigma0"])


def load_remapped(directory: str | os.PathLike, pixels: dict | None = None) -> RemappedStack:
    """The stack written by :func:`run_remap` into ``directory``, with its grid and scan models rebuilt; ``pixels``:
    arrays taken instead of the stored ones of those names (e.g. memory maps of ``values``, ``valid``, ``sigma``)."""
    if Path(directory).is_file():
        raise SeaiceError(f"{directory}: a file, not the folder written by `seaice remap`; give that folder")
    path = Path(directory) / "remapped.npz"
    if not path.exists():
        raise SeaiceError(f"{path}: file not found (run `seaice remap` first)")
    try:
        with np.load(path, allow_pickle=False) as data:
            stored = {k: data[k] for k in data.files if k not in (pixels or {})}
    except (zipfile.BadZipFile, EOFError, ValueError, OSError) as error:
        raise SeaiceError(f"{path}: truncated or not a remapped stack ({error}); run `seaice remap` again") from None
    stored.update(pixels or {})
    missing = [k for k in _STORED if k not in stored]
    if missing:
        raise SeaiceError(f"{path}: no {', '.join(missing)} (written by another version?): run `seaice remap` again")
    spec = json.loads(str(stored["grid"]))
    grid = make_grid(spec.get("projection", "nsidc-north"), spec["centre_deg"], spec["pixel_m"], spec["shape"])
    for name in ("values", "valid", "sigma"):
        if np.shape(stored[name])[1:] != grid.shape or np.shape(stored[name])[0] != len(stored["names"]):
            raise SeaiceError(f"{path}: {name} of shape {np.shape(stored[name])} for {len(stored['names'])} images on "
                              f"a grid of {grid.shape}: not a remapped stack; run `seaice remap` again")
    return RemappedStack(stored["values"], stored["valid"], stored["times"], tuple(str(n) for n in stored["names"]),
                         str(stored["epoch"]), grid, spec, _stored_models(stored), stored["covariance"],
                         stored["sigma"])


def _same_grid(a: MapGrid, b: MapGrid) -> bool:
    """Same projection (PROJ definition), shape and geotransform (to 1e-9 of a pixel)."""
    return (a.shape == b.shape and a.projection.proj_string() == b.projection.proj_string()
            and all(abs(float(getattr(a, f)) - float(getattr(b, f))) <= 1e-9 * float(a.pixel_width)
                    for f in ("x_first", "y_first", "pixel_width", "pixel_height")))


def geotiff_stack(paths, times=None) -> RemappedStack:
    """Single-band GeoTIFFs of one grid made by any tool (:func:`~seaice_jax.io.products.read_geotiff`) as a
    stack without scan models (a tracked displacement's σ is then the tracking σ alone).

    Args:
        paths: two or more GeoTIFF files, in time order. times: their ISO 8601 UTC times (default: each file's
            acquisition time, :func:`~seaice_jax.io.products.read_geotiff`: the ``ACQUISITION_TIME`` item the
            package writes, else the TIFF ``DateTime`` tag).

    Raises:
        SeaiceError: naming the file whose grid (CRS, geotransform, shape) differs from the first's, or whose time
            is missing or not later than the one before.
    """
    paths = [Path(p) for p in paths]
    if times is not None and len(times) != len(paths):
        raise SeaiceError(f"--times: {len(times)} times for {len(paths)} GeoTIFF files")
    values, grid = [], None
    moments = []
    for k, path in enumerate(paths):
        image, image_grid, tag_time = read_geotiff(path)
        if grid is None:
            grid = image_grid
        elif not _same_grid(image_grid, grid):
            raise SeaiceError(f"{path}: its grid (CRS, geotransform or shape) differs from that of {paths[0]}")
        moment = times[k] if times is not None else tag_time
        if moment is None:
            raise SeaiceError(f"{path}: no time (no TIFF DateTime tag): give each file's time with --times")
        try:
            moments.append(parse_time(moment))
        except ValueError:
            raise SeaiceError(f"{path}: time {moment!r} is not an ISO 8601 date-time") from None
        values.append(image)
    assert grid is not None  # paths is not empty
    seconds = np.array([(m - moments[0]).total_seconds() for m in moments])
    later = np.diff(seconds) > 0
    if not later.all():
        raise SeaiceError(f"{paths[int(np.argmin(later)) + 1]}: its time is not later than that of the file before")
    stack_values = np.stack(values)
    projection = grid.projection
    definition = projection.definition if isinstance(projection, CrsProjection) else f"EPSG:{projection.epsg_code()}"
    return RemappedStack(stack_values, np.isfinite(stack_values), seconds, tuple(p.stem for p in paths),
                         format_time(moments[0]), grid, {"projection": definition}, (), np.zeros((0, 0)),
                         np.full(stack_values.shape, np.nan))
