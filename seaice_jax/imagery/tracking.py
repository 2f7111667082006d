"""Automatic ice displacement between two remapped images by normalised cross-correlation (what source 001's
recommendations asked for instead of a technician's cursor).

For each point of a regular grid (or given points) in the first image, a square patch is searched for in the
second image around a first guess (zero, given, or from feature matching): OpenCV ``matchTemplate``
(``TM_CCOEFF_NORMED``), sub-pixel peak by a quadratic fit to the 3 x 3 neighbourhood of the maximum. Quality:
peak correlation, peak sharpness (peak minus the best correlation more than two pixels from it) and the patch's
contrast; vectors that disagree with their neighbours are rejected by the normalised median test (Westerweel &
Scarano 2005, *Exp. Fluids* 39). Clouds are flat: their patches fail the contrast or correlation test. With a land
mask, a vector that starts or ends on land is flagged :data:`ON_LAND` and never good: land does not drift, and its
apparent motion is the two images' geolocation misfit.

**A patch across two motions** — pack ice beside fast ice or land — measures a mix of both, which no σ from its
peak describes (in simulated pairs with fast ice such vectors erred by 3.6 times their σ). A good vector is flagged
:data:`MIXED_MOTION` when land lies in its patch (at the start or the end; with a land mask) or when the patches
around it disagree with it (:func:`neighbour_disagreement`: eight satellite patches a third of a patch away, χ² of
the nine displacements about their mean over their σ, threshold :data:`MIXED_MOTION_THRESHOLD`) — the fast-ice edge,
which no mask knows. Both read only the images and the land mask (``experiments/results/tracking_calibration.md``:
detections, false alarms and the σ of the good vectors left).

**Each vector's σ** comes from its correlation peak (:func:`peak_covariance`), as for least-squares matching with
noise in both images (Förstner 1982; the same model as the tie points of :mod:`seaice_jax.imagery.ties`): the
displacement's covariance is C = 2 (1 − ρ)/N_eff (−H)⁻¹ pixel², ρ the peak's NCC (1 − ρ ≈ the noise-to-signal
variance ratio), H its curvature per pixel² (from the quadratic fit), N_eff = patch² / ``correlation_area`` the
independent samples of the template; σ² = ``sigma_floor``² + diag C per axis (row, column). The two constants are
calibrated by Monte Carlo against simulated sequences with known drift (``experiments/tracking_calibration.py``,
seeds 0-29, checked on the fresh seeds 1000-1029: ``experiments/results/tracking_calibration.md``). **What the
neighbours say** then scales that variance: σ² → σ² (a + b χ²_ν / m), χ²_ν the vector's neighbour statistic
(:func:`neighbour_disagreement`, where it is measured), m its median over the vectors of the same call the
mixed-motion flag leaves (:func:`disagreement_reference`) and ``disagreement_scale`` = (a, b)
(:data:`DISAGREEMENT_SCALE`). The local scatter of the nine displacements is a second estimate of the peak
variance's scale, pooled with the model's as in an empirical-Bayes (moderated) variance, the weights fitted on
vectors of one motion; the scatter is read against the pair's own typical χ²_ν because overlapping patches share
noise, so that the statistic of one motion is smaller in noisy pairs (median 0.85 against 1.30 in clean ones) at
the same calibration of the peak's σ. A vector of one motion keeps its σ on average; one whose surroundings
disagree more than the pair's vectors do (the fast-ice edge the flag misses) gets a larger σ.

Positions are 0-based (row, column) of the images' common :class:`~seaice_jax.geometry.projections.MapGrid`;
:meth:`Displacements.in_map` gives metres and latitude/longitude.
"""

from dataclasses import dataclass, replace

import cv2
import numpy as np

from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.projections import MapGrid

GOOD, NO_DATA, LOW_CONTRAST, LOW_CORRELATION, FLAT_PEAK, AT_EDGE, OUTLIER, ON_LAND, MIXED_MOTION = range(9)
STATUS = {GOOD: "good", NO_DATA: "patch outside an image or missing data", LOW_CONTRAST: "patch without texture",
          LOW_CORRELATION: "correlation below threshold", FLAT_PEAK: "correlation peak not distinct",
          AT_EDGE: "peak at the edge of the search window", OUTLIER: "disagrees with its neighbours",
          ON_LAND: "start or end on land",
          MIXED_MOTION: "patch across two motions, land in it or the patches beside it disagree"}
"""``status`` codes of a displacement vector (written as ``status_flag`` in CF-NetCDF files): the one vocabulary of
the package's tracking and tie matching (:data:`seaice_jax.io.products.TO_OSISAF_STATUS` translates it)."""


MIXED_MOTION_THRESHOLD = 4.0
"""χ² per degree of freedom of a vector's and its satellites' displacements about their weighted mean above which
its patch is taken to see two motions (:func:`neighbour_disagreement`). Tuned on the tuning seeds 0-29 and
64000-64029 of ``experiments/tracking_calibration.py`` (simulated pairs with fast ice): the neighbour test flags
1.2 % / 2.2 % of the vectors of one motion without land in their patch (3.2 % / 4.2 % of all of one motion with the
land rule), and with the land rule 75 % / 76 % of the vectors whose patch straddles the fast-ice edge or the coast;
the good vectors left are calibrated (empirical / stated σ 1.01 / 0.97; 2.45 / 2.66 without the flag; σ from the
peak alone, before :data:`DISAGREEMENT_SCALE`). Between 3.5 and 5 that ratio moves by 2-4 %."""
DISAGREEMENT_SCALE = (0.337, 0.567)
"""``(a, b)``: a tracked vector's variance from its peak is scaled by a + b χ²_ν / m, χ²_ν its neighbour statistic
(:func:`neighbour_disagreement`; 1 where not measured), m the call's reference (:func:`disagreement_reference`).
Fitted by maximum likelihood (errors Gaussian, both axes) on the good vectors of one motion of the tuning seeds
0-29 and 64000-64029 of ``experiments/tracking_calibration.py`` (0.351, 0.585 and 0.323, 0.550 fitted on each
half): there the error / σ from the peak alone grows with χ²_ν (RMS 0.74 at χ²_ν < 0.5 to 1.42 at 3-4) alike
for vectors of one motion and for those across two motions the flag leaves (0.70 to 1.43), whose χ²_ν is larger
(median 1.66 against 1.07). With the scale: one motion 1.00, across two motions unflagged 0.98 (0.97 and 1.09
from the peak alone), 0.96-1.07 in bins of χ²_ν of 0.5 for one motion; by noise level 0.97-1.01 (0.96-0.99 from
the peak alone; 0.94-1.07 with a + b χ²_ν not referred to m, (0.375, 0.46), which m replaced). Checked on fresh
seeds in ``experiments/results/calibration.md`` and ``experiments/results/tracking_calibration.md``."""
DISAGREEMENT_REFERENCE = 1.15
"""The reference m of :data:`DISAGREEMENT_SCALE` where a call has fewer than :data:`MIN_REFERENCE_VECTORS`
measured statistics: the median over the tuning pairs of their medians (1.146; 0.77-1.67 from pair to pair)."""
MIN_REFERENCE_VECTORS = 20
"""Measured neighbour statistics (not flagged) a call of :func:`track` needs for its own reference m."""
CORRELATION_AREA = 3.3
"""Calibrated template pixels per independent sample of the tracking σ (``experiments/tracking_calibration.py``)."""
SIGMA_FLOOR = 0.04
"""Calibrated σ floor of a tracked displacement, pixels per axis (``experiments/tracking_calibration.py``)."""


@dataclass(frozen=True)
class TrackingOptions:
    """Choices of :func:`track`.

    Attributes:
        patch: side of the square template, pixels (odd). search: largest displacement searched, pixels, around
            the first guess. spacing: pixels between grid points (when no points are given).
        min_correlation: peak NCC below this is rejected. min_sharpness: peak minus the best correlation more
            than two pixels away. min_contrast: standard deviation of the template (image units).
        median_threshold: normalised median test threshold; neighbours: vectors it compares with.
        first_guess: ``"zero"`` or ``"features"`` (ORB matches and a RANSAC similarity transform).
        correlation_area: template pixels per independent sample of the σ model, N_eff = patch² /
            correlation_area (module docstring). sigma_floor: pixels, the σ the correlation peak cannot see (the
            quadratic fit's pull toward whole pixels), added in quadrature per axis. Both calibrated
            (``experiments/results/tracking_calibration.md``).
        mixed_motion_threshold: χ² per degree of freedom above which the patches beside a vector disagree with it
            (:func:`neighbour_disagreement`) and it is :data:`MIXED_MOTION`; ``None``: no such test (a patch with
            land in it is :data:`MIXED_MOTION` all the same when a land mask is given).
        disagreement_scale: ``(a, b)``, dimensionless: each σ² from the peak is scaled by a + b χ²_ν / m where the
            neighbour statistic χ²_ν is measured, m its median over the call (:data:`DISAGREEMENT_SCALE`, calibrated
            with the defaults of ``correlation_area`` and ``sigma_floor``); ``None``: σ from the peak alone.
    """

    patch: int = 15
    search: int = 6
    spacing: int = 8
    min_correlation: float = 0.6
    min_sharpness: float = 0.05
    min_contrast: float = 0.03
    median_threshold: float = 3.0
    neighbours: int = 8
    first_guess: str = "zero"
    correlation_area: float = CORRELATION_AREA
    sigma_floor: float = SIGMA_FLOOR
    mixed_motion_threshold: float | None = MIXED_MOTION_THRESHOLD
    disagreement_scale: tuple[float, float] | None = DISAGREEMENT_SCALE

    def __post_init__(self):
        if self.patch < 5 or self.patch % 2 == 0:
            raise SeaiceError(f"patch must be an odd number of pixels >= 5, got {self.patch}")
        if self.search < 1:
            raise SeaiceError(f"search must be at least 1 pixel, got {self.search}")
        if self.first_guess not in ("zero", "features"):
            raise SeaiceError(f"first_guess must be 'zero' or 'features', got {self.first_guess!r}")
        if not self.correlation_area > 0:
            raise SeaiceError(f"correlation_area must be > 0 pixels, got {self.correlation_area}")
        if not self.sigma_floor >= 0:
            raise SeaiceError(f"sigma_floor must be >= 0 pixels, got {self.sigma_floor}")
        if self.mixed_motion_threshold is not None and not self.mixed_motion_threshold > 0:
            raise SeaiceError(f"mixed_motion_threshold must be > 0 or None, got {self.mixed_motion_threshold}")
        if self.disagreement_scale is not None and not (
                len(self.disagreement_scale) == 2 and min(self.disagreement_scale) >= 0
                and sum(self.disagreement_scale) > 0):
            raise SeaiceError(f"disagreement_scale must be two numbers >= 0, not both 0, or None, got "
                              f"{self.disagreement_scale}")


@dataclass(frozen=True)
class Displacements:
    """Displacement vectors between two images of one grid.

    Attributes:
        row, column: ``(n,)`` start positions (0-based pixels of the grid). d_row, d_column: ``(n,)`` pixels.
        correlation, sharpness: ``(n,)`` peak NCC and its distinctness. status: ``(n,)`` :data:`STATUS` codes.
        sigma_row, sigma_column: ``(n,)`` pixels, σ of ``d_row``, ``d_column`` from the correlation peak, scaled by
            the neighbour statistic (module docstring; NaN where not measured).
        disagreement: ``(n,)`` the neighbour statistic χ²_ν (:func:`neighbour_disagreement`; NaN where not
            measured: not good before the test, land in the patch, too few satellites), or ``None`` where no
            neighbour test was run.
    """

    row: np.ndarray
    column: np.ndarray
    d_row: np.ndarray
    d_column: np.ndarray
    correlation: np.ndarray
    sharpness: np.ndarray
    status: np.ndarray
    sigma_row: np.ndarray
    sigma_column: np.ndarray
    disagreement: np.ndarray | None = None

    @property
    def good(self) -> np.ndarray:
        return self.status == GOOD

    def in_map(self, grid: MapGrid):
        """Start and end positions in map metres and radians: dict of ``x, y, dx, dy`` (m, along the grid's
        axes) and ``latitude, longitude, end_latitude, end_longitude``."""
        x, y = (np.asarray(a) for a in grid.to_xy(self.row, self.column))
        x_end, y_end = (np.asarray(a) for a in grid.to_xy(self.row + self.d_row, self.column + self.d_column))
        lat, lon = (np.asarray(a) for a in grid.projection.inverse(x, y))
        lat_end, lon_end = (np.asarray(a) for a in grid.projection.inverse(x_end, y_end))
        return dict(x=x, y=y, dx=x_end - x, dy=y_end - y, latitude=lat, longitude=lon, end_latitude=lat_end,
                    end_longitude=lon_end)


def grid_points(shape, options: TrackingOptions):
    """Rows and columns ``(n,)`` of a regular grid of points far enough from the edges for patch and search."""
    margin = options.patch // 2 + options.search
    rows = np.arange(margin, shape[0] - margin, options.spacing)
    columns = np.arange(margin, shape[1] - margin, options.spacing)
    r, c = np.meshgrid(rows, columns, indexing="ij")
    return r.ravel().astype(float), c.ravel().astype(float)


def feature_guess(first, second, valid_first=None, valid_second=None):
    """A first guess of the motion: ORB features matched between the images and a RANSAC similarity transform.

    Returns:
        a function ``(row, column) -> (d_row, d_column)``, or ``None`` when too few features match.
    """
    images = [_as_uint8(a, m) for a, m in ((first, valid_first), (second, valid_second))]
    orb = cv2.ORB.create(nfeatures=2000, edgeThreshold=15, patchSize=15)
    (k1, d1), (k2, d2) = (orb.detectAndCompute(a, None) for a in images)
    if d1 is None or d2 is None or len(k1) < 8 or len(k2) < 8:
        return None
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(d1, d2)
    if len(matches) < 8:
        return None
    p1 = np.array([k1[m.queryIdx].pt for m in matches], np.float32)
    p2 = np.array([k2[m.trainIdx].pt for m in matches], np.float32)
    transform, inliers = cv2.estimateAffinePartial2D(p1, p2, method=cv2.RANSAC, ransacReprojThreshold=2.0)
    if transform is None or inliers.sum() < 6:
        return None

    def guess(row, column):
        x = transform[0, 0] * column + transform[0, 1] * row + transform[0, 2]
        y = transform[1, 0] * column + transform[1, 1] * row + transform[1, 2]
        return y - row, x - column

    return guess


def _as_uint8(image, valid):
    image = np.where(np.isfinite(image) if valid is None else valid & np.isfinite(image), image, np.nan)
    low, high = np.nanpercentile(image, [1, 99])
    return np.nan_to_num(np.clip((image - low) / max(high - low, 1e-12), 0, 1) * 255).astype(np.uint8)


def correlation_peak(template, window):
    """NCC (``TM_CCOEFF_NORMED``) of ``template`` at every offset in ``window`` (float32 arrays) and its maximum.

    Returns:
        ``(surface, i, j, correlation, sharpness)``: the surface ``(window − template + 1)`` per axis, the maximum's
        indices, its value, and its value minus the best correlation more than two pixels from it.
    """
    surface = cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED)
    i, j = np.unravel_index(int(np.argmax(surface)), surface.shape)
    peak = float(surface[i, j])
    away = surface.copy()
    away[max(i - 2, 0):i + 3, max(j - 2, 0):j + 3] = -1.0
    return surface, int(i), int(j), peak, peak - float(away.max())


def quadratic_peak(surface, i, j):
    """Quadratic fit to the 3 x 3 neighbourhood of the maximum at interior ``(i, j)``.

    Returns:
        ``(offset, hessian)``: the sub-pixel offset ``(di, dj)`` (clipped to ±1; zero where the fit has no
        maximum) and the fit's ``(2, 2)`` second derivatives (per pixel²).
    """
    patch = surface[i - 1:i + 2, j - 1:j + 2].astype(float)
    gi = 0.5 * (patch[2, 1] - patch[0, 1])
    gj = 0.5 * (patch[1, 2] - patch[1, 0])
    hii = patch[2, 1] - 2 * patch[1, 1] + patch[0, 1]
    hjj = patch[1, 2] - 2 * patch[1, 1] + patch[1, 0]
    hij = 0.25 * (patch[2, 2] - patch[2, 0] - patch[0, 2] + patch[0, 0])
    hessian = np.array([[hii, hij], [hij, hjj]])
    if np.linalg.det(hessian) <= 0 or hii >= 0:
        return np.zeros(2), hessian
    return np.clip(-np.linalg.solve(hessian, [gi, gj]), -1.0, 1.0), hessian


def peak_covariance(correlation: float, hessian: np.ndarray, samples: float) -> np.ndarray:
    """``(2, 2)`` pixel² covariance of a displacement from its NCC peak: C = 2 (1 − ρ)/N_eff (−H)⁻¹ (module
    docstring), ``correlation`` ρ, ``hessian`` H ``(2, 2)`` per pixel² (negative definite), ``samples`` N_eff."""
    return 2.0 * max(1.0 - correlation, 0.0) / samples * np.linalg.inv(-hessian)


def track(first, second, options: TrackingOptions = TrackingOptions(), points=None, valid_first=None,
          valid_second=None, guess=None, land=None) -> Displacements:
    """Displacements of the texture of ``first`` found in ``second`` (two images of one map grid).

    Args:
        first, second: ``(rows, columns)`` arrays (NaN: no data).
        points: ``(rows (n,), columns (n,))`` start positions; default :func:`grid_points`.
        valid_first, valid_second: bool masks (default: finite values).
        guess: ``(d_row (n,), d_column (n,))`` first guesses in pixels, overriding ``options.first_guess``.
        land: ``(rows, columns)`` bool, True on land: a vector whose start or end pixel is land is
            :data:`ON_LAND` (a start on land is not tracked), before the median test; a good vector with land in
            its patch (at the start or the end) is :data:`MIXED_MOTION`, after it.

    The median test (:func:`median_test`) comes before the neighbour test, which looks at the good vectors left
    without land in their patch: its χ²_ν (``disagreement``) flags a vector :data:`MIXED_MOTION` above
    ``options.mixed_motion_threshold`` and scales its σ² by ``options.disagreement_scale`` (a + b χ²_ν / m, m the
    median statistic of the vectors tracked in this call that the flag leaves: :func:`disagreement_reference`).
    """
    first, second = np.asarray(first, float), np.asarray(second, float)
    if first.shape != second.shape:
        raise SeaiceError(f"the images must share one grid, got shapes {first.shape} and {second.shape}")
    valid_first = np.isfinite(first) if valid_first is None else valid_first & np.isfinite(first)
    valid_second = np.isfinite(second) if valid_second is None else valid_second & np.isfinite(second)
    rows, columns = grid_points(first.shape, options) if points is None else (
        np.asarray(points[0], float), np.asarray(points[1], float))
    if guess is not None:
        guess_row, guess_column = (np.broadcast_to(np.asarray(g, float), rows.shape) for g in guess)
    elif options.first_guess == "features" and (predict := feature_guess(first, second, valid_first,
                                                                        valid_second)) is not None:
        guess_row, guess_column = predict(rows, columns)
    else:
        guess_row, guess_column = np.zeros_like(rows), np.zeros_like(rows)
    images = _prepared(first, second, valid_first, valid_second)
    n = rows.size
    names = ("d_row", "d_column", "correlation", "sharpness", "sigma_row", "sigma_column")
    out = {k: np.full(n, np.nan) for k in names}
    status = np.full(n, GOOD)
    starts_on_land = np.zeros(n, bool) if land is None else on_land(land, rows, columns)
    status[starts_on_land] = ON_LAND
    for k in np.nonzero(~starts_on_land)[0]:
        status[k], *measured = _track_point(images, rows[k], columns[k], guess_row[k], guess_column[k], options)
        for name, value in zip(names, measured, strict=True):
            out[name][k] = value
    tracked = _as_measured(rows, columns, guess_row, guess_column, status, out, ~starts_on_land)
    if land is not None:
        status[on_land(land, rows + out["d_row"], columns + out["d_column"])] = ON_LAND
    tested = median_test(Displacements(rows, columns, status=status, **out), options)
    mixed = np.zeros(n, bool)
    if land is not None:  # land does not move: a patch with land in it sees two motions wherever the ice drifts
        half = options.patch // 2
        mixed |= patch_touches_land(land, rows, columns, half) | patch_touches_land(
            land, rows + tested.d_row, columns + tested.d_column, half)
    if options.mixed_motion_threshold is None and options.disagreement_scale is None:
        disagreement = None
    else:
        good = np.nonzero(tested.good & ~mixed)[0]
        disagreement = np.full(n, np.nan)
        disagreement[good] = _neighbour_disagreement(images, rows[good], columns[good], guess_row[good],
                                                     guess_column[good], options, tracked)
        if options.mixed_motion_threshold is not None:
            mixed |= disagreement > options.mixed_motion_threshold  # NaN: not tested, not flagged
    status = tested.status.copy()
    status[tested.good & mixed] = MIXED_MOTION
    root_scale = np.sqrt(disagreement_variance_scale(disagreement, options))
    return replace(tested, status=status, sigma_row=tested.sigma_row * root_scale,
                   sigma_column=tested.sigma_column * root_scale, disagreement=disagreement)


def disagreement_reference(disagreement, options: TrackingOptions = TrackingOptions()) -> float:
    """The reference m of the variance scale: the median of the measured statistics ``disagreement`` ``(n,)``
    (χ²_ν of :func:`neighbour_disagreement`, NaN where not measured) of one call that the mixed-motion flag leaves
    (at most ``options.mixed_motion_threshold``), the pair's own level of the statistic for one motion;
    :data:`DISAGREEMENT_REFERENCE` where fewer than :data:`MIN_REFERENCE_VECTORS` are measured."""
    statistic = np.asarray(disagreement, float)
    kept = statistic[np.isfinite(statistic)]
    if options.mixed_motion_threshold is not None:
        kept = kept[kept <= options.mixed_motion_threshold]
    return float(np.median(kept)) if kept.size >= MIN_REFERENCE_VECTORS else DISAGREEMENT_REFERENCE


def disagreement_variance_scale(disagreement, options: TrackingOptions = TrackingOptions()) -> np.ndarray:
    """``(n,)`` the factor a + b χ²_ν / m of a vector's σ² from its peak (``options.disagreement_scale`` = (a, b)),
    ``disagreement`` χ²_ν ``(n,)`` of all the vectors of one call (:func:`neighbour_disagreement`; NaN: not
    measured, factor 1), m their :func:`disagreement_reference`; ``None`` (no neighbour test): 1. 1 everywhere when
    ``disagreement_scale`` is ``None``."""
    if disagreement is None or options.disagreement_scale is None:
        return np.ones(() if disagreement is None else np.shape(disagreement))
    base, weight = options.disagreement_scale
    statistic = np.asarray(disagreement, float)
    reference = disagreement_reference(statistic, options)
    return np.where(np.isfinite(statistic), base + weight * np.nan_to_num(statistic) / reference, 1.0)


def _as_measured(rows, columns, guess_row, guess_column, status, out, tracked) -> dict:
    """The points ``tracked`` ``(n,)`` bool at whole pixels as :func:`_neighbour_disagreement` keeps its patches:
    ``{(row, column, guess row, guess column): (d_row, d_column, sigma_row, sigma_column) or None}`` (None: not
    good as :func:`_track_point` returned it), so that a satellite on a lattice point is not tracked twice."""
    whole = tracked & (rows == np.round(rows)) & (columns == np.round(columns))
    return {(round(rows[k]), round(columns[k]), round(guess_row[k]), round(guess_column[k])):
            (out["d_row"][k], out["d_column"][k], out["sigma_row"][k], out["sigma_column"][k])
            if status[k] == GOOD else None for k in np.nonzero(whole)[0]}


def _prepared(first, second, valid_first, valid_second):
    """The two images with no data as 0 (float32) and their validity masks, as :func:`_track_point` takes them."""
    return (np.where(valid_first, first, 0.0).astype(np.float32), np.where(valid_second, second, 0.0).astype(
        np.float32), valid_first, valid_second)


def patch_touches_land(land, rows, columns, half: int) -> np.ndarray:
    """``(n,)`` bool: a land pixel of ``land`` ``(n_rows, n_columns)`` bool lies in the square of ``2 half + 1``
    pixels centred on the grid cell nearest each position ``rows, columns`` ``(n,)`` (0-based pixels); the part of
    the square off the grid counts as sea; False where a position is NaN. By an integral image: O(1) per point."""
    land = np.asarray(land, bool)
    integral = np.pad(np.cumsum(np.cumsum(land, axis=0, dtype=np.int64), axis=1), ((1, 0), (1, 0)))
    row, column = np.rint(np.asarray(rows, float)), np.rint(np.asarray(columns, float))
    finite = np.isfinite(row) & np.isfinite(column)
    row, column = np.where(finite, row, 0.0).astype(int), np.where(finite, column, 0.0).astype(int)
    top, bottom = np.clip(row - half, 0, land.shape[0]), np.clip(row + half + 1, 0, land.shape[0])
    left, right = np.clip(column - half, 0, land.shape[1]), np.clip(column + half + 1, 0, land.shape[1])
    count = integral[bottom, right] - integral[top, right] - integral[bottom, left] + integral[top, left]
    return finite & (count > 0)


SATELLITE_SPACING = 1 / 3
"""Offset of a vector's satellite patches (:func:`neighbour_disagreement`) in units of the patch side: 5 pixels for
the default 15-pixel patch, so that each satellite shares two thirds of the vector's patch (in one axis) and sees a
third of a patch beyond it. Tuned with the threshold: at 6 pixels the test flags two to three times the vectors of
one motion for 4 % more detections (the satellites reach fast ice the vector's own patch does not)."""
MIN_SATELLITES = 4
"""Good satellite patches a vector needs for :func:`neighbour_disagreement` (fewer: NaN, not tested)."""


def neighbour_disagreement(first, second, rows, columns, options: TrackingOptions = TrackingOptions(), guess=None,
                           valid_first=None, valid_second=None) -> np.ndarray:
    """``(n,)`` χ² per degree of freedom of the displacement at each position ``rows, columns`` ``(n,)`` (pixels)
    and those of its eight satellites (patches offset by ±``SATELLITE_SPACING`` x the patch side in row and
    column, tracked as :func:`track` tracks a point, land or not) about their weighted mean, with each one's
    σ from its peak: of order 1 or less where the patch and its surroundings move as one (median 1.1 over the
    simulated pairs of the tuning; neighbouring patches share pixels, so the values are not χ²-distributed and the
    threshold is tuned, :data:`MIXED_MOTION_THRESHOLD`), large where a
    patch straddles two motions (pack ice beside fast ice or land: the vector mixes both, its σ describes neither).
    NaN where fewer than :data:`MIN_SATELLITES` satellites are good. ``first, second, guess, valid_first,
    valid_second``: as for :func:`track`."""
    first, second = np.asarray(first, float), np.asarray(second, float)
    valid_first = np.isfinite(first) if valid_first is None else valid_first & np.isfinite(first)
    valid_second = np.isfinite(second) if valid_second is None else valid_second & np.isfinite(second)
    rows, columns = np.asarray(rows, float), np.asarray(columns, float)
    guess_row, guess_column = (np.zeros_like(rows), np.zeros_like(rows)) if guess is None else (
        np.broadcast_to(np.asarray(g, float), rows.shape) for g in guess)
    return _neighbour_disagreement(_prepared(first, second, valid_first, valid_second), rows, columns, guess_row,
                                   guess_column, options)


def _neighbour_disagreement(images, rows, columns, guess_row, guess_column, options: TrackingOptions,
                            measured: dict | None = None):
    """:func:`neighbour_disagreement` on prepared ``images`` (:func:`_prepared`). Every patch is tracked at whole
    pixels (the position rounded), once: neighbouring vectors share satellites, and ``measured`` (as
    :func:`_as_measured` makes it; updated) holds those tracked already."""
    offset = max(1, round(SATELLITE_SPACING * options.patch))
    steps = [(p, q) for p in (-offset, 0, offset) for q in (-offset, 0, offset) if (p, q) != (0, 0)]
    measured = {} if measured is None else measured

    def displacement(row: int, column: int, guess: tuple[int, int]):
        key = (row, column, *guess)
        if key not in measured:
            status, d_row, d_column, _, _, sigma_row, sigma_column = _track_point(images, row, column, guess[0],
                                                                                  guess[1], options)
            measured[key] = (d_row, d_column, sigma_row, sigma_column) if status == GOOD else None
        return measured[key]

    result = np.full(rows.size, np.nan)
    for k in np.nonzero(np.isfinite(rows) & np.isfinite(columns))[0]:
        row, column, guess = round(rows[k]), round(columns[k]), (round(guess_row[k]), round(guess_column[k]))
        centre = displacement(row, column, guess)
        satellites = [v for p, q in steps if (v := displacement(row + p, column + q, guess)) is not None]
        if centre is not None and len(satellites) >= MIN_SATELLITES:
            result[k] = _scatter_about_mean(np.array([centre, *satellites]))
    return result


def _scatter_about_mean(vectors: np.ndarray) -> float:
    """χ² per degree of freedom of displacements about their weighted mean: ``vectors`` ``(m, 4)`` rows of
    ``(d_row, d_column, sigma_row, sigma_column)`` pixels, each axis apart, 2 (m − 1) degrees of freedom."""
    displacement, weight = vectors[:, :2], vectors[:, 2:] ** -2.0
    mean = np.sum(weight * displacement, axis=0) / np.sum(weight, axis=0)
    return float(np.sum(weight * (displacement - mean) ** 2) / (2 * (len(vectors) - 1)))


def on_land(land, rows, columns) -> np.ndarray:
    """``(n,)`` bool: the grid cell nearest each position ``rows, columns`` ``(n,)`` (0-based pixels) is land in
    ``land`` ``(n_rows, n_columns)`` bool; False off the grid and where a position is NaN."""
    land = np.asarray(land, bool)
    row, column = np.rint(np.asarray(rows, float)), np.rint(np.asarray(columns, float))
    inside = (row >= 0) & (row < land.shape[0]) & (column >= 0) & (column < land.shape[1])
    result = np.zeros(row.shape, bool)
    result[inside] = land[row[inside].astype(int), column[inside].astype(int)]
    return result


def _track_point(images, row, column, guess_row, guess_column, options: TrackingOptions):
    """One point: ``(status, d_row, d_column, correlation, sharpness, sigma_row, sigma_column)`` (pixels; NaN where
    not measured). ``images``: the two images with no data as 0 (float32) and their validity masks."""
    a, b, valid_first, valid_second = images
    h, s = options.patch // 2, options.search
    missing = (NO_DATA, *[np.nan] * 6)
    if not (np.isfinite(row) and np.isfinite(column)):
        return missing
    r, c = int(round(row)), int(round(column))
    gr, gc = int(round(guess_row)), int(round(guess_column))
    r2, c2 = r + gr, c + gc
    if (r - h < 0 or c - h < 0 or r + h + 1 > a.shape[0] or c + h + 1 > a.shape[1] or r2 - h - s < 0
            or c2 - h - s < 0 or r2 + h + s + 1 > b.shape[0] or c2 + h + s + 1 > b.shape[1]
            or not valid_first[r - h:r + h + 1, c - h:c + h + 1].all()
            or not valid_second[r2 - h - s:r2 + h + s + 1, c2 - h - s:c2 + h + s + 1].all()):
        return missing
    template = a[r - h:r + h + 1, c - h:c + h + 1]
    if template.std() < options.min_contrast:
        return LOW_CONTRAST, *[np.nan] * 6
    surface, i, j, peak, sharpness = correlation_peak(template, b[r2 - h - s:r2 + h + s + 1, c2 - h - s:c2 + h + s + 1])
    if i in (0, surface.shape[0] - 1) or j in (0, surface.shape[1] - 1):
        return AT_EDGE, np.nan, np.nan, peak, sharpness, np.nan, np.nan
    (di, dj), hessian = quadratic_peak(surface, i, j)
    d_row, d_column = gr + i - s + di + (r - row), gc + j - s + dj + (c - column)
    if np.linalg.det(hessian) <= 0 or hessian[0, 0] >= 0:  # no maximum in the fit: no sub-pixel position, no σ
        return FLAT_PEAK, d_row, d_column, peak, sharpness, np.nan, np.nan
    covariance = peak_covariance(peak, hessian, options.patch**2 / options.correlation_area)
    sigma_row, sigma_column = np.sqrt(options.sigma_floor**2 + np.diagonal(covariance))
    status = LOW_CORRELATION if peak < options.min_correlation else FLAT_PEAK if sharpness < options.min_sharpness \
        else GOOD
    return status, d_row, d_column, peak, sharpness, sigma_row, sigma_column


_DENSE_NEIGHBOURS = 2048
"""Good vectors up to which the median test's neighbours come from one distance matrix (40 bytes per pair: 160 MB
here); beyond, from blocks of rows (:func:`_nearest`), so that memory grows with the vectors, not their square
(``track --spacing 1`` on a 337² grid, 97 000 vectors, was killed at 20 GB)."""


def _nearest(position, k: int, block: int = 256):
    """``(n, k)`` indices of each point's ``k`` nearest other points (``position`` ``(n, 2)``, ``n > k``; ties in any
    order). Exact, in memory and time about linear in ``n``: the points sorted by their first coordinate, a block of
    ``block`` points compares itself with the points within ``r`` of its span in that coordinate, and keeps the
    answers whose ``k``-th distance is at most ``r`` (nothing outside that band is nearer); ``r`` doubles for the
    rest."""
    n = position.shape[0]
    order = np.argsort(position[:, 0], kind="stable")
    ordered = position[order]
    first = ordered[:, 0]
    extent = np.ptp(position, axis=0)
    # the radius of a disc holding k points at the mean density, and a half more
    start_radius = 1.5 * np.sqrt(max(extent[0] * extent[1], np.max(extent) ** 2 / n, 1e-300) / n * k / np.pi)
    nearest = np.empty((n, k), int)
    for begin in range(0, n, block):
        pending = np.arange(begin, min(begin + block, n))
        radius = start_radius
        while pending.size:
            low = np.searchsorted(first, first[pending].min() - radius, "left")
            high = np.searchsorted(first, first[pending].max() + radius, "right")
            if high - low <= k and (low > 0 or high < n):
                radius *= 2.0
                continue
            across = ordered[pending, 0, None] - first[None, low:high]
            along = ordered[pending, 1, None] - ordered[None, low:high, 1]
            distance = across * across + along * along
            distance[np.arange(pending.size), pending - low] = np.inf  # not itself
            chosen = np.argpartition(distance, k - 1, axis=1)[:, :k]
            kth = np.take_along_axis(distance, chosen, 1).max(axis=1)
            done = (kth <= radius * radius) | ((low == 0) & (high == n))
            nearest[order[pending[done]]] = order[low + chosen[done]]
            pending = pending[~done]
            radius *= 2.0
    return nearest


def median_test(displacements: Displacements, options: TrackingOptions = TrackingOptions()) -> Displacements:
    """Flag as :data:`OUTLIER` the good vectors that fail the normalised median test against their
    ``options.neighbours`` nearest good neighbours: |d − median| / (median |d_i − median| + 0.1 px) > threshold."""
    good = np.nonzero(displacements.good)[0]
    if good.size <= options.neighbours:
        return displacements
    position = np.stack([displacements.row[good], displacements.column[good]], 1)
    vector = np.stack([displacements.d_row[good], displacements.d_column[good]], 1)
    if good.size <= _DENSE_NEIGHBOURS:
        distance = np.linalg.norm(position[:, None] - position[None], axis=-1)
        np.fill_diagonal(distance, np.inf)
        nearest = np.argsort(distance, axis=1)[:, :options.neighbours]
    else:
        nearest = _nearest(position, options.neighbours)
    neighbours = vector[nearest]  # (g, k, 2)
    median = np.median(neighbours, axis=1)
    spread = np.median(np.abs(neighbours - median[:, None]), axis=1)
    normalised = np.abs(vector - median) / (spread + 0.1)
    status = displacements.status.copy()
    status[good[(normalised > options.median_threshold).any(axis=1)]] = OUTLIER
    return replace(displacements, status=status)
