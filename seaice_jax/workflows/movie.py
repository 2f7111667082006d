"""``seaice movie`` (source 001, MOVIE): a film of a remapped stack with the followed floes drawn on it."""

import os

import numpy as np

from seaice_jax.drift.records import read_records
from seaice_jax.errors import SeaiceError
from seaice_jax.imagery.movie import render_frames, write_movie
from seaice_jax.io.remapped import RemappedStack, load_remapped
from seaice_jax.memory import check_memory, film_peak
from seaice_jax.outputs import output_file
from seaice_jax.report.maps import map_overlay
from seaice_jax.timefmt import time_after
from seaice_jax.workflows.step import Step
from seaice_jax.workflows.track import land_of_grid


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
