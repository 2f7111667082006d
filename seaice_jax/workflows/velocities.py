"""``seaice velocities``: velocities, box averages and deformation of followed floes (:func:`floe_kinematics` ->
:class:`FloeKinematics`), written as CSV and figures (:func:`write_kinematics`); :func:`run_velocities` is the
command."""

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seaice_jax.drift.kinematics import (
    BoxAverages,
    Deformation,
    Velocities,
    box_averages,
    box_time_series,
    deformation,
    plausible_velocities,
    velocities,
)
from seaice_jax.drift.records import FloeRecords, read_records
from seaice_jax.files import write_csv
from seaice_jax.io.products import write_fixes_geojson, write_trajectories_geojson
from seaice_jax.io.sequence import named_projection
from seaice_jax.outputs import output_folder
from seaice_jax.report.figures import plot_box_averages, plot_trajectories, plot_velocity_series
from seaice_jax.timefmt import time_after
from seaice_jax.workflows.step import Step


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
