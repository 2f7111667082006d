"""Any projected coordinate reference system pyproj knows (an EPSG code, a PROJ string, WKT) as a
:class:`~seaice_jax.geometry.projections.Projection`.

:class:`CrsProjection` computes on the host with PROJ (through ``jax.pure_callback``), so it works inside ``jit``
and ``vmap`` like the JAX projections; its derivatives (``jacfwd``, ``jvp``: the grid convergence of
:func:`~seaice_jax.drift.kinematics.east_north_axes`) are central differences of PROJ's own numbers, step
:data:`DIFFERENCE_STEP`. :func:`projection_from_definition` returns the JAX projection where there is one (the NSIDC
sea-ice grids EPSG:3413 and EPSG:3976) and a :class:`CrsProjection` otherwise.

Latitude and longitude are geodetic on the CRS's own datum (PROJ's ``geodetic_crs`` of the CRS: no datum shift),
radians; x, y in metres.
"""

import functools
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pyproj
from pyproj.exceptions import CRSError

from seaice_jax.errors import SeaiceError
from seaice_jax.geometry._vectors import as_float as _as_float
from seaice_jax.geometry.projections import Projection, nsidc_polar_stereographic

DIFFERENCE_STEP = 1e-6
"""Central-difference step of :class:`CrsProjection`'s derivatives: radians for ``forward``, metres × 10⁶ (1 m)
for ``inverse`` (the truncation error, ~step² × the third derivative, stays below 1e-9 of the derivative)."""

_NATIVE = {3413: "north", 3976: "south"}


@functools.lru_cache(maxsize=64)
def checked_crs(definition: str) -> pyproj.CRS:
    """The projected CRS of ``definition`` (``"EPSG:3031"``, a PROJ string, WKT), in metres.

    Raises:
        SeaiceError: naming the definition, when pyproj does not know it, or it is not a projected CRS in metres.
    """
    try:
        crs = pyproj.CRS.from_user_input(definition)
    except CRSError as error:
        raise SeaiceError(f"map projection {definition!r}: pyproj does not know it ({error})") from None
    if not crs.is_projected:
        raise SeaiceError(f"map projection {definition!r}: not a projected CRS ({crs.type_name})")
    units = {axis.unit_name for axis in crs.axis_info}
    if units != {"metre"}:
        raise SeaiceError(f"map projection {definition!r}: axes in {', '.join(sorted(units))}, metres are needed")
    return crs


@functools.lru_cache(maxsize=64)
def _transformers(definition: str) -> tuple[pyproj.Transformer, pyproj.Transformer]:
    """``(forward, inverse)``: geodetic (lon, lat degrees) -> (x, y) m of the CRS, and back (always x first)."""
    crs = checked_crs(definition)
    geodetic = crs.geodetic_crs
    assert geodetic is not None  # a projected CRS has one
    return (pyproj.Transformer.from_crs(geodetic, crs, always_xy=True),
            pyproj.Transformer.from_crs(crs, geodetic, always_xy=True))


def _host_map(definition: str, inverse: bool, first, second):
    """On the host: ``(x, y)`` of (latitude, longitude) radians, or ``(latitude, longitude)`` radians of ``(x, y)``
    with ``inverse``; NaN where PROJ has no answer."""
    forward, backward = _transformers(definition)
    first, second = np.asarray(first, float), np.asarray(second, float)
    if inverse:
        longitude, latitude = backward.transform(first, second, errcheck=False)
        out = np.radians(latitude), np.radians(longitude)
    else:
        out = forward.transform(np.degrees(second), np.degrees(first), errcheck=False)
    return tuple(np.where(np.isfinite(v), v, np.nan).astype(float).reshape(first.shape) for v in out)


def _host_jacobian(definition: str, inverse: bool, first, second):
    """``(..., 2, 2)``: derivatives of :func:`_host_map`'s two outputs (rows) by its two inputs (columns), central
    differences of step :data:`DIFFERENCE_STEP` (radians, or metres × 10⁶ for ``inverse``)."""
    step = DIFFERENCE_STEP * (1e6 if inverse else 1.0)
    first, second = np.asarray(first, float), np.asarray(second, float)
    columns = []
    for d_first, d_second in ((step, 0.0), (0.0, step)):
        plus = _host_map(definition, inverse, first + d_first, second + d_second)
        minus = _host_map(definition, inverse, first - d_first, second - d_second)
        columns.append(np.stack([(p - m) / (2 * step) for p, m in zip(plus, minus, strict=True)], -1))
    return np.stack(columns, -1)


def _shapes(first, second):
    return jax.ShapeDtypeStruct(first.shape, first.dtype), jax.ShapeDtypeStruct(second.shape, second.dtype)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1))
def _pyproj_map(definition: str, inverse: bool, first, second):
    return jax.pure_callback(functools.partial(_host_map, definition, inverse), _shapes(first, second), first,
                             second, vmap_method="broadcast_all")


@_pyproj_map.defjvp
def _pyproj_map_jvp(definition, inverse, primals, tangents):
    first, second = primals
    out = _pyproj_map(definition, inverse, first, second)
    jacobian = jax.pure_callback(functools.partial(_host_jacobian, definition, inverse),
                                 jax.ShapeDtypeStruct((*first.shape, 2, 2), first.dtype), first, second,
                                 vmap_method="broadcast_all")
    d_first, d_second = tangents
    return out, (jacobian[..., 0, 0] * d_first + jacobian[..., 0, 1] * d_second,
                 jacobian[..., 1, 0] * d_first + jacobian[..., 1, 1] * d_second)


class CrsProjection(Projection):
    """A projected CRS by its ``definition`` (``"EPSG:3031"``, a PROJ string, WKT), computed by PROJ.

    Raises:
        SeaiceError: when pyproj does not know the definition, or it is not a projected CRS in metres.
    """

    definition: str = eqx.field(static=True)

    def __check_init__(self):
        checked_crs(self.definition)

    @property
    def crs(self) -> pyproj.CRS:
        return checked_crs(self.definition)

    def forward(self, latitude, longitude):
        """``(x, y)`` metres of geodetic ``(latitude, longitude)`` radians (NaN where PROJ has no answer)."""
        latitude, longitude = jnp.broadcast_arrays(_as_float(latitude), _as_float(longitude))
        return _pyproj_map(self.definition, False, latitude, longitude)

    def inverse(self, x, y):
        """Geodetic ``(latitude, longitude)`` radians of ``(x, y)`` metres."""
        x, y = jnp.broadcast_arrays(_as_float(x), _as_float(y))
        return _pyproj_map(self.definition, True, x, y)

    def host_transform(self, first, second, inverse: bool = False) -> tuple[np.ndarray, ...]:
        """:meth:`forward` (or, ``inverse``, :meth:`inverse`) computed by PROJ on NumPy arrays, outside JAX: for
        host-side work such as drawing, where a JAX callback inside a compiled function gains nothing."""
        return _host_map(self.definition, inverse, first, second)

    def proj_string(self) -> str:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # "you will likely lose important projection information"
            return self.crs.to_proj4()

    def cf_parameters(self) -> dict:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            attributes = self.crs.to_cf()
        if "grid_mapping_name" not in attributes:
            return {}
        return {key: value for key, value in attributes.items() if key not in ("crs_wkt", "horizontal_datum_name",
                                                                                 "geographic_crs_name",
                                                                                 "projected_crs_name",
                                                                                 "reference_ellipsoid_name",
                                                                                 "prime_meridian_name")}

    def epsg_code(self) -> int | None:
        return self.crs.to_epsg(min_confidence=100)

    def cf_grid_mapping(self) -> dict:
        """As :meth:`Projection.cf_grid_mapping`, with the WKT of the CRS itself (nothing lost through PROJ)."""
        attributes = {**self.cf_parameters(), "proj4_params": self.proj_string(), "crs_wkt": self.crs.to_wkt()}
        code = self.epsg_code()
        if code is not None:
            attributes["epsg_code"] = f"EPSG:{code}"
        return attributes


def projection_from_definition(definition: str) -> Projection:
    """The projection of a CRS ``definition`` (``"EPSG:3413"``, a PROJ string, WKT): the JAX
    :func:`~seaice_jax.geometry.projections.nsidc_polar_stereographic` for EPSG:3413 and EPSG:3976, else a
    :class:`CrsProjection`.

    Raises:
        SeaiceError: when pyproj does not know the definition, or it is not a projected CRS in metres.
    """
    code = checked_crs(definition).to_epsg(min_confidence=100)
    if code in _NATIVE:
        return nsidc_polar_stereographic(_NATIVE[code])
    return CrsProjection(definition)
