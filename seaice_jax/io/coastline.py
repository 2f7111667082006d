"""The coastline: GSHHG shorelines at full resolution, offline, clipped to a region, projected, and as a land mask.

The source is GSHHG (Wessel & Smith 1996, "A global, self-consistent, hierarchical, high-resolution shoreline
database", J. Geophys. Res. 101(B4)) at its full resolution (~100 m), as shipped inside the ``roaring-landmask`` wheel
(MET Norway, the land mask OpenDrift uses): no download at run time, the same polygons for drawing the coast, for the
simulated scenes' land and for land masks, so a figure's coast and a mask's land never disagree. GSHHG level 1 is the
land-sea boundary; its lakes (level 2) are not in these polygons (land in lakes counts as land), which for sea ice is
what is wanted. Natural Earth (cartopy's default) was not chosen: cartopy downloads it at first use, and its 1:10 m
coast is 5-10 times coarser than a 1 km AVHRR pixel needs.

Loading the world's polygons takes ~2.5 s once per process (cached); a region is clipped from them in ~0.3 s.
Longitudes are degrees east in [-180, 180], latitudes degrees north.
"""

import functools
import importlib
from dataclasses import dataclass

import numpy as np

from seaice_jax.errors import SeaiceError


@functools.cache
def _world():
    """``(polygons, tree)``: every GSHHG land polygon (shapely, lon/lat degrees) and an STRtree over them."""
    import shapely

    roaring_landmask = importlib.import_module("roaring_landmask")  # a compiled module without type stubs

    world = shapely.from_wkb(roaring_landmask.Shapes.wkb(roaring_landmask.LandmaskProvider.Gshhg))
    polygons = np.asarray(world.geoms)
    return polygons, shapely.STRtree(polygons)


@dataclass(frozen=True)
class Coastline:
    """The land polygons of a longitude/latitude box (shapely polygons in degrees, clipped to the box).

    ``bounds``: ``(west, south, east, north)`` degrees. A box crossing the antimeridian has ``west > east``.
    """

    polygons: tuple
    bounds: tuple[float, float, float, float]

    def rings(self) -> list[np.ndarray]:
        """Every boundary ring (exterior and holes) as a ``(n, 2)`` array of (longitude, latitude) degrees.

        Rings are the polygons' boundaries after clipping, so they include the box's edges where land meets them;
        use :meth:`shorelines` for the coast alone.
        """
        import shapely

        return [np.asarray(ring.coords) for polygon in self.polygons for ring in
                shapely.get_rings(polygon)]

    def shorelines(self) -> list[np.ndarray]:
        """The coast itself: the rings with the parts that run along the clipping box's edges removed, as ``(n, 2)``
        (longitude, latitude) arrays — what a map draws as the coastline."""
        west, south, east, north = self.bounds
        pieces = []
        for ring in self.rings():
            lon, lat = ring[:, 0], ring[:, 1]
            on_edge = (np.isclose(lon, west) | np.isclose(lon, east) | np.isclose(lat, south)
                       | np.isclose(lat, north))
            keep = ~(on_edge[:-1] & on_edge[1:])  # a segment along the box's edge is not coast
            start = 0
            for stop in [*np.flatnonzero(~keep), len(keep)]:
                if stop > start:
                    pieces.append(ring[start:stop + 1])
                start = stop + 1
        return pieces

    def projected(self, projection) -> list[np.ndarray]:
        """:meth:`shorelines` in a projection's plane coordinates: ``(n, 2)`` arrays of (x, y) metres
        (``projection``: any of :mod:`seaice_jax.geometry.projections`, ``forward(latitude, longitude)``)."""
        out = []
        for line in self.shorelines():
            x, y = projection.forward(np.radians(line[:, 1]), np.radians(line[:, 0]))
            out.append(np.column_stack([np.asarray(x), np.asarray(y)]))
        return out

    def contains(self, latitude, longitude) -> np.ndarray:
        """``True`` where the point (degrees, any shape) is on land; points outside the box are ``False``."""
        import shapely

        latitude, longitude = np.broadcast_arrays(np.asarray(latitude, float), np.asarray(longitude, float))
        if not self.polygons:
            return np.zeros(latitude.shape, bool)
        land = shapely.union_all(list(self.polygons))
        shapely.prepare(land)
        return shapely.contains_xy(land, longitude, latitude)


def _clip(west: float, south: float, east: float, north: float) -> list:
    import shapely

    polygons, tree = _world()
    box = shapely.box(west, south, east, north)
    clipped = shapely.clip_by_rect(polygons[tree.query(box)], west, south, east, north)
    return [part for geometry in clipped if not geometry.is_empty
            for part in getattr(geometry, "geoms", [geometry]) if part.geom_type == "Polygon" and part.area > 0]


@functools.lru_cache(maxsize=16)
def coastline(west: float, south: float, east: float, north: float) -> Coastline:
    """The GSHHG land of the box ``west``-``east`` degrees east, ``south``-``north`` degrees north (``west > east``:
    a box across the antimeridian). Cached per box within a process."""
    for name, value, low, high in (("west", west, -180, 180), ("east", east, -180, 180),
                                   ("south", south, -90, 90), ("north", north, -90, 90)):
        if not low <= value <= high:
            raise SeaiceError(f"coastline box: {name} = {value} degrees is outside [{low}, {high}]")
    if south >= north:
        raise SeaiceError(f"coastline box: south ({south}) must be below north ({north})")
    if west < east:
        polygons = _clip(west, south, east, north)
    else:
        polygons = _clip(west, south, 180.0, north) + _clip(-180.0, south, east, north)
    return Coastline(tuple(polygons), (west, south, east, north))


def coastline_of_grid(grid, margin: float = 0.5) -> Coastline:
    """The coastline covering a :class:`~seaice_jax.geometry.projections.MapGrid` (its edges' latitude/longitude box,
    widened by ``margin`` degrees; a grid around a pole takes every longitude up to the pole)."""
    latitude, longitude = grid.latitude_longitude()
    latitude, longitude = np.degrees(np.asarray(latitude)), np.degrees(np.asarray(longitude))
    loop = np.concatenate([longitude[0, :], longitude[1:, -1], longitude[-1, -2::-1], longitude[-2:0:-1, 0]])
    south = max(-90.0, float(latitude.min()) - margin)
    north = min(90.0, float(latitude.max()) + margin)
    turns = np.unwrap(np.radians(np.append(loop, loop[0])))
    if abs(turns[-1] - turns[0]) > np.pi:  # the grid's boundary winds around a pole: every longitude
        return coastline(-180.0, south, 180.0, 90.0 if north > 0 else north)
    west = (float(np.degrees(turns.min())) - margin + 180.0) % 360.0 - 180.0
    east = (float(np.degrees(turns.max())) + margin + 180.0) % 360.0 - 180.0
    if np.degrees(turns.max() - turns.min()) + 2 * margin >= 360.0:
        west, east = -180.0, 180.0
    return coastline(west, south, east, north)


def land_mask_of_grid(grid) -> np.ndarray:
    """``bool[rows, columns]``: ``True`` where a :class:`~seaice_jax.geometry.projections.MapGrid` cell's centre is on
    GSHHG land."""
    latitude, longitude = grid.latitude_longitude()
    return coastline_of_grid(grid).contains(np.degrees(np.asarray(latitude)), np.degrees(np.asarray(longitude)))
