"""``seaice simulate lancaster``: a simulated satellite image sequence written as a project (images, control
points, the truth: drift fields and models) that ``seaice remap``, ``adjust``, ``track`` read."""

import os
from pathlib import Path

import numpy as np

from seaice_jax.drift.kinematics import grid_to_east_north
from seaice_jax.files import atomic_path
from seaice_jax.geometry.projections import MapGrid
from seaice_jax.geometry.scan import SCAN_UNKNOWNS
from seaice_jax.imagery.tracking import GOOD, STATUS
from seaice_jax.io.products import write_drift_netcdf
from seaice_jax.io.remapped import save_models
from seaice_jax.io.sequence import make_grid, write_sequence
from seaice_jax.memory import check_disk, check_memory, simulate_disk, simulate_peak
from seaice_jax.outputs import output_folder
from seaice_jax.simulate.satellite import land_mask, scene_xy, simulate_sequence, true_displacement

SIMULATED_GRID = {"projection": "nsidc-north", "centre_deg": [74.0, -85.0], "pixel_m": [2500.0, 2500.0],
                  "shape": [150, 150]}
"""The map grid of :func:`write_simulated_sequence`'s projects: 375 km square at 2.5 km, EPSG:3413."""
_UNKNOWNS = len(SCAN_UNKNOWNS)


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
