"""An approximate transformer: source-pixel maps evaluated exactly on a coarse lattice of output pixels and
bilinearly in between, with the interpolation error bounded tile by tile.

GDAL's approximate transformer (``GDALApproxTransform``) does this along scan lines: the exact transform at the
ends and the middle of a run, linear interpolation when the middle misses by less than the threshold, else the
run is halved; a run where the exact transform fails at any of those points is transformed exactly. Here the
same idea on square tiles of output pixels, vectorised over tiles and images:

1. the exact transform at the corners of tiles of ``step`` x ``step`` output pixels and at each tile's centre and
   edge midpoints (its *checkpoints*);
2. a tile whose bilinear interpolation from its corners misses the exact source position at a checkpoint by
   more than the tolerance (Euclidean distance, source pixels) is split into four; the parent's checkpoints are
   the children's corners, so each level evaluates only the children's checkpoints. A tile of 2 x 2 pixels is
   exact: each of its pixels is a corner or a checkpoint;
3. a tile where the transform is defined (``ok``) at some of its nine samples but not all is split the same
   way, down to exact pixels; one undefined at all nine is undefined throughout. A straight boundary of the
   defined region (the flight line of a radar strip, the ends of its time span) that crosses a tile always
   separates its corners, so it never hides between samples (a boundary curving within a tile could);
4. where a decision is taken on the source position (inside or outside an image: ``row_edges``,
   ``column_edges``), the pixels whose approximate position lies within the threshold of an edge get the exact
   transform, so none falls on the other side of an edge than its exact position.

For a map that is quadratic over a tile the bilinear error is largest at the checkpoints (the x² term's error
peaks at the edge midpoints, the bilinear xy term is reproduced); the tolerance is ``_MARGIN`` times the
threshold to cover the higher-order terms. ``max_error=0`` evaluates every pixel exactly.
"""

from collections.abc import Callable

import equinox as eqx
import numpy as np

Transform = Callable[[np.ndarray, np.ndarray, np.ndarray], tuple]
"""``transform(image, row, column) -> (source_row, source_column, ok)``: the exact source position (0-based,
pixels) of output pixels ``(row, column)`` (0-based, float64, ``(n,)``) of images ``image`` (``(n,)`` int), and
whether it is defined there."""

_MARGIN = 0.5
"""Checkpoint tolerance as a fraction of the threshold (the higher-order terms between checkpoints)."""

_CHUNK = 8192
_SMALL = 512
"""The exact transform sees ``_CHUNK`` points per call while more than half of them remain, else ``_SMALL``
(padded): two compilations of a jitted transform, whatever the number of images and refinements."""

# the nine samples of a tile in half-tile units: four corners, then the checkpoints
_CORNERS = ((0, 0), (0, 2), (2, 0), (2, 2))
_CHECKPOINTS = ((1, 0), (0, 1), (1, 1), (1, 2), (2, 1))
_CHECKPOINT_CORNERS = ((0, 2), (0, 1), (0, 1, 2, 3), (1, 3), (2, 3))  # the corners each checkpoint lies between


class SourceMaps(eqx.Module):
    """Where each output pixel comes from in its image.

    Attributes:
        row, column: ``(k, n_rows, n_columns)`` float64, 0-based source position (pixels), NaN where not ``ok``.
        ok: ``(k, n_rows, n_columns)`` bool, where the transform is defined.
        exact_points: how many points went through the exact transform.
    """

    row: np.ndarray
    column: np.ndarray
    ok: np.ndarray
    exact_points: int


def evaluate(transform: Transform, image, row, column):
    """``transform`` at ``(n,)`` points, in padded chunks (see ``_CHUNK``); ``ok`` also requires finite output.

    Returns:
        ``(source_row, source_column, ok)``, ``(n,)`` each, NaN where not ok.
    """
    n = len(image)
    source_row, source_column, ok = np.full(n, np.nan), np.full(n, np.nan), np.zeros(n, bool)
    start = 0
    while start < n:
        size = _CHUNK if n - start > _CHUNK // 2 else _SMALL
        stop = min(n, start + size)
        filler = size - (stop - start)
        arguments = [np.concatenate([a[start:stop], np.full(filler, a[start])]) for a in (image, row, column)]
        r, c, defined = (np.asarray(v)[: stop - start] for v in transform(*arguments))
        good = defined & np.isfinite(r) & np.isfinite(c)
        source_row[start:stop] = np.where(good, r, np.nan)
        source_column[start:stop] = np.where(good, c, np.nan)
        ok[start:stop] = good
        start = stop
    return source_row, source_column, ok


def exact_maps(transform: Transform, count: int, shape: tuple[int, int]) -> SourceMaps:
    """The exact transform at every output pixel of ``count`` images into a grid of ``shape``."""
    image, row, column = (a.ravel() for a in np.meshgrid(np.arange(count), np.arange(shape[0], dtype=float),
                                                          np.arange(shape[1], dtype=float), indexing="ij"))
    source_row, source_column, ok = evaluate(transform, image, row, column)
    full = (count, *shape)
    return SourceMaps(source_row.reshape(full), source_column.reshape(full), ok.reshape(full), image.size)


def approximate_maps(transform: Transform, count: int, shape: tuple[int, int], max_error: float = 0.05,
                     step: int = 32, row_edges=(), column_edges=()) -> SourceMaps:
    """Source-pixel maps of ``count`` images into a grid of ``shape`` within ``max_error`` source pixels of the
    exact transform (module docstring).

    Args:
        transform: the exact transform (see :data:`Transform`).
        max_error: source pixels; 0 evaluates every pixel exactly.
        step: the coarsest tile, output pixels (a power of two, at least 2).
        row_edges, column_edges: source rows and columns where a decision is taken (an image's edges, say): the
            pixels whose approximate position lies within ``max_error`` of one get the exact transform, so no
            approximate position falls on the other side of an edge than the exact one.
    """
    if not max_error >= 0:
        raise ValueError(f"max_error must be >= 0 source pixels, got {max_error}")
    if step < 2 or step & (step - 1):
        raise ValueError(f"step must be a power of two >= 2, got {step}")
    if max_error == 0:
        return exact_maps(transform, count, shape)
    tolerance = _MARGIN * max_error
    height, width = (-(-n // step) * step for n in shape)
    samples = _Samples(transform, count, height + 1, width + 1)
    image, top, left = (a.ravel() for a in np.meshgrid(np.arange(count), np.arange(0, height, step),
                                                       np.arange(0, width, step), indexing="ij"))
    samples.add(image, top, left, step, step // 2)
    maps = [_dense_bilinear(v[:, ::step, ::step], step) for v in (samples.row, samples.column)]
    ok = np.ones((count, height, width), bool)
    near_edges = []  # accepted tiles (image, top, left, size) whose range of positions reaches an edge
    size = step
    while image.size:
        half = size // 2
        rows, columns, defined = samples.tile_samples(image, top, left, half)
        error = np.zeros(image.size)
        for k, corners in enumerate(_CHECKPOINT_CORNERS):
            miss = [v[:, 4 + k] - v[:, list(corners)].mean(axis=1) for v in (rows, columns)]
            error = np.maximum(error, np.hypot(*miss))
        accept, none_defined = defined.all(axis=1) & (error <= tolerance), ~defined.any(axis=1)
        tiles = [a.reshape(count, height // size, size, width // size, size) for a in (ok, *maps)]
        if size < step:  # the coarsest tiles are filled already
            where = (image[accept], top[accept] // size, slice(None), left[accept] // size, slice(None))
            tiles[0][where] = True
            for tile, v in zip(tiles[1:], (rows, columns), strict=True):
                tile[where] = _bilinear(v[accept, :4], size)
        tiles[0][image[none_defined], top[none_defined] // size, :, left[none_defined] // size, :] = False
        near = accept & (_reaches(rows[:, :4], row_edges, max_error) | _reaches(columns[:, :4], column_edges,
                                                                               max_error))
        near_edges.append((image[near], top[near], left[near], size))
        split = ~accept & ~none_defined
        image, top, left = image[split], top[split], left[split]
        if half == 1:  # 2 x 2 tiles: every pixel is a sample
            samples.copy_exact(image, top, left, ok, *maps)
            break
        image, top, left = (np.concatenate([a + da for da in offsets]) for a, offsets in
                            ((image, (0, 0, 0, 0)), (top, (0, 0, half, half)), (left, (0, half, 0, half))))
        size = half
        samples.add(image, top, left, size, size // 2)
    maps = SourceMaps(maps[0], maps[1], ok, samples.evaluated)
    maps = make_exact(transform, maps, _pixels_near(maps, near_edges, row_edges, column_edges, max_error))
    if not ok.all():
        maps = SourceMaps(np.where(ok, maps.row, np.nan), np.where(ok, maps.column, np.nan), ok, maps.exact_points)
    if (height, width) == tuple(shape):
        return maps
    return SourceMaps(maps.row[:, : shape[0], : shape[1]], maps.column[:, : shape[0], : shape[1]],
                      maps.ok[:, : shape[0], : shape[1]], maps.exact_points)


def make_exact(transform: Transform, maps: SourceMaps, where) -> SourceMaps:
    """``maps`` with the exact transform at the pixels where ``where`` (``(k, n_rows, n_columns)`` bool) holds, or
    at the flat indices ``where`` (written in place; returned with ``exact_points`` counted)."""
    image, row, column = np.nonzero(where) if np.ndim(where) == 3 else np.unravel_index(where, maps.ok.shape)
    if image.size:
        source_row, source_column, ok = evaluate(transform, image, row.astype(float), column.astype(float))
        maps.row[image, row, column], maps.column[image, row, column] = source_row, source_column
        maps.ok[image, row, column] = ok
    return SourceMaps(maps.row, maps.column, maps.ok, maps.exact_points + image.size)


def _dense_bilinear(nodes, step):
    """``(k, (m − 1)·step, (n − 1)·step)`` bilinear interpolation of ``(k, m, n)`` values ``step`` pixels apart."""
    u = np.arange(step) / step
    count, m, n = nodes.shape
    along = (nodes[:, :-1, None, :] + (nodes[:, 1:] - nodes[:, :-1])[:, :, None, :] * u[:, None]).reshape(
        count, (m - 1) * step, n)
    out = np.empty((count, (m - 1) * step, n - 1, step))
    np.multiply((along[:, :, 1:] - along[:, :, :-1])[..., None], u, out=out)
    out += along[:, :, :-1, None]
    return out.reshape(count, (m - 1) * step, (n - 1) * step)


def _reaches(corners, edges, margin):
    """``(t,)``: whether a tile whose ``(t, 4)`` corner values bound its values comes within ``margin`` of an
    edge."""
    low, high = corners.min(axis=1) - margin, corners.max(axis=1) + margin
    return np.any([(low <= edge) & (edge <= high) for edge in edges], axis=0) if len(edges) else np.zeros(
        len(corners), bool)


def _pixels_near(maps, tiles, row_edges, column_edges, margin):
    """Flat indices of the pixels of ``tiles`` whose position lies within ``margin`` of an edge."""
    flat = []
    for image, top, left, size in tiles:
        offsets = np.arange(size)
        pixels = np.ravel_multi_index((image[:, None, None], top[:, None, None] + offsets[:, None],
                                       left[:, None, None] + offsets), maps.ok.shape).ravel()
        near = np.zeros(pixels.size, bool)
        for values, edges in ((maps.row, row_edges), (maps.column, column_edges)):
            v = values.ravel()[pixels]
            for edge in edges:
                near |= np.abs(v - edge) <= margin
        flat.append(pixels[near])
    return np.concatenate(flat) if flat else np.zeros(0, int)


def _bilinear(corners, size):
    """``(t, size, size)`` bilinear interpolation inside tiles from their ``(t, 4)`` corner values (top left, top
    right, bottom left, bottom right), at 0 .. size − 1 output pixels from the top left."""
    u = np.arange(size) / size
    left = corners[:, 0, None] + (corners[:, 2] - corners[:, 0])[:, None] * u
    right = corners[:, 1, None] + (corners[:, 3] - corners[:, 1])[:, None] * u
    return left[:, :, None] + (right - left)[:, :, None] * u


class _Samples:
    """The exact transform's values on the lattice of output pixels, evaluated once each, on demand."""

    def __init__(self, transform, count, rows, columns):
        self.transform = transform
        self.row = np.empty((count, rows, columns))  # read only where known
        self.column = np.empty((count, rows, columns))
        self.ok = np.empty((count, rows, columns), bool)
        self.known = np.zeros((count, rows, columns), bool)
        self.evaluated = 0

    def add(self, image, top, left, size, spacing):
        """Evaluate the points ``spacing`` apart inside the tiles (``size`` pixels) not evaluated yet."""
        offsets = np.arange(0, size + 1, spacing)
        rows = (top[:, None] + offsets).repeat(offsets.size, axis=1)
        columns = np.tile(left[:, None] + offsets, offsets.size)
        images = np.broadcast_to(image[:, None], rows.shape)
        flat = np.unique(np.ravel_multi_index((images.ravel(), rows.ravel(), columns.ravel()), self.ok.shape))
        flat = flat[~self.known.ravel()[flat]]
        if flat.size:
            i, r, c = np.unravel_index(flat, self.ok.shape)
            values = evaluate(self.transform, i, r.astype(float), c.astype(float))
            for array, value in zip((self.row, self.column, self.ok), values, strict=True):
                np.put(array, flat, value)
            np.put(self.known, flat, True)
            self.evaluated += flat.size

    def tile_samples(self, image, top, left, half):
        """``(t, 9)`` rows, columns and ok at each tile's corners and checkpoints (order of ``_CORNERS`` then
        ``_CHECKPOINTS``)."""
        offsets = np.array(_CORNERS + _CHECKPOINTS) * half
        where = (image[:, None], top[:, None] + offsets[:, 0], left[:, None] + offsets[:, 1])
        return self.row[where], self.column[where], self.ok[where]

    def copy_exact(self, image, top, left, ok, row, column):
        """Copy the samples of 2 x 2 tiles (all evaluated) into the maps."""
        for dr in (0, 1):
            for dc in (0, 1):
                where = (image, top + dr, left + dc)
                ok[where], row[where], column[where] = self.ok[where], self.row[where], self.column[where]
