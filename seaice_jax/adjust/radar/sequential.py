"""The sequential method of 1979 (source 000, section 2 and Appendix B), kept faithfully as the baseline.

:func:`sequential_block` runs it step by step on a block of strips: (1) nadir calibration of sweep delay and
range scale per strip, (2) navigation filtering, (3) rectification of each strip with its own navigation (A5),
(4) internal adjustment strip by strip, (5) external adjustment by moving averages of control-point
discrepancies (a single control point gives a shift).

Internal adjustment models the tie-point discrepancies between a strip and the previous one (eq. B1) as piecewise
cubic polynomials of the along-track coordinate (eq. B2), each piece fixed by the function values and tangents at
its two joints (eqs B3, B4); values and tangents at the joints come from a local regression of the discrepancies
around each joint.

Eq. B4 as printed holds for a unit interval (Δ = 1) and its a₃ has e where e′ belongs; this module uses the
cubic Hermite form valid for any Δ:
a₀ = e_{k−1}, a₁ = e′_{k−1}, a₂ = [3(e_k − e_{k−1})/Δ − 2e′_{k−1} − e′_k]/Δ,
a₃ = [e′_{k−1} + e′_k − 2(e_k − e_{k−1})/Δ]/Δ².
"""

from dataclasses import dataclass

import numpy as np

from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.earth import latitude_longitude
from seaice_jax.sensors.slar import NadirCalibration, nadir_calibration
from seaice_jax.sensors.strips import Measurements, nadir_altitudes, strip_ground_points


def piece_coefficients(value_start, slope_start, value_end, slope_end, length):
    """Coefficients (a₀, a₁, a₂, a₃) of one cubic piece in the local coordinate x − x_{k−1} (eqs B3, B4)."""
    chord = (value_end - value_start) / length
    return (value_start, slope_start, (3.0 * chord - 2.0 * slope_start - slope_end) / length,
            (slope_start + slope_end - 2.0 * chord) / length**2)


@dataclass(frozen=True)
class PiecewiseCubic:
    """A C¹ piecewise cubic through values and tangents at the joints (eq. B2).

    Attributes:
        joints: ``(p + 1,)`` increasing along-track coordinates x_k.
        values, slopes: ``(p + 1, c)`` function values e_k and tangents e′_k at the joints (c components, e.g.
            Δx and Δy of eq. B1).
    """

    joints: np.ndarray
    values: np.ndarray
    slopes: np.ndarray

    def __call__(self, x):
        """``(n, c)`` values at ``x`` ``(n,)``; beyond the end joints the end pieces extend."""
        x = np.atleast_1d(np.asarray(x, float))
        k = np.clip(np.searchsorted(self.joints, x, side="right") - 1, 0, self.joints.size - 2)
        length = (self.joints[k + 1] - self.joints[k])[:, None]
        a0, a1, a2, a3 = piece_coefficients(self.values[k], self.slopes[k], self.values[k + 1], self.slopes[k + 1],
                                            length)
        u = (x - self.joints[k])[:, None]
        return a0 + u * (a1 + u * (a2 + u * a3))


def local_regression(x, values, at, half_width, degree=2):
    """Value and tangent at ``at`` of a polynomial of ``degree`` fitted to the points within ±half_width.

    Args:
        x: ``(n,)``; values: ``(n, c)``.

    Returns:
        ``(value (c,), tangent (c,))``.

    Raises:
        SeaiceError: naming the joint when fewer than twice the polynomial's coefficients lie near it.
    """
    near = np.abs(np.asarray(x) - at) <= half_width
    if near.sum() < 2 * (degree + 1):  # twice the coefficients: a tangent from barely enough points is wild
        raise SeaiceError(f"joint at x = {at:g}: only {int(near.sum())} tie points within ±{half_width:g} for a "
                          f"degree-{degree} local regression (at least {2 * (degree + 1)})")
    design = np.vander(np.asarray(x)[near] - at, degree + 1, increasing=True)
    coefficients, *_ = np.linalg.lstsq(design, np.asarray(values)[near], rcond=None)
    return coefficients[0], coefficients[1]


def fit_piecewise_cubic(x, discrepancies, joints, half_width=None, degree=2) -> PiecewiseCubic:
    """Piecewise cubic model of tie-point discrepancies along a strip (source 000, Appendix B).

    Args:
        x: ``(n,)`` along-track coordinates of the tie points.
        discrepancies: ``(n, c)`` their discrepancies with the previous strip (eq. B1).
        joints: ``(p + 1,)`` increasing joint positions x_k.
        half_width: of the local regression window at each joint (default: the joint spacing).
        degree: of the local regression.
    """
    joints = np.asarray(joints, float)
    if joints.ndim != 1 or joints.size < 2 or np.any(np.diff(joints) <= 0):
        raise SeaiceError("joints must be at least two increasing along-track positions")
    values = np.asarray(discrepancies, float)
    values = values[:, None] if values.ndim == 1 else values
    half_width = float(np.max(np.diff(joints))) if half_width is None else float(half_width)
    pairs = [local_regression(x, values, at, half_width, degree) for at in joints]
    return PiecewiseCubic(joints, np.stack([v for v, _ in pairs]), np.stack([s for _, s in pairs]))


@dataclass(frozen=True)
class SequentialResult:
    """The sequential method's results, one row per measurement (point on a strip), map metres.

    Attributes:
        rectified: ``(m, 2)`` after steps 1-3. internal: after the internal adjustment. adjusted: after the
            external adjustment (equal to ``internal`` without control points).
        calibrations: the nadir calibration of each strip.
        tie_before, tie_after: ``(k, 2)`` discrepancies (across, along track) of tie points between each strip and
            the previous one, before and after the internal adjustment.
        pieces: number of cubic pieces used per strip (0 for the first, the reference).
    """

    rectified: np.ndarray
    internal: np.ndarray
    adjusted: np.ndarray
    calibrations: tuple[NadirCalibration, ...]
    tie_before: np.ndarray
    tie_after: np.ndarray
    pieces: tuple[int, ...]

    def point_positions(self, measurements: Measurements, count: int, stage: str = "adjusted"):
        """``(count, 2)`` mean position of each point over the strips it was measured on (NaN if none)."""
        values = getattr(self, stage)
        total = np.zeros((count, 2))
        seen = np.zeros(count)
        np.add.at(total, measurements.point, np.nan_to_num(values))
        np.add.at(seen, measurements.point, np.isfinite(values).all(axis=1))
        with np.errstate(invalid="ignore", divide="ignore"):
            return total / seen[:, None]


def _track_axes(x, positions):
    """Unit vectors (across, along) of a strip in the map: along = direction of increasing film x."""
    keep = np.isfinite(positions).all(axis=1)
    centred = x[keep] - x[keep].mean()
    slope = centred @ (positions[keep] - positions[keep].mean(axis=0))
    along = slope / np.linalg.norm(slope)
    return np.array([along[1], -along[0]]), along


def _internal_correction(x, discrepancy, x_range, pieces):
    """Piecewise cubic of the discrepancies with as many pieces (<= ``pieces``) as the tie points support, as a
    function of film x, and the number of pieces (``None, 0`` where the ties span under a tenth of the strip: a
    constant shift then).

    The joints span the tie points, not the whole strip: beyond the outermost tie the correction is held at its
    value there. Extrapolating the cubics (or a regression line at a joint with its ties all to one side) can
    throw the far end of a strip by tens of kilometres where the overlap with the previous strip is short.
    """
    low, high = float(np.min(x)), float(np.max(x))
    if high - low < 0.1 * (x_range[1] - x_range[0]):
        return None, 0
    for count in range(pieces, 0, -1):
        joints = np.linspace(low, high, count + 1)
        try:
            cubic = fit_piecewise_cubic(x, discrepancy, joints, half_width=np.diff(joints)[0],
                                        degree=2 if count > 1 else 1)
        except SeaiceError:
            continue
        return (lambda at, cubic=cubic: cubic(np.clip(at, low, high))), count
    return None, 0


def moving_average_correction(control_positions, discrepancies, positions, smoothing=10_000.0):
    """External adjustment: the control-point discrepancies interpolated by a distance-weighted moving average
    (weights 1/(d² + smoothing²)); one control point gives a constant shift.

    Args:
        control_positions, discrepancies: ``(k, 2)`` map metres (known minus adjusted).
        positions: ``(m, 2)`` where to evaluate the correction.
    """
    control_positions = np.asarray(control_positions, float)
    distance2 = np.sum((np.asarray(positions)[:, None, :] - control_positions[None]) ** 2, axis=-1)
    weight = 1.0 / (distance2 + smoothing**2)
    return weight @ np.asarray(discrepancies) / weight.sum(axis=1, keepdims=True)


def sequential_block(strips, measurements: Measurements, plane, control=None, pieces: int = 4,
                     filter_window: float | None = 180.0, calibrate: bool = True,
                     smoothing: float = 10_000.0, filter_weighting: str = "flat") -> SequentialResult:
    """The sequential method of source 000 on a block of strips.

    Args:
        strips: the block's :class:`~seaice_jax.sensors.strips.StripRecord`, in flight order (each strip is
            adjusted to the previous one).
        measurements: image coordinates of points on the strips.
        plane: the map projection (``forward(lat, lon) -> (x, y)`` metres), e.g. a tangent plane.
        control: ``{point index: (x, y)}`` known map positions of control points (optional).
        pieces: cubic pieces per strip for the internal adjustment (fewer where the tie points are sparse).
        filter_window: s of the navigation moving average (``None``: no filter).
        filter_weighting: ``"flat"`` or ``"inverse_cube"`` weights of the moving average (source 002, Table 1).
        calibrate: do the nadir calibration (else use the nominal constants).
        smoothing: m, of the external moving average.
    """
    calibrations = []
    for strip in strips:
        if calibrate:
            calibrations.append(nadir_calibration(strip.nadir_y, nadir_altitudes(strip), strip.sweep_delay,
                                                  strip.range_scale))
    sweep = [c.sweep_delay for c in calibrations] if calibrate else None
    scale = [c.range_scale for c in calibrations] if calibrate else None
    points = strip_ground_points(strips, measurements, filter_window, sweep_delay=sweep, range_scale=scale,
                     filter_weighting=filter_weighting)
    lat, lon = latitude_longitude(points)
    rectified = np.stack([np.asarray(a) for a in plane.forward(lat, lon)], axis=1)

    internal = rectified.copy()
    before, after, used = [], [], [0]
    for i in range(1, len(strips)):
        on_strip = np.nonzero(measurements.strip == i)[0]
        if on_strip.size == 0:
            used.append(0)
            continue
        previous = {p: k for k, p in zip(np.nonzero(measurements.strip == i - 1)[0],
                                         measurements.point[measurements.strip == i - 1], strict=True)}
        ties = [(k, previous[measurements.point[k]]) for k in on_strip if measurements.point[k] in previous]
        ties = [(k, q) for k, q in ties if np.isfinite(internal[q]).all() and np.isfinite(rectified[k]).all()]
        across, along = _track_axes(measurements.x[on_strip], rectified[on_strip])
        if not ties:
            used.append(0)
            continue
        mine, theirs = (np.array(a) for a in zip(*ties, strict=True))
        discrepancy = internal[theirs] - rectified[mine]  # eq. B1
        before.append(np.stack([discrepancy @ across, discrepancy @ along], 1))
        x_range = (float(np.min(measurements.x[on_strip])), float(np.max(measurements.x[on_strip])))
        correction, count = _internal_correction(measurements.x[mine], discrepancy, x_range, pieces)
        used.append(count)
        if correction is not None:
            internal[on_strip] = rectified[on_strip] + correction(measurements.x[on_strip])
        else:
            internal[on_strip] = rectified[on_strip] + discrepancy.mean(axis=0)
        remaining = internal[theirs] - internal[mine]
        after.append(np.stack([remaining @ across, remaining @ along], 1))

    adjusted = internal.copy()
    if control:
        ids = np.array(sorted(control))
        valid = np.isfinite(internal).all(axis=1)
        rows = [np.nonzero((measurements.point == p) & valid)[0] for p in ids]
        current = np.array([internal[r].mean(axis=0) if r.size else [np.nan, np.nan] for r in rows])
        seen = np.isfinite(current).all(axis=1)
        if not seen.any():
            raise SeaiceError(f"none of the control points {', '.join(str(p) for p in ids)} has a rectified position "
                              "(not measured on any strip, or no ground solution)")
        known = np.array([control[p] for p in ids])[seen]
        adjusted[valid] = internal[valid] + moving_average_correction(known, known - current[seen], internal[valid],
                                                                      smoothing)
    empty = np.zeros((0, 2))
    return SequentialResult(rectified, internal, adjusted, tuple(calibrations),
                            np.concatenate(before) if before else empty, np.concatenate(after) if after else empty,
                            tuple(used))
