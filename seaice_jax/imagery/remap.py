"""Remap satellite images into one map grid (source 001, VHR2/VHR3), many at once with ``vmap``.

Every output pixel of a :class:`~seaice_jax.geometry.projections.MapGrid` is taken through the inverse scan model
(:meth:`~seaice_jax.geometry.scan.ScanModel.inverse`) to a fractional pixel and scan line of each image and
sampled there, bilinearly or at the nearest pixel. Pixels outside an image's swath get a ``False`` validity mask
(and NaN). The 1985 "fill" option (mean of the valid neighbours of each empty pixel) is :func:`fill_holes`.

Images are given as arrays ``(n_scans, n_pixels)``: row = scan line − 1, column = pixel − 1.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.ndimage import map_coordinates

from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.projections import MapGrid
from seaice_jax.geometry.scan import ScanModel

METHODS = {"nearest": 0, "bilinear": 1}


def sample(image, row, column, method: str = "bilinear"):
    """``image`` at fractional 0-based ``(row, column)``; NaN outside the image (pixel centres ± 0.5) and where
    the image itself is NaN (missing data)."""
    rows, columns = image.shape
    inside = (row >= -0.5) & (row <= rows - 0.5) & (column >= -0.5) & (column <= columns - 0.5)
    # at the outermost half pixel, sample the edge pixel (clamped coordinates)
    r, c = jnp.clip(row, 0.0, rows - 1.0), jnp.clip(column, 0.0, columns - 1.0)
    value = map_coordinates(image, [r, c], order=METHODS[method], mode="nearest")
    return jnp.where(inside, value, jnp.nan)


def _remap_one(image, model: ScanModel, latitude, longitude, method):
    pixel, scan = model.inverse(latitude, longitude)
    value = sample(image[: model.n_scans, : model.n_pixels], scan - 1.0, pixel - 1.0, method)
    return value, jnp.isfinite(value)


@eqx.filter_jit
def _remap_batch(images, models, grid, method):
    latitude, longitude = grid.latitude_longitude()
    return jax.vmap(_remap_one, in_axes=(0, 0, None, None, None))(images, models, latitude, longitude, method)


@eqx.filter_jit
def _swath(model, grid):
    pixel, scan = model.inverse(*grid.latitude_longitude())
    return (pixel >= 0.5) & (pixel <= model.n_pixels + 0.5) & (scan >= 0.5) & (scan <= model.n_scans + 0.5)


def stack_models(models):
    """One :class:`ScanModel` whose array leaves carry a leading batch axis (all must share direction and
    size, the static fields)."""
    static = {(m.direction, m.n_pixels, m.n_scans) for m in models}
    if len(static) > 1:
        raise SeaiceError(f"models to stack must share direction and size, got {sorted(static)}")
    return jax.tree.map(lambda *leaves: jnp.stack(leaves), *models)


def remap(images, models, grid: MapGrid, method: str = "bilinear", fill: int = 0):
    """Remap images, each with its own scan model, into ``grid``.

    Images with the same direction and size go through one jitted, vmapped call (one compilation per group and
    grid shape).

    Args:
        images: sequence of ``(n_scans, n_pixels)`` arrays (NaN marks missing data).
        models: one :class:`ScanModel` per image.
        grid: the output :class:`MapGrid`.
        method: ``"bilinear"`` or ``"nearest"``.
        fill: passes of :func:`fill_holes` over missing data inside each swath (0: none).

    Returns:
        ``(values, valid)``: ``(k, n_rows, n_columns)`` float64 (NaN outside a swath) and bool.
    """
    if method not in METHODS:
        raise SeaiceError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    if len(images) != len(models):
        raise SeaiceError(f"{len(images)} images but {len(models)} scan models")
    for k, (image, model) in enumerate(zip(images, models, strict=True)):
        if np.shape(image) != (model.n_scans, model.n_pixels):
            raise SeaiceError(f"image {k}: shape {np.shape(image)} does not match its scan model "
                              f"({model.n_scans} scan lines x {model.n_pixels} pixels)")
    values = np.full((len(images), *grid.shape), np.nan)
    valid = np.zeros((len(images), *grid.shape), bool)
    groups = {}
    for k, model in enumerate(models):
        groups.setdefault((model.direction, model.n_pixels, model.n_scans), []).append(k)
    for members in groups.values():
        batch = jnp.stack([jnp.asarray(images[k], float) for k in members])
        v, ok = _remap_batch(batch, stack_models([models[k] for k in members]), grid, method)
        values[members], valid[members] = np.asarray(v), np.asarray(ok)
    if fill:
        swaths = swath_masks(models, grid)
        for k in range(len(images)):
            filled = np.asarray(fill_holes(jnp.asarray(values[k]), jnp.asarray(valid[k]), fill))
            values[k] = np.where(swaths[k], filled, np.nan)
            valid[k] = np.isfinite(values[k])
    return values, valid


def swath_masks(models, grid: MapGrid):
    """``(k, n_rows, n_columns)`` bool: where each model's image covers the grid (whatever the data)."""
    return np.stack([np.asarray(_swath(model, grid)) for model in models])


@jax.jit
def _fill_pass(values, valid):
    padded_v = jnp.pad(jnp.where(valid, values, 0.0), 1)
    padded_n = jnp.pad(valid.astype(float), 1)
    rows, columns = values.shape
    total = sum(padded_v[1 + i: 1 + i + rows, 1 + j: 1 + j + columns] for i in (-1, 0, 1) for j in (-1, 0, 1))
    count = sum(padded_n[1 + i: 1 + i + rows, 1 + j: 1 + j + columns] for i in (-1, 0, 1) for j in (-1, 0, 1))
    fillable = ~valid & (count > 0)
    return jnp.where(fillable, total / jnp.maximum(count, 1.0), values), valid | fillable


def fill_holes(values, valid, passes: int = 1):
    """The 1985 "fill": each empty pixel with at least one valid neighbour (8-neighbourhood) takes their mean;
    repeated ``passes`` times (a hole ``2·passes`` pixels wide closes).

    Returns:
        the filled ``values`` (still NaN where nothing reached).
    """
    values = jnp.where(valid, values, jnp.nan)
    for _ in range(passes):
        values, valid = _fill_pass(values, valid)
    return jnp.where(valid, values, jnp.nan)
