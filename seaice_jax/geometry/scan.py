"""Great-circle scan model of whisk-broom satellite images (NOAA VHRR/AVHRR, Landsat MSS).

Source 001 (Arctic Sciences 1985), section 3.3 (eqs 3.3-1 to 3.3-10) and Appendix C; conventions fixed in
DESIGN.md ("Great-circle scan model"):

* spherical Earth, circular orbit of inclination i, ascending node longitude φ0, constant altitude H, period T_s;
* the orbital angle η (from the ascending node) is linear in scan line between η_1 (line 1) and η_N (line N);
  southbound passes have η increasing with scan line, northbound passes decreasing (the only difference);
* the scanner angle is linear in pixel, zero at the subtrack pixel p_s, positive to the right of the direction
  of flight, with pixel numbers increasing to the left: ψ(p) = span · (p_s − p)/(N_p − 1);
* with H = 0 (image already corrected for Earth curvature) ψ is the Earth-central cross-track angle β; with
  H > 0, β = asin((R + H)/R · sin ψ) − ψ;
* ground point: cos β u(η) − sin β n (u sub-satellite unit vector, n orbit normal; −n is the right of flight);
* Earth rotation subtracts (T_s/T_e) η from the longitude.

With the parameters printed in Figure 3-3 of source 001 and T_e = 1440 min this reproduces the printed station
deviations to about 1 arc minute (tests/test_scan.py).
"""

import functools
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from seaice_jax._shapes import is_traced
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry._checks import raise_where_nan
from seaice_jax.geometry._vectors import as_float as _as_float
from seaice_jax.geometry.earth import MEAN_RADIUS, SIDEREAL_DAY, latitude_longitude, unit_vector
from seaice_jax.geometry.earth import wrap_angle as _wrap

Direction = Literal["south", "north"]

SCAN_UNKNOWNS = ("scanner_angle_span", "subtrack_pixel", "orbital_angle_first", "orbital_angle_span",
                 "ascending_node")
"""The five per-image unknowns of :class:`ScanModel`, in the order every estimate, covariance and file lists them
(all angles in radians except ``subtrack_pixel``, a pixel)."""

_DIRECTION_SIGN = {"south": 1.0, "north": -1.0}


_ORBIT_RANGES = {"inclination (radians)": "within (0, π)", "period (s)": "finite and > 0",
                 "altitude (m)": "finite and >= 0", "earth_day (s)": "> 0 (inf: no Earth rotation)",
                 "radius (m)": "finite and > 0"}


class Orbit(eqx.Module):
    """The fixed (per satellite or per pass) orbit of the scan model.

    Attributes:
        inclination: i, radians (NOAA and Landsat orbits are retrograde: i = 180° − maximum latitude).
        period: T_s, seconds.
        altitude: H, metres; 0 for images already corrected for Earth curvature.
        earth_day: T_e, seconds of one Earth rotation (sidereal day by default; the 1985 program used 1440 min;
            ``inf`` switches Earth rotation off).
        radius: R, metres.
    """

    inclination: Float[Array, ""] = eqx.field(converter=_as_float)
    period: Float[Array, ""] = eqx.field(converter=_as_float)
    altitude: Float[Array, ""] = eqx.field(converter=_as_float, default=0.0)
    earth_day: Float[Array, ""] = eqx.field(converter=_as_float, default=SIDEREAL_DAY)
    radius: Float[Array, ""] = eqx.field(converter=_as_float, default=MEAN_RADIUS)

    def __check_init__(self):
        """Outside jit: 0 < i < π, T_s > 0, T_e > 0 (``inf`` allowed), H >= 0, R > 0 (finite), else an error
        naming the parameter."""
        fields = (self.inclination, self.period, self.altitude, self.earth_day, self.radius)
        if is_traced(*fields):
            return
        inclination, period, altitude, earth_day, radius = (np.asarray(v) for v in fields)
        checks = [("inclination (radians)", inclination, (inclination > 0) & (inclination < np.pi)),
                  ("period (s)", period, np.isfinite(period) & (period > 0)),
                  ("altitude (m)", altitude, np.isfinite(altitude) & (altitude >= 0)),
                  ("earth_day (s)", earth_day, earth_day > 0),
                  ("radius (m)", radius, np.isfinite(radius) & (radius > 0))]
        for name, value, good in checks:
            if not np.all(good):
                raise SeaiceError(f"Orbit: {name} must be {_ORBIT_RANGES[name]}, got {value}")

    @classmethod
    def from_max_latitude(cls, max_latitude, period, altitude=0.0, earth_day=SIDEREAL_DAY, radius=MEAN_RADIUS,
                          retrograde=True):
        """Orbit from the maximum latitude θ_m of the subtrack (radians): i = π − θ_m if retrograde, else θ_m.

        Raises:
            SeaiceError: outside jit, for θ_m outside (0, π/2].
        """
        if not is_traced(max_latitude) and not np.all((np.asarray(max_latitude) > 0)
                                                      & (np.asarray(max_latitude) <= np.pi / 2)):
            raise SeaiceError(f"Orbit: maximum latitude must be within (0°, 90°], got "
                              f"{np.degrees(np.asarray(max_latitude))}°")
        max_latitude = jnp.asarray(max_latitude, float)
        inclination = jnp.pi - max_latitude if retrograde else max_latitude
        return cls(inclination, period, altitude, earth_day, radius)

    @property
    def max_latitude(self):
        """Maximum latitude of the subtrack, radians."""
        return jnp.where(self.inclination > jnp.pi / 2, jnp.pi - self.inclination, self.inclination)

    @property
    def rotation_ratio(self):
        """T_s / T_e: Earth rotation (radians of longitude) per radian of orbital angle."""
        return self.period / self.earth_day

    @jax.jit
    def central_angle(self, scanner_angle):
        """Earth-central cross-track angle β from the scanner angle ψ: β = asin((R+H)/R sin ψ) − ψ (ψ if H = 0).

        NaN where the line of sight misses the Earth.
        """
        ratio = (self.radius + self.altitude) / self.radius
        sine = ratio * jnp.sin(scanner_angle)
        hits = jnp.abs(sine) <= 1.0
        beta = jnp.arcsin(jnp.where(hits, sine, 0.0)) - scanner_angle
        return jnp.where(hits, jnp.where(self.altitude > 0, beta, scanner_angle), jnp.nan)

    @jax.jit
    def scanner_angle_from_central(self, central_angle):
        """Inverse of :meth:`central_angle`: tan ψ = sin β / ((R+H)/R − cos β) (ψ = β if H = 0)."""
        ratio = (self.radius + self.altitude) / self.radius
        psi = jnp.arctan2(jnp.sin(central_angle), ratio - jnp.cos(central_angle))
        return jnp.where(self.altitude > 0, psi, central_angle)


def _ground_vector(beta, eta, inclination):
    """The ground point's unit vector g = cos β u(η) − sin β n in the frame with the ascending node on the x axis
    (source 001 eqs 3.3-8 to 3.3-10), its components and the sines and cosines they are made of."""
    cb, sb, ce, se = jnp.cos(beta), jnp.sin(beta), jnp.cos(eta), jnp.sin(eta)
    ci, si = jnp.cos(inclination), jnp.sin(inclination)
    return (cb * ce, cb * se * ci + sb * si, cb * se * si - sb * ci), (cb, sb, ce, se, ci, si)


@jax.custom_jvp
def _ground_direction(beta, eta, inclination):
    """Latitude and longitude east of the ascending node (radians, the Earth not rotating) of the ground point at
    Earth-central cross-track angle ``beta`` and orbital angle ``eta`` on an orbit of ``inclination``, each
    ``(...)`` broadcastable (source 001 eqs 3.3-8 to 3.3-10).

    Differentiated in closed form: with g = cos β u(η) − sin β n a unit vector, ∂latitude = ∂g_z / h and
    ∂longitude = (g_x ∂g_y − g_y ∂g_x) / h² (h² = g_x² + g_y²), ∂g/∂β = −sin β u(η) − cos β n, ∂g/∂η = cos β u'(η),
    ∂g/∂i = (0, −g_z, g_y): a few products per point and unknown, where autodiff differentiates every operation.
    """
    return latitude_longitude(jnp.stack(jnp.broadcast_arrays(*_ground_vector(beta, eta, inclination)[0]), axis=-1))


@_ground_direction.defjvp
def _ground_direction_jvp(primals, tangents):
    beta, eta, inclination = primals
    beta_dot, eta_dot, inclination_dot = tangents
    (gx, gy, gz), (cb, sb, ce, se, ci, si) = _ground_vector(beta, eta, inclination)
    dx = -sb * ce * beta_dot - cb * se * eta_dot
    dy = (-sb * se * ci + cb * si) * beta_dot + cb * ce * ci * eta_dot - gz * inclination_dot
    dz = (-sb * se * si - cb * ci) * beta_dot + cb * ce * si * eta_dot + gy * inclination_dot
    squared = gx**2 + gy**2
    primal = latitude_longitude(jnp.stack(jnp.broadcast_arrays(gx, gy, gz), axis=-1))
    return primal, (dz / jnp.sqrt(squared), (gx * dy - gy * dx) / squared)


class ScanModel(eqx.Module):
    """The five per-image unknowns of the great-circle scan model and the fixed orbit.

    Attributes:
        scanner_angle_span: ψ_1 − ψ_N, radians: scanner angle between the first and last pixel (the Earth-central
            angle β when the orbit's altitude is 0). Printed as "OFFSET" in Figure 3-3.
        subtrack_pixel: p_s, the (fractional, 1-based) pixel of the orbital subtrack; may lie off the image.
        orbital_angle_first: η_1, radians from the ascending node at scan line 1.
        orbital_angle_span: |η_N − η_1|, radians ("ANGLE" in Figure 3-3).
        ascending_node: φ0, longitude of the ascending node, radians.
        orbit: the fixed :class:`Orbit`.
        direction: ``"south"`` (η increases with scan line) or ``"north"`` (η decreases).
        n_pixels, n_scans: image size (pixels per scan line, scan lines).
    """

    scanner_angle_span: Float[Array, ""] = eqx.field(converter=_as_float)
    subtrack_pixel: Float[Array, ""] = eqx.field(converter=_as_float)
    orbital_angle_first: Float[Array, ""] = eqx.field(converter=_as_float)
    orbital_angle_span: Float[Array, ""] = eqx.field(converter=_as_float)
    ascending_node: Float[Array, ""] = eqx.field(converter=_as_float)
    orbit: Orbit
    direction: Direction = eqx.field(static=True, default="south")
    n_pixels: int = eqx.field(static=True, default=512)
    n_scans: int = eqx.field(static=True, default=512)

    def __check_init__(self):
        if self.direction not in _DIRECTION_SIGN:
            raise ValueError(f"direction must be 'south' or 'north', got {self.direction!r}")
        if self.n_pixels < 2 or self.n_scans < 2:
            raise ValueError(f"image size must be at least 2 x 2, got n_pixels={self.n_pixels}, "
                             f"n_scans={self.n_scans}")

    @classmethod
    def from_edges(cls, scanner_angle_first, scanner_angle_last, orbital_angle_first, orbital_angle_last,
                   ascending_node, orbit, n_pixels=512, n_scans=512):
        """Model from the angles at the image edges as a 1985 printout lists them (radians).

        The subtrack pixel follows from where the scanner angle crosses zero; the direction from the sign of
        η_N − η_1.
        """
        span = jnp.asarray(scanner_angle_first - scanner_angle_last, float)
        subtrack = 1.0 + scanner_angle_first / span * (n_pixels - 1)
        eta_span = float(orbital_angle_last - orbital_angle_first)
        return cls(span, subtrack, jnp.asarray(orbital_angle_first, float), jnp.asarray(abs(eta_span)),
                   jnp.asarray(ascending_node, float), orbit, "south" if eta_span >= 0 else "north",
                   n_pixels, n_scans)

    def reversed(self) -> "ScanModel":
        """The same model described with the other direction: η₁ + s·span·f is the same line for (``"south"``,
        span) and (``"north"``, −span), s = ±1 the direction's sign. Forward and inverse are unchanged."""
        span = self.orbital_angle_span
        return ScanModel(self.scanner_angle_span, self.subtrack_pixel, self.orbital_angle_first,
                         -span if is_traced(span) else -np.asarray(span), self.ascending_node, self.orbit,
                         "north" if self.direction == "south" else "south", self.n_pixels, self.n_scans)

    @property
    def _eta_sign(self):
        return _DIRECTION_SIGN[self.direction]

    @property
    def scanner_angle_first(self):
        """Scanner angle at pixel 1, radians."""
        return self.scanner_angle(1.0)

    @property
    def scanner_angle_last(self):
        """Scanner angle at the last pixel, radians."""
        return self.scanner_angle(float(self.n_pixels))

    @property
    def orbital_angle_last(self):
        """Orbital angle η_N at the last scan line, radians."""
        return self.orbital_angle(float(self.n_scans))

    @jax.jit
    def scanner_angle(self, pixel):
        """Scanner angle ψ (radians) at fractional 1-based ``pixel``: span · (p_s − p)/(N_p − 1)."""
        return self.scanner_angle_span * (self.subtrack_pixel - jnp.asarray(pixel, float)) / (self.n_pixels - 1)

    @jax.jit
    def orbital_angle(self, scan):
        """Orbital angle η (radians from the ascending node) at fractional 1-based scan line ``scan``."""
        fraction = (jnp.asarray(scan, float) - 1.0) / (self.n_scans - 1)
        return self.orbital_angle_first + self._eta_sign * self.orbital_angle_span * fraction

    def forward(self, pixel, scan):
        """Latitude and longitude (radians, on the sphere) of fractional 1-based ``pixel``, ``scan``.

        Source 001 eqs 3.3-8, 3.3-9 with the Earth-rotation term 3.3-10 in the form of DESIGN.md.

        Args:
            pixel, scan: ``(...)`` broadcastable.

        Returns:
            ``(latitude, longitude)``, each ``(...)``; longitude in (-π, π]. Outside jit, pixels whose line of
            sight misses the Earth (H > 0) raise :class:`~seaice_jax.errors.GeometryError`.
        """
        if is_traced(self, pixel, scan):
            return self.forward_unchecked(pixel, scan)
        # eager: described southbound, both directions share one compiled program per shape
        southbound = self if self.direction == "south" else self.reversed()
        latitude, longitude = southbound.forward_unchecked(pixel, scan)
        raise_where_nan(latitude, "pixel", "the scanner's line of sight misses the Earth")
        return latitude, longitude

    @jax.jit
    def forward_unchecked(self, pixel, scan):
        """:meth:`forward` without the check: NaN where the line of sight misses the Earth (for simulations that
        mask such pixels themselves)."""
        pixel, scan = jnp.broadcast_arrays(jnp.asarray(pixel, float), jnp.asarray(scan, float))
        beta = self.orbit.central_angle(self.scanner_angle(pixel))
        eta = self.orbital_angle(scan)
        latitude, from_node = _ground_direction(beta, eta, self.orbit.inclination)
        longitude = self.ascending_node + from_node - self.orbit.rotation_ratio * eta
        return latitude, _wrap(longitude)

    def inverse(self, latitude, longitude, iterations=8):
        """Fractional 1-based ``(pixel, scan)`` of a point given by latitude and longitude (radians).

        Closed form for a stationary Earth; the Earth-rotation term is resolved by ``iterations`` fixed-point
        steps (each shrinks the error by T_s/T_e ≈ 0.07). The orbital angle is taken on the branch nearest the
        image's centre line.

        Args:
            latitude, longitude: ``(...)`` radians.

        Returns:
            ``(pixel, scan)``, each ``(...)``.
        """
        if not is_traced(latitude):
            beyond = np.abs(np.asarray(latitude, float)) > np.pi / 2
            if np.any(beyond):
                raise ValueError(f"latitude out of range [-90°, 90°] at index {np.argwhere(beyond).tolist()[:10]}")
        return self._inverse(latitude, longitude, iterations)

    @functools.partial(jax.jit, static_argnames="iterations")
    def _inverse(self, latitude, longitude, iterations):
        latitude = jnp.asarray(latitude, float)
        eta, beta = orbit_coordinates(self.orbit, self.ascending_node, latitude, longitude,
                                      self.orbital_angle(0.5 * (1.0 + self.n_scans)), iterations)
        psi = self.orbit.scanner_angle_from_central(beta)
        pixel = self.subtrack_pixel - psi * (self.n_pixels - 1) / self.scanner_angle_span
        scan = 1.0 + (eta - self.orbital_angle_first) * (self.n_scans - 1) / (
            self._eta_sign * self.orbital_angle_span
        )
        return pixel, scan

    @jax.jit
    def carried_to(self, target: "ScanModel", pixel, scan):
        """``(pixel, scan)`` in ``target``'s image of the ground this model sees at ``pixel``, ``scan`` (``(...)``):
        ``target.inverse`` of :meth:`forward_unchecked` (NaN where the line of sight misses the Earth)."""
        return target.inverse(*self.forward_unchecked(pixel, scan))


@functools.partial(jax.jit, static_argnames="iterations")
def orbit_coordinates(orbit: Orbit, ascending_node, latitude, longitude, orbital_angle_reference, iterations=8):
    """Orbital angle η and Earth-central cross-track angle β of ground points, for an orbit and node.

    The closed-form core of :meth:`ScanModel.inverse`: for a stationary Earth, β = −asin(g·n) and η is the
    in-plane angle of g; Earth rotation adds (T_s/T_e) η to the longitude, resolved by fixed-point steps. η is
    taken on the branch nearest ``orbital_angle_reference``.

    Args:
        latitude, longitude: ``(...)`` radians.

    Returns:
        ``(eta, beta)``, each ``(...)`` radians.
    """
    latitude, longitude = jnp.broadcast_arrays(jnp.asarray(latitude, float), jnp.asarray(longitude, float))
    inc = orbit.inclination
    eta = jnp.broadcast_to(orbital_angle_reference, latitude.shape)
    for _ in range(iterations):
        relative = longitude - ascending_node + orbit.rotation_ratio * eta
        g = unit_vector(latitude, relative)
        gx, gy, gz = g[..., 0], g[..., 1], g[..., 2]
        in_plane = gy * jnp.cos(inc) + gz * jnp.sin(inc)
        eta = orbital_angle_reference + _wrap(jnp.arctan2(in_plane, gx) - orbital_angle_reference)
    beta = jnp.arcsin(jnp.clip(gy * jnp.sin(inc) - gz * jnp.cos(inc), -1.0, 1.0))
    return eta, beta


class SatelliteOrbit(eqx.Module):
    """Nominal orbit of a satellite in the 1985 program's menu (source 001, Appendix A, VHR2 function 6).

    Attributes:
        period_minutes, inclination_degrees, altitude_km: nominal mean values.
        source: where the numbers come from.
    """

    period_minutes: float = eqx.field(static=True)
    inclination_degrees: float = eqx.field(static=True)
    altitude_km: float = eqx.field(static=True)
    source: str = eqx.field(static=True)


SATELLITES: dict[str, SatelliteOrbit] = {
    # NSSDCA master catalogue 1974-089A: perigee 1444 km, apogee 1459 km, 114.9 min, 101.7 deg.
    # The period 114.90 also appears in the VHR2 operator's manual example (source 001, Appendix A).
    "NOAA-4": SatelliteOrbit(114.90, 101.7, 1451.0, "NSSDCA 1974-089A; source 001 App. A example period"),
    # NSSDCA master catalogue 1976-077A: perigee 1504 km, apogee 1522 km, 116.2 min, 102.1 deg.
    "NOAA-5": SatelliteOrbit(116.2, 102.1, 1513.0, "NSSDCA 1976-077A"),
    # NSSDCA master catalogue 1979-057A: perigee 796 km, apogee 812 km, 101.2 min, 98.7 deg.
    "NOAA-6": SatelliteOrbit(101.2, 98.7, 804.0, "NSSDCA 1979-057A"),
    # NSSDCA master catalogue 1978-096A: perigee 847 km, apogee 866 km, 102.1 min, 98.9 deg.
    "TIROS-N": SatelliteOrbit(102.1, 98.9, 856.0, "NSSDCA 1978-096A"),
    # Period and maximum latitude as printed by the 1985 program for the NOAA-7 Lancaster Sound imagery
    # (source 001, Figure 3-3: ORBITAL PERIOD 102.03, ORB MAX LATITUDE 81.10 -> i = 98.90 deg);
    # altitude NSSDCA master catalogue 1981-059A: perigee 847 km, apogee 868 km.
    "NOAA-7": SatelliteOrbit(102.03, 98.90, 857.0, "source 001 Figure 3-3; NSSDCA 1981-059A"),
    # NSSDCA master catalogue 1972-058A: perigee 907 km, apogee 915 km, 103.3 min, 99.1 deg.
    "LANDSAT-1": SatelliteOrbit(103.3, 99.1, 911.0, "NSSDCA 1972-058A"),
    # NSSDCA master catalogue 1975-004A: perigee 908 km, apogee 918 km, 103.2 min, 99.2 deg.
    "LANDSAT-2": SatelliteOrbit(103.2, 99.2, 913.0, "NSSDCA 1975-004A"),
    # NSSDCA master catalogue 1978-026A: perigee 900 km, apogee 919 km, 103.1 min, 99.1 deg.
    "LANDSAT-3": SatelliteOrbit(103.1, 99.1, 910.0, "NSSDCA 1978-026A"),
}


def satellite_orbit(name: str, altitude=None, earth_day=SIDEREAL_DAY, radius=MEAN_RADIUS,
                    period=None, max_latitude=None) -> Orbit:
    """The :class:`Orbit` of a satellite from :data:`SATELLITES`, with optional overrides.

    Args:
        name: e.g. ``"NOAA-7"`` (case-insensitive; ``"LDSAT-1"`` as the 1985 menu spells it is accepted).
        altitude: metres; ``None`` takes the table's; 0 for curvature-corrected images.
        earth_day: seconds of one Earth rotation.
        period: seconds, overrides the table.
        max_latitude: radians, overrides the table's inclination (retrograde orbit assumed).
    """
    key = name.strip().upper().replace("LDSAT", "LANDSAT").replace("_", "-")
    if key not in SATELLITES:
        raise ValueError(f"unknown satellite {name!r}; known: {', '.join(SATELLITES)}")
    entry = SATELLITES[key]
    inclination = jnp.radians(entry.inclination_degrees) if max_latitude is None else jnp.pi - max_latitude
    return Orbit(
        inclination,
        entry.period_minutes * 60.0 if period is None else period,
        entry.altitude_km * 1000.0 if altitude is None else altitude,
        earth_day,
        radius,
    )


def scan_unknowns(model: ScanModel) -> Float[Array, " 5"]:
    """The five unknowns of ``model`` as a vector, in the order of :data:`SCAN_UNKNOWNS`."""
    return jnp.stack([jnp.asarray(getattr(model, name), float) for name in SCAN_UNKNOWNS])


def with_scan_unknowns(model: ScanModel, values) -> ScanModel:
    """``model`` with its five unknowns replaced by ``values (5,)`` (order of :data:`SCAN_UNKNOWNS`)."""
    return eqx.tree_at(lambda m: tuple(getattr(m, name) for name in SCAN_UNKNOWNS), model,
                       replace=tuple(values[j] for j in range(len(SCAN_UNKNOWNS))))
