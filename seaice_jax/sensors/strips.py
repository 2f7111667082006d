"""Radar strips as the instruments record them, and their rectification (source 000, steps 1-3).

A :class:`StripRecord` holds what one strip provides — navigation records, altimeter, time marks, nadir returns,
the radar's nominal constants — and :class:`Measurements` the image coordinates of points on the strips.
:func:`strip_ground_points` turns measurements into ground points by the radargrammetric method (eqs A1, A2, A5
with filtered navigation). A :class:`Coverage` is one flight over a block: its strips, measurements and control
points (read from a project, or simulated — the simulator keeps its truth apart).
"""

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from seaice_jax._shapes import bucket, padded_to_bucket
from seaice_jax.geometry.earth import MEAN_RADIUS
from seaice_jax.geometry.range_doppler import LookSide, ground_point, look_sign
from seaice_jax.sensors.navigation import NavigationSpline, fit_navigation, moving_average
from seaice_jax.sensors.slar import imaging_time, slant_range


@dataclass(frozen=True)
class StripRecord:
    """What one strip provides, as real data would.

    Attributes:
        name: e.g. ``"S01"``. start_time, end_time: s.
        record_times: ``(k,)``; record_positions, record_velocities: ``(k, 3)`` recorded navigation (ECEF m, m/s);
        record_altitudes: ``(k,)`` altimeter readings, m.
        mark_x, mark_times: ``(n,)`` time marks on the film (mm, s).
        nadir_x, nadir_y: ``(n,)`` image coordinates of nadir returns, mm.
        sweep_delay, range_scale: the radar's nominal constants. look_side: ``"right"`` or ``"left"``.
    """

    name: str
    start_time: float
    end_time: float
    record_times: np.ndarray
    record_positions: np.ndarray
    record_velocities: np.ndarray
    record_altitudes: np.ndarray
    mark_x: np.ndarray
    mark_times: np.ndarray
    nadir_x: np.ndarray
    nadir_y: np.ndarray
    sweep_delay: float
    range_scale: float
    look_side: LookSide


@dataclass(frozen=True)
class Measurements:
    """Image measurements of features: one row per (point, strip).

    Attributes:
        point: ``(m,)`` feature index. strip: ``(m,)`` strip index. x, y: ``(m,)`` image coordinates, mm.
    """

    point: np.ndarray
    strip: np.ndarray
    x: np.ndarray
    y: np.ndarray


@dataclass(frozen=True)
class Coverage:
    """One flight over a block: its strips, the image measurements on them, and the control points.

    Attributes:
        name: e.g. the date. epoch: s, the flight's time origin (take-off) from the project's.
        strips: :class:`StripRecord` per strip, in flight order. measurements: point indices into the block's points.
        control: ``{point index: (x, y, σ)}`` map metres, positions known independently (stations, map points).
    """

    name: str
    epoch: float
    strips: tuple[StripRecord, ...]
    measurements: Measurements
    control: dict[int, tuple[float, float, float]]


def strip_navigation(strip: StripRecord, filter_window: float | None = 180.0, filter_order: int = 2,
                     filter_weighting: str = "flat") -> NavigationSpline:
    """The strip's navigation as a trajectory whose velocity is the derivative of its position (step 2).

    With ``filter_window`` (s), the recorded positions and the recorded velocities are each low-pass filtered by
    the moving polynomial of source 002 (:func:`~seaice_jax.sensors.navigation.moving_average`, degree
    ``filter_order``, ``filter_weighting``), and one cubic spline with knots every ``filter_window / 2`` s is
    fitted to both (:func:`~seaice_jax.sensors.navigation.fit_navigation`): the velocities give its shape, the
    positions its level, so the velocity that orients the zero-Doppler plane carries the velocity records' noise
    (cm/s), not the position records' noise differentiated over a record interval (tenths of m/s, tilting the
    plane enough to move far-range points tens of metres along track). ``None``: the records as recorded
    (interpolated by :class:`~seaice_jax.sensors.navigation.NavigationSpline`, no filter).
    """
    if not filter_window:
        return NavigationSpline(strip.record_times, strip.record_positions, strip.record_velocities)
    positions, _ = moving_average(strip.record_times, strip.record_positions, filter_window, filter_order,
                                  filter_weighting)
    velocities, _ = moving_average(strip.record_times, strip.record_velocities, filter_window, filter_order,
                                   filter_weighting)
    return fit_navigation(strip.record_times, positions, velocities, filter_window / 2).trajectory


def strip_ground_points(strips, measurements: Measurements, filter_window: float | None = 180.0,
                        filter_order: int = 2, sweep_delay=None, range_scale=None, radius=MEAN_RADIUS,
                        filter_weighting: str = "flat"):
    """The radargrammetric method of source 000 (steps 1-3): image measurements -> ground points ``(m, 3)``.

    Time by eq. A1 from the time marks, slant range by eq. A2 (with per-strip ``sweep_delay``/``range_scale`` if
    given, e.g. from nadir calibration, else the nominal constants), the sensor state from the (filtered)
    navigation records, the ground point by eq. A5. Points without a solution (a slant range shorter than the
    flying height after the range errors, say) are NaN rows.
    """
    points = np.empty((measurements.x.size, 3))
    for j, strip in enumerate(strips):
        rows = np.nonzero(measurements.strip == j)[0]
        if rows.size == 0:
            continue
        navigation = strip_navigation(strip, filter_window, filter_order, filter_weighting)
        c = strip.sweep_delay if sweep_delay is None else sweep_delay[j]
        f = strip.range_scale if range_scale is None else range_scale[j]
        # padded: strips of similar size share one compilation
        ground = image_to_ground(navigation, jnp.asarray(strip.mark_x), jnp.asarray(strip.mark_times),
                                jnp.asarray(padded_to_bucket(measurements.x[rows])),
                                jnp.asarray(padded_to_bucket(measurements.y[rows])), c, f,
                                look_sign(strip.look_side), radius)
        points[rows] = np.asarray(ground)[:rows.size]
    return points


@jax.jit
def image_to_ground(navigation, mark_x, mark_times, x, y, sweep_delay, range_scale, sign, radius):
    """Ground points ``(..., 3)`` (m, Earth-centred) of image points ``x, y`` (mm, any shape) of one strip: time by
    eq. A1, slant range by eq. A2, the ground point by eq. A5 on the ``navigation`` trajectory; ``sign`` +1 right,
    −1 left looking. NaN where there is no ground point."""
    position, velocity = navigation(imaging_time(x, mark_x, mark_times))
    return ground_point(position, velocity, slant_range(y, sweep_delay, range_scale), radius, sign, on_failure="nan")


def nadir_altitudes(strip: StripRecord):
    """Altimeter heights ``(n,)`` (m) at the imaging times of a strip's nadir returns (eq. A1, then the records)."""
    n = strip.nadir_x.size
    if n == 0:
        return np.zeros(0)
    # padded to a bucket: one compilation serves strips of similar counts of returns and marks
    marks = bucket(strip.mark_x.size)
    step = np.arange(1, marks - strip.mark_x.size + 1)  # padding marks continue the last interval's rate
    rate = (strip.mark_times[-1] - strip.mark_times[-2]) / (strip.mark_x[-1] - strip.mark_x[-2])
    mark_x = np.concatenate([strip.mark_x, strip.mark_x[-1] + step])
    mark_times = np.concatenate([strip.mark_times, strip.mark_times[-1] + rate * step])
    times = _imaging_times(jnp.asarray(padded_to_bucket(strip.nadir_x)), jnp.asarray(mark_x),
                           jnp.asarray(mark_times))
    return np.interp(np.asarray(times)[:n], strip.record_times, strip.record_altitudes)


_imaging_times = jax.jit(imaging_time)
