"""Remap satellite images into one map grid (source 001, VHR2/VHR3), many at once.

Every output pixel of a :class:`~seaice_jax.geometry.projections.MapGrid` is taken through the inverse scan model
(:meth:`~seaice_jax.geometry.scan.ScanModel.inverse`) to a fractional pixel and scan line of each image and
sampled there, bilinearly or at the nearest pixel. Pixels outside an image's swath get a ``False`` validity mask
(and NaN). The 1985 "fill" option (mean of the valid neighbours of each empty pixel) is :func:`fill_holes`.

Two paths give the same masks:

* ``max_error_pixels > 0`` (the default, 0.05): the source-pixel maps through the approximate transformer of
  :mod:`seaice_jax.imagery.approximate` (exact on a coarse lattice, bilinear in between, refined where it misses
  by more than the threshold), made exact wherever the approximation could change a decision — within the
  threshold of an image edge, or where the sampled pixels could reach missing data — then resampled by
  ``cv2.remap`` (bilinear; its weights are quantised to 1/32 pixel) or gathered (nearest);
* ``max_error_pixels = 0``: the exact float64 inverse of every output pixel and a JAX gather
  (:func:`sample`), jitted and ``vmap``-ped over the images: differentiable end to end (:func:`remap_exact`).

Images are given as arrays ``(n_scans, n_pixels)``: row = scan line − 1, column = pixel − 1.

Radar strips are orthorectified the same way through the range-Doppler inverse (:func:`orthorectify_strip`).
"""

import functools

import cv2
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.ndimage import map_coordinates
from jaxtyping import Array, Float

from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.earth import MEAN_RADIUS, sphere_to_cartesian
from seaice_jax.geometry.projections import MapGrid
from seaice_jax.geometry.range_doppler import LookSide, imaging_time_and_range, look_sign
from seaice_jax.geometry.scan import ScanModel
from seaice_jax.imagery.approximate import SourceMaps, approximate_maps, make_exact

_STEP = 32
"""The approximate transformer's coarsest tiles, output pixels."""
_BATCH = 8
"""Images whose maps are built together (the exact transform's calls are shared; memory stays ~40 MB per
512 x 512 grid)."""

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


def remap(images, models, grid: MapGrid, method: str = "bilinear", fill: int = 0, max_error_pixels: float = 0.05):
    """Remap images, each with its own scan model, into ``grid``.

    Args:
        images: sequence of ``(n_scans, n_pixels)`` arrays (NaN marks missing data).
        models: one :class:`ScanModel` per image.
        grid: the output :class:`MapGrid`.
        method: ``"bilinear"`` or ``"nearest"``.
        fill: passes of :func:`fill_holes` over missing data inside each swath (0: none).
        max_error_pixels: largest distance (source pixels) between the approximate and the exact source position
            of an output pixel; 0 takes the exact, differentiable JAX path (module docstring).

    Returns:
        ``(values, valid)``: ``(k, n_rows, n_columns)`` float64 (NaN outside a swath) and bool.
    """
    _check_method(method)
    if not max_error_pixels >= 0:
        raise SeaiceError(f"max_error_pixels must be >= 0 source pixels, got {max_error_pixels}")
    if len(images) != len(models):
        raise SeaiceError(f"{len(images)} images but {len(models)} scan models")
    for k, (image, model) in enumerate(zip(images, models, strict=True)):
        if np.shape(image) != (model.n_scans, model.n_pixels):
            raise SeaiceError(f"image {k}: shape {np.shape(image)} does not match its scan model "
                              f"({model.n_scans} scan lines x {model.n_pixels} pixels)")
    if max_error_pixels == 0:
        values, valid = remap_exact(images, models, grid, method)
        swaths = swath_masks(models, grid) if fill else np.zeros_like(valid)
    else:
        values = np.full((len(images), *grid.shape), np.nan)
        valid = np.zeros((len(images), *grid.shape), bool)
        swaths = np.zeros((len(images), *grid.shape), bool)
        for members, transform in _batches(models, grid):
            batch = [np.asarray(images[k], float) for k in members]
            maps = approximate_maps(transform, len(members), grid.shape, max_error_pixels, step=_STEP,
                                    **_edges(batch[0].shape))
            near = [_near_missing(image, maps.row[i], maps.column[i], maps.ok[i], method, max_error_pixels)
                    for i, image in enumerate(batch)]
            maps = make_exact(transform, maps, np.stack(near))
            for i, k in enumerate(members):
                values[k], valid[k] = resample(batch[i], maps.row[i], maps.column[i], maps.ok[i], method)
                if fill:
                    swaths[k] = _inside(batch[i].shape, maps.row[i], maps.column[i], maps.ok[i])
    if fill:
        for k in range(len(images)):
            filled = np.asarray(fill_holes(jnp.asarray(values[k]), jnp.asarray(valid[k]), fill))
            values[k] = np.where(swaths[k], filled, np.nan)
            valid[k] = np.isfinite(values[k])
    return values, valid


def remap_exact(images, models, grid: MapGrid, method: str = "bilinear"):
    """:func:`remap` through the exact inverse of every output pixel and a JAX gather: images with the same
    direction and size go through one jitted, ``vmap``-ped call (one compilation per group and grid shape);
    differentiable inside (:func:`sample`).

    Returns:
        ``(values, valid)`` as :func:`remap` (no fill).
    """
    _check_method(method)
    values = np.full((len(images), *grid.shape), np.nan)
    valid = np.zeros((len(images), *grid.shape), bool)
    for members in _groups(models).values():
        batch = jnp.stack([jnp.asarray(images[k], float) for k in members])
        v, ok = _remap_batch(batch, stack_models([models[k] for k in members]), grid, method)
        values[members], valid[members] = np.asarray(v), np.asarray(ok)
    return values, valid


def scan_maps(models, grid: MapGrid, max_error_pixels: float = 0.05) -> SourceMaps:
    """Where each pixel of ``grid`` lies in each model's image: 0-based source (row, column) = (scan line − 1,
    pixel − 1), within ``max_error_pixels`` of the exact inverse scan model (0: exact; see
    :mod:`seaice_jax.imagery.approximate`). The maps extend beyond the image (``ok`` is true everywhere the
    inverse is defined)."""
    count = len(models)
    row, column = np.empty((count, *grid.shape)), np.empty((count, *grid.shape))
    ok, exact_points = np.empty((count, *grid.shape), bool), 0
    for members, transform in _batches(models, grid):
        maps = approximate_maps(transform, len(members), grid.shape, max_error_pixels, step=_STEP)
        row[members], column[members], ok[members] = maps.row, maps.column, maps.ok
        exact_points += maps.exact_points
    return SourceMaps(row, column, ok, exact_points)


def resample(image, row, column, ok, method: str = "bilinear"):
    """``image`` at 0-based source maps ``(row, column)`` (``(n_rows, n_columns)``, defined where ``ok``), with
    the masks of :func:`sample`: NaN outside the image (pixel centres ± 0.5) and wherever a sampled pixel is
    missing (NaN). Bilinear by ``cv2.remap`` (weights quantised to 1/32 pixel), nearest by a gather (half away
    from zero, as :func:`sample`).

    Returns:
        ``(values, valid)``: ``(n_rows, n_columns)`` float64 and bool.
    """
    image = np.asarray(image, float)
    inside = _inside(image.shape, row, column, ok)
    finite = np.isfinite(image)
    if method == "nearest":
        value = image[_pixel(row, image.shape[0], inside, 0.5), _pixel(column, image.shape[1], inside, 0.5)]
        valid = inside & np.isfinite(value)
        return np.where(valid, value, np.nan), valid
    # float32 maps clamped at the outermost half pixel as `sample`; outside the image, a position that reads only
    # the border (NaN)
    outside = ~inside
    r, c = (_clamped(position, size, outside) for position, size in zip((row, column), image.shape, strict=True))
    complete = bool(finite.all())
    # one more row and column (copies of the last) for the zero-weight neighbour at the last row and column
    padded = np.pad(image if complete else np.where(finite, image, 0.0), ((0, 1), (0, 1)), mode="edge")
    value = cv2.remap(padded, c, r, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    if complete:
        return value, inside
    # missing data: the four pixels that `sample` reads (floor and next, clamped) must all be present
    padded = np.pad(finite, ((0, 1), (0, 1)), mode="edge")
    block = padded[:-1, :-1] & padded[1:, :-1] & padded[:-1, 1:] & padded[1:, 1:]
    valid = inside & block[_pixel(row, image.shape[0], inside, 0.0), _pixel(column, image.shape[1], inside, 0.0)]
    return np.where(valid, value, np.nan), valid


def _inside(shape, row, column, ok):
    """Where source positions fall on an image of ``shape`` (pixel centres ± 0.5), as in :func:`sample`."""
    rows, columns = shape
    inside = row >= -0.5
    inside &= row <= rows - 0.5
    inside &= column >= -0.5
    inside &= column <= columns - 0.5
    inside &= ok
    return inside


def _pixel(position, size, inside, shift):
    """The pixel ``floor(position + shift)`` of float64 positions clamped to [0, size − 1] (0 outside): the one
    :func:`sample` reads (nearest: shift 0.5), or the first of two (bilinear: 0)."""
    clamped = np.clip(np.where(inside, position, 0.0), 0.0, size - 1.0)
    return np.floor(clamped + shift).astype(int)


def _clamped(position, size, outside):
    """float32 ``position`` clamped to [0, size − 1] (float32 rounding is monotone: the same as clamping first),
    −2 where ``outside``."""
    clamped = position.astype(np.float32)
    np.clip(clamped, 0.0, size - 1.0, out=clamped)
    np.copyto(clamped, np.float32(-2.0), where=outside)
    return clamped


def _near_missing(image, row, column, ok, method, max_error):
    """Where a source position within ``max_error`` of ``(row, column)`` could read other pixels of ``image``
    and missing data (NaN) lies within two pixels (``(n_rows, n_columns)`` bool; none if nothing is missing)."""
    missing = ~np.isfinite(image)
    if not missing.any():
        return np.zeros(np.shape(row), bool)
    near_missing = cv2.dilate(missing.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    shift = 0.5 if method == "nearest" else 0.0  # nearest reads floor(x + 0.5), bilinear floor(x) and the next
    crossing, nearest = np.zeros(np.shape(row), bool), []
    for position, size in zip((row, column), np.shape(image), strict=True):
        position = np.where(ok, position, 0.0)
        low, high = (np.clip(position + d, 0.0, size - 1.0) for d in (-max_error, max_error))
        crossing |= np.floor(low + shift) != np.floor(high + shift)
        nearest.append(np.clip(np.floor(position + 0.5), 0, size - 1).astype(int))
    return crossing & near_missing[nearest[0], nearest[1]] & ok


def _edges(shape):
    """Keywords of :func:`approximate_maps`: the source rows and columns where :func:`sample` decides between
    inside and outside an image of ``shape``."""
    rows, columns = shape
    return {"row_edges": (-0.5, rows - 0.5), "column_edges": (-0.5, columns - 0.5)}


def _groups(models):
    groups = {}
    for k, model in enumerate(models):
        groups.setdefault((model.direction, model.n_pixels, model.n_scans), []).append(k)
    return groups


def _batches(models, grid):
    """``(members, transform)`` for batches of up to ``_BATCH`` images of one group: the exact transform of
    :mod:`seaice_jax.imagery.approximate` for those images."""
    for members in _groups(models).values():
        group = [models[k] for k in members]
        stacked = jax.tree.map(lambda *leaves: np.stack([np.asarray(v) for v in leaves]), *group)
        for start in range(0, len(members), _BATCH):
            chunk = members[start: start + _BATCH]
            yield chunk, functools.partial(_scan_transform, stacked, start, grid)


def _scan_transform(stacked, offset, grid, image, row, column):
    models = jax.tree.map(lambda leaf: leaf[image + offset], stacked)
    return _scan_points(models, grid, row, column)


@eqx.filter_jit
def _scan_points(models, grid, row, column):
    """Exact 0-based source ``(row, column)`` of output pixels ``(row, column)`` ``(n,)``, each through its own
    model (leaves with a leading ``(n,)`` axis), and ``ok`` (true: the closed-form inverse is defined
    everywhere)."""
    latitude, longitude = grid.projection.inverse(*grid.to_xy(row, column))
    pixel, scan = jax.vmap(lambda model, lat, lon: model.inverse(lat, lon))(models, latitude, longitude)
    return scan - 1.0, pixel - 1.0, jnp.ones(row.shape, bool)


def _check_method(method):
    if method not in METHODS:
        raise SeaiceError(f"method must be one of {', '.join(METHODS)}, got {method!r}")


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
                       look_side: LookSide, grid: MapGrid, method: str = "bilinear", radius: float = MEAN_RADIUS,
                       max_error_pixels: float = 0.05):
    """Remap a radar strip into ``grid`` through the range-Doppler inverse (source 000 eqs A1, A2, A5 backwards).

    Each output pixel's ground point (on the sphere) gives its imaging time (zero Doppler along ``navigation``)
    and slant range; the time marks give x (eq. A1 inverted), sweep delay and range scale give y = r / f − c
    (eq. A2 inverted), and the strip is sampled there. Pixels on the other side of the flight line, before or after
    the strip, or outside the raster are masked.

    Args:
        navigation: the strip's trajectory ``t -> (position, velocity)`` (e.g.
            :func:`~seaice_jax.sensors.strips.strip_navigation`). mark_x, mark_times: ``(n,)`` time marks (mm, s).
        sweep_delay: c, mm. range_scale: f, m/mm. look_side: ``"right"`` or ``"left"``.
        max_error_pixels: as :func:`remap`: the approximate transformer within this many raster pixels, then
            ``cv2.remap``; 0: the exact inverse of every output pixel and a JAX gather (differentiable inside).

    Returns:
        ``(values, valid)``: ``(n_rows, n_columns)``.
    """
    _check_method(method)
    if not max_error_pixels >= 0:
        raise SeaiceError(f"max_error_pixels must be >= 0 raster pixels, got {max_error_pixels}")
    arguments = (raster, navigation, jnp.asarray(mark_x, float), jnp.asarray(mark_times, float), float(sweep_delay),
                 float(range_scale), float(look_sign(look_side)), float(radius), grid)
    if max_error_pixels == 0:
        values, valid = _orthorectify(*arguments, method)
        return np.asarray(values), np.asarray(valid)
    transform = functools.partial(_strip_transform, arguments)
    data = np.asarray(raster.data, float)
    maps = approximate_maps(transform, 1, grid.shape, max_error_pixels, step=_STEP, **_edges(data.shape))
    near = _near_missing(data, maps.row[0], maps.column[0], maps.ok[0], method, max_error_pixels)
    maps = make_exact(transform, maps, near[None])
    return resample(data, maps.row[0], maps.column[0], maps.ok[0], method)


def _strip_coordinates(raster, navigation, mark_x, mark_times, sweep_delay, range_scale, sign, radius, latitude,
                       longitude):
    """0-based raster ``(row, column)`` of ground points (radians, any shape) and ``ok``: on the look side, imaged
    within the strip's time marks."""
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
    return row, column, side & (time >= mark_times[0]) & (time <= mark_times[-1])


@eqx.filter_jit
def _orthorectify(raster, navigation, mark_x, mark_times, sweep_delay, range_scale, sign, radius, grid, method):
    row, column, ok = _strip_coordinates(raster, navigation, mark_x, mark_times, sweep_delay, range_scale, sign,
                                         radius, *grid.latitude_longitude())
    value = sample(raster.data, row, column, method)
    inside = ok & jnp.isfinite(value)
    return jnp.where(inside, value, jnp.nan), inside


def _strip_transform(arguments, image, row, column):
    del image  # one strip
    return _strip_points(arguments, row, column)


@eqx.filter_jit
def _strip_points(arguments, row, column):
    """:func:`_strip_coordinates` of output pixels ``(row, column)`` ``(n,)``; ``arguments`` as
    :func:`_orthorectify` takes them (the grid last)."""
    raster, navigation, mark_x, mark_times, sweep_delay, range_scale, sign, radius, grid = arguments
    latitude, longitude = grid.projection.inverse(*grid.to_xy(row, column))
    return _strip_coordinates(raster, navigation, mark_x, mark_times, sweep_delay, range_scale, sign, radius,
                              latitude, longitude)
