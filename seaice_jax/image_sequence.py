"""Satellite image sequences end to end (source 001, VHR2/VHR3, ICE, MOVIE): rectify each image on its control
points, remap all into one grid, track the ice automatically, derive velocities, boxes, deformation and a film.
Each step computes everything before it writes, and writes atomically; the CLI's ``remap``, ``track``,
``velocities`` and ``movie`` are thin wrappers around :func:`run_remap`, :func:`run_track`,
:func:`run_velocities` and :func:`run_movie`."""

import json
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from seaice_jax.adjust.orbit_fit import (
    control_point_deviations,
    fit_scan_model,
    position_jacobian,
    propagate_position_sigma,
)
from seaice_jax.drift.kinematics import (
    box_averages,
    box_time_series,
    deformation,
    east_north_axes,
    grid_to_east_north,
    velocities,
)
from seaice_jax.drift.records import FloeRecords, read_records, time_after, write_records
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.projections import MapGrid
from seaice_jax.geometry.scan import Orbit, ScanModel
from seaice_jax.imagery.movie import render_frames, write_movie
from seaice_jax.imagery.remap import remap
from seaice_jax.imagery.tracking import GOOD, STATUS, TrackingOptions, grid_points, track
from seaice_jax.io.files import atomic_path, write_csv
from seaice_jax.io.products import write_drift_netcdf, write_geotiff, write_trajectories_geojson
from seaice_jax.io.sequence import make_grid, named_projection, read_sequence
from seaice_jax.plots import (
    plot_box_averages,
    plot_remapped,
    plot_trajectories,
    plot_vectors,
    plot_velocity_series,
)

_MODEL_FIELDS = ("scanner_angle_span", "subtrack_pixel", "orbital_angle_first", "orbital_angle_span",
                 "ascending_node")


@dataclass(frozen=True)
class Step:
    """What a step computed and wrote: ``files``, a text ``report`` and the main results (``results``)."""

    files: tuple[Path, ...]
    report: str
    results: dict


def run_remap(project_path: str | os.PathLike, out_dir: str | os.PathLike, method: str = "bilinear",
              fill: int = 1, progress: bool = True) -> Step:
    """Rectify (fit the scan model of every image with control points) and remap the sequence into its grid.

    Writes ``<image>.tif`` (GeoTIFF), ``remapped.npz`` (the stack, validity masks, times, scan models, their
    covariance — block-diagonal, one fit per image — and the geolocation σ of every grid pixel),
    ``rectification.csv`` (control-point deviations per image, as the 1985 VHR2 printout) and ``remapped.png``."""
    project = read_sequence(project_path)
    out = Path(out_dir)
    grid = project.grid
    models, lines, deviations = [], [], {k: [] for k in ("image", "point", "north_km", "east_km")}
    covariance = np.zeros((5 * len(project.images),) * 2)
    for k, image in enumerate(tqdm(project.images, desc="rectify", disable=not progress, leave=False)):
        if image.model is not None:
            models.append(image.model)
            lines.append(f"  {image.name}: scan model given ({image.model.direction}bound)")
            continue
        fit = fit_scan_model(image.control, image.orbit, direction=image.direction, n_pixels=image.data.shape[1],
                             n_scans=image.data.shape[0])
        models.append(fit.model)
        covariance[5 * k:5 * k + 5, 5 * k:5 * k + 5] = np.asarray(fit.adjustment.covariance)
        lines.append(f"  {image.name}: {fit.model.direction}bound, {len(image.control)} control points, "
                     f"σ̂0 {float(fit.adjustment.sigma0):.2f}")
    for image, model in zip(project.images, models, strict=True):
        if image.control is not None:
            north, east = control_point_deviations(model, image.control)
            deviations["image"] += [image.name] * north.size
            deviations["point"] += list(image.control.ids)
            deviations["north_km"].append(north / 1000)
            deviations["east_km"].append(east / 1000)
            distance = np.hypot(north, east) / 1000
            lines.append(f"  {image.name}: control-point deviation mean {distance.mean():.2f} km (max N-S "
                         f"{np.abs(north).max() / 1000:.2f}, E-W {np.abs(east).max() / 1000:.2f} km)")
    latitude, longitude = grid.latitude_longitude()
    sigma_maps = []
    for k, model in enumerate(models):
        pixel, scan = model.inverse(latitude, longitude)
        sn, se = (np.asarray(a) for a in propagate_position_sigma(model, covariance[5 * k:5 * k + 5,
                                                                                    5 * k:5 * k + 5], pixel, scan))
        sigma_maps.append(np.sqrt(0.5 * (sn**2 + se**2)))
    values, valid = remap([im.data for im in project.images], models, grid, method=method, fill=fill)
    names = [im.name for im in project.images]
    times = np.array([im.time for im in project.images])
    files = []
    for k, name in enumerate(tqdm(names, desc="write GeoTIFF", disable=not progress, leave=False)):
        label = f"{name} {time_after(project.epoch, times[k])}"
        files.append(write_geotiff(out / f"{name}.tif", values[k], grid, label))
    parameters = np.array([[float(getattr(m, f)) for f in _MODEL_FIELDS] for m in models])
    with atomic_path(out / "remapped.npz") as temporary, open(temporary, "wb") as stream:
        np.savez_compressed(stream, values=values, valid=valid, times=times, names=np.array(names),
                            epoch=project.epoch, grid=json.dumps(project.grid_spec), sigma=np.stack(sigma_maps),
                            covariance=covariance, parameters=parameters,
                            directions=np.array([m.direction for m in models]),
                            shapes=np.array([[m.n_scans, m.n_pixels] for m in models]),
                            orbits=np.array([[float(m.orbit.inclination), float(m.orbit.period),
                                              float(m.orbit.altitude), float(m.orbit.earth_day),
                                              float(m.orbit.radius)] for m in models]))
    files.append(out / "remapped.npz")
    if deviations["point"]:
        files.append(write_csv(out / "rectification.csv", {k: np.concatenate(v) if k.endswith("km") else np.array(v)
                                                           for k, v in deviations.items()}))
    x, y = (np.asarray(a) / 1000 for a in grid.xy())
    extent = [x.min(), x.max(), y.min(), y.max()]
    files.append(plot_remapped(out / "remapped.png", values, [f"{n}\n{time_after(project.epoch, t)[:16]}"
                                                              for n, t in zip(names, times, strict=True)], extent))
    report = [f"remapped {len(names)} images into a {grid.n_rows} x {grid.n_columns} grid of "
              f"{float(grid.pixel_width):.0f} x {float(grid.pixel_height):.0f} m ({method}, fill {fill}):", *lines]
    return Step(tuple(files), "\n".join(report), dict(values=values, valid=valid, models=models, grid=grid,
                                                       times=times, names=names, epoch=project.epoch,
                                                       covariance=covariance))


def load_remapped(directory: str | os.PathLike) -> dict:
    """The stack written by :func:`run_remap`, with its grid and scan models rebuilt."""
    path = Path(directory) / "remapped.npz"
    if not path.exists():
        raise SeaiceError(f"{path}: file not found (run `seaice remap` first)")
    with np.load(path) as data:
        stored = {k: data[k] for k in data.files}
    missing = [k for k in ("values", "valid", "times", "names", "epoch", "grid", "sigma", "covariance",
                           "parameters", "orbits", "directions", "shapes") if k not in stored]
    if missing:
        raise SeaiceError(f"{path}: no {', '.join(missing)} (written by another version?): run `seaice remap` again")
    spec = json.loads(str(stored["grid"]))
    grid = make_grid(spec.get("projection", "nsidc-north"), spec["centre_deg"], spec["pixel_m"], spec["shape"])
    models = [ScanModel(*p, Orbit(*o), str(d), int(s[1]), int(s[0])) for p, o, d, s in zip(
        stored["parameters"], stored["orbits"], stored["directions"], stored["shapes"], strict=True)]
    return dict(values=stored["values"], valid=stored["valid"], times=stored["times"],
                names=[str(n) for n in stored["names"]], epoch=str(stored["epoch"]), sigma=stored["sigma"],
                covariance=stored["covariance"], grid=grid, models=models)


def run_track(remapped_dir: str | os.PathLike, out_dir: str | os.PathLike,
              options: TrackingOptions | None = None, tracking_sigma: float = 0.2,
              progress: bool = True) -> Step:
    """Track the ice between consecutive remapped images.

    Writes per pair ``drift_<a>_<b>.nc`` (CF-NetCDF on the tracking lattice; the displacement σ combines
    ``tracking_sigma`` pixels with both images' geolocation σ) and its figure ``drift_<a>_<b>.png`` (vectors with
    95 % ellipses), and for the whole sequence ``floes.csv`` (floe records: every lattice point of the first image
    followed through the sequence while its tracking stays good) and ``trajectories.geojson``."""
    options = options or TrackingOptions()
    stack = load_remapped(remapped_dir)
    values, valid, grid, times, names = (stack[k] for k in ("values", "valid", "grid", "times", "names"))
    if len(names) < 2:
        raise SeaiceError(f"{remapped_dir}: tracking needs at least two images, got {len(names)}")
    out = Path(out_dir)
    rows, columns = grid_points(grid.shape, options)
    lattice_shape = (np.unique(rows).size, np.unique(columns).size)
    lattice = make_lattice(grid, rows, columns, lattice_shape)
    files, lines = [], []
    # Lagrangian: the lattice of the first image followed from image to image
    floe_row, floe_column = rows.copy(), columns.copy()
    alive = np.ones(rows.size, bool)
    fixes = [(np.arange(rows.size), 0, rows.copy(), columns.copy())]
    for k in tqdm(range(len(names) - 1), desc="track", disable=not progress, leave=False):
        pair = track(values[k], values[k + 1], options, valid_first=valid[k], valid_second=valid[k + 1])
        good = pair.good
        map_vectors = pair.in_map(grid)
        sigma = displacement_sigma(stack, k, map_vectors, tracking_sigma * float(grid.pixel_width))
        fields = {"dX": np.where(good, map_vectors["dx"], np.nan).reshape(lattice_shape),
                  "dY": np.where(good, map_vectors["dy"], np.nan).reshape(lattice_shape),
                  "dX_uncertainty": np.where(good, sigma[:, 0], np.nan).reshape(lattice_shape),
                  "dY_uncertainty": np.where(good, sigma[:, 1], np.nan).reshape(lattice_shape),
                  "status_flag": pair.status.reshape(lattice_shape)}
        interval = times[k + 1] - times[k]
        east, north = grid_to_east_north(grid.projection, map_vectors["x"], map_vectors["y"],
                                         map_vectors["dx"] / interval, map_vectors["dy"] / interval)
        fields["u_east"] = np.where(good, east, np.nan).reshape(lattice_shape)
        fields["v_north"] = np.where(good, north, np.nan).reshape(lattice_shape)
        rates = None
        if good.sum() >= 3:  # deformation of the Delaunay triangles of the good vectors (lattice indices)
            index = np.nonzero(good)[0]
            start_xy = np.stack([map_vectors["x"], map_vectors["y"]], 1)[index]
            velocity = np.stack([map_vectors["dx"], map_vectors["dy"]], 1)[index] / interval
            rates = deformation(start_xy, velocity, sigma[index] / interval)  # (relative errors: conservative)
            rates = replace(rates, triangles=index[rates.triangles])
        files.append(write_drift_netcdf(out / f"drift_{names[k]}_{names[k + 1]}.nc", lattice, fields, times[k],
                                        times[k + 1], stack["epoch"], STATUS,
                                        title=f"Sea-ice drift {names[k]} to {names[k + 1]}", deformation=rates))
        positions = np.stack([map_vectors["x"], map_vectors["y"]], 1)[good]
        files.append(plot_vectors(
            out / f"drift_{names[k]}_{names[k + 1]}.png", positions, np.stack([map_vectors["dx"], map_vectors["dy"]],
                                                                              1)[good],
            f"Tracked drift {names[k]} -> {names[k + 1]} ({good.sum()} vectors)",
            f"{interval / 86400:.2f} days; ellipses: 95 % from the stated σ (geolocation and tracking)",
            background=np.stack([map_vectors["x"], map_vectors["y"]], 1)[~good],
            covariances=np.stack([np.diag(v) for v in sigma[good] ** 2]) if good.any() else None))
        chained = track(values[k], values[k + 1], options, points=(floe_row, floe_column), valid_first=valid[k],
                        valid_second=valid[k + 1])
        alive &= chained.good
        floe_row = np.where(alive, floe_row + np.nan_to_num(chained.d_row), np.nan)
        floe_column = np.where(alive, floe_column + np.nan_to_num(chained.d_column), np.nan)
        fixes.append((np.nonzero(alive)[0], k + 1, floe_row[alive], floe_column[alive]))
        speed = np.hypot(map_vectors["dx"][good], map_vectors["dy"][good]) / interval * 86.4
        lines.append(f"  {names[k]} -> {names[k + 1]}: {good.sum()} of {good.size} vectors good, median speed "
                     f"{np.median(speed) if speed.size else np.nan:.1f} km/day; rejected: "
                     + ", ".join(f"{(pair.status == s).sum()} {STATUS[s]}" for s in STATUS
                                 if s != GOOD and (pair.status == s).any()))
    records = _records_from_fixes(fixes, stack, grid)
    files.append(write_records(out / "floes.csv", records))
    files.append(write_trajectories_geojson(out / "trajectories.geojson", records.floe, records.time,
                                            records.latitude, records.longitude, records.epoch))
    report = [f"tracked {len(names) - 1} image pairs on a {lattice_shape[0]} x {lattice_shape[1]} lattice "
              f"(patch {options.patch} px, search ±{options.search} px):", *lines,
              f"  {len(set(records.floe.tolist()))} floes followed, {len(records)} fixes"]
    return Step(tuple(files), "\n".join(report), dict(records=records, lattice=lattice))


def displacement_sigma(stack, k, vectors, tracking_sigma: float):
    """σ ``(n, 2)`` (m, along the grid's x and y) of displacements from image ``k`` to ``k + 1``: the geolocation
    errors of both images at the vector's start and end through their scan models' joint covariance (the
    cross-covariance of co-registered images included), plus ``tracking_sigma`` m per coordinate."""
    models, grid = stack["models"], stack["grid"]
    covariance = stack["covariance"][5 * k:5 * k + 10, 5 * k:5 * k + 10]
    jacobians = []
    for model, x, y in ((models[k], vectors["x"], vectors["y"]),
                        (models[k + 1], vectors["x"] + np.nan_to_num(vectors["dx"]),
                         vectors["y"] + np.nan_to_num(vectors["dy"]))):
        lat, lon = grid.projection.inverse(x, y)
        pixel, scan = model.inverse(lat, lon)
        jacobians.append(np.asarray(position_jacobian(model, pixel, scan)))  # (n, 2 north/east, 5)
    design = np.concatenate([-jacobians[0], jacobians[1]], axis=2)  # end minus start
    north_east = np.einsum("nij,jk,nlk->nil", design, covariance, design)
    east_dir, north_dir = east_north_axes(grid.projection, vectors["x"], vectors["y"])
    rotation = np.stack([north_dir, east_dir], axis=2)  # grid components of (north, east)
    on_grid = np.einsum("nij,njk,nlk->nil", rotation, north_east, rotation)
    return np.sqrt(np.diagonal(on_grid, axis1=1, axis2=2) + tracking_sigma**2)


def make_lattice(grid, rows, columns, shape):
    """The :class:`MapGrid` of the tracking lattice (every ``spacing``-th pixel of ``grid``)."""
    step_r = (rows.max() - rows.min()) / max(shape[0] - 1, 1)
    step_c = (columns.max() - columns.min()) / max(shape[1] - 1, 1)
    x0, y0 = grid.to_xy(rows.min(), columns.min())
    return MapGrid(grid.projection, x0, y0, float(grid.pixel_width) * step_c, float(grid.pixel_height) * step_r,
                   shape[0], shape[1])


def _records_from_fixes(fixes, stack, grid) -> FloeRecords:
    """Floe records of the tracked lattice points: grid position -> latitude, longitude and each image's own
    pixel and scan line (through its scan model)."""
    columns = {k: [] for k in ("floe", "time", "image", "pixel", "scan", "latitude", "longitude")}
    for ids, k, rows, cols in fixes:
        x, y = grid.to_xy(rows, cols)
        lat, lon = (np.asarray(a) for a in grid.projection.inverse(x, y))
        pixel, scan = (np.asarray(a) for a in stack["models"][k].inverse(lat, lon))
        columns["floe"] += [f"G{i:04d}" for i in ids]
        columns["time"].append(np.full(ids.size, stack["times"][k]))
        columns["image"] += [stack["names"][k]] * ids.size
        for name, value in (("pixel", pixel), ("scan", scan), ("latitude", lat), ("longitude", lon)):
            columns[name].append(value)
    arrays = {k: (np.concatenate(v) if k not in ("floe", "image") else np.array(v)) for k, v in columns.items()}
    order = np.lexsort((arrays["time"], arrays["floe"]))
    return FloeRecords(**{k: v[order] for k, v in arrays.items()}, epoch=stack["epoch"])


def run_velocities(records_path: str | os.PathLike, out_dir: str | os.PathLike, projection: str = "nsidc-north",
                   box_size: float = 50_000.0, velocity_sigma: float | None = None, images=None) -> Step:
    """Velocities, box averages (Figure 4-7), daily box series (Figure 4-5), deformation and trajectories from a
    floe record file (manual or from ``seaice track``).

    Args:
        projection: the map grid whose axes the grid-relative components follow (``nsidc-north``/``-south``).
        box_size: m. velocity_sigma: m/s of each velocity component for the deformation σ (default: the
            positions' σ of 1 km over each interval, √2·1000/Δt).
        images: the known image ids (validation).
    """
    records = read_records(records_path, images=images)
    metric = named_projection(projection, (np.degrees(records.latitude[0]), np.degrees(records.longitude[0])))
    x, y = (np.asarray(a) for a in metric.forward(records.latitude, records.longitude))
    v = velocities(records.floe, records.time, x, y, metric)
    out = Path(out_dir)
    files = [write_csv(out / "velocities.csv", {
        "floe_id": v.floe, "time": np.array([time_after(records.epoch, t) for t in v.time]), "interval_s": v.interval,
        "x_m": v.x, "y_m": v.y, "u_grid_m_s": v.u_grid, "v_grid_m_s": v.v_grid, "u_east_m_s": v.u_east,
        "v_north_m_s": v.v_north})]
    origin = (np.floor(v.x.min() / box_size) * box_size, np.floor(v.y.min() / box_size) * box_size)
    boxes = box_averages(v.x, v.y, v.u_grid, v.v_grid, box_size, origin)
    files.append(write_csv(out / "box_averages.csv", {"x_m": boxes.x, "y_m": boxes.y, "u_grid_m_s": boxes.u,
                                                      "v_grid_m_s": boxes.v, "sigma_u_m_s": boxes.sigma_u,
                                                      "sigma_v_m_s": boxes.sigma_v, "count": boxes.count}))
    files.append(plot_box_averages(out / "box_averages.png", boxes, f"Box-averaged velocity ({box_size / 1000:.0f} "
                                   "km boxes) with ±1σ rectangles", background=np.stack([x, y], 1)))
    series = box_time_series(v, box_size, origin)
    busiest = dict(sorted(series.items(), key=lambda item: -item[1]["count"].sum())[:6])
    files.append(plot_velocity_series(out / "velocity_series.png", busiest, "Daily box-averaged velocity",
                                      records.epoch[:10]))
    rows = {k: [] for k in ("start", "end", "x_m", "y_m", "divergence_s", "sigma_divergence_s", "shear_s",
                            "sigma_shear_s", "vorticity_s", "sigma_vorticity_s")}
    for t in np.unique(v.time):
        at = v.time == t
        if at.sum() < 3:
            continue
        sigma = velocity_sigma if velocity_sigma is not None else np.sqrt(2) * 1000.0 / v.interval[at]
        rates = deformation(np.stack([v.x[at], v.y[at]], 1), np.stack([v.u_grid[at], v.v_grid[at]], 1), sigma)
        centre = np.stack([v.x[at], v.y[at]], 1)[rates.triangles].mean(axis=1)
        half = v.interval[at][0] / 2
        rows["start"] += [time_after(records.epoch, t - half)] * len(rates.area)
        rows["end"] += [time_after(records.epoch, t + half)] * len(rates.area)
        rows["x_m"].append(centre[:, 0]), rows["y_m"].append(centre[:, 1])
        for name in ("divergence", "shear", "vorticity"):
            rows[f"{name}_s"].append(getattr(rates, name))
            rows[f"sigma_{name}_s"].append(getattr(rates, f"sigma_{name}"))
    if rows["start"]:
        files.append(write_csv(out / "deformation.csv", {k: np.concatenate(val) if k not in ("start", "end")
                                                         else np.array(val) for k, val in rows.items()}))
    files.append(write_trajectories_geojson(out / "trajectories.geojson", records.floe, records.time,
                                            records.latitude, records.longitude, records.epoch))
    files.append(plot_trajectories(out / "trajectories.png", records.floe, x, y, "Floe trajectories (start: dot)"))
    speed = v.speed * 86.4
    report = [f"{len(v.floe)} velocities of {len(set(records.floe.tolist()))} floes: median speed "
              f"{np.median(speed):.1f} km/day (max {speed.max():.1f}); {len(boxes.x)} boxes of "
              f"{box_size / 1000:.0f} km; {sum(len(r) for r in rows['divergence_s'])} deformation triangles"]
    return Step(tuple(files), "\n".join(report), dict(velocities=v, boxes=boxes, series=series))


def run_movie(remapped_dir: str | os.PathLike, out_path: str | os.PathLike, land_mask=None, records=None,
              fps: float = 2.0, scale: int = 2) -> Step:
    """A time-lapse film (GIF or MP4) of the remapped sequence with date labels, the land filled (``land_mask``:
    a ``.npy`` bool array on the grid) and the tracked floes of a record file marked."""
    stack = load_remapped(remapped_dir)
    land = None
    if land_mask is not None:
        land = np.load(land_mask)
        if land.shape != stack["grid"].shape:
            raise SeaiceError(f"{land_mask}: land mask shape {land.shape} is not the grid's {stack['grid'].shape}")
    points = None
    if records is not None:
        floes = read_records(records, images=set(stack["names"]))
        grid = stack["grid"]
        points = []
        for name in stack["names"]:
            at = floes.image == name
            x, y = grid.projection.forward(floes.latitude[at], floes.longitude[at])
            points.append(np.stack([np.asarray(a) for a in grid.to_pixel(x, y)], 1))
    labels = [time_after(stack["epoch"], t)[:16].replace("T", " ") for t in stack["times"]]
    frames = render_frames(stack["values"], labels, land, points, scale)
    path = write_movie(out_path, frames, fps)
    return Step((path,), f"film of {len(frames)} frames ({frames.shape[2]} x {frames.shape[1]} pixels) -> {path}",
                {})


SIMULATED_GRID = {"projection": "nsidc-north", "centre_deg": [74.0, -85.0], "pixel_m": [2500.0, 2500.0],
                  "shape": [150, 150]}
"""The map grid of :func:`write_simulated_sequence`'s projects: 375 km square at 2.5 km, EPSG:3413."""


def write_simulated_sequence(out_dir: str | os.PathLike, seed: int = 0, images: int = 6, size: int = 256,
                             clouds: bool = False, sequence=None) -> Path:
    """Simulate a Lancaster-Sound-like sequence (:func:`~seaice_jax.simulate.satellite.simulate_sequence`) and
    write it as a project with ``land_mask.npy`` on its grid (for films)."""
    from seaice_jax.io.sequence import write_sequence
    from seaice_jax.simulate.satellite import land_mask, simulate_sequence

    sequence = sequence or simulate_sequence(seed, n_images=images, size=size, clouds=clouds)
    out = Path(out_dir)
    grid = make_grid(**{k: SIMULATED_GRID[k] for k in ("projection", "centre_deg", "pixel_m", "shape")})
    with atomic_path(out / "land_mask.npy") as temporary, open(temporary, "wb") as stream:
        np.save(stream, land_mask(sequence.scene, grid))
    return write_sequence(sequence, out, SIMULATED_GRID)
