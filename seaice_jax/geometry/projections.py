"""Map projections: forward ``(latitude, longitude) -> (x, y)`` and inverse, as eqx.Module value types.

* :class:`TangentPlane`: orthographic projection onto the plane tangent at the centre of the area (the map frame
  of source 000), on the sphere.
* :class:`Equirectangular`: metric plate carrée, true scale at a reference latitude (PROJ ``eqc``).
* :class:`ImageGrid`: the equi-rectangular image grid of source 001 (section 3.3 footnote, VHR3): reference
  latitude/longitude at a reference pixel/line, pixel sizes in metres, longitude scaled at the reference latitude.
* :class:`LambertConformalConic` and :class:`PolarStereographic`: on a sphere or an ellipsoid (Snyder 1987,
  *Map Projections — A Working Manual*, USGS PP 1395, eqs 15-1 to 15-11 and 21-33 to 21-40). The usual sea-ice
  grids (NSIDC EPSG:3413 and EPSG:3976) come from :func:`nsidc_polar_stereographic`.

All but :class:`ImageGrid` are :class:`Projection` s: metric ``forward``/``inverse``, their PROJ definition
(:meth:`Projection.proj_string`) and CF grid-mapping attributes (:meth:`Projection.cf_grid_mapping`, with the WKT
from pyproj). :class:`MapGrid` is a raster in any of them (remapped images, GeoTIFF, CF-NetCDF grids).

Angles in radians, lengths in metres. Latitude/longitude are on the figure the projection is defined on (the
sphere for the spherical ones, geodetic for an ellipsoid; see :mod:`seaice_jax.geometry.earth` for conversions).
Tests compare every projection with PROJ (pyproj).
"""

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from seaice_jax.geometry._vectors import along
from seaice_jax.geometry._vectors import as_float as _as_float
from seaice_jax.geometry.earth import MEAN_RADIUS, WGS84_FLATTENING, WGS84_SEMI_MAJOR_AXIS, unit_vector
from seaice_jax.geometry.earth import wrap_angle as _wrap


def _degrees(value) -> float:
    return float(np.degrees(float(value)))


def _figure(semi_major_axis, flattening) -> str:
    """The PROJ figure: an ellipsoid ``+a +rf`` or, with flattening 0, a sphere ``+R``."""
    a, f = float(semi_major_axis), float(flattening)
    return f"+a={a!r} +rf={1 / f!r}" if f > 0 else f"+R={a!r}"


class Projection(eqx.Module):
    """A map projection: metric ``forward`` ``(latitude, longitude) -> (x, y)`` and ``inverse``, with its PROJ
    definition and its CF grid mapping. Angles in radians, lengths in metres; arrays of any (broadcast) shape."""

    @abc.abstractmethod
    def forward(self, latitude, longitude) -> tuple[Array, Array]:
        """``(x, y)`` metres of ``(latitude, longitude)`` radians."""

    @abc.abstractmethod
    def inverse(self, x, y) -> tuple[Array, Array]:
        """``(latitude, longitude)`` radians of ``(x, y)`` metres."""

    @abc.abstractmethod
    def proj_string(self) -> str:
        """The PROJ definition (metres), e.g. ``+proj=stere +lat_0=90 ...``."""

    @abc.abstractmethod
    def cf_parameters(self) -> dict:
        """CF 1.10 (Appendix F) ``grid_mapping_name`` and its parameters (degrees, metres); empty if CF has none."""

    def epsg_code(self) -> int | None:
        """The EPSG code of this exact projection, if it has one."""
        return None

    def cf_grid_mapping(self) -> dict:
        """Attributes of a CF grid-mapping variable: :meth:`cf_parameters`, ``proj4_params``, ``crs_wkt`` (WKT2 by
        pyproj) and ``epsg_code`` where there is one."""
        import pyproj

        code = self.epsg_code()
        crs = pyproj.CRS.from_epsg(code) if code is not None else pyproj.CRS.from_proj4(self.proj_string())
        attrs = {**self.cf_parameters(), "proj4_params": self.proj_string(), "crs_wkt": crs.to_wkt()}
        if code is not None:
            attrs["epsg_code"] = f"EPSG:{code}"
        return attrs



class TangentPlane(Projection):
    """Orthographic projection onto the plane tangent to the sphere at (``latitude``, ``longitude``).

    x points east, y north at the tangent point. Points on the far hemisphere map to NaN.
    """

    latitude: Float[Array, ""] = eqx.field(converter=_as_float)
    longitude: Float[Array, ""] = eqx.field(converter=_as_float)
    radius: Float[Array, ""] = eqx.field(converter=_as_float, default=MEAN_RADIUS)

    def _axes(self):
        up = unit_vector(self.latitude, self.longitude)
        east = jnp.stack([-jnp.sin(self.longitude), jnp.cos(self.longitude), jnp.zeros_like(self.longitude)])
        return east, jnp.cross(up, east), up

    @jax.jit
    def forward(self, latitude, longitude):
        """``(x, y)`` metres in the tangent plane of ``(latitude, longitude)`` radians, each ``(...)``."""
        east, north, up = self._axes()
        g = unit_vector(latitude, longitude)
        front = g @ up >= 0.0
        return (jnp.where(front, self.radius * (g @ east), jnp.nan),
                jnp.where(front, self.radius * (g @ north), jnp.nan))

    @jax.jit
    def inverse(self, x, y):
        """``(latitude, longitude)`` radians of tangent-plane ``(x, y)`` metres; NaN beyond the sphere's disk."""
        east, north, up = self._axes()
        e, n = jnp.broadcast_arrays(_as_float(x) / self.radius, _as_float(y) / self.radius)
        h2 = 1.0 - e**2 - n**2
        vertical = jnp.sqrt(jnp.where(h2 >= 0.0, h2, 0.0))
        g = along(e, east) + along(n, north) + along(vertical, up)
        latitude = jnp.arctan2(g[..., 2], jnp.hypot(g[..., 0], g[..., 1]))
        longitude = jnp.arctan2(g[..., 1], g[..., 0])
        return jnp.where(h2 >= 0.0, latitude, jnp.nan), jnp.where(h2 >= 0.0, longitude, jnp.nan)

    def proj_string(self) -> str:
        return (f"+proj=ortho +lat_0={_degrees(self.latitude)!r} +lon_0={_degrees(self.longitude)!r} "
                f"+R={float(self.radius)!r} +units=m +no_defs")

    def cf_parameters(self) -> dict:
        return {"grid_mapping_name": "orthographic", "latitude_of_projection_origin": _degrees(self.latitude),
                "longitude_of_projection_origin": _degrees(self.longitude), "earth_radius": float(self.radius)}


class Equirectangular(Projection):
    """Equi-rectangular (plate carrée with true scale at the reference latitude), metric, on the sphere:
    x = R (λ − λ_ref) cos φ_ref, y = R (φ − φ_ref). Same as PROJ ``eqc`` with ``lat_ts = lat_0 = φ_ref``."""

    reference_latitude: Float[Array, ""] = eqx.field(converter=_as_float)
    reference_longitude: Float[Array, ""] = eqx.field(converter=_as_float)
    radius: Float[Array, ""] = eqx.field(converter=_as_float, default=MEAN_RADIUS)

    @jax.jit
    def forward(self, latitude, longitude):
        """``(x east, y north)`` metres of ``(latitude, longitude)`` radians."""
        x = self.radius * _wrap(_as_float(longitude) - self.reference_longitude) * jnp.cos(self.reference_latitude)
        y = self.radius * (_as_float(latitude) - self.reference_latitude)
        x, y = jnp.broadcast_arrays(x, y)
        return x, y

    @jax.jit
    def inverse(self, x, y):
        """``(latitude, longitude)`` radians of ``(x, y)`` metres."""
        latitude = self.reference_latitude + _as_float(y) / self.radius
        longitude = _wrap(self.reference_longitude + _as_float(x) / (self.radius * jnp.cos(self.reference_latitude)))
        latitude, longitude = jnp.broadcast_arrays(latitude, longitude)
        return latitude, longitude

    def proj_string(self) -> str:
        return (f"+proj=eqc +lat_ts={_degrees(self.reference_latitude)!r} +lat_0={_degrees(self.reference_latitude)!r} "
                f"+lon_0={_degrees(self.reference_longitude)!r} +R={float(self.radius)!r} +units=m +no_defs")

    def cf_parameters(self) -> dict:
        return {}  # CF 1.10 has no equidistant cylindrical grid mapping: proj4_params and crs_wkt describe it


class ImageGrid(eqx.Module):
    """Equi-rectangular image grid (source 001): 1-based pixel (columns, east) and line (rows, south).

    x = R (λ − λ_ref) cos φ_ref, y = R (φ − φ_ref); pixel = pixel_ref + x / pixel_width,
    line = line_ref − y / pixel_height. The unit latitude and longitude cells keep the ratio of their surface
    lengths at the reference latitude (source 001, footnote to section 3.3). Same as PROJ ``eqc`` with
    ``lat_ts = lat_0 = φ_ref``.
    """

    reference_latitude: Float[Array, ""] = eqx.field(converter=_as_float)
    reference_longitude: Float[Array, ""] = eqx.field(converter=_as_float)
    reference_pixel: Float[Array, ""] = eqx.field(converter=_as_float)
    reference_line: Float[Array, ""] = eqx.field(converter=_as_float)
    pixel_width: Float[Array, ""] = eqx.field(converter=_as_float)
    pixel_height: Float[Array, ""] = eqx.field(converter=_as_float)
    radius: Float[Array, ""] = eqx.field(converter=_as_float, default=MEAN_RADIUS)

    @property
    def projection(self) -> Equirectangular:
        """The metric projection of the grid."""
        return Equirectangular(self.reference_latitude, self.reference_longitude, self.radius)

    @jax.jit
    def map_xy(self, latitude, longitude):
        """Metric map coordinates ``(x east, y north)`` relative to the reference point."""
        return self.projection.forward(latitude, longitude)

    @jax.jit
    def forward(self, latitude, longitude):
        """``(pixel, line)`` (fractional, 1-based) of ``(latitude, longitude)`` radians."""
        x, y = self.map_xy(latitude, longitude)
        return self.reference_pixel + x / self.pixel_width, self.reference_line - y / self.pixel_height

    @jax.jit
    def inverse(self, pixel, line):
        """``(latitude, longitude)`` radians of fractional 1-based ``(pixel, line)``."""
        x = (_as_float(pixel) - self.reference_pixel) * self.pixel_width
        y = (self.reference_line - _as_float(line)) * self.pixel_height
        return self.projection.inverse(x, y)


class MapGrid(eqx.Module):
    """A raster in a metric map projection: rows run south (top row first), columns east.

    Pixel centres: x = x_first + column · pixel_width, y = y_first − row · pixel_height (0-based row, column).
    ``projection`` is any :class:`Projection` (:class:`PolarStereographic`, :class:`Equirectangular`,
    :class:`LambertConformalConic`, :class:`TangentPlane`).

    Attributes:
        x_first, y_first: m, centre of the top-left pixel. pixel_width, pixel_height: m.
        n_rows, n_columns: raster shape.
    """

    projection: Projection
    x_first: Float[Array, ""] = eqx.field(converter=_as_float)
    y_first: Float[Array, ""] = eqx.field(converter=_as_float)
    pixel_width: Float[Array, ""] = eqx.field(converter=_as_float)
    pixel_height: Float[Array, ""] = eqx.field(converter=_as_float)
    n_rows: int = eqx.field(static=True, default=256)
    n_columns: int = eqx.field(static=True, default=256)

    def __check_init__(self):
        if self.n_rows < 1 or self.n_columns < 1:
            raise ValueError(f"a map grid needs at least one row and column, got {self.n_rows} x {self.n_columns}")

    @classmethod
    def centred(cls, projection, latitude, longitude, pixel_width, pixel_height, n_rows, n_columns):
        """The grid of ``n_rows`` x ``n_columns`` pixels centred on ``(latitude, longitude)`` radians."""
        x, y = projection.forward(latitude, longitude)
        return cls(projection, x - 0.5 * (n_columns - 1) * pixel_width, y + 0.5 * (n_rows - 1) * pixel_height,
                   pixel_width, pixel_height, n_rows, n_columns)

    @classmethod
    def from_image_grid(cls, grid: ImageGrid, n_rows: int, n_columns: int):
        """The raster of source 001's equi-rectangular image grid (pixel 1, line 1 at the top left)."""
        return cls(grid.projection, (1.0 - grid.reference_pixel) * grid.pixel_width,
                   (grid.reference_line - 1.0) * grid.pixel_height, grid.pixel_width, grid.pixel_height, n_rows,
                   n_columns)

    @property
    def shape(self) -> tuple[int, int]:
        return self.n_rows, self.n_columns

    @jax.jit
    def xy(self):
        """Map coordinates ``(x, y)`` of every pixel centre, each ``(n_rows, n_columns)`` m."""
        x = self.x_first + self.pixel_width * jnp.arange(self.n_columns, dtype=float)
        y = self.y_first - self.pixel_height * jnp.arange(self.n_rows, dtype=float)
        return jnp.meshgrid(x, y)

    @jax.jit
    def latitude_longitude(self):
        """``(latitude, longitude)`` radians of every pixel centre, each ``(n_rows, n_columns)``."""
        return self.projection.inverse(*self.xy())

    @jax.jit
    def to_xy(self, row, column):
        """Map coordinates (m) of fractional 0-based ``(row, column)``."""
        return (self.x_first + self.pixel_width * _as_float(column), self.y_first - self.pixel_height * _as_float(row))

    @jax.jit
    def to_pixel(self, x, y):
        """Fractional 0-based ``(row, column)`` of map coordinates (m)."""
        return (self.y_first - _as_float(y)) / self.pixel_height, (_as_float(x) - self.x_first) / self.pixel_width


def _cf_figure(semi_major_axis, flattening) -> dict:
    """CF figure attributes: ``semi_major_axis`` and ``inverse_flattening``, or ``earth_radius`` for a sphere."""
    a, f = float(semi_major_axis), float(flattening)
    return {"semi_major_axis": a, "inverse_flattening": 1 / f} if f > 0 else {"earth_radius": a}


def _eccentricity(flattening):
    return jnp.sqrt(flattening * (2.0 - flattening))


def _m(latitude, e):
    """Snyder eq. 14-15: cos φ / √(1 − e² sin² φ)."""
    return jnp.cos(latitude) / jnp.sqrt(1.0 - (e * jnp.sin(latitude)) ** 2)


def _t(latitude, e):
    """Snyder eq. 15-9: tan(π/4 − φ/2) / ((1 − e sin φ)/(1 + e sin φ))^(e/2)."""
    es = e * jnp.sin(latitude)
    return jnp.tan(jnp.pi / 4 - latitude / 2) / ((1.0 - es) / (1.0 + es)) ** (e / 2)


def _latitude_from_t(t, e, iterations=12):
    """Snyder eq. 7-9, fixed-point iteration (each step gains a factor of about e²)."""
    latitude = jnp.pi / 2 - 2.0 * jnp.arctan(t)
    for _ in range(iterations):
        es = e * jnp.sin(latitude)
        latitude = jnp.pi / 2 - 2.0 * jnp.arctan(t * ((1.0 - es) / (1.0 + es)) ** (e / 2))
    return latitude


class LambertConformalConic(Projection):
    """Lambert conformal conic with one or two standard parallels (Snyder eqs 15-1 to 15-11).

    Attributes:
        standard_parallel_1, standard_parallel_2: radians (equal for the one-parallel form).
        origin_latitude, central_meridian: radians.
        false_easting, false_northing: metres.
        semi_major_axis, flattening: the figure (flattening 0 for a sphere of that radius).
    """

    standard_parallel_1: Float[Array, ""] = eqx.field(converter=_as_float)
    standard_parallel_2: Float[Array, ""] = eqx.field(converter=_as_float)
    origin_latitude: Float[Array, ""] = eqx.field(converter=_as_float)
    central_meridian: Float[Array, ""] = eqx.field(converter=_as_float)
    false_easting: Float[Array, ""] = eqx.field(converter=_as_float, default=0.0)
    false_northing: Float[Array, ""] = eqx.field(converter=_as_float, default=0.0)
    semi_major_axis: Float[Array, ""] = eqx.field(converter=_as_float, default=WGS84_SEMI_MAJOR_AXIS)
    flattening: Float[Array, ""] = eqx.field(converter=_as_float, default=WGS84_FLATTENING)

    def _constants(self):
        e = _eccentricity(self.flattening)
        m1, m2 = _m(self.standard_parallel_1, e), _m(self.standard_parallel_2, e)
        t1, t2 = _t(self.standard_parallel_1, e), _t(self.standard_parallel_2, e)
        same = jnp.abs(self.standard_parallel_1 - self.standard_parallel_2) < 1e-12
        n = jnp.where(same, jnp.sin(self.standard_parallel_1),
                      (jnp.log(m1) - jnp.log(m2)) / jnp.where(same, 1.0, jnp.log(t1) - jnp.log(t2)))
        big_f = m1 / (n * t1**n)
        rho0 = self.semi_major_axis * big_f * _t(self.origin_latitude, e) ** n
        return e, n, big_f, rho0

    @jax.jit
    def forward(self, latitude, longitude):
        """``(x, y)`` metres of ``(latitude, longitude)`` radians."""
        e, n, big_f, rho0 = self._constants()
        rho = self.semi_major_axis * big_f * _t(_as_float(latitude), e) ** n
        theta = n * _wrap(_as_float(longitude) - self.central_meridian)
        x = self.false_easting + rho * jnp.sin(theta)
        y = self.false_northing + rho0 - rho * jnp.cos(theta)
        x, y = jnp.broadcast_arrays(x, y)
        return x, y

    @jax.jit
    def inverse(self, x, y):
        """``(latitude, longitude)`` radians of ``(x, y)`` metres."""
        e, n, big_f, rho0 = self._constants()
        dx = _as_float(x) - self.false_easting
        dy = rho0 - (_as_float(y) - self.false_northing)
        sign = jnp.sign(n)
        rho = sign * jnp.hypot(dx, dy)
        theta = jnp.arctan2(sign * dx, sign * dy)
        t = (rho / (self.semi_major_axis * big_f)) ** (1.0 / n)
        latitude = _latitude_from_t(t, e)
        longitude = _wrap(theta / n + self.central_meridian)
        latitude, longitude = jnp.broadcast_arrays(latitude, longitude)
        return latitude, longitude

    def proj_string(self) -> str:
        return (f"+proj=lcc +lat_1={_degrees(self.standard_parallel_1)!r} "
                f"+lat_2={_degrees(self.standard_parallel_2)!r} +lat_0={_degrees(self.origin_latitude)!r} "
                f"+lon_0={_degrees(self.central_meridian)!r} "
                f"+x_0={float(self.false_easting)!r} +y_0={float(self.false_northing)!r} "
                f"{_figure(self.semi_major_axis, self.flattening)} +units=m +no_defs")

    def cf_parameters(self) -> dict:
        return {"grid_mapping_name": "lambert_conformal_conic",
                "standard_parallel": [_degrees(self.standard_parallel_1), _degrees(self.standard_parallel_2)],
                "latitude_of_projection_origin": _degrees(self.origin_latitude),
                "longitude_of_central_meridian": _degrees(self.central_meridian),
                "false_easting": float(self.false_easting), "false_northing": float(self.false_northing),
                **_cf_figure(self.semi_major_axis, self.flattening)}


class PolarStereographic(Projection):
    """Polar stereographic, north or south, true scale at ``standard_parallel`` (Snyder eqs 21-33 to 21-40).

    Attributes:
        standard_parallel: latitude of true scale, radians (±π/2 for true scale at the pole); its sign picks the
            hemisphere (the pole of projection).
        central_meridian: longitude that points down (north) or up (south) from the pole, radians.
        false_easting, false_northing: metres.
        semi_major_axis, flattening: the figure.
    """

    standard_parallel: Float[Array, ""] = eqx.field(converter=_as_float)
    central_meridian: Float[Array, ""] = eqx.field(converter=_as_float)
    false_easting: Float[Array, ""] = eqx.field(converter=_as_float, default=0.0)
    false_northing: Float[Array, ""] = eqx.field(converter=_as_float, default=0.0)
    semi_major_axis: Float[Array, ""] = eqx.field(converter=_as_float, default=WGS84_SEMI_MAJOR_AXIS)
    flattening: Float[Array, ""] = eqx.field(converter=_as_float, default=WGS84_FLATTENING)

    def _constants(self):
        """Hemisphere sign and the factor k with ρ = k · t(hemisphere · φ)."""
        e = _eccentricity(self.flattening)
        hemisphere = jnp.where(self.standard_parallel >= 0, 1.0, -1.0)
        parallel = hemisphere * self.standard_parallel
        at_pole = jnp.abs(parallel - jnp.pi / 2) < 1e-12
        safe = jnp.where(at_pole, jnp.pi / 4, parallel)
        k_parallel = self.semi_major_axis * _m(safe, e) / _t(safe, e)
        k_pole = 2.0 * self.semi_major_axis / jnp.sqrt((1.0 + e) ** (1.0 + e) * (1.0 - e) ** (1.0 - e))
        return e, hemisphere, jnp.where(at_pole, k_pole, k_parallel)

    @jax.jit
    def forward(self, latitude, longitude):
        """``(x, y)`` metres of ``(latitude, longitude)`` radians."""
        e, hemisphere, k = self._constants()
        rho = k * _t(hemisphere * _as_float(latitude), e)
        dl = _as_float(longitude) - self.central_meridian
        x = self.false_easting + rho * jnp.sin(dl)
        y = self.false_northing - hemisphere * rho * jnp.cos(dl)
        x, y = jnp.broadcast_arrays(x, y)
        return x, y

    @jax.jit
    def inverse(self, x, y):
        """``(latitude, longitude)`` radians of ``(x, y)`` metres."""
        e, hemisphere, k = self._constants()
        dx = _as_float(x) - self.false_easting
        dy = _as_float(y) - self.false_northing
        latitude = hemisphere * _latitude_from_t(jnp.hypot(dx, dy) / k, e)
        longitude = _wrap(self.central_meridian + jnp.arctan2(dx, -hemisphere * dy))
        latitude, longitude = jnp.broadcast_arrays(latitude, longitude)
        return latitude, longitude

    def proj_string(self) -> str:
        pole = 90.0 if float(self.standard_parallel) >= 0 else -90.0
        return (f"+proj=stere +lat_0={pole:g} +lat_ts={_degrees(self.standard_parallel)!r} "
                f"+lon_0={_degrees(self.central_meridian)!r} +x_0={float(self.false_easting)!r} "
                f"+y_0={float(self.false_northing)!r} {_figure(self.semi_major_axis, self.flattening)} +units=m "
                "+no_defs")

    def cf_parameters(self) -> dict:
        return {"grid_mapping_name": "polar_stereographic",
                "latitude_of_projection_origin": 90.0 if float(self.standard_parallel) >= 0 else -90.0,
                "standard_parallel": _degrees(self.standard_parallel),
                "straight_vertical_longitude_from_pole": _degrees(self.central_meridian),
                "false_easting": float(self.false_easting), "false_northing": float(self.false_northing),
                **_cf_figure(self.semi_major_axis, self.flattening)}

    def epsg_code(self) -> int | None:
        """3413 or 3976 for the NSIDC sea-ice grids (:func:`nsidc_polar_stereographic`), else ``None``."""
        for code, hemisphere in ((3413, "north"), (3976, "south")):
            reference = nsidc_polar_stereographic(hemisphere)
            if all(np.isclose(float(getattr(self, f)), float(getattr(reference, f)), rtol=0, atol=1e-12)
                   for f in ("standard_parallel", "central_meridian", "false_easting", "false_northing",
                             "semi_major_axis", "flattening")):
                return code
        return None


def nsidc_polar_stereographic(hemisphere: str = "north") -> PolarStereographic:
    """The NSIDC sea-ice polar stereographic grids on WGS84.

    ``"north"``: EPSG:3413 (true scale at 70°N, central meridian 45°W). ``"south"``: EPSG:3976 (true scale at
    70°S, central meridian 0°).
    """
    if hemisphere == "north":
        return PolarStereographic(jnp.radians(70.0), jnp.radians(-45.0))
    if hemisphere == "south":
        return PolarStereographic(jnp.radians(-70.0), 0.0)
    raise ValueError(f"hemisphere must be 'north' or 'south', got {hemisphere!r}")
