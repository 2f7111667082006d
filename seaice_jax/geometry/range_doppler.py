"""Range-Doppler intersection: image time and slant range + sensor state -> ground point, and back.

Source 000 (Leberl et al. 1979), eq. A5; source 002 (Leberl et al. 1976), eq. 3. All vectors are geocentric
and Earth-fixed (metres, m/s); the velocity is the sensor's velocity relative to the rotating Earth, so the
Doppler condition refers to stationary ground points.
"""

from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from seaice_jax._shapes import is_traced
from seaice_jax.errors import GeometryError
from seaice_jax.geometry._checks import raise_where_nan
from seaice_jax.geometry.earth import MEAN_RADIUS

LookSide = Literal["right", "left"]
"""The look side of a radar, by name (files, flight plans, strip records); :func:`look_sign` turns it into the sign
of eq. A5's ``c`` term, :data:`RIGHT` or :data:`LEFT`, which jitted code uses."""
RIGHT = 1.0
"""Sign of look side ``"right"``: to the right of the direction of flight (the ``w`` vector of eq. A5)."""
LEFT = -1.0
"""Sign of look side ``"left"``: to the left of the direction of flight."""


def look_sign(look_side: LookSide | ArrayLike) -> jnp.ndarray:
    """A :data:`LookSide` (or an array of +1/−1) -> float array of +1 (:data:`RIGHT`) / −1 (:data:`LEFT`)."""
    if isinstance(look_side, str):
        sides = {"right": RIGHT, "left": LEFT}
        if look_side not in sides:
            raise ValueError(f"look_side must be 'right' or 'left', got {look_side!r}")
        return jnp.asarray(sides[look_side])
    if not is_traced(look_side):
        values = np.asarray(look_side, float)
        if not np.all(np.abs(values) == 1.0):
            raise ValueError(f"look_side must be 'right', 'left' or +1 (right) / -1 (left), got "
                             f"{np.unique(values[np.abs(values) != 1.0]).tolist()}")
    return jnp.sign(jnp.asarray(look_side, float))


def _norm(v):
    return jnp.sqrt(jnp.sum(v * v, axis=-1))


def _dot(a, b):
    return jnp.sum(a * b, axis=-1)


def _check_sensor(position, velocity, slant_range) -> None:
    """Outside jit: name the indices of non-finite inputs or of a zero velocity (no Doppler plane), which would
    otherwise be reported as impossible geometry."""
    if is_traced(position, velocity, slant_range):
        return
    position, velocity, slant_range = (np.asarray(v, float) for v in (position, velocity, slant_range))
    shape = np.broadcast_shapes(position.shape[:-1], velocity.shape[:-1], slant_range.shape)
    checks = [("position", ~np.all(np.isfinite(position), axis=-1), "not finite"),
              ("velocity", ~np.all(np.isfinite(velocity), axis=-1), "not finite"),
              ("slant range", ~np.isfinite(slant_range), "not finite"),
              ("velocity", np.all(velocity == 0, axis=-1), "zero (the sensor must move: its velocity defines the "
                                                           "Doppler plane)")]
    for what, bad, reason in checks:
        bad = np.atleast_1d(np.broadcast_to(bad, shape))
        if np.any(bad):
            indices = np.nonzero(bad)
            listed = list(zip(*(i.tolist() for i in indices), strict=True))[:10]
            raise GeometryError(f"{what} {reason} at index {listed} ({int(bad.sum())} in all)", indices)


def ground_point(
    position, velocity, slant_range, radius=MEAN_RADIUS, look_side: LookSide | ArrayLike = "right", wavelength=0.0,
    doppler=0.0,
    on_failure="raise",
):
    """Ground point imaged at slant range ``slant_range`` from a sensor at ``position`` moving with ``velocity``.

    Source 000, eq. A5 (the printed ``2|ṡ|`` in the denominator of ``a`` is a typo for ``2|s|``), generalised to a
    non-zero Doppler centroid: the point satisfies

    * |p| = ``radius`` (use R + h for a point at height h above the sphere),
    * |p − s| = r,
    * (p − s)·ṡ = λ f_D r / 2   (zero Doppler when ``wavelength * doppler == 0``).

    With ŝ = s/|s|, a = (R² + |s|² − r²)/(2|s|), w = ṡ×s/|ṡ×s| (pointing right of the flight direction) and
    u = s×w/|s×w| (horizontal, forward): p = a ŝ + b u + c w with
    b = [λ f_D r/2 + (|s| − a) ŝ·ṡ] / (u·ṡ) and c = ±√(r² − b² − (|s| − a)²), + for the right look side.

    Broadcasts over any leading batch shape. Works under jit, vmap and grad.

    Args:
        position: ``(..., 3)`` sensor position, m.
        velocity: ``(..., 3)`` sensor velocity, m/s.
        slant_range: ``(...)`` m.
        radius: ``(...)`` radius of the sphere the point lies on, m.
        look_side: ``"right"``, ``"left"`` or an array of +1 (right) / −1 (left).
        wavelength: radar wavelength λ, m (only the product λ f_D matters).
        doppler: Doppler centroid f_D, Hz.
        on_failure: ``"raise"`` or ``"nan"`` (mark impossible points with NaN, e.g. to process a whole strip
            and report the failures per point).

    Returns:
        ``(..., 3)`` ground point, m. When called outside jit, a slant range with no intersection (shorter than
        the sensor's height, or beyond the horizon) raises :class:`~seaice_jax.errors.GeometryError` naming the
        indices; inside jit/vmap, or with ``on_failure="nan"``, those points are NaN.
    """
    if on_failure not in ("raise", "nan"):
        raise ValueError(f"on_failure must be 'raise' or 'nan', got {on_failure!r}")
    point = _ground_point(position, velocity, slant_range, radius, look_sign(look_side), wavelength, doppler)
    if on_failure == "nan":
        return point
    _check_sensor(position, velocity, slant_range)
    raise_where_nan(
        point,
        "slant range",
        "the range sphere does not meet the Earth sphere in the Doppler plane (range shorter than the sensor's "
        "height above the surface, or beyond the horizon)",
        vector_axes=1,
    )
    return point


def _broadcast_batch(vectors, scalars):
    """Broadcast ``(..., 3)`` vectors and ``(...)`` scalars to one batch shape (explicitly, no rank promotion)."""
    vectors = [jnp.asarray(x, float) for x in vectors]
    scalars = [jnp.asarray(x, float) for x in scalars]
    batch = jnp.broadcast_shapes(*(x.shape[:-1] for x in vectors), *(x.shape for x in scalars))
    return ([jnp.broadcast_to(x, batch + (3,)) for x in vectors] + [jnp.broadcast_to(x, batch) for x in scalars])


def _ground_point(position, velocity, slant_range, radius, sign, wavelength, doppler):
    s, v, r, R, sign, wavelength, doppler = _broadcast_batch(
        (position, velocity), (slant_range, radius, sign, wavelength, doppler)
    )
    s_len = _norm(s)
    s_hat = s / s_len[..., None]
    a = (R**2 + s_len**2 - r**2) / (2.0 * s_len)
    w = jnp.cross(v, s)
    w = w / _norm(w)[..., None]
    u = jnp.cross(s, w)
    u = u / _norm(u)[..., None]
    below = s_len - a
    b = (0.5 * wavelength * doppler * r + below * _dot(s_hat, v)) / _dot(u, v)
    radicand = r**2 - b**2 - below**2
    visible = (radicand >= 0.0) & (r**2 <= s_len**2 - R**2)
    c = jnp.sqrt(jnp.where(visible, radicand, 1.0))
    point = a[..., None] * s_hat + b[..., None] * u + (sign * c)[..., None] * w
    return jnp.where(visible[..., None], point, jnp.nan)


def doppler_residual(time, point, trajectory, wavelength=0.0, doppler=0.0):
    """(p − s(t))·ṡ(t) − λ f_D |p − s(t)| / 2, in m²/s: zero when ``point`` is imaged at ``time``."""
    position, velocity = trajectory(time)
    offset = point - position
    return _dot(offset, velocity) - 0.5 * wavelength * doppler * _norm(offset)


def imaging_time_and_range(
    point, trajectory, time_start, time_end, wavelength=0.0, doppler=0.0, grid_points=33, iterations=8
):
    """Inverse of :func:`ground_point`: the time a ground point is imaged and its slant range.

    Solves the Doppler condition (p − s(t))·ṡ(t) = λ f_D r / 2 along the trajectory. A fixed grid of
    ``grid_points`` times in [time_start, time_end] gives the start (the smallest |residual|/|ṡ|), then
    ``iterations`` Newton steps with the derivative by forward-mode autodiff through the trajectory. The fixed
    counts keep it jit-, vmap- and grad-able (gradients flow through the unrolled Newton steps).

    Args:
        point: ``(..., 3)`` ground points, m.
        trajectory: callable ``t -> (position (3,), velocity (3,))`` for scalar ``t``, e.g. a
            :class:`~seaice_jax.geometry.trajectory.CircularTrajectory` or a navigation spline.
        time_start, time_end: seconds bracketing the imaging times (the strip's time span).

    Returns:
        ``(time, slant_range)``, each ``(...)``.
    """
    point = jnp.asarray(point, float)
    time, slant = _solve_times(point.reshape(-1, 3), trajectory, time_start, time_end, wavelength, doppler,
                               grid_points, iterations)
    return time.reshape(point.shape[:-1]), slant.reshape(point.shape[:-1])


@eqx.filter_jit
def _solve_times(points, trajectory, time_start, time_end, wavelength, doppler, grid_points, iterations):
    """:func:`_solve_time` for ``(n, 3)`` points; compiled once per trajectory type and array shapes (a
    trajectory that is an ``eqx.Module`` is an argument, not a constant baked into the compiled code)."""
    return jax.vmap(lambda p: _solve_time(p, trajectory, time_start, time_end, wavelength, doppler, grid_points,
                                          iterations))(points)


def _solve_time(point, trajectory, time_start, time_end, wavelength, doppler, grid_points, iterations):
    grid = jnp.linspace(time_start, time_end, grid_points)
    residual_on_grid = jax.vmap(lambda t: doppler_residual(t, point, trajectory, wavelength, doppler))(grid)
    speed_on_grid = jax.vmap(lambda t: _norm(trajectory(t)[1]))(grid)
    start = grid[jnp.argmin(jnp.abs(residual_on_grid) / speed_on_grid)]
    return refined_imaging_time(point, trajectory, start, wavelength, doppler, iterations)


def refined_imaging_time(point, trajectory, time, wavelength=0.0, doppler=0.0, iterations=8):
    """Newton's method on the Doppler condition from ``time``, a time near the imaging time (for one point).

    ``iterations`` steps, the derivative by forward-mode autodiff through the trajectory; differentiable with respect
    to ``point`` and the trajectory (gradients flow through the unrolled steps). A start within a few seconds of a
    satellite's imaging time (a measured image time, say) needs three or four steps.

    Args:
        point: ``(3,)`` ground point, m. trajectory: ``t -> (position, velocity)``. time: scalar start, s.

    Returns:
        ``(time, slant_range)``, scalars.
    """

    def newton_step(t, _):
        value, slope = jax.jvp(lambda tt: doppler_residual(tt, point, trajectory, wavelength, doppler),
                               (t,), (jnp.ones_like(t),))
        return t - value / slope, None

    time, _ = jax.lax.scan(newton_step, jnp.asarray(time, float), None, length=iterations)
    position, _ = trajectory(time)
    return time, _norm(point - position)


def incidence_angle(point, sensor_position):
    """Local incidence angle (radians) at ``point``: between the local vertical and the direction to the sensor.

    Args:
        point, sensor_position: ``(..., 3)`` m.
    """
    up = point / _norm(point)[..., None]
    look = sensor_position - point
    return jnp.arccos(_dot(up, look) / _norm(look))
