"""``seaice track`` (source 001, ICE): track the ice automatically between consecutive images of a remapped stack,
with each vector's σ (tracking and geolocation), follow floes through the sequence, write drift products (CF-NetCDF,
OSI SAF-like, GeoJSON, CSV) and figures. :func:`track_sequence` computes (-> :class:`TrackedSequence`),
:func:`write_tracked` writes, :func:`run_track` is the command."""

import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from seaice_jax.adjust.orbit.fit import position_jacobian
from seaice_jax.drift.kinematics import (
    Deformation,
    check_tracking_interval,
    deformation,
    east_north_axes,
    grid_to_east_north,
)
from seaice_jax.drift.records import FloeRecords, write_records
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.projections import MapGrid
from seaice_jax.imagery.tracking import GOOD, STATUS, TrackingOptions, grid_points, on_land, track
from seaice_jax.io.coastline import land_mask_of_grid
from seaice_jax.io.products import (
    write_drift_netcdf,
    write_fixes_geojson,
    write_osisaf_drift,
    write_trajectories_geojson,
)
from seaice_jax.io.remapped import RemappedStack, geotiff_stack, load_remapped
from seaice_jax.memory import check_memory, track_peak
from seaice_jax.outputs import output_folder
from seaice_jax.report.figures import plot_vectors
from seaice_jax.workflows.step import Step


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
        correlation peak and its neighbour statistic (:func:`~seaice_jax.imagery.tracking.track`). correlation:
        ``(n,)`` the peak's normalised cross-correlation (NaN where not measured).
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
    correlation peak and the disagreement of the patches around it, :mod:`seaice_jax.imagery.tracking`) with both
    images' geolocation σ. ``land``: ``(n_rows, n_columns)`` bool on the grid, True on land: a vector that starts
    or ends on land has the status :data:`~seaice_jax.imagery.tracking.ON_LAND` (never good), and no floe is
    followed onto or from land; a good vector whose patch reaches over the coast is
    :data:`~seaice_jax.imagery.tracking.MIXED_MOTION` (so is one whose surrounding patches disagree with it: the
    fast-ice edge)."""
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
