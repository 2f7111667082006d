"""The coastline: GSHHG shorelines at full resolution, offline, clipped to a region, projected, and as a land mask.

The source is GSHHG (Wessel & Smith 1996, "A global, self-consistent, hierarchical, high-resolution shoreline
database", J. Geophys. Res. 101(B4)) at its full resolution (~100 m), as shipped inside the ``roaring-landmask`` wheel
(MET Norway, the land mask OpenDrift uses): no download at run time, the same polygons for drawing the coast, for the
simulated scenes' land and for land masks, so a figure's coast and a mask's land never disagree. GSHHG level 1 is the
land-sea boundary; its lakes (level 2) are not in these polygons (land in lakes counts as land), which for sea ice is
what is wanted. Natural Earth (cartopy's default) was not chosen: cartopy downloads it at first use, and its 1:10 m
coast is 5-10 times coarser than a 1 km AVHRR pixel needs.

Loading the world's polygons takes ~2.5-4 s once per process; a region is clipped from them in 0.02-0.3 s and kept
on disk (:func:`coastline_cache_folder`), so later processes asking for the same box skip the load.
Longitudes are degrees east in [-180, 180], latitudes degrees north.
"""

import functools
import importlib
import importlib.metadata
import os
from dataclasses import dataclass
from pathlib import Path

import equinox as eqx
import numpy as np

from seaice_jax._shapes import bucket, pad
from seaice_jax.errors import SeaiceError
from seaice_jax.files import atomic_path
from seaice_jax.geometry.crs import CrsProjection

COASTLINE_CACHE_VARIABLE = "SEAICE_COASTLINE_CACHE_DIR"
"""Environment variable naming the folder of clipped coastline regions (empty: no cache on disk)."""


@eqx.filter_jit
def _call(function, *arrays):
    return function(*arrays)


def bucketed(function, *arrays) -> tuple[np.ndarray, ...]:
    """``function(*arrays)`` (a JAX function of equal-shape arrays, elementwise, e.g. a projection's bound
    ``forward``/``inverse`` or a scan model's ``inverse``) as NumPy arrays, evaluated under ``jit`` with the
    flattened arrays padded (with their first element, or zeros) to a bucket length
    (:func:`~seaice_jax._shapes.bucket`): drawing calls such functions with ever-changing lengths; eagerly, each
    call would compile every operation again (seconds), jitted, each length once."""
    arrays = [np.asarray(a, float) for a in np.broadcast_arrays(*arrays)]
    owner = getattr(function, "__self__", None)
    if isinstance(owner, CrsProjection):  # PROJ on the host: nothing to compile, and no callback inside jit (it
        # waited for ever on its own input under the tests' one XLA thread: tests/test_any_grid.py)
        return owner.host_transform(*arrays, inverse=function.__name__ == "inverse")
    shape = arrays[0].shape
    size = arrays[0].size
    length = max(bucket(size), 16)
    padded = [pad(a.ravel(), length, a.flat[0] if size else 0.0) for a in arrays]
    return tuple(np.asarray(value, float)[:size].reshape(shape) for value in _call(function, *padded))


@functools.cache
def _world():
    """``(polygons, tree)``: every GSHHG land polygon (shapely, lon/lat degrees) and an STRtree over them."""
    import shapely

    roaring_landmask = importlib.import_module("roaring_landmask")  # a compiled module without type stubs

    world = shapely.from_wkb(roaring_landmask.Shapes.wkb(roaring_landmask.LandmaskProvider.Gshhg))
    polygons = np.asarray(world.geoms)
    return polygons, shapely.STRtree(polygons)


def _runs(points: np.ndarray, joined: np.ndarray) -> list[np.ndarray]:
    """The polylines of ``points`` ``(n, 2)`` whose consecutive vertices ``k``, ``k + 1`` are joined where
    ``joined[k]`` (``(n - 1,)`` bool): one array per run of joined segments (isolated vertices are dropped)."""
    before = np.concatenate([[False], joined[:-1]])
    after = np.concatenate([joined[1:], [False]])
    starts, ends = np.flatnonzero(joined & ~before), np.flatnonzero(joined & ~after)
    return [points[start:end + 2] for start, end in zip(starts, ends, strict=True)]


def _joined_lines(lines: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """All vertices of ``lines`` in one ``(n, 2)`` array and ``(n - 1,)`` bool: the segment k -> k + 1 lies within a
    line."""
    if not lines:
        return np.zeros((0, 2)), np.zeros(0, bool)
    index = np.repeat(np.arange(len(lines)), [len(line) for line in lines])
    return np.concatenate(lines), index[:-1] == index[1:]


def _to_plane(projection, longitude_latitude: np.ndarray) -> np.ndarray:
    """``(n, 2)`` (longitude, latitude) degrees -> ``(n, 2)`` (x, y) metres of ``projection``."""
    return np.column_stack(bucketed(projection.forward, np.radians(longitude_latitude[:, 1]),
                                    np.radians(longitude_latitude[:, 0])))


@dataclass(frozen=True)
class Coastline:
    """The land polygons of a longitude/latitude box (shapely polygons in degrees, clipped to the box).

    ``bounds``: ``(west, south, east, north)`` degrees. A box crossing the antimeridian has ``west > east``.
    GSHHG level-1 polygons have no holes (lakes are level 2, not shipped), so each polygon is its exterior ring.
    """

    polygons: tuple
    bounds: tuple[float, float, float, float]

    def rings(self) -> list[np.ndarray]:
        """Every boundary ring (exterior and holes) as a ``(n, 2)`` array of (longitude, latitude) degrees.

        Rings are the polygons' boundaries after clipping, so they include the box's edges where land meets them;
        use :meth:`shorelines` for the coast alone.
        """
        import shapely

        coordinates, index = shapely.get_coordinates(shapely.get_rings(list(self.polygons)), return_index=True)
        return np.split(coordinates, np.flatnonzero(np.diff(index)) + 1) if len(coordinates) else []

    @functools.cached_property
    def _shorelines(self) -> list[np.ndarray]:
        points, joined = _joined_lines(self.rings())
        if not len(points):
            return []
        west, south, east, north = self.bounds
        longitude, latitude = points[:, 0], points[:, 1]
        on_edge = (np.isclose(latitude, south) | np.isclose(latitude, north)
                   | np.isclose(np.abs(longitude), 180.0)  # GSHHG splits its polygons at the antimeridian
                   | np.isclose(longitude, west) | np.isclose(longitude, east))
        return _runs(points, joined & ~(on_edge[:-1] & on_edge[1:]))  # a segment along the box's edge is not coast

    def shorelines(self) -> list[np.ndarray]:
        """The coast itself: the rings with the parts that run along the clipping box's edges (and the antimeridian,
        where GSHHG splits its polygons) removed, as ``(n, 2)`` (longitude, latitude) arrays — what a map draws as
        the coastline."""
        return list(self._shorelines)

    def projected(self, projection, tolerance: float = 0.0) -> list[np.ndarray]:
        """:meth:`shorelines` in a projection's plane coordinates: ``(n, 2)`` arrays of (x, y) metres
        (``projection``: any of :mod:`seaice_jax.geometry.projections`, ``forward(latitude, longitude)``).

        Lines are broken where the projection gives NaN (a tangent plane's far side). ``tolerance`` > 0 (metres)
        simplifies each line (Douglas-Peucker) to within that distance, e.g. a figure's pixel, for fast drawing.
        """
        import shapely

        longitude_latitude, joined = _joined_lines(self.shorelines())
        if not len(longitude_latitude):
            return []
        points = _to_plane(projection, longitude_latitude)
        finite: np.ndarray = np.all(np.isfinite(points), axis=1)
        lines = _runs(points, joined & finite[:-1] & finite[1:])
        if tolerance <= 0 or not lines:
            return lines
        geometries = shapely.simplify(shapely.linestrings(np.concatenate(lines), indices=np.repeat(
            np.arange(len(lines)), [len(line) for line in lines])), tolerance, preserve_topology=False)
        coordinates, index = shapely.get_coordinates(geometries, return_index=True)
        return np.split(coordinates, np.flatnonzero(np.diff(index)) + 1)

    def projected_polygons(self, projection, tolerance: float = 0.0, step: float = 0.05) -> list:
        """The land polygons in a projection's plane (shapely, metres), for filling land on a map: edges longer
        than ``step`` degrees (the clipping box's) are first divided so they follow the projection's curves;
        ``tolerance`` > 0 metres simplifies them (islands smaller than that may vanish); polygons touching the
        projection's NaN region are left out."""
        import shapely

        if not self.polygons:
            return []
        polygons = np.asarray(self.polygons, dtype=object)
        west, south, east, north = self.bounds
        bounds = shapely.bounds(polygons)
        clipped = (np.isclose(bounds[:, 0], west) | np.isclose(bounds[:, 2], east) | np.isclose(bounds[:, 1], south)
                   | np.isclose(bounds[:, 3], north))  # only these have the box's long straight edges
        polygons[clipped] = shapely.segmentize(polygons[clipped], step)
        polygons = shapely.transform(polygons, lambda points: _to_plane(projection, points))
        if tolerance > 0:
            polygons = shapely.simplify(polygons, tolerance, preserve_topology=False)
        coordinates, index = shapely.get_coordinates(polygons, return_index=True)
        bad = np.zeros(len(polygons), bool)
        bad[index[~np.isfinite(coordinates).all(axis=1)]] = True
        return [polygon for polygon, skip in zip(polygons, bad, strict=True) if not skip and not polygon.is_empty]

    @functools.cached_property
    def _index(self):
        """The polygons (prepared) and an STRtree over them, for :meth:`contains`."""
        import shapely

        polygons = np.asarray(self.polygons, dtype=object)
        shapely.prepare(polygons)
        return polygons, shapely.STRtree(polygons)

    def contains(self, latitude, longitude) -> np.ndarray:
        """``True`` where the point (degrees, any shape) is on land; points outside the box (or NaN) are ``False``.

        Candidates by the polygons' bounding boxes (STRtree), then point in (prepared) polygon: ~1 µs a point."""
        import shapely

        latitude, longitude = np.broadcast_arrays(np.asarray(latitude, float), np.asarray(longitude, float))
        land = np.zeros(latitude.size, bool)
        if not self.polygons:
            return land.reshape(latitude.shape)
        polygons, tree = self._index
        latitude_flat, longitude_flat = latitude.ravel(), longitude.ravel()
        finite = np.flatnonzero(np.isfinite(latitude_flat) & np.isfinite(longitude_flat))
        point, polygon = tree.query(shapely.points(longitude_flat[finite], latitude_flat[finite]))
        inside = shapely.contains_xy(polygons[polygon], longitude_flat[finite][point], latitude_flat[finite][point])
        land[finite[point[inside]]] = True
        return land.reshape(latitude.shape)


def _clip(west: float, south: float, east: float, north: float) -> list:
    import shapely

    polygons, tree = _world()
    box = shapely.box(west, south, east, north)
    clipped = shapely.clip_by_rect(polygons[tree.query(box)], west, south, east, north)
    return [part for geometry in clipped if not geometry.is_empty
            for part in getattr(geometry, "geoms", [geometry]) if part.geom_type == "Polygon" and part.area > 0]


def coastline_cache_folder() -> Path | None:
    """Folder of the clipped regions kept on disk: ``$SEAICE_COASTLINE_CACHE_DIR`` when set (empty: none), else
    ``$XDG_CACHE_HOME/seaice_jax/coastline`` (default ``~/.cache/seaice_jax/coastline``)."""
    if COASTLINE_CACHE_VARIABLE in os.environ:
        folder = os.environ[COASTLINE_CACHE_VARIABLE]
        return Path(folder).expanduser() if folder else None
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache").expanduser() / "seaice_jax" / "coastline"


def _clip_kept(west: float, south: float, east: float, north: float) -> list:
    """:func:`_clip`, read from / written to :func:`coastline_cache_folder` as WKB (exact doubles), one file per box
    and GSHHG release (the roaring-landmask version); a damaged or unwritable entry is simply computed again."""
    import shapely

    folder = coastline_cache_folder()
    if folder is None:
        return _clip(west, south, east, north)
    path = folder / f"gshhg-{importlib.metadata.version('roaring-landmask')}_{west!r}_{south!r}_{east!r}_{north!r}.wkb"
    if path.is_file():
        try:
            return list(shapely.get_parts(shapely.from_wkb(path.read_bytes())))
        except (OSError, shapely.errors.GEOSException):
            pass
    polygons = _clip(west, south, east, north)
    try:
        with atomic_path(path) as temporary:
            temporary.write_bytes(shapely.to_wkb(shapely.multipolygons(polygons) if polygons else
                                                 shapely.from_wkt("MULTIPOLYGON EMPTY")))
    except OSError:
        pass
    return polygons


@functools.lru_cache(maxsize=16)
def coastline(west: float, south: float, east: float, north: float) -> Coastline:
    """The GSHHG land of the box ``west``-``east`` degrees east, ``south``-``north`` degrees north (``west > east``:
    a box across the antimeridian). Cached per box within a process and on disk (:func:`coastline_cache_folder`)."""
    for name, value, low, high in (("west", west, -180, 180), ("east", east, -180, 180),
                                   ("south", south, -90, 90), ("north", north, -90, 90)):
        if not low <= value <= high:
            raise SeaiceError(f"coastline box: {name} = {value} degrees is outside [{low}, {high}]")
    if south >= north:
        raise SeaiceError(f"coastline box: south ({south}) must be below north ({north})")
    if west < east:
        polygons = _clip_kept(west, south, east, north)
    else:
        polygons = _clip_kept(west, south, 180.0, north) + _clip_kept(-180.0, south, east, north)
    return Coastline(tuple(polygons), (west, south, east, north))


def bounds_of_grid(grid, margin: float = 0.5) -> tuple[float, float, float, float]:
    """``(west, south, east, north)`` degrees covering a :class:`~seaice_jax.geometry.projections.MapGrid`'s pixel
    centres, widened by ``margin`` degrees; ``west > east`` across the antimeridian; a grid around a pole takes
    every longitude up to the pole."""
    latitude, longitude = (np.degrees(a) for a in bucketed(grid.projection.inverse, *grid.xy()))
    finite = np.isfinite(latitude) & np.isfinite(longitude)
    if not finite.any():
        raise SeaiceError("the map grid has no pixel with a latitude and longitude (all beyond the projection)")
    loop = np.concatenate([longitude[0, :], longitude[1:, -1], longitude[-1, -2::-1], longitude[-2:0:-1, 0]])
    loop = loop[np.isfinite(loop)]
    return outline_box(loop, float(latitude[finite].min()), float(latitude[finite].max()), margin)


def outline_box(longitude, south: float, north: float, margin: float) -> tuple[float, float, float, float]:
    """``(west, south, east, north)`` degrees of a region whose boundary runs through ``longitude`` (degrees, in
    order around it) and whose latitudes span ``south``-``north``, widened by ``margin`` degrees; ``west > east``
    across the antimeridian; a boundary winding around a pole takes every longitude up to the pole."""
    south, north = max(-90.0, south - margin), min(90.0, north + margin)
    turns = np.unwrap(np.radians(np.append(longitude, longitude[0])))
    if abs(turns[-1] - turns[0]) > np.pi:  # the boundary winds around a pole: every longitude
        return (-180.0, south, 180.0, 90.0) if north > 0 else (-180.0, -90.0, 180.0, north)
    if np.degrees(turns.max() - turns.min()) + 2 * margin >= 360.0:
        return -180.0, south, 180.0, north
    west = (float(np.degrees(turns.min())) - margin + 180.0) % 360.0 - 180.0
    east = (float(np.degrees(turns.max())) + margin + 180.0) % 360.0 - 180.0
    return west, south, east, north


def coastline_of_grid(grid, margin: float = 0.5) -> Coastline:
    """The coastline covering a :class:`~seaice_jax.geometry.projections.MapGrid` (:func:`bounds_of_grid`, widened
    by ``margin`` degrees)."""
    return coastline(*bounds_of_grid(grid, margin))


def land_mask_of_grid(grid) -> np.ndarray:
    """``bool[rows, columns]``: ``True`` where a :class:`~seaice_jax.geometry.projections.MapGrid` cell's centre is on
    GSHHG land."""
    latitude, longitude = bucketed(grid.projection.inverse, *grid.xy())
    return coastline_of_grid(grid).contains(np.degrees(latitude), np.degrees(longitude))
