"""Radar image measurements -> time of imaging and slant range (source 000, Appendix A, eqs A1-A4).

Comparator coordinates x', y' are rotated and shifted into the image frame x (along the time-mark line) and y
(across it, from the range reference line) by :class:`ImageFrame`; eq. A1 gives the time by linear interpolation
between time marks, eq. A2 the slant range r = (y + c) f from the sweep delay c and the range scale f. Nadir
returns, whose slant range must equal the altimeter's height over the ice, calibrate c and f (eqs A3, A4).
"""

from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from seaice_jax.errors import SeaiceError


class ImageFrame(eqx.Module):
    """Rotation and shift from comparator (x', y') to image coordinates (x, y).

    x runs along the time-mark line in the direction of increasing time; y is the perpendicular distance from the
    range reference line, positive toward increasing range.

    Attributes:
        origin: ``(2,)`` comparator coordinates of the image origin (on the range reference line).
        x_axis: ``(2,)`` unit vector of the x direction in comparator coordinates.
        y_axis: ``(2,)`` unit vector of the y direction.
    """

    origin: Float[Array, "2"]
    x_axis: Float[Array, "2"]
    y_axis: Float[Array, "2"]

    @classmethod
    def from_lines(cls, time_marks, range_reference, far_range_point):
        """The frame from measured points on the time-mark line and on the range reference line.

        Args:
            time_marks: ``(n, 2)`` comparator coordinates of time marks, in time order (n >= 2).
            range_reference: ``(m, 2)`` points on the range reference line (m >= 1; parallel to the marks).
            far_range_point: ``(2,)`` any point at larger range than the reference line (fixes the sign of y).
        """
        marks = np.asarray(time_marks, float)
        if marks.ndim != 2 or marks.shape[0] < 2 or marks.shape[1] != 2:
            raise SeaiceError(f"time marks must be (n >= 2, 2) comparator coordinates, got shape {marks.shape}")
        centred = marks - marks.mean(axis=0)
        direction = np.linalg.svd(centred, full_matrices=False)[2][0]
        if direction @ (marks[-1] - marks[0]) < 0:
            direction = -direction
        normal = np.array([-direction[1], direction[0]])
        reference = np.atleast_2d(np.asarray(range_reference, float)).mean(axis=0)
        if normal @ (np.asarray(far_range_point, float) - reference) < 0:
            normal = -normal
        origin = reference - direction * (direction @ (reference - marks[0]))
        return cls(jnp.asarray(origin), jnp.asarray(direction), jnp.asarray(normal))

    @jax.jit
    def to_image(self, x_comparator, y_comparator):
        """``(x, y)`` image coordinates of comparator points (same units, e.g. mm on the film)."""
        dx = jnp.asarray(x_comparator, float) - self.origin[0]
        dy = jnp.asarray(y_comparator, float) - self.origin[1]
        return dx * self.x_axis[0] + dy * self.x_axis[1], dx * self.y_axis[0] + dy * self.y_axis[1]

    @jax.jit
    def to_comparator(self, x, y):
        """``(x', y')`` comparator coordinates of image points (the inverse of :meth:`to_image`)."""
        x, y = jnp.asarray(x, float), jnp.asarray(y, float)
        return (self.origin[0] + x * self.x_axis[0] + y * self.y_axis[0],
                self.origin[1] + x * self.x_axis[1] + y * self.y_axis[1])

    @classmethod
    def placed(cls, angle: float, origin):
        """The frame of a film laid on the comparator turned by ``angle`` (radians) with its image origin at
        comparator ``origin`` ``(2,)``."""
        axis = jnp.array([np.cos(angle), np.sin(angle)])
        return cls(jnp.asarray(origin, float), axis, jnp.array([-axis[1], axis[0]]))


def check_time_marks(mark_x, mark_times, where: str = "time marks"):
    """Raise naming the first mark whose position or time does not increase."""
    mark_x, mark_times = np.asarray(mark_x, float), np.asarray(mark_times, float)
    if mark_x.shape != mark_times.shape or mark_x.ndim != 1 or mark_x.size < 2:
        raise SeaiceError(f"{where}: need at least two marks with one position and one time each")
    for name, values in (("position", mark_x), ("time", mark_times)):
        steps = np.diff(values)
        if np.any(steps <= 0):
            k = int(np.argmax(steps <= 0)) + 1
            raise SeaiceError(f"{where}: mark {k} {name} {values[k]} does not increase (mark {k - 1}: "
                              f"{values[k - 1]})")


def imaging_time(x, mark_x, mark_times):
    """Time of imaging of image points at along-track coordinate ``x`` (source 000, eq. A1).

    t = t_i + (x − x_i)(t_{i+1} − t_i)/(x_{i+1} − x_i) between the marks around x; the first and last intervals
    extend beyond the marks. Marks must increase (see :func:`check_time_marks`).

    Args:
        x: ``(...)`` image x.
        mark_x, mark_times: ``(n,)`` positions and times (s) of the time marks.
    """
    mark_x, mark_times = jnp.asarray(mark_x, float), jnp.asarray(mark_times, float)
    x = jnp.asarray(x, float)
    i = jnp.clip(jnp.searchsorted(mark_x, x, side="right") - 1, 0, mark_x.shape[0] - 2)
    return mark_times[i] + (x - mark_x[i]) * (mark_times[i + 1] - mark_times[i]) / (mark_x[i + 1] - mark_x[i])


def slant_range(y, sweep_delay, range_scale):
    """Slant range r = (y + c) f (source 000, eq. A2).

    Args:
        y: image range coordinate (e.g. mm). sweep_delay: c, same units as y. range_scale: f, metres per unit.
    """
    return (jnp.asarray(y, float) + sweep_delay) * range_scale


@dataclass(frozen=True)
class NadirCalibration:
    """Result of the nadir calibration (eqs A3, A4).

    Attributes:
        sweep_delay, range_scale: the improved constants c = c0 + Δc and f = f0 + Δf.
        sigma_sweep_delay, sigma_range_scale: their standard deviations (the range-scale σ is NaN when it was
            not estimated).
        scale_estimated: False when the altitudes varied too little to separate Δc from Δf and Δc alone was
            estimated (f kept at f0).
        message: what was done, in words.
        residuals: ``(n,)`` metres, r_n − h_n after calibration.
    """

    sweep_delay: float
    range_scale: float
    sigma_sweep_delay: float
    sigma_range_scale: float
    scale_estimated: bool
    message: str
    residuals: np.ndarray


def nadir_calibration(y_nadir, altitude, sweep_delay, range_scale, sigma_range=None,
                      condition_limit: float = 100.0) -> NadirCalibration:
    """Sweep delay and range scale from nadir returns and the altimeter (source 000, eqs A3, A4).

    Over ice of height zero the slant range of a nadir return equals the flight altitude, so
    r_n − h_n = (y_n + c0) Δf + f0 Δc (+ measurement errors) is linear in (Δc, Δf); least squares gives both. If
    the altitude barely varies the two columns are nearly proportional and Δc, Δf cannot be separated: when the
    condition number of the column-scaled design exceeds ``condition_limit`` only Δc is estimated, and the result
    says so. (The condition is about mean(y + c) / spread(y): 100 means altitudes spanning roughly 1-2 % of
    their mean; a survey flight at several levels gives about 5, level flight thousands.)

    Args:
        y_nadir: ``(n,)`` image y of the nadir returns. altitude: ``(n,)`` altimeter heights h_n (m).
        sweep_delay, range_scale: the nominal constants c0, f0.
        sigma_range: σ of r_n − h_n (m); default: estimated from the residuals.
    """
    y = np.asarray(y_nadir, float)
    h = np.asarray(altitude, float)
    if y.shape != h.shape or y.ndim != 1:
        raise SeaiceError(f"nadir calibration: y_nadir and altitude must be equal-length vectors, got {y.shape} "
                          f"and {h.shape}")
    if y.size < 1:
        raise SeaiceError("nadir calibration needs at least one nadir return")
    discrepancy = (y + sweep_delay) * range_scale - h
    design = np.stack([np.full_like(y, range_scale), y + sweep_delay], axis=1)
    scaled = design / np.linalg.norm(design, axis=0)
    singular = np.linalg.svd(scaled, compute_uv=False)
    condition = singular[0] / singular[-1] if y.size >= 2 and singular[-1] > 0 else np.inf
    both = condition <= condition_limit
    columns = design if both else design[:, :1]
    if y.size < columns.shape[1]:
        raise SeaiceError(f"nadir calibration: {y.size} nadir return(s) for {columns.shape[1]} unknowns")
    solution, *_ = np.linalg.lstsq(columns, -discrepancy, rcond=None)
    residuals = discrepancy + columns @ solution
    dof = y.size - columns.shape[1]
    if sigma_range is None:
        sigma_range = float(np.sqrt(residuals @ residuals / dof)) if dof > 0 else np.nan
    covariance = sigma_range**2 * np.linalg.inv(columns.T @ columns)
    delta_c = float(solution[0])
    delta_f = float(solution[1]) if both else 0.0
    if both:
        message = f"estimated sweep delay and range scale from {y.size} nadir returns (condition {condition:.3g})"
    else:
        spread = float(np.ptp(h))
        message = (f"altitude varies by only {spread:.1f} m over {y.size} nadir returns: sweep delay and range scale "
                   f"cannot be separated (condition {condition:.3g} > {condition_limit:g}); estimated the sweep "
                   "delay alone, range scale kept at its nominal value")
    return NadirCalibration(
        sweep_delay=sweep_delay + delta_c, range_scale=range_scale + delta_f,
        sigma_sweep_delay=float(np.sqrt(covariance[0, 0])),
        sigma_range_scale=float(np.sqrt(covariance[1, 1])) if both else float("nan"),
        scale_estimated=bool(both), message=message, residuals=residuals)
