"""Remap satellite images into one map grid (source 001, VHR2/VHR3), many at once with ``vmap``.

Every output pixel of a :class:`~seaice_jax.geometry.projections.MapGrid` is taken through the inverse scan model
(:meth:`~seaice_jax.geometry.scan.ScanModel.inverse`) to a fractional pixel and scan line of each image and
sampled there, bilinearly or at the nearest pixel. Pixels outside an image's swath get a ``False`` validity mask
(and NaN). The 1985 "fill" option (mean of the valid neighbours of each empty pixel) is :func:`fill_holes`.

Images are given as arrays ``(n_scans, n_pixels)``: row = scan line − 1, column = pixel − 1.

Radar strips are orthorectified the same way through the range-Doppler inverse (:func:`orthorectify_strip`).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.ndimage import map_coordinates
from jaxtyping import Array, Float

from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.earth import MEAN_RADIUS, sphere_to_cartesian
from seaice_jax.geometry.projections import MapGrid
from seaice_jax.geometry.range_doppler import imaging_time_and_range, look_sign
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


class StripRaster(eqx.Module):
    """A scanned radar strip in image coordinates: ``data[i, j]`` at x = x_first + i · pixel_size along track and
    y = y_first + j · pixel_size across (mm of film, the frame of :class:`~seaice_jax.sensors.slar.ImageFrame`)."""

    data: Float[Array, "rows columns"]
    x_first: Float[Array, ""] = eqx.field(converter=lambda v: jnp.asarray(v, float))
    y_first: Float[Array, ""] = eqx.field(converter=lambda v: jnp.asarray(v, float))
    pixel_size: Float[Array, ""] = eqx.field(converter=lambda v: jnp.asarray(v, float))


def orthorectify_strip(raster: StripRaster, navigation, mark_x, mark_times, sweep_delay: float, range_scale: float,
                       look_side: str, grid: MapGrid, method: str = "bilinear", radius: float = MEAN_RADIUS):
    """Remap a radar strip into ``grid`` through the range-Doppler inverse (source 000 eqs A1, A2, A5 backwards).

    Each output pixel's ground point (on the sphere) gives its imaging time (zero Doppler along ``navigation``)
    and slant range; the time marks give x (eq. A1 inverted), sweep delay and range scale give y = r / f − c
    (eq. A2 inverted), and the strip is sampled there. Pixels on the other side of the flight line, before or after
    the strip, or outside the raster are masked.

    Args:
        navigation: the strip's trajectory ``t -> (position, velocity)`` (e.g.
            :func:`~seaice_jax.sensors.strips.strip_navigation`). mark_x, mark_times: ``(n,)`` time marks (mm, s).
        sweep_delay: c, mm. range_scale: f, m/mm. look_side: ``"right"`` or ``"left"``.

    Returns:
        ``(values, valid)``: ``(n_rows, n_columns)``.
    """
    if method not in METHODS:
        raise SeaiceError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    values, valid = _orthorectify(raster, navigation, jnp.asarray(mark_x, float), jnp.asarray(mark_times, float),
                                  float(sweep_delay), float(range_scale), float(look_sign(look_side)), grid, method,
                                  float(radius))
    return np.asarray(values), np.asarray(valid)


@eqx.filter_jit
def _orthorectify(raster, navigation, mark_x, mark_times, sweep_delay, range_scale, sign, grid, method, radius):
    latitude, longitude = grid.latitude_longitude()
    points = sphere_to_cartesian(latitude, longitude, 0.0, radius)
    time, slant = imaging_time_and_range(points, navigation, mark_times[0], mark_times[-1])
    position, velocity = jax.vmap(navigation)(time.ravel())
    position, velocity = position.reshape(points.shape), velocity.reshape(points.shape)
    right = jnp.cross(velocity, position)  # w of eq. A5: to the right of the flight direction
    side = jnp.sum((points - position) * right, axis=-1) * sign > 0
    x = jnp.interp(time, mark_times, mark_x)
    y = slant / range_scale - sweep_delay
    row = (x - raster.x_first) / raster.pixel_size
    column = (y - raster.y_first) / raster.pixel_size
    value = sample(raster.data, row, column, method)
    inside = side & (time >= mark_times[0]) & (time <= mark_times[-1]) & jnp.isfinite(value)
    return jnp.where(inside, value, jnp.nan), inside
