"""``seaice remap`` (source 001, VHR2/VHR3): rectify each image of a sequence on its control points (or adopt the
models ``seaice adjust`` wrote), remap all into one grid, write GeoTIFFs, the stack, the rectification table and an
overview figure. :func:`remap_sequence` computes (-> :class:`~seaice_jax.io.remapped.RemappedStack`),
:func:`write_remapped` writes, :func:`run_remap` is the command."""

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from seaice_jax.adjust.orbit.fit import OrbitFit, control_point_deviations, fit_scan_model, propagate_position_sigma
from seaice_jax.errors import SeaiceError
from seaice_jax.files import write_csv
from seaice_jax.geometry.projections import MapGrid
from seaice_jax.geometry.scan import SCAN_UNKNOWNS, ScanModel
from seaice_jax.imagery.coast_control import coast_control
from seaice_jax.imagery.remap import remap
from seaice_jax.io.products import write_geotiff
from seaice_jax.io.remapped import RemappedStack, load_models, save_stack
from seaice_jax.io.sequence import SequenceImage, SequenceProject, read_sequence
from seaice_jax.outputs import output_folder
from seaice_jax.report.figures import plot_remapped
from seaice_jax.timefmt import time_after
from seaice_jax.workflows.rectify import image_coastline
from seaice_jax.workflows.step import Step

_UNKNOWNS = len(SCAN_UNKNOWNS)


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
