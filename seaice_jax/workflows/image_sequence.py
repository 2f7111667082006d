"""Satellite image sequences end to end (source 001, VHR2/VHR3, ICE, MOVIE): rectify each image on its control
points, remap all into one grid, track the ice automatically, derive velocities, boxes, deformation and a film.

Each step computes a typed result first (:func:`remap_sequence` -> :class:`RemappedStack`, :func:`track_sequence`
-> :class:`TrackedSequence`, :func:`floe_kinematics` -> :class:`FloeKinematics`), then writes it atomically. The
CLI's ``remap``, ``track``, ``velocities`` and ``movie`` are thin wrappers around :func:`run_remap`,
:func:`run_track`, :func:`run_velocities` and :func:`run_movie`, each returning a :class:`Step`."""

import json
import os
import zipfile
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Generic, TypeVar, cast

import numpy as np
from tqdm.auto import tqdm

from seaice_jax.adjust.orbit.fit import (
    OrbitFit,
    control_point_deviations,
    fit_scan_model,
    position_jacobian,
    propagate_position_sigma,
)
from seaice_jax.drift.kinematics import (
    BoxAverages,
    Deformation,
    Velocities,
    box_averages,
    box_time_series,
    check_tracking_interval,
    deformation,
    east_north_axes,
    grid_to_east_north,
    plausible_velocities,
    velocities,
)
from seaice_jax.drift.records import FloeRecords, read_records, write_records
from seaice_jax.errors import SeaiceError
from seaice_jax.files import atomic_path, write_csv
from seaice_jax.geometry.crs import CrsProjection
from seaice_jax.geometry.projections import MapGrid
from seaice_jax.geometry.scan import SCAN_UNKNOWNS, Direction, Orbit, ScanModel
from seaice_jax.imagery.coast_control import coast_control
from seaice_jax.imagery.movie import render_frames, write_movie
from seaice_jax.imagery.remap import remap
from seaice_jax.imagery.tracking import GOOD, STATUS, TrackingOptions, grid_points, on_land, track
from seaice_jax.io.coastline import land_mask_of_grid
from seaice_jax.io.products import (
    read_geotiff,
    write_drift_netcdf,
    write_fixes_geojson,
    write_geotiff,
    write_osisaf_drift,
    write_trajectories_geojson,
)
from seaice_jax.io.sequence import (
    SequenceImage,
    SequenceProject,
    make_grid,
    named_projection,
    read_sequence,
    write_sequence,
)
from seaice_jax.memory import check_disk, check_memory, film_peak, simulate_disk, simulate_peak, track_peak
from seaice_jax.outputs import output_file, output_folder
from seaice_jax.report.figures import (
    plot_box_averages,
    plot_remapped,
    plot_trajectories,
    plot_vectors,
    plot_velocity_series,
)
from seaice_jax.report.maps import map_overlay
from seaice_jax.simulate.satellite import land_mask, scene_xy, simulate_sequence, true_displacement
from seaice_jax.timefmt import format_time, parse_time, time_after
from seaice_jax.workflows.rectify import image_coastline

Result = TypeVar("Result")
_UNKNOWNS = len(SCAN_UNKNOWNS)


@dataclass(frozen=True)
class Step(Generic[Result]):
    """What a step computed (``result``) and wrote (``files``), and its text ``report``."""

    files: tuple[Path, ...]
    report: str
    result: Result


# ------------------------------------------------------------------------------------------------ remap


@dataclass(frozen=True)
class Rectification:
    """How one image's scan model was found.

    Attributes:
        name: the image. model: its scan model. control: number of control points used (0: the model was given).
        sigma0: σ̂0 of the fit (``nan`` if given). point_ids: the image's control points; north, east: ``(n,)``
        their deviations, m (all empty without control points).
    """

    name: str
    model: ScanModel
    control: int
    sigma0: float
    point_ids: tuple[str, ...]
    north: np.ndarray
    east: np.ndarray


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


def rectify_images(project: SequenceProject, progress: bool = False):
    """The scan model of every image: given, fitted to its control points (VHR2), or fitted to control points found
    on the coastline from its rough model (``control = "coastline"``, w-test rejection:
    :func:`~seaice_jax.imagery.coast_control.coast_control`).

    Returns:
        ``(rectifications, covariance)``: one :class:`Rectification` per image and the block-diagonal covariance
        ``(5·images, 5·images)`` of the fitted unknowns.

    Raises:
        SeaiceError: the coastline matching failed (too few points, no coast in the image), naming file and image.
    """
    rectifications = []
    covariance = np.zeros((_UNKNOWNS * len(project.images),) * 2)
    for k, image in enumerate(tqdm(project.images, desc="rectify", disable=not progress, leave=False)):
        model, sigma0, control = image.model, float("nan"), image.control
        if model is None:
            if image.rough is not None:
                fit = _coastline_fit(project.path, image)
                control = fit.control
            else:
                assert control is not None  # read_sequence: a model, control points or a rough model
                fit = fit_scan_model(control, image.orbit, direction=image.direction,
                                     n_pixels=image.data.shape[1], n_scans=image.data.shape[0])
            assert fit.adjustment is not None  # the Gauss-Newton fit carries its adjustment
            model, sigma0 = fit.model, float(fit.adjustment.sigma0)
            block = slice(_UNKNOWNS * k, _UNKNOWNS * (k + 1))
            covariance[block, block] = np.asarray(fit.adjustment.covariance)
        north = east = np.zeros(0)
        ids = ()
        if control is not None:
            north, east = (np.asarray(a) for a in control_point_deviations(model, control))
            ids = control.ids
        rectifications.append(Rectification(image.name, model, 0 if image.model is not None else len(ids), sigma0,
                                            ids, north, east))
    return tuple(rectifications), covariance


def _coastline_fit(path: Path, image: SequenceImage) -> OrbitFit:
    """The fit of ``image``'s scan model to control points found on the GSHHG coastline from its rough model."""
    assert image.rough is not None
    try:
        coast = image_coastline(image.rough)
        return coast_control(image.data, image.rough, coast.contains, search=image.control_search).fit
    except SeaiceError as error:
        raise SeaiceError(f"{path}: image {image.name!r}: control = 'coastline': {error}") from None


def geolocation_sigma(models, covariance, grid: MapGrid) -> np.ndarray:
    """``(images, n_rows, n_columns)`` m: the geolocation σ (√ of the mean of the north and east variances) of every
    grid pixel in each image, from the covariance of its scan model's unknowns."""
    latitude, longitude = grid.latitude_longitude()
    maps = []
    for k, model in enumerate(models):
        pixel, scan = model.inverse(latitude, longitude)
        block = covariance[_UNKNOWNS * k:_UNKNOWNS * (k + 1), _UNKNOWNS * k:_UNKNOWNS * (k + 1)]
        sigma_north, sigma_east = (np.asarray(a) for a in propagate_position_sigma(model, block, pixel, scan))
        maps.append(np.sqrt(0.5 * (sigma_north**2 + sigma_east**2)))
    return np.stack(maps)


def adopted_models(project: SequenceProject, models_path: str | os.PathLike):
    """The scan models and their joint covariance from a models file (:func:`save_models`, e.g. ``seaice adjust``),
    as :func:`rectify_images` returns them (each image's control-point deviations from its adopted model)."""
    models, covariance, sigma0 = load_models(models_path, project)
    rectifications = []
    for image, model in zip(project.images, models, strict=True):
        north = east = np.zeros(0)
        ids = ()
        if image.control is not None:
            north, east = (np.asarray(a) for a in control_point_deviations(model, image.control))
            ids = image.control.ids
        rectifications.append(Rectification(image.name, model, len(ids), sigma0, ids, north, east))
    return tuple(rectifications), covariance


def check_grid_reached(path, grid_spec: dict, names, pixels) -> None:
    """Refuse a map grid that no image reaches (``pixels``: each image's count of valid pixels on the grid): its
    output would be all empty.

    Raises:
        SeaiceError: naming the project's grid and the images.
    """
    if len(names) and not np.any(np.asarray(pixels) > 0):
        shape, size = grid_spec.get("shape", ["?", "?"]), grid_spec.get("pixel_m", ["?", "?"])
        raise SeaiceError(f"{path}: [grid] ({grid_spec.get('projection', 'nsidc-north')}, centre_deg "
                          f"{grid_spec.get('centre_deg')}, {shape[0]} x {shape[1]} pixels of {size[0]} x {size[1]} m) "
                          f"misses every image: no pixel of {', '.join(names)} falls in it; check the grid's "
                          "centre_deg, pixel_m and shape against the images' control points")


def remap_sequence(project: SequenceProject, method: str = "bilinear", fill: int = 1, progress: bool = False,
                   models_path: str | os.PathLike | None = None, check_reached: bool = True):
    """Rectify every image (or adopt the models of ``models_path``: :func:`adopted_models`) and remap the sequence
    into its grid; a grid that no image reaches is refused (:func:`check_grid_reached`) unless not
    ``check_reached`` (one image of an archive: the archive is checked whole).

    Returns:
        ``(stack, rectifications)``: the :class:`RemappedStack` and one :class:`Rectification` per image.
    """
    rectifications, covariance = (rectify_images(project, progress) if models_path is None
                                  else adopted_models(project, models_path))
    models = tuple(r.model for r in rectifications)
    values, valid = remap([im.data for im in project.images], list(models), project.grid, method=method, fill=fill)
    if check_reached:
        check_grid_reached(project.path, project.grid_spec, [im.name for im in project.images],
                           np.asarray(valid).sum(axis=(1, 2)))
    stack = RemappedStack(np.asarray(values), np.asarray(valid), np.array([im.time for im in project.images]),
                          tuple(im.name for im in project.images), project.epoch, project.grid, project.grid_spec,
                          models, covariance, geolocation_sigma(models, covariance, project.grid))
    return stack, rectifications


def remap_report(stack: RemappedStack, rectifications, method: str, fill: int) -> str:
    grid = stack.grid
    lines = [f"remapped {len(stack.names)} images into a {grid.n_rows} x {grid.n_columns} grid of "
             f"{float(grid.pixel_width):.0f} x {float(grid.pixel_height):.0f} m ({method}, fill {fill}):"]
    for r in rectifications:
        lines.append(f"  {r.name}: scan model given ({r.model.direction}bound)" if not r.control else
                     f"  {r.name}: {r.model.direction}bound, {r.control} control points, σ̂0 {r.sigma0:.2f}")
    missing = [name for name, valid in zip(stack.names, stack.valid, strict=True) if not valid.any()]
    if missing:
        lines.append(f"  note: no pixel of {', '.join(missing)} falls in the grid (their remapped images are empty)")
    for r in rectifications:
        if r.north.size:
            distance = np.hypot(r.north, r.east) / 1000
            lines.append(f"  {r.name}: control-point deviation mean {distance.mean():.2f} km (max N-S "
                         f"{np.abs(r.north).max() / 1000:.2f}, E-W {np.abs(r.east).max() / 1000:.2f} km)")
    return "\n".join(lines)


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


def write_rectification(path: Path, rectifications) -> list[Path]:
    """``rectification.csv``: the control-point deviations (north, east km) of every image fitted to control points,
    as the 1985 VHR2 printout; ``[]`` (nothing written) when no image had control points."""
    measured = [r for r in rectifications if r.north.size]
    if not measured:
        return []
    return [write_csv(path, {
        "image": [r.name for r in measured for _ in r.north],
        "point": [point for r in measured for point in r.point_ids],
        "north_km": np.concatenate([r.north for r in measured]) / 1000,
        "east_km": np.concatenate([r.east for r in measured]) / 1000})]


def write_remapped(stack: RemappedStack, rectifications, out_dir: str | os.PathLike,
                   progress: bool = False) -> tuple[Path, ...]:
    """``<image>.tif`` (GeoTIFF, the image's time as its acquisition time), ``remapped.npz``, ``rectification.csv``
    (control-point deviations per image, as the 1985 VHR2 printout) and ``remapped.png``."""
    out = Path(out_dir)
    labels = [time_after(stack.epoch, t) for t in stack.times]
    files = [write_geotiff(out / f"{name}.tif", values, stack.grid, f"{name} {label}", time=label)
             for name, values, label in tqdm(list(zip(stack.names, stack.values, labels, strict=True)),
                                             desc="write GeoTIFF", disable=not progress, leave=False)]
    files.append(save_stack(out / "remapped.npz", stack))
    files += write_rectification(out / "rectification.csv", rectifications)
    files.append(write_overview(out / "remapped.png", stack.names, stack.times, stack.epoch, stack.grid,
                                lambda k: stack.values[k]))
    return tuple(files)


OVERVIEW_PANELS = 12
"""Images the ``remapped.png`` overview shows at most, evenly spaced through the sequence (the first and the last
among them): an archive's figure stays readable, and only the images shown are read."""


def write_overview(path: Path, names, times, epoch: str, grid: MapGrid, image,
                   limit: int = OVERVIEW_PANELS) -> Path:
    """``remapped.png``: images of the sequence on the grid side by side
    (:func:`~seaice_jax.report.figures.plot_remapped`), at most ``limit`` of them, evenly spaced (each titled with
    its name, time and, when some are left out, its place in the sequence); ``image(k)`` gives image ``k``'s
    values ``grid.shape``, called for the images shown only."""
    count = len(names)
    shown = np.unique(np.round(np.linspace(0, count - 1, min(count, limit))).astype(int))
    titles = [f"{names[k]}" + (f" ({k + 1} of {count})" if shown.size < count else "") + "\n"
              + time_after(epoch, times[k])[:16] for k in shown]
    x, y = (np.asarray(a) / 1000 for a in grid.xy())
    return plot_remapped(path, [image(int(k)) for k in shown], titles, [x.min(), x.max(), y.min(), y.max()],
                         projection=grid.projection)


def run_remap(project_path: str | os.PathLike, out_dir: str | os.PathLike, method: str = "bilinear",
              fill: int = 1, progress: bool = True, overwrite: bool = False,
              models_path: str | os.PathLike | None = None) -> Step[RemappedStack]:
    """Rectify (fit the scan model of every image with control points, or adopt those of ``models_path``, e.g.
    written by ``seaice adjust``) and remap the sequence into its grid; write it (:func:`write_remapped`) as one
    run (:func:`~seaice_jax.outputs.output_folder`)."""
    inputs = (project_path,) if models_path is None else (project_path, models_path)
    with output_folder(out_dir, overwrite, inputs=inputs) as folder:
        stack, rectifications = remap_sequence(read_sequence(project_path), method, fill, progress, models_path)
        files = folder.final(write_remapped(stack, rectifications, folder.path, progress))
    return Step(files, remap_report(stack, rectifications, method, fill), stack)


# ------------------------------------------------------------------------------------------------ track


def displacement_sigma(models, covariance, grid: MapGrid, x, y, dx, dy, tracking_sigma) -> np.ndarray:
    """σ ``(n, 2)`` (m, along the grid's x and y) of displacements ``dx, dy`` (m) from map points ``x, y`` of one
    image to the next: the geolocation errors of both images at the vector's start and end through their scan
    models (``models``: the two :class:`ScanModel`) and the joint covariance ``(10, 10)`` of their unknowns (the
    cross-covariance of co-registered images included), and the tracking's σ ``tracking_sigma`` (m: one number for
    both coordinates, or ``(n, 2)`` per vector along x and y), independent of them."""
    jacobians = []
    for model, xs, ys in ((models[0], x, y), (models[1], x + np.nan_to_num(dx), y + np.nan_to_num(dy))):
        lat, lon = grid.projection.inverse(xs, ys)
        pixel, scan = model.inverse(lat, lon)
        jacobians.append(np.asarray(position_jacobian(model, pixel, scan)))  # (n, 2 north/east, 5)
    design = np.concatenate([-jacobians[0], jacobians[1]], axis=2)  # end minus start
    north_east = np.einsum("nij,jk,nlk->nil", design, covariance, design)
    east_dir, north_dir = east_north_axes(grid.projection, x, y)
    rotation = np.stack([north_dir, east_dir], axis=2)  # grid components of (north, east)
    on_grid = np.einsum("nij,njk,nlk->nil", rotation, north_east, rotation)
    return np.sqrt(np.diagonal(on_grid, axis1=1, axis2=2) + tracking_sigma**2)


def make_lattice(grid: MapGrid, rows, columns, shape) -> MapGrid:
    """The :class:`MapGrid` of the tracking lattice (every ``spacing``-th pixel of ``grid``)."""
    step_r = (rows.max() - rows.min()) / max(shape[0] - 1, 1)
    step_c = (columns.max() - columns.min()) / max(shape[1] - 1, 1)
    x0, y0 = grid.to_xy(rows.min(), columns.min())
    return MapGrid(grid.projection, x0, y0, float(grid.pixel_width) * step_c, float(grid.pixel_height) * step_r,
                   shape[0], shape[1])


@dataclass(frozen=True)
class TrackedPair:
    """The drift tracked from image ``first`` to ``first + 1`` on the lattice (every array ``(n,)``, lattice order).

    Attributes:
        first: image index. interval: s. status: tracking flags (:data:`~seaice_jax.imagery.tracking.STATUS`).
        x, y: m, start positions; dx, dy: m along the grid axes; sigma: ``(n, 2)`` m of ``dx, dy`` (both images'
        geolocation and the tracking). tracking_sigma: ``(n, 2)`` m, the tracking's part, from each vector's
        correlation peak. correlation: ``(n,)`` the peak's normalised cross-correlation (NaN where not measured).
        u_east, v_north: m/s toward geographic east and north. deformation: of the Delaunay triangles of the good
        vectors (lattice indices), or ``None`` with fewer than three.
    """

    first: int
    interval: float
    status: np.ndarray
    x: np.ndarray
    y: np.ndarray
    dx: np.ndarray
    dy: np.ndarray
    sigma: np.ndarray
    tracking_sigma: np.ndarray
    correlation: np.ndarray
    u_east: np.ndarray
    v_north: np.ndarray
    deformation: Deformation | None

    @property
    def good(self) -> np.ndarray:
        return self.status == GOOD


@dataclass(frozen=True)
class TrackedSequence:
    """The ice tracked through a remapped sequence: per pair of consecutive images a :class:`TrackedPair` on the
    ``lattice``, and the floe ``records`` (the lattice of the first image followed while its tracking stays good)."""

    pairs: tuple[TrackedPair, ...]
    lattice: MapGrid
    records: FloeRecords
    options: TrackingOptions


def _tracking_sigma(displacements, grid: MapGrid) -> np.ndarray:
    """``(n, 2)`` m along the grid's x and y: the tracked vectors' σ (pixels of columns and rows) in metres."""
    return np.column_stack([displacements.sigma_column * abs(float(grid.pixel_width)),
                            displacements.sigma_row * abs(float(grid.pixel_height))])


def track_pair(stack: RemappedStack, k: int, options: TrackingOptions, land=None) -> TrackedPair:
    """The drift from image ``k`` of ``stack`` to ``k + 1``, as :func:`track_sequence` tracks each pair (``land``:
    ``(n_rows, n_columns)`` bool on the grid, True on land)."""
    pair = track(stack.values[k], stack.values[k + 1], options, valid_first=stack.valid[k],
                 valid_second=stack.valid[k + 1], land=land)
    status = pair.status
    good = status == GOOD
    vectors = pair.in_map(stack.grid)
    x, y, dx, dy = (vectors[key] for key in ("x", "y", "dx", "dy"))
    tracking_sigma = _tracking_sigma(pair, stack.grid)
    if stack.models:
        sigma = displacement_sigma(stack.models[k:k + 2], stack.pair_covariance(k), stack.grid, x, y, dx, dy,
                                   tracking_sigma)
    else:  # GeoTIFFs without scan models: the tracking alone
        sigma = tracking_sigma
    interval = float(stack.times[k + 1] - stack.times[k])
    east, north = (np.asarray(a) for a in grid_to_east_north(stack.grid.projection, x, y, dx / interval,
                                                              dy / interval))
    rates = None
    if good.sum() >= 3:
        index = np.nonzero(good)[0]
        rates = deformation(np.stack([x, y], 1)[index], np.stack([dx, dy], 1)[index] / interval,
                            sigma[index] / interval)  # (relative errors: conservative)
        rates = replace(rates, triangles=index[rates.triangles])
    return TrackedPair(k, interval, status, x, y, dx, dy, sigma, tracking_sigma, pair.correlation, east, north,
                       rates)


def follow_floes(stack: RemappedStack, rows, columns, options: TrackingOptions, progress: bool,
                 land=None) -> FloeRecords:
    """Floe records of the lattice points of the first image, followed from image to image while their tracking
    stays good: grid position -> latitude, longitude and each image's own pixel and scan line (the grid's 1-based
    column and row for images without a scan model), and the tracking σ and correlation of the step that reached
    each fix (NaN at a floe's first). ``land``: ``(n_rows, n_columns)`` bool on the grid, True on land: no floe
    starts there, and one whose step starts or ends on it is no longer followed."""
    floe_row, floe_column = rows.copy(), columns.copy()
    alive = np.ones(rows.size, bool) if land is None else ~on_land(land, rows, columns)
    first = np.nonzero(alive)[0]
    fixes = [(first, 0, rows[alive], columns[alive], np.full((first.size, 2), np.nan), np.full(first.size, np.nan))]
    for k in tqdm(range(len(stack.names) - 1), desc="follow floes", disable=not progress, leave=False):
        chained = track(stack.values[k], stack.values[k + 1], options, points=(floe_row, floe_column),
                        valid_first=stack.valid[k], valid_second=stack.valid[k + 1], land=land)
        alive &= chained.good
        floe_row = np.where(alive, floe_row + np.nan_to_num(chained.d_row), np.nan)
        floe_column = np.where(alive, floe_column + np.nan_to_num(chained.d_column), np.nan)
        fixes.append((np.nonzero(alive)[0], k + 1, floe_row[alive], floe_column[alive],
                      _tracking_sigma(chained, stack.grid)[alive], chained.correlation[alive]))
    columns_out = {k: [] for k in ("floe", "time", "image", "pixel", "scan", "latitude", "longitude",
                                   "tracking_sigma", "correlation")}
    for ids, k, fix_rows, fix_columns, tracking_sigma, correlation in fixes:
        x, y = stack.grid.to_xy(fix_rows, fix_columns)
        lat, lon = (np.asarray(a) for a in stack.grid.projection.inverse(x, y))
        pixel, scan = ((np.asarray(a) for a in stack.models[k].inverse(lat, lon)) if stack.models
                       else (np.asarray(fix_columns) + 1.0, np.asarray(fix_rows) + 1.0))
        columns_out["floe"] += [f"G{i:04d}" for i in ids]
        columns_out["time"].append(np.full(ids.size, stack.times[k]))
        columns_out["image"] += [stack.names[k]] * ids.size
        for name, value in (("pixel", pixel), ("scan", scan), ("latitude", lat), ("longitude", lon),
                            ("tracking_sigma", tracking_sigma), ("correlation", correlation)):
            columns_out[name].append(value)
    arrays = {k: (np.concatenate(v) if k not in ("floe", "image") else np.array(v)) for k, v in columns_out.items()}
    order = np.lexsort((arrays["time"], arrays["floe"]))
    return FloeRecords(**{k: v[order] for k, v in arrays.items()}, epoch=stack.epoch)


def track_sequence(stack: RemappedStack, options: TrackingOptions | None = None, progress: bool = False,
                   land=None) -> TrackedSequence:
    """Track the ice between consecutive remapped images; each vector's σ combines its tracking σ (from its
    correlation peak, :mod:`seaice_jax.imagery.tracking`) with both images' geolocation σ. ``land``: ``(n_rows,
    n_columns)`` bool on the grid, True on land: a vector that starts or ends on land has the status
    :data:`~seaice_jax.imagery.tracking.ON_LAND` (never good), and no floe is followed onto or from land, while
    patches at sea may reach over the coast."""
    options = options or TrackingOptions()
    if len(stack.names) < 2:
        raise SeaiceError(f"tracking needs at least two images, got {len(stack.names)}")
    check_tracking_interval(stack.names, stack.times, float(stack.grid.pixel_width))
    rows, columns = grid_points(stack.grid.shape, options)
    check_memory(track_peak(rows.size, stack.grid.shape[0] * stack.grid.shape[1], len(stack.names)),
                 f"--spacing {options.spacing}: tracking {rows.size} lattice points")
    lattice = make_lattice(stack.grid, rows, columns, (np.unique(rows).size, np.unique(columns).size))
    pairs = tuple(track_pair(stack, k, options, land)
                  for k in tqdm(range(len(stack.names) - 1), desc="track", disable=not progress, leave=False))
    return TrackedSequence(pairs, lattice, follow_floes(stack, rows, columns, options, progress, land), options)


def track_report(stack: RemappedStack, tracked: TrackedSequence) -> str:
    lattice, options, records = tracked.lattice, tracked.options, tracked.records
    lines = [f"tracked {len(tracked.pairs)} image pairs on a {lattice.n_rows} x {lattice.n_columns} lattice "
             f"(patch {options.patch} px, search ±{options.search} px):"]
    for pair in tracked.pairs:
        good = pair.good
        speed = np.hypot(pair.dx[good], pair.dy[good]) / pair.interval * 86.4
        lines.append(f"  {stack.names[pair.first]} -> {stack.names[pair.first + 1]}: {good.sum()} of {good.size} "
                     f"vectors good, median speed {np.median(speed) if speed.size else np.nan:.1f} km/day; rejected: "
                     + ", ".join(f"{(pair.status == s).sum()} {STATUS[s]}" for s in STATUS
                                 if s != GOOD and (pair.status == s).any()))
    lines.append(f"  {len(set(records.floe.tolist()))} floes followed, {len(records)} fixes")
    return "\n".join(lines)


def write_pair(stack: RemappedStack, lattice: MapGrid, pair: TrackedPair, out: Path, layout: str) -> list[Path]:
    """``drift_<a>_<b>.nc`` (CF-NetCDF on the lattice), its figure ``drift_<a>_<b>.png`` and, for ``layout``
    ``"osisaf"``, ``drift_<a>_<b>_osisaf.nc`` in the OSI SAF drift layout."""
    good, shape = pair.good, lattice.shape
    a, b = stack.names[pair.first], stack.names[pair.first + 1]

    def field(values):
        return np.where(good, values, np.nan).reshape(shape)

    fields = {"dX": field(pair.dx), "dY": field(pair.dy), "dX_uncertainty": field(pair.sigma[:, 0]),
              "dY_uncertainty": field(pair.sigma[:, 1]), "status_flag": pair.status.reshape(shape),
              "u_east": field(pair.u_east), "v_north": field(pair.v_north),
              "dX_tracking_uncertainty": field(pair.tracking_sigma[:, 0]),
              "dY_tracking_uncertainty": field(pair.tracking_sigma[:, 1]),
              "correlation": pair.correlation.reshape(shape)}
    start = np.stack([pair.x, pair.y], 1)
    osisaf = ([write_osisaf_drift(out / f"drift_{a}_{b}_osisaf.nc", lattice, fields, stack.times[pair.first],
                                 stack.times[pair.first + 1], stack.epoch, title=f"Sea-ice drift {a} to {b}")]
              if layout == "osisaf" else [])
    return osisaf + [write_drift_netcdf(out / f"drift_{a}_{b}.nc", lattice, fields, stack.times[pair.first],
                               stack.times[pair.first + 1], stack.epoch, STATUS, title=f"Sea-ice drift {a} to {b}",
                               deformation=pair.deformation),
            plot_vectors(out / f"drift_{a}_{b}.png", start[good], np.stack([pair.dx, pair.dy], 1)[good],
                         f"Tracked drift {a} -> {b} ({good.sum()} vectors)",
                         f"{pair.interval / 86400:.2f} days; ellipses: 95 % from the stated σ (geolocation and "
                         "tracking)", background=start[~good],
                         covariances=np.stack([np.diag(v) for v in pair.sigma[good] ** 2]) if good.any() else None,
                         projection=lattice.projection, background_label="points without a good vector")]


def write_tracked(stack: RemappedStack, tracked: TrackedSequence, out_dir: str | os.PathLike,
                  layout: str = "project") -> tuple[Path, ...]:
    """Per pair ``drift_<a>_<b>.nc`` and ``.png`` (vectors with 95 % ellipses); ``floes.csv`` and
    ``trajectories.geojson`` (lines) and ``fixes.geojson`` (points) for the whole sequence."""
    out = Path(out_dir)
    files = [path for pair in tracked.pairs for path in write_pair(stack, tracked.lattice, pair, out, layout)]
    records = tracked.records
    files.append(write_records(out / "floes.csv", records))
    files.append(write_trajectories_geojson(out / "trajectories.geojson", records.floe, records.time,
                                            records.latitude, records.longitude, records.epoch))
    files.append(write_fixes_geojson(out / "fixes.geojson", records.floe, records.time, records.latitude,
                                     records.longitude, records.epoch, records.tracking_sigma, records.correlation))
    return tuple(files)


def land_of_grid(land: str | os.PathLike, grid: MapGrid, kind: str = "land mask") -> np.ndarray:
    """The land mask on ``grid``: ``"coastline"`` (GSHHG, :func:`~seaice_jax.io.coastline.land_mask_of_grid`) or a
    ``.npy`` bool array of the grid's shape (any other file is refused naming it and ``kind``: a mask of 0/1 floats
    or of another grid would mark the wrong cells)."""
    if str(land) == "coastline":
        return land_mask_of_grid(grid)
    if not Path(land).is_file():
        raise SeaiceError(f"{land}: no such {kind} (give 'coastline' or a .npy bool array on the grid)")
    try:
        mask = np.load(land, allow_pickle=False)
    except (OSError, ValueError) as error:
        raise SeaiceError(f"{land}: not a .npy array ({error})") from None
    if mask.shape != grid.shape or mask.dtype != bool:
        raise SeaiceError(f"{land}: a {kind} must be a bool array of the grid's shape {grid.shape}, got "
                          f"{mask.dtype} {mask.shape}")
    return mask


def run_track(remapped_dir, out_dir: str | os.PathLike, options: TrackingOptions | None = None,
              progress: bool = True, overwrite: bool = False, layout: str = "project", times=None,
              land: str | os.PathLike | None = "coastline") -> Step[TrackedSequence]:
    """Track the ice (:func:`track_sequence`) through the stack written by :func:`run_remap` (``remapped_dir``: its
    folder) or through GeoTIFFs of one grid made elsewhere (``remapped_dir``: a list of files, ``times`` their ISO
    8601 times unless their DateTime tags give them: :func:`geotiff_stack`), and write it (:func:`write_tracked`,
    ``layout`` ``"project"`` or ``"osisaf"``) as one run (:func:`~seaice_jax.outputs.output_folder`); ``land``:
    ``"coastline"`` (the default: GSHHG land on the grid) or a ``.npy`` mask (:func:`land_of_grid`): vectors that
    start or end on its land are flagged "on land"; ``None``: no land mask."""
    files_given = isinstance(remapped_dir, list | tuple)
    inputs = tuple(remapped_dir) if files_given else (remapped_dir,)
    with output_folder(out_dir, overwrite, inputs=inputs) as folder:
        stack = geotiff_stack(remapped_dir, times) if files_given else load_remapped(remapped_dir)
        if len(stack.names) < 2:
            raise SeaiceError(f"{remapped_dir}: tracking needs at least two images, got {len(stack.names)}")
        tracked = track_sequence(stack, options, progress, None if land is None else land_of_grid(land, stack.grid))
        files = folder.final(write_tracked(stack, tracked, folder.path, layout))
    return Step(files, track_report(stack, tracked), tracked)


# ------------------------------------------------------------------------------------------------ velocities


@dataclass(frozen=True)
class FloeKinematics:
    """Velocities and what derives from them, for a floe record file.

    Attributes:
        records: the floe records. x, y: ``(n,)`` m, their map positions. velocities: between consecutive fixes.
        boxes: box averages (Figure 4-7). series: daily box series (Figure 4-5). box_size: m.
        deformation: ``(time, interval, rates)`` (s, s, the triangles' strain rates) per fix time with at least
            three floes.
        projection: the map projection of ``x``, ``y`` (for the maps' coastline and graticule).
        notes: what was left out and why (implausible velocities, points on one line, degenerate triangles).
    """

    records: FloeRecords
    x: np.ndarray
    y: np.ndarray
    velocities: Velocities
    boxes: BoxAverages
    series: dict
    box_size: float
    deformation: tuple[tuple[float, float, Deformation], ...]
    projection: object = None
    notes: tuple[str, ...] = ()


def _deformations(v: Velocities, velocity_sigma: float | None, epoch: str):
    """Deformation of the floes' Delaunay triangles at every fix time with at least three floes (times whose floes
    lie on one line have none), and notes on what was left out."""
    out, notes = [], []
    for t in np.unique(v.time):
        at = v.time == t
        if at.sum() < 3:
            continue
        sigma = velocity_sigma if velocity_sigma is not None else np.sqrt(2) * 1000.0 / v.interval[at]
        rates = deformation(np.stack([v.x[at], v.y[at]], 1), np.stack([v.u_grid[at], v.v_grid[at]], 1), sigma)
        if rates.note:
            notes.append(f"deformation at {time_after(epoch, t)}: {rates.note}")
        if len(rates.area):
            out.append((float(t), float(v.interval[at][0]), rates))
    return tuple(out), tuple(notes)


def floe_kinematics(records: FloeRecords, projection: str = "nsidc-north", box_size: float = 50_000.0,
                    velocity_sigma: float | None = None) -> FloeKinematics:
    """Velocities, box averages, daily box series and deformation of floe records.

    Args:
        projection: the map grid whose axes the grid-relative components follow (``nsidc-north``/``-south``).
        box_size: m. velocity_sigma: m/s of each velocity component for the deformation σ (default: the
            positions' σ of 1 km over each interval, √2·1000/Δt).
    """
    metric = named_projection(projection, (np.degrees(records.latitude[0]), np.degrees(records.longitude[0])))
    x, y = (np.asarray(a) for a in metric.forward(records.latitude, records.longitude))
    v, implausible = plausible_velocities(velocities(records.floe, records.time, x, y, metric),
                                          epoch=records.epoch)
    origin = (np.floor(v.x.min() / box_size) * box_size, np.floor(v.y.min() / box_size) * box_size)
    rates, notes = _deformations(v, velocity_sigma, records.epoch)
    return FloeKinematics(records, x, y, v, box_averages(v.x, v.y, v.u_grid, v.v_grid, box_size, origin),
                          box_time_series(v, box_size, origin), box_size, rates, metric,
                          (implausible, *notes) if implausible else notes)


def _deformation_columns(result: FloeKinematics) -> dict:
    v, epoch = result.velocities, result.records.epoch
    rows = {k: [] for k in ("start", "end", "x_m", "y_m", "divergence_per_s", "sigma_divergence_per_s",
                            "shear_per_s", "sigma_shear_per_s", "vorticity_per_s", "sigma_vorticity_per_s")}
    for time, interval, rates in result.deformation:
        at = v.time == time
        centre = np.stack([v.x[at], v.y[at]], 1)[rates.triangles].mean(axis=1)
        rows["start"] += [time_after(epoch, time - interval / 2)] * len(rates.area)
        rows["end"] += [time_after(epoch, time + interval / 2)] * len(rates.area)
        rows["x_m"].append(centre[:, 0])
        rows["y_m"].append(centre[:, 1])
        for name in ("divergence", "shear", "vorticity"):
            rows[f"{name}_per_s"].append(getattr(rates, name))
            rows[f"sigma_{name}_per_s"].append(getattr(rates, f"sigma_{name}"))
    return {k: np.concatenate(val) if k not in ("start", "end") else np.array(val) for k, val in rows.items()}


def write_kinematics(result: FloeKinematics, out_dir: str | os.PathLike) -> tuple[Path, ...]:
    """``velocities.csv``, ``box_averages.csv`` and ``.png``, ``velocity_series.png``, ``deformation.csv``,
    ``trajectories.geojson``, ``fixes.geojson`` and ``trajectories.png``."""
    out = Path(out_dir)
    v, boxes, records = result.velocities, result.boxes, result.records
    files = [write_csv(out / "velocities.csv", {
        "floe_id": v.floe, "time": np.array([time_after(records.epoch, t) for t in v.time]), "interval_s": v.interval,
        "x_m": v.x, "y_m": v.y, "u_grid_m_s": v.u_grid, "v_grid_m_s": v.v_grid, "u_east_m_s": v.u_east,
        "v_north_m_s": v.v_north}),
        write_csv(out / "box_averages.csv", {"x_m": boxes.x, "y_m": boxes.y, "u_grid_m_s": boxes.u,
                                             "v_grid_m_s": boxes.v, "sigma_u_m_s": boxes.sigma_u,
                                             "sigma_v_m_s": boxes.sigma_v, "count": boxes.count}),
        plot_box_averages(out / "box_averages.png", boxes, f"Box-averaged velocity ({result.box_size / 1000:.0f} "
                          "km boxes) with ±1σ rectangles", background=np.stack([result.x, result.y], 1),
                          projection=result.projection)]
    busiest = dict(sorted(result.series.items(), key=lambda item: -item[1]["count"].sum())[:6])
    files.append(plot_velocity_series(out / "velocity_series.png", busiest, "Daily box-averaged velocity",
                                      records.epoch[:10]))
    if result.deformation:
        files.append(write_csv(out / "deformation.csv", _deformation_columns(result)))
    files.append(write_trajectories_geojson(out / "trajectories.geojson", records.floe, records.time,
                                            records.latitude, records.longitude, records.epoch))
    files.append(write_fixes_geojson(out / "fixes.geojson", records.floe, records.time, records.latitude,
                                     records.longitude, records.epoch))
    files.append(plot_trajectories(out / "trajectories.png", records.floe, result.x, result.y,
                                   "Floe trajectories (start: dot)", projection=result.projection))
    return tuple(files)


def kinematics_report(result: FloeKinematics) -> str:
    v = result.velocities
    speed = v.speed * 86.4
    triangles = sum(len(rates.area) for *_, rates in result.deformation)
    return "\n".join([
        f"{len(v.floe)} velocities of {len(set(result.records.floe.tolist()))} floes: median speed "
        f"{np.median(speed):.1f} km/day (max {speed.max():.1f}); {len(result.boxes.x)} boxes of "
        f"{result.box_size / 1000:.0f} km; {triangles} deformation triangles",
        *(f"  note: {note}" for note in result.notes)])


def run_velocities(records_path: str | os.PathLike, out_dir: str | os.PathLike, projection: str = "nsidc-north",
                   box_size: float = 50_000.0, velocity_sigma: float | None = None,
                   images=None, overwrite: bool = False) -> Step[FloeKinematics]:
    """Velocities, box averages (Figure 4-7), daily box series (Figure 4-5), deformation and trajectories from a
    floe record file (manual or from ``seaice track``; ``images``: the known image ids, for validation), written as
    one run (:func:`~seaice_jax.outputs.output_folder`); see :func:`floe_kinematics` for the other arguments."""
    with output_folder(out_dir, overwrite, inputs=(records_path,)) as folder:
        result = floe_kinematics(read_records(records_path, images=images), projection, box_size, velocity_sigma)
        files = folder.final(write_kinematics(result, folder.path))
    return Step(files, kinematics_report(result), result)


# ------------------------------------------------------------------------------------------------ film


def _floe_pixels(records_path, stack: RemappedStack):
    """Per image, the ``(n, 2)`` grid (row, column) of the floes of a record file."""
    floes = read_records(records_path, images=set(stack.names))
    points = []
    for name in stack.names:
        at = floes.image == name
        x, y = stack.grid.projection.forward(floes.latitude[at], floes.longitude[at])
        points.append(np.stack([np.asarray(a) for a in stack.grid.to_pixel(x, y)], 1))
    return points


def run_movie(remapped_dir: str | os.PathLike, out_path: str | os.PathLike, land_mask=None, records=None,
              fps: float = 2.0, scale: int = 2, overwrite: bool = False, map_decorations: bool = True) -> Step[None]:
    """A time-lapse film (GIF or MP4) of the remapped sequence with date labels, the land filled (``land_mask``:
    a ``.npy`` bool array on the grid; without one, the GSHHG land) and the tracked floes of a record file marked;
    with ``map_decorations`` the coastline, a labelled graticule and a scale bar
    (:func:`~seaice_jax.report.maps.map_overlay`); ``fps`` > 0, ``scale`` >= 1 and the film within the memory budget
    (:func:`~seaice_jax.memory.film_peak`)."""
    if not (np.isfinite(fps) and fps > 0 and int(scale) == scale and scale >= 1):
        raise SeaiceError(f"film: fps must be > 0 and scale an integer >= 1, got fps {fps}, scale {scale}")
    stack = load_remapped(remapped_dir)
    check_memory(film_peak(len(stack.names), stack.grid.shape[0] * stack.grid.shape[1] * scale**2),
                 f"--scale {scale}: a film of {len(stack.names)} frames of {stack.grid.shape[1] * scale} x "
                 f"{stack.grid.shape[0] * scale} pixels")
    land = None if land_mask is None else land_of_grid(land_mask, stack.grid)
    points = None if records is None else _floe_pixels(records, stack)
    labels = [time_after(stack.epoch, t)[:16].replace("T", " ") for t in stack.times]
    overlay = map_overlay(stack.grid, int(scale), land=land is None) if map_decorations else None
    frames = render_frames(stack.values, labels, land, points, scale, overlay)
    with output_file(out_path, overwrite, inputs=(remapped_dir,)) as staging:
        path, = staging.final([write_movie(staging.path / staging.target.name, frames, fps)])
    return Step((path,), f"film of {len(frames)} frames ({frames.shape[2]} x {frames.shape[1]} pixels) -> {path}",
                None)


# ------------------------------------------------------------------------------------------------ simulation


SIMULATED_GRID = {"projection": "nsidc-north", "centre_deg": [74.0, -85.0], "pixel_m": [2500.0, 2500.0],
                  "shape": [150, 150]}
"""The map grid of :func:`write_simulated_sequence`'s projects: 375 km square at 2.5 km, EPSG:3413."""


STATIC_MARGIN = 3000.0
"""m: the static mask of a simulated sequence stops this far inside the fast-ice edge (a tie's patch there does not
move)."""


def true_drift_fields(sequence, grid: MapGrid, first: int) -> dict:
    """The true displacement of every cell centre of ``grid`` from image ``first`` of a simulated ``sequence`` to
    the next, as the fields of :func:`~seaice_jax.io.products.write_drift_netcdf` (``dX, dY`` m along the grid's
    axes, zero σ, ``status_flag`` GOOD, ``u_east, v_north`` m/s)."""
    scene, a, b = sequence.scene, sequence.images[first], sequence.images[first + 1]
    x, y = (np.asarray(v).ravel() for v in grid.xy())
    start = np.stack([np.asarray(v) for v in scene.projection.forward(*grid.projection.inverse(x, y))], 1)
    end = start + true_displacement(scene, start, a.time, b.time)
    end_x, end_y = (np.asarray(v) for v in grid.projection.forward(*scene.projection.inverse(end[:, 0], end[:, 1])))
    dx, dy = end_x - x, end_y - y
    interval = b.time - a.time
    east, north = (np.asarray(v) for v in grid_to_east_north(grid.projection, x, y, dx / interval, dy / interval))
    return {"dX": dx.reshape(grid.shape), "dY": dy.reshape(grid.shape), "dX_uncertainty": np.zeros(grid.shape),
            "dY_uncertainty": np.zeros(grid.shape), "status_flag": np.full(grid.shape, GOOD),
            "u_east": east.reshape(grid.shape), "v_north": north.reshape(grid.shape)}


def write_simulated_truth(sequence, grid: MapGrid, out_dir: str | os.PathLike) -> tuple[Path, ...]:
    """``truth/models.npz`` (the true scan models, zero covariance: :func:`save_models`) and, for every consecutive
    pair, ``truth/drift_<a>_<b>.nc``: the true displacement of every grid cell, in the layout of ``seaice
    track``'s drift files (on the project's grid instead of the tracking lattice)."""
    out = Path(out_dir) / "truth"
    out.mkdir(parents=True, exist_ok=True)
    images = sequence.images
    files = [save_models(out / "models.npz", [im.name for im in images], [im.model for im in images],
                         np.zeros((_UNKNOWNS * len(images),) * 2), 0.0, "truth")]
    for k in range(len(images) - 1):
        a, b = images[k].name, images[k + 1].name
        files.append(write_drift_netcdf(out / f"drift_{a}_{b}.nc", grid, true_drift_fields(sequence, grid, k),
                                        images[k].time, images[k + 1].time, sequence.epoch, STATUS,
                                        title=f"True sea-ice drift {a} to {b} (simulation)"))
    return tuple(files)


def write_simulated_sequence(out_dir: str | os.PathLike, seed: int = 0, images: int = 6, size: int = 256,
                             clouds: bool = False, sequence=None, overwrite: bool = False) -> Path:
    """Simulate a Lancaster-Sound-like sequence (:func:`~seaice_jax.simulate.satellite.simulate_sequence`) and
    write it as a project with ``land_mask.npy`` on its grid (for films), ``static_mask.npy`` (land and fast ice
    :data:`STATIC_MARGIN` inside its edge: where ``seaice adjust`` seeks ties) and the truth
    (:func:`write_simulated_truth`), as one run (:func:`~seaice_jax.outputs.output_folder`). A simulation whose
    estimated peak memory (:func:`~seaice_jax.memory.simulate_peak`) or files exceed the budget or the free disk is
    refused before it starts."""
    if sequence is None:
        what = f"--size {size} --images {images}: simulating {images} images of {size} x {size} pixels"
        check_memory(simulate_peak(size, images), what)
        shape = SIMULATED_GRID["shape"]
        check_disk(simulate_disk(size, images, shape[0] * shape[1]), out_dir, what)
    with output_folder(out_dir, overwrite) as folder:
        sequence = sequence or simulate_sequence(seed, n_images=images, size=size, clouds=clouds)
        grid = make_grid(**{k: SIMULATED_GRID[k] for k in ("projection", "centre_deg", "pixel_m", "shape")})
        offset = np.asarray(sequence.scene.coast_offset(scene_xy(sequence.scene, grid)))
        masks = {"land_mask.npy": land_mask(sequence.scene, grid),
                 "static_mask.npy": offset > -float(sequence.scene.fast_ice_width) + STATIC_MARGIN}
        for name, mask in masks.items():
            with atomic_path(folder.path / name) as temporary, open(temporary, "wb") as stream:
                np.save(stream, mask)
        write_simulated_truth(sequence, grid, folder.path)
        project, = folder.final([write_sequence(sequence, folder.path, SIMULATED_GRID)])
    return project
