"""Radar strips as the instruments record them, and their rectification (source 000, steps 1-3).

A :class:`StripRecord` holds what one strip provides — navigation records, altimeter, time marks, nadir returns,
the radar's nominal constants — and :class:`Measurements` the image coordinates of points on the strips.
:func:`rectify` turns measurements into ground points by the radargrammetric method (eqs A1, A2, A5 with filtered
navigation). Simulated strips also carry their truth (``truth``, ``true_sweep_delay``, ``true_range_scale``).
"""

from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from seaice_jax._shapes import bucket, pad
from seaice_jax.geometry.earth import MEAN_RADIUS
from seaice_jax.geometry.range_doppler import ground_point, look_sign
from seaice_jax.sensors.navigation import NavigationSpline, moving_average
from seaice_jax.sensors.slar import imaging_time, slant_range


@dataclass(frozen=True)
class StripRecord:
    """What one strip provides, as real data would (plus its truth, for checking).

    Attributes:
        name: e.g. ``"S01"``. start_time, end_time: s.
        record_times: ``(k,)``; record_positions, record_velocities: ``(k, 3)`` recorded navigation (ECEF m, m/s);
        record_altitudes: ``(k,)`` altimeter readings, m.
        mark_x, mark_times: ``(n,)`` time marks on the film (mm, s).
        nadir_x, nadir_y: ``(n,)`` image coordinates of nadir returns, mm.
        sweep_delay, range_scale: the radar's nominal constants. look_side.
        truth: the true trajectory; true_sweep_delay, true_range_scale; true_navigation_error: ``(k, 2)`` the
            systematic north/east error of the recorded positions at the record times (simulations only).
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
    look_side: str
    truth: object = field(default=None, repr=False)
    true_sweep_delay: float = float("nan")
    true_range_scale: float = float("nan")
    true_navigation_error: np.ndarray | None = field(default=None, repr=False)


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


def strip_navigation(strip: StripRecord, filter_window: float | None = 180.0, filter_order: int = 2,
                     filter_weighting: str = "flat") -> NavigationSpline:
    """The strip's navigation as a trajectory: the records, low-pass filtered (step 2) unless ``filter_window`` is
    ``None`` (the filter's velocities are its polynomials' derivatives)."""
    positions, velocities = strip.record_positions, strip.record_velocities
    if filter_window:
        positions, velocities = moving_average(strip.record_times, positions, filter_window, filter_order,
                                               filter_weighting)
    return NavigationSpline(strip.record_times, positions, velocities)


def rectify(strips, measurements: Measurements, filter_window: float | None = 180.0, filter_order: int = 2,
            sweep_delay=None, range_scale=None, radius=MEAN_RADIUS, filter_weighting: str = "flat"):
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
        size = bucket(rows.size)  # padded: strips of similar size share one compilation
        ground = image_to_ground(navigation, jnp.asarray(strip.mark_x), jnp.asarray(strip.mark_times),
                                jnp.asarray(pad(measurements.x[rows], size, measurements.x[rows[0]])),
                                jnp.asarray(pad(measurements.y[rows], size, measurements.y[rows[0]])), c, f,
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
    times = imaging_time(strip.nadir_x, strip.mark_x, strip.mark_times)
    return np.interp(np.asarray(times), strip.record_times, strip.record_altitudes)
