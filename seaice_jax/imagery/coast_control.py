"""Control points from the coastline: the image's land/sea edges matched to the coast projected through the current
model (source 001, VHR2: the operator overlaid the coastline on the image to judge a rectification; here the overlay
is matched automatically, and the matches become control points of the orbit fit).

From a rough model (the ascending node and the pass time as a user knows them, tens of kilometres off), each level
of a coarse-to-fine loop:

1. predicts the land in image space: every pixel centre through the current model (:meth:`ScanModel.forward`)
   into the land test (GSHHG: :meth:`~seaice_jax.io.coastline.Coastline.contains`, passed in by the caller — this
   layer does no I/O);
2. matches windows of the prediction (where the coast crosses them) in the image: at every shift the image window
   is fitted by least squares as an unknown step function of the distance to the predicted coast
   (:func:`profile_fit`: land, sea bands 0-2, 2-5, 5-10, 10-20 pixels offshore, farther sea; both smoothed by a
   Gaussian), which needs no assumption on the sign of the land/sea contrast and takes a band of fast ice along
   the coast in its stride; the best R² wins (the first level searches the whole image's shift first), refined to
   a sub-pixel shift by a quadratic fitted to the 3 x 3 values around the peak. The last level, whose matches
   are the final control points, fits land against sea (:data:`COAST_STEP`: the sea bands bias the position
   landward, :data:`COAST_BANDS`) only on the image's pixels within a few pixels of the predicted coast, the
   same pixels at every shift (:data:`COAST_EDGE`: farther out, pack beyond a band of fast ice pulls it landward
   too; a band moving with the template pushed it seaward);
3. proposes a control point per match: the image position where the window was found, the ground position the
   current model gives the window's centre, and σ from the peak: ``C = (1 − ρ²) / (ρ n) (−H_ρ)⁻¹`` pixel² (ρ = √R²
   at the peak, H_ρ its Hessian per pixel², n the independent pixels fitted), the larger axis of C taken as
   an isotropic σ, times :data:`MATCH_SIGMA_SCALE` (calibrated: the fits' σ̂0 is 1 on simulated images), turned into
   metres with the local pixel size;
4. fits the scan model (:func:`~seaice_jax.adjust.orbit.fit.fit_scan_model`) and removes, one at a time, the point
   with the largest |w| beyond the critical value (Baarda's data snooping, :mod:`seaice_jax.adjust.engine.quality`),
   refitting each time. The points' errors are not independent (issue 29): matches whose windows overlap share
   pixels (:data:`MATCH_OVERLAP_CORRELATION`), and the coastline database and the imaged coast may disagree by an
   error field all of one image's points share (a shift, :data:`COAST_DATUM_SIGMA`, and gradients,
   :data:`COAST_DATUM_GRADIENT_SIGMA`; zero on simulated images, whose coast is the database's), so every fit is
   solved with these in the points' covariance (:func:`coast_point_covariance`, :func:`correlated_fit`): the
   model's covariance, σ̂0 and the w-tests account for them; the global test also for the errors' heavy tails
   (:data:`MATCH_ERROR_KURTOSIS`).

The next level starts from the fitted model with a smaller search, smaller windows and less smoothing.
"""

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import jax.numpy as jnp
import numpy as np

from seaice_jax.adjust.engine.quality import noncentrality
from seaice_jax.adjust.orbit.fit import OrbitFit, fit_scan_model, position_jacobian
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.earth import MEAN_RADIUS
from seaice_jax.geometry.scan import ScanModel, scan_unknowns, with_scan_unknowns
from seaice_jax.sensors.control import ControlPoints

LandTest = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""``land(latitude_deg, longitude_deg) -> bool array`` of the same shape: True on land."""


COAST_BANDS = (0.0, -2.0, -5.0, -10.0, -20.0)
"""Signed distances (pixels, > 0 on land) bounding the profile's bins: land (d > 0), then sea bands 0-2, 2-5, 5-10
and 10-20 pixels offshore; farther sea is the baseline. The sea bands model a band of fast ice along the coast,
which the whole image's search and the coarse levels need to lock on; but their position is biased landward: a
free bin next to the coast on the sea side can take the land's brightness, so a seaward displacement of the image
costs the fit little and a landward one much, the R² peak is lopsided and its quadratic vertex lies landward of the
coast (0.13-0.16 pixel when the image is the prediction itself, 0.17 on simulated images, issue 29). The last
level therefore matches with :data:`COAST_STEP`."""

COAST_STEP = (0.0,)
"""The profile of land against sea (one bin, d > 0; the rest is the baseline): no free sea bin can take the land's
brightness, so the peak does not lean landward as with :data:`COAST_BANDS` (0.00 ± 0.002 pixel when the image is
the prediction, against 0.13-0.16 with the bands). Unbiased only where the sea fitted is one brightness: over a
whole window fast ice and pack differ and the peak leans landward again, so the last level fits it within
:data:`COAST_EDGE` of the coast. Too little model for the whole image's search (on seeds 61000 and 61001 it found
shifts 30-40 pixels off) and fewer matches at the first level, so it is for the last level, which starts within a
pixel or two."""


COAST_EDGE = 3.0
"""Pixels: the last level fits its profile (:data:`COAST_STEP`) only on the image's pixels within this distance of
the predicted coast placed at the expected shift (:attr:`MatchLevel.edge`), the same pixels at every shift. Over the
whole window one baseline stands for fast ice and pack, which differ, and the land's relief is in the fit: the
matches lean 0.039 ± 0.007 pixel landward along the coast's normal, with a per-match RMS of 620 m (simulated
images, the true model's prediction, ``experiments/coast_control_calibration.py --lean 61000 61060``); within 3
pixels: 0.018 ± 0.002 pixel landward, RMS 330-380 m, twice the matches found. A band that moved with the template
(96156a4-f6d2c78) leaned 0.068 ± 0.002 pixel seaward: R² over a different set of pixels at each shift preferred
shifts that put the band over quieter pixels (fast ice rather than textured land), pulling opposite coasts apart
(issue 29).
Wider bands reach the pack beyond a band of fast ice (8 pixels: 0.047 landward; with the moving band 0.15)."""


@dataclass(frozen=True)
class MatchLevel:
    """One level of the coarse-to-fine loop (pixels of the image).

    Attributes:
        search: ± pixels searched around the expected position (at the first level, around the whole image's
            shift). window: side of the square templates. step: spacing of the template centres.
        smoothing: σ of the Gaussian applied to image and prediction.
        bands: signed distances (pixels, > 0 on land) bounding the brightness profile's bins
            (:data:`COAST_BANDS`, or :data:`COAST_STEP` for a position without the bands' landward lean).
        edge: pixels; the profile is fitted only on the image's pixels within this distance of the predicted coast
            at the expected shift, fixed in the image at every shift of the search (the band's indicator smoothed as
            the templates, less ``search`` pixels at the window's border; :data:`COAST_EDGE`), ``None``: over the
            window under the templates.
    """

    search: int
    window: int
    step: int
    smoothing: float
    bands: tuple[float, ...] = COAST_BANDS
    edge: float | None = None


MATCH_SIGMA_SCALE = 0.89
"""Factor on the σ from the correlation peak, calibrated by Monte Carlo so that the final fits' σ̂0 is 1
(``experiments/coast_control_calibration.py``, one simulated 512 x 512 image per seed): pooled σ̂0 0.992
(0.987-0.998) on the 200 tuning images 61000-61199 with the calibrated :class:`CoastErrors`. With the band fixed
in the image frame (:data:`COAST_EDGE`, issue 29) a run at 0.88 with the previous error model (c 0.90, σ_c 19 m,
σ_g 0) gave 1.019 (1.012-1.025); 0.89 with the error model re-estimated from that run gave 0.992. Before: 0.88
(the band moving with the template), 1.5 (whole windows at the last level), 1.7 (the banded profile). A larger σ
lets the w-test keep more moderately wrong matches too, so σ̂0 does not fall as 1/factor."""

DEFAULT_LEVELS = (MatchLevel(6, 64, 32, 2.0), MatchLevel(3, 48, 24, 1.0),
                  MatchLevel(2, 40, 20, 0.7, COAST_STEP, COAST_EDGE))
"""Coarse to fine: after the first level's global shift (``search`` of :func:`coast_control`) the windows look only a
few pixels around it; the last level's control points are matched with :data:`COAST_STEP` within
:data:`COAST_EDGE` of the predicted coast."""


@dataclass(frozen=True)
class CoastMatches:
    """Windows of the predicted land found in the image.

    Attributes:
        pixel, scan: ``(n,)`` 1-based image position where each window's centre was found.
        predicted_pixel, predicted_scan: ``(n,)`` the window's centre in the prediction (where the current model
            puts the ground feature). sigma: ``(n,)`` pixels, isotropic σ of the match. correlation: ``(n,)`` √R² of
            the coast profile's fit at the peak.
    """

    pixel: np.ndarray
    scan: np.ndarray
    predicted_pixel: np.ndarray
    predicted_scan: np.ndarray
    sigma: np.ndarray
    correlation: np.ndarray


@dataclass(frozen=True)
class CoastControl:
    """The result of :func:`coast_control`.

    Attributes:
        model: the final fitted :class:`ScanModel`. fit: its :class:`OrbitFit` (control points, w-tests).
        rejected: ids of the points removed by the w-test, per level. matched: control points proposed per level.
        shift: ``(pixel, scan)`` the whole image's shift found at the first level (how far off the start was).
        window: side (pixels) of the last level's windows, which the final points were matched with (their
            correlation: :func:`coast_point_covariance`).
    """

    model: ScanModel
    fit: OrbitFit
    rejected: tuple[tuple[str, ...], ...]
    matched: tuple[int, ...]
    shift: tuple[float, float]
    window: int = 0


def predicted_land(model: ScanModel, land: LandTest) -> np.ndarray:
    """``(n_scans, n_pixels)`` float 0/1: the land test at every pixel centre through ``model`` (1-based pixel,
    scan; row = scan − 1, column = pixel − 1). Pixels whose ground the model cannot reach are sea."""
    scan, pixel = np.meshgrid(np.arange(1.0, model.n_scans + 1), np.arange(1.0, model.n_pixels + 1), indexing="ij")
    latitude, longitude = (np.asarray(a) for a in model.forward_unchecked(jnp.asarray(pixel), jnp.asarray(scan)))
    reached = np.isfinite(latitude) & np.isfinite(longitude)
    latitude, longitude = np.where(reached, latitude, 0.0), np.where(reached, longitude, 0.0)
    inside = np.asarray(land(np.degrees(latitude), np.degrees(longitude)), bool)
    return (inside & reached).astype(float)


def _smooth(values: np.ndarray, sigma: float) -> np.ndarray:
    return cv2.GaussianBlur(values.astype(np.float32), (0, 0), sigma) if sigma > 0 else values.astype(np.float32)


def _quadratic_peak(surface: np.ndarray, row: int, column: int):
    """Sub-pixel peak of a correlation surface at its maximum ``(row, column)`` (not on the border): a quadratic
    ``a + g·d + ½ dᵀ H d`` fitted by least squares to the 3 x 3 values; returns ``(offset (2,) [column, row],
    peak value, H (2, 2))`` or ``None`` where H is not negative definite or the peak leaves the 3 x 3."""
    patch = surface[row - 1:row + 2, column - 1:column + 2].astype(float)
    dy, dx = np.mgrid[-1:2, -1:2]
    design = np.stack([np.ones(9), dx.ravel(), dy.ravel(), 0.5 * dx.ravel() ** 2, dx.ravel() * dy.ravel(),
                       0.5 * dy.ravel() ** 2], 1)
    a, gx, gy, hxx, hxy, hyy = np.linalg.lstsq(design, patch.ravel(), rcond=None)[0]
    hessian = np.array([[hxx, hxy], [hxy, hyy]])
    if not np.all(np.linalg.eigvalsh(hessian) < 0):
        return None
    offset = -np.linalg.solve(hessian, [gx, gy])
    if np.any(np.abs(offset) > 1.0):
        return None
    return offset, float(a + 0.5 * np.dot([gx, gy], offset)), hessian


def signed_distance(land: np.ndarray) -> np.ndarray:
    """``(rows, columns)`` pixels from each cell of the boolean raster ``land`` to the nearest cell of the other kind
    (exact Euclidean distance transform) less half a cell, positive on land: the zero line runs midway between a
    land and a sea cell."""
    land = np.asarray(land, bool).astype(np.uint8)
    inland = cv2.distanceTransform(land, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    offshore = cv2.distanceTransform(1 - land, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return np.where(land > 0, inland - 0.5, 0.5 - offshore)


def coast_bands(prediction: np.ndarray, smoothing: float, bands: tuple[float, ...] = COAST_BANDS) -> np.ndarray:
    """``(k, rows, columns)`` float32: indicators of the profile bins (``bands``: signed distances bounding them,
    pixels, > 0 on land; :data:`COAST_BANDS`) of the prediction's signed distance to its coast (pixels, exact
    Euclidean distance transform), each smoothed by a Gaussian of σ ``smoothing`` pixels."""
    distance = signed_distance(prediction > 0.5)
    edges = (np.inf, *bands)
    return np.stack([_smooth(((distance <= high) & (distance > low)).astype(np.float32), smoothing)
                     for high, low in zip(edges[:-1], edges[1:], strict=True)])


def profile_fit(region: np.ndarray, templates: np.ndarray, weight: np.ndarray | None = None,
                minimum_share: float = 0.02) -> np.ndarray:
    """``(m, n)`` R² of the least-squares fit of the image at every shift to the templates.

    At offset ``(i, j)`` the templates ``(k, h, w)`` (the profile bins: brightness an unknown function of the
    distance to the coast, whatever its sign or shape) lie over ``region[i:i + h, j:j + w]`` (``region`` is
    ``(m + h − 1, n + w − 1)``); the image is regressed on an intercept and the templates, R² = bᵀ G⁻¹ b / S with b
    the covariances of the templates with the image, G their Gram matrix and S the image's sum of squares about its
    mean.

    ``weight``: ``None`` fits the window under the templates (it moves with them); an ``(m + h − 1, n + w − 1)``
    array weights each pixel of ``region`` (fixed in the image: the same pixels at every shift, so the best R² is
    the least residual sum of squares; it must be 0 where a shift leaves the templates' cover: outside
    ``[m − 1, h)`` x ``[n − 1, w)``). Templates covering less than ``minimum_share`` of the (weighted) pixels, or
    not independent, are left out (with a weight, at the shift where they cover least); none left: zeros."""
    height, width = templates.shape[1:]
    rows, columns = region.shape[0] - height + 1, region.shape[1] - width + 1
    if weight is not None:
        return _fixed_profile_fit(region, templates, np.asarray(weight, float), minimum_share)
    share = templates.astype(float).mean(axis=(1, 2))
    centred = templates[share > minimum_share] - share[share > minimum_share, None, None]
    if len(centred) == 0:
        return np.zeros((rows, columns))
    gram = np.einsum("kij,lij->kl", centred, centred)
    if np.linalg.cond(gram) > 1e8:
        return np.zeros((rows, columns))
    count = float(height * width)
    region = region.astype(np.float32)
    ones = np.ones((height, width), np.float32)
    total = cv2.matchTemplate(region, ones, cv2.TM_CCORR).astype(float)
    squares = cv2.matchTemplate(region * region, ones, cv2.TM_CCORR).astype(float)
    spread = squares - total**2 / count
    covariance = np.stack([cv2.matchTemplate(region, t.astype(np.float32), cv2.TM_CCORR).astype(float)
                           for t in centred])
    explained = np.einsum("kij,kl,lij->ij", covariance, np.linalg.inv(gram), covariance)
    return np.where(spread > 1e-9 * count, explained / np.maximum(spread, 1e-300), 0.0)


def _fixed_profile_fit(region: np.ndarray, templates: np.ndarray, weight: np.ndarray,
                       minimum_share: float) -> np.ndarray:
    """:func:`profile_fit` with ``weight`` fixed in the image frame: per shift the weighted sums of the templates
    and their products are cross-correlations of the weight with them, those with the image cross-correlations of
    weight x image; the image's own sums do not depend on the shift."""
    height, width = templates.shape[1:]
    rows, columns = region.shape[0] - height + 1, region.shape[1] - width + 1
    inner = np.zeros(weight.shape, bool)
    inner[rows - 1:height, columns - 1:width] = True
    if np.any(weight[~inner] != 0.0):
        raise ValueError("profile_fit: the weight must be 0 where a shift leaves the templates' cover")
    count = float(weight.sum())
    mean = float(np.sum(weight * region)) / count
    spread = float(np.sum(weight * (region - mean) ** 2))

    def correlated(image, template):
        return cv2.matchTemplate(image.astype(np.float32), template.astype(np.float32), cv2.TM_CCORR).astype(float)

    share = np.stack([correlated(weight, t) for t in templates]) / count  # (k, rows, columns)
    kept = share.min(axis=(1, 2)) > minimum_share
    if not np.any(kept) or spread <= 1e-9 * count:
        return np.zeros((rows, columns))
    kept_templates, share = templates[kept], share[kept]
    k = len(kept_templates)
    gram = np.empty((rows, columns, k, k))
    for a in range(k):
        for b in range(a, k):
            product = correlated(weight, kept_templates[a] * kept_templates[b]) - count * share[a] * share[b]
            gram[..., a, b] = gram[..., b, a] = product
    covariance = np.stack([correlated(weight * (region - mean), t) for t in kept_templates], -1)
    scale = np.sqrt(np.einsum("...kk->...k", gram))
    conditioned = gram / (scale[..., :, None] * scale[..., None, :])
    if np.any(np.linalg.cond(conditioned) > 1e8):
        return np.zeros((rows, columns))
    explained = np.einsum("...k,...k->...", covariance, np.linalg.solve(gram, covariance[..., None])[..., 0])
    return explained / spread


def global_shift(image: np.ndarray, prediction: np.ndarray, search: int, smoothing: float = 2.0):
    """The whole image's shift ``(pixel, scan)`` from the prediction (the image shows the predicted land
    displaced by it): the prediction's interior profile (:func:`profile_fit`) fitted over ± ``search`` pixels, the
    best R² wins (sub-pixel by a quadratic).

    Raises:
        SeaiceError: the image is too small for the search; the prediction has no coast in its interior.
    """
    rows, columns = prediction.shape
    if rows <= 2 * search + 8 or columns <= 2 * search + 8:
        raise SeaiceError(f"automatic control: the image ({columns} x {rows}) is too small for a search of "
                          f"±{search} pixels")
    interior = prediction[search:rows - search, search:columns - search]
    if not 0.005 < float(interior.mean()) < 0.995:
        raise SeaiceError("automatic control: the coastline predicted from the start model does not cross the image "
                          f"(land fraction {float(prediction.mean()):.2f}); no coast to match — check the node and "
                          "time of the pass, or use manual control points")
    templates = coast_bands(prediction, smoothing)[:, search:rows - search, search:columns - search]
    surface = profile_fit(_smooth(image, smoothing), templates)
    row, column = np.unravel_index(int(np.argmax(surface)), surface.shape)
    offset = np.zeros(2)
    if 0 < row < surface.shape[0] - 1 and 0 < column < surface.shape[1] - 1:
        peak = _quadratic_peak(surface, int(row), int(column))
        if peak is not None:
            offset = peak[0]
    return float(column - search + offset[0]), float(row - search + offset[1])


def match_coast(image: np.ndarray, prediction: np.ndarray, level: MatchLevel, expected=(0.0, 0.0),
                minimum_fit: float = 0.3, land_fraction=(0.1, 0.9),
                sigma_scale: float = MATCH_SIGMA_SCALE) -> CoastMatches:
    """Windows of the prediction (those the coast crosses: land fraction within ``land_fraction``) found in the
    image around the ``expected`` ``(pixel, scan)`` shift ± ``level.search`` by the coast profile's best fit
    (:func:`profile_fit`); matches with R² below ``minimum_fit``, on the search's border or without a clear peak
    are left out. ``correlation``: √R² at the peak; ``sigma``: ``sigma_scale`` times the σ from the peak (module
    docstring, 3.)."""
    rows, columns = prediction.shape
    smooth_image = _smooth(image, level.smoothing)
    bands = coast_bands(prediction, level.smoothing, level.bands)
    half, search = level.window // 2, level.search
    shift_column, shift_row = (int(round(v)) for v in expected)
    weight = (None if level.edge is None else
              _smooth(np.abs(signed_distance(prediction > 0.5)) <= level.edge, level.smoothing).astype(float))
    found = []
    for row in range(half, rows - half, level.step):
        for column in range(half, columns - half, level.step):
            window = prediction[row - half:row + half, column - half:column + half]
            if not land_fraction[0] <= window.mean() <= land_fraction[1]:
                continue
            top, left = row - half + shift_row - search, column - half + shift_column - search
            bottom, right = top + 2 * half + 2 * search, left + 2 * half + 2 * search
            if top < 0 or left < 0 or bottom > rows or right > columns:
                continue
            templates = bands[:, row - half:row + half, column - half:column + half]
            fitted = None
            if weight is not None:  # the band around the coast where the image shows it at the expected shift
                fitted = np.zeros((bottom - top, right - left))
                fitted[2 * search:2 * half, 2 * search:2 * half] = weight[row - half + search:row + half - search,
                                                                          column - half + search:column + half - search]
            surface = profile_fit(smooth_image[top:bottom, left:right], templates, fitted)
            r, c = np.unravel_index(int(np.argmax(surface)), surface.shape)
            if not (0 < r < surface.shape[0] - 1 and 0 < c < surface.shape[1] - 1):
                continue
            peak = _quadratic_peak(surface, int(r), int(c))
            if peak is None or peak[1] < minimum_fit:
                continue
            offset, fit, hessian = peak
            rho = float(np.sqrt(min(fit, 0.998)))
            # R² = ρ²: the curvature of ρ is half that of R² over ρ
            pixels = float((2 * half) ** 2 if fitted is None else fitted.sum())
            independent = pixels / max(1.0, 4 * np.pi * level.smoothing**2)
            covariance = (1 - rho**2) / (rho * independent) * np.linalg.inv(-hessian / (2 * rho))
            sigma = sigma_scale * float(np.sqrt(np.max(np.linalg.eigvalsh(covariance))))
            centre_pixel, centre_scan = column + 0.5, row + 0.5  # 1-based: the even window's centre is a pixel edge
            found.append((centre_pixel + shift_column + c - search + offset[0],
                          centre_scan + shift_row + r - search + offset[1], centre_pixel, centre_scan, sigma, rho))
    if not found:
        return CoastMatches(*(np.zeros(0) for _ in range(6)))
    return CoastMatches(*(np.array(values) for values in zip(*found, strict=True)))


def proposed_control(matches: CoastMatches, model: ScanModel, prefix: str = "C",
                     minimum_sigma: float = 0.1) -> ControlPoints:
    """Control points from matches: image position where each window was found, ground position of the window's
    centre through ``model`` (the model the prediction was made with), σ (m) = the match's σ (at least
    ``minimum_sigma`` pixels) times the geometric mean of the local pixel sizes along and across the scan."""
    lat, lon = (np.asarray(a) for a in model.forward_unchecked(matches.predicted_pixel, matches.predicted_scan))
    lat_p, lon_p = (np.asarray(a) for a in model.forward_unchecked(matches.predicted_pixel + 1.0,
                                                                   matches.predicted_scan))
    lat_s, lon_s = (np.asarray(a) for a in model.forward_unchecked(matches.predicted_pixel,
                                                                   matches.predicted_scan + 1.0))
    radius = float(model.orbit.radius)
    size_p = radius * np.hypot(lat_p - lat, (lon_p - lon) * np.cos(lat))
    size_s = radius * np.hypot(lat_s - lat, (lon_s - lon) * np.cos(lat))
    sigma = np.maximum(matches.sigma, minimum_sigma) * np.sqrt(size_p * size_s)
    ids = [f"{prefix}{k + 1}" for k in range(len(lat))]
    return ControlPoints(matches.pixel, matches.scan, lat, lon, sigma, ids)


PAD = 64
"""Control points are padded to a multiple of this (copies of the first point with a σ that gives them no weight),
so that the fits of every level and image share a few compiled shapes."""

_NO_WEIGHT = 1e12
"""σ (m) of a padding or rejected point: no weight in the fit, no redundancy, w = 0."""

MATCH_OVERLAP_CORRELATION = 0.85
"""c (dimensionless): the correlation of two coastline matches' errors (per ground axis) is c times the share of
pixels their windows have in common (:func:`window_overlap`). Maximum likelihood on the true errors of the points
kept by :func:`coast_control` on the 200 tuning images 61000-61199 (``experiments/coast_control_calibration.py``,
``error_model`` there; jointly with :data:`COAST_DATUM_SIGMA` and :data:`COAST_DATUM_GRADIENT_SIGMA`): 0.85
(0.845-0.85, profile likelihood) in the run at scale 0.88 that the constants were taken from, 0.835 (0.835-0.84)
in the confirming run at 0.89, with the last level fitting a band fixed in the image within :data:`COAST_EDGE` of
the coast (issue 29; 0.90 when the band moved with the template, 0.86 with whole windows, 0.74 with the banded
profile)."""

COAST_DATUM_SIGMA = 23.0
"""σ_c (m, per ground axis, north and east): the shift that all of one image's coastline control points share:
where the coast the image shows and the coastline database (GSHHG, from which the prediction is made) differ, and
what the matcher errs alike along one image's coast. Maximum likelihood on the tuning images 61000-61199 (see
:data:`MATCH_OVERLAP_CORRELATION`): 23 m (20-26 m; the confirming run 21 m, 18-25 m) — on simulated images, whose
coast is the GSHHG coast (the raster's zero line within 10 m of the polygon on average), the matcher's part alone;
the kept points' weighted mean error per image there is −2 ± 2 m north, −12 ± 3 m east, scattered by 36 m from
image to image. With the band moving with the template it was 19 m (+4, +8 m), with whole windows the matcher
leaned landward (+13 ± 4 m north, −29 ± 4 m east, a bias no random shift describes), with the banded profile
~120 m. On real images, where database and imaged coast differ, pass a :class:`CoastErrors` with the larger
σ_c."""

COAST_DATUM_GRADIENT_SIGMA = 0.1e-3
"""σ_g (m per m, dimensionless): σ of each of the four gradients (north and east error along north and east) of
the error field an image's coastline points share, about their centroid. Maximum likelihood on the tuning images
61000-61199 with the band fixed in the image frame (:data:`COAST_EDGE`; ``error_model`` of
``experiments/coast_control_calibration.py``): 0.10e-3 in both runs (10 m per 100 km; the affine fields of the
kept points' errors per image scatter by 19-25 m per 100 km, their estimation noise included, about means of
−5 to +9). When the band moved with the template the estimate was 0.15e-3 but most of it was a stretch all images
shared (−13 and +20 m per 100 km, opposite coasts pulled apart), not adopted, and the rectified model's check
pixels were 1.198 times their stated σ on fresh images (issue 29); with whole windows 0, with the banded profile
0.42e-3."""

MATCH_ERROR_KURTOSIS = 4.3
"""κ (effective): σ̂0² of a coastline-controlled fit varies (κ − 1)/r about 1, not 2/r, so its global test uses
r' = 2r/(κ − 1) degrees of freedom (:attr:`~seaice_jax.adjust.orbit.fit.OrbitFit.error_kurtosis`): the points'
σ is too small or too large by a factor common to an image, and the matches the w-test keeps include moderately
wrong ones. Set where that test rejects 5 % of 680 fits with the calibrated constants
(``experiments/coast_control_calibration.py``'s ``effective_kurtosis``): the 95 % quantile of each fit's critical
κ, 4.34 (90 % over images 3.85-4.57; the moment estimate 1 + mean r (σ̂0² − 1)², 4.19, 3.92-4.47). The 680 are the
200 tuning images 61000-61199 and two sets of 240 that had checked the other constants (51480-51719,
51720-51959): 200 fits alone were too few — the tuning images gave 5.21 (3.80-5.96) by the quantile and 4.59 by
the moments, the two checking sets 3.87 and 4.18 by the quantile, and at 5.2 and 4.6 they were rejected 1.7 % and
1.7 % (issue 29; the checking sets' figures from the script's ``effective_kurtosis`` on their cached fits). On the
fresh images 51960-52199: 4.2 % (2.3-7.5 %, ``experiments/calibration.py``). With the band moving with the template
κ was 3.85, with whole windows 7.9."""


@dataclass(frozen=True)
class CoastErrors:
    """The coastline control points' error model beyond each point's own σ (per ground axis, north and east alike
    and independent); the defaults are the calibrated constants.

    Attributes:
        overlap_correlation: c, dimensionless (:data:`MATCH_OVERLAP_CORRELATION`). datum_sigma: σ_c, m
            (:data:`COAST_DATUM_SIGMA`). datum_gradient_sigma: σ_g, m per m (:data:`COAST_DATUM_GRADIENT_SIGMA`).
        kurtosis: κ of the whitened errors, for the global test (:data:`MATCH_ERROR_KURTOSIS`).
    """

    overlap_correlation: float = MATCH_OVERLAP_CORRELATION
    datum_sigma: float = COAST_DATUM_SIGMA
    datum_gradient_sigma: float = COAST_DATUM_GRADIENT_SIGMA
    kurtosis: float = MATCH_ERROR_KURTOSIS


INDEPENDENT_POINTS = CoastErrors(0.0, 0.0, 0.0, 3.0)
"""Independent, normal points: each its own σ only (the model before issue 29)."""

_WEIGHTLESS = 1e-3 * _NO_WEIGHT
"""σ (m) from which a point counts as padding or rejected in :func:`correlated_fit`."""


def window_overlap(pixel, scan, window: float) -> np.ndarray:
    """``(n, n)``: the share of pixels two square windows of side ``window`` pixels centred at ``(pixel, scan)``
    ``(n,)`` have in common, (1 − |Δpixel|/window)₊ (1 − |Δscan|/window)₊ (1 on the diagonal; positive
    semi-definite: the autocorrelation of a square). ``window`` 0: the identity."""
    if window <= 0:
        return np.eye(len(np.asarray(pixel)))
    pixel, scan = np.asarray(pixel, float), np.asarray(scan, float)
    along = np.clip(1.0 - np.abs(pixel[:, None] - pixel[None]) / window, 0.0, None)
    across = np.clip(1.0 - np.abs(scan[:, None] - scan[None]) / window, 0.0, None)
    return along * across


def centroid_offsets(latitude, longitude, included, radius: float = MEAN_RADIUS) -> np.ndarray:
    """``(n, 2)`` m: north and east offsets of points at ``latitude``, ``longitude`` ``(n,)`` radians from the
    centroid of those ``included`` ``(n,)`` bool (longitudes unwrapped next to the first point; none included: from
    latitude and longitude 0), on a sphere of ``radius`` m."""
    latitude, longitude, included = np.asarray(latitude, float), np.asarray(longitude, float), np.asarray(included)
    east = np.angle(np.exp(1j * (longitude - longitude[0]))) if latitude.size else longitude
    centre_latitude = float(np.mean(latitude[included])) if included.any() else 0.0
    centre_east = float(np.mean(east[included])) if included.any() else 0.0
    return radius * np.stack([latitude - centre_latitude, np.cos(centre_latitude) * (east - centre_east)], 1)


def coast_point_covariance(sigma, pixel, scan, latitude, longitude, window: float,
                           errors: CoastErrors = CoastErrors(), shared=None, radius: float = MEAN_RADIUS) -> np.ndarray:
    """``(n, n)`` m²: the covariance of control points' errors along one ground axis (north or east alike; the axes
    independent), Σ = S [(1 − c) I + c K] S + s sᵀ ∘ (σ_c² + σ_g² XXᵀ) among the coastline points ``s``.

    The first term is each point's own error (σ from its match) with the correlation of matches whose windows
    share pixels (K: :func:`window_overlap`); the second an error field all the coastline points share, affine on
    the ground — a shift of σ_c per axis and gradients of σ_g (m per m) about the points' centroid (X: ``(n, 2)``
    north/east metres from it) — where the coast in the image and in the database differ.

    Args:
        sigma: ``(n,)`` m, each point's σ (S = diag σ). pixel, scan: ``(n,)`` image positions of the points.
        latitude, longitude: ``(n,)`` radians, their ground positions. window: pixels, side of the windows the
            points were matched with. errors: c, σ_c, σ_g (:class:`CoastErrors`; default the calibrated ones).
        shared: ``(n,)`` bool s, the coastline points (default all); the others (manual points) are independent
            of every point. radius: m, of the sphere.
    """
    sigma = np.broadcast_to(np.asarray(sigma, float), np.shape(pixel))
    count = len(sigma)
    shared = np.ones(count, bool) if shared is None else np.asarray(shared, bool)
    both = np.outer(shared, shared)
    c = errors.overlap_correlation
    correlation = np.where(both, (1.0 - c) * np.eye(count) + c * window_overlap(pixel, scan, window), np.eye(count))
    offsets = centroid_offsets(latitude, longitude, shared & (sigma < _WEIGHTLESS), radius)
    field = errors.datum_sigma**2 + errors.datum_gradient_sigma**2 * (offsets @ offsets.T)
    return sigma[:, None] * correlation * sigma[None] + np.where(both, field, 0.0)


def _axis_weight(covariance: np.ndarray, weighted: np.ndarray) -> np.ndarray:
    """``(n, n)`` 1/m²: the inverse of ``covariance`` over the ``weighted`` points, zero for the others."""
    index = np.flatnonzero(weighted)
    weight = np.zeros_like(covariance)
    block = covariance[np.ix_(index, index)]
    factor = np.linalg.cholesky(block)
    inverse = np.linalg.inv(factor)
    weight[np.ix_(index, index)] = inverse.T @ inverse
    return weight


def correlated_fit(fit: OrbitFit, covariance, iterations: int = 2) -> OrbitFit:
    """``fit`` solved again with correlated control points: ``covariance`` ``(n, n)`` m² of the points' errors
    along each ground axis, north and east alike and independent of each other (e.g.
    :func:`coast_point_covariance`). Points of σ ≥ :data:`_WEIGHTLESS` (padding, removed points) have no weight.

    Generalized least squares in local north/east metres (east on the known parallel; Jacobian
    :func:`~seaice_jax.adjust.orbit.fit.position_jacobian`), ``iterations`` Gauss-Newton steps from the fit's model
    (the solution for independent points; the steps are small).

    Returns:
        the fit with its model and adjustment replaced: parameters; cofactor ``(5, 5)`` (JᵀΣ⁻¹J)⁻¹; covariance
        σ̂0² · cofactor; σ̂0 = √(vᵀΣ⁻¹v / r) (r unchanged); per observation (latitude, longitude; radians where the
        engine has them) residuals v (computed − known), redundancy numbers (Q_vv Σ⁻¹)_ii, w = (Σ⁻¹v)_i /
        √(Σ⁻¹Q_vvΣ⁻¹)_ii, minimal detectable bias, estimated error −(Σ⁻¹v)_i / (Σ⁻¹Q_vvΣ⁻¹)_ii, and each w's largest
        |correlation| with another (flat index: latitudes, then longitudes). Weightless points have redundancy 0
        and w 0. A diagonal ``covariance`` (σ_i²) gives the fit with independent points back.

    Raises:
        SeaiceError: the fit has no adjustment (Appendix C).
    """
    adjustment = fit.adjustment
    if adjustment is None:
        raise SeaiceError("correlated control points need a Gauss-Newton fit (Appendix C gives no covariance)")
    control = fit.control
    count = len(control)
    sigma = np.broadcast_to(np.asarray(control.sigma, float), (count,))
    weighted = sigma < _WEIGHTLESS
    weight = np.kron(np.eye(2), _axis_weight(np.asarray(covariance, float), weighted))  # north block, east block
    known_latitude, known_longitude = np.asarray(control.latitude, float), np.asarray(control.longitude, float)
    radius = float(fit.model.orbit.radius)
    size = PAD * -(-count // PAD)  # evaluated on PAD-padded points: a few shapes, each compiled once
    pixel, scan = (np.concatenate([np.asarray(a, float), np.full(size - count, float(np.asarray(a)[0]))])
                   for a in (control.pixel, control.scan))

    def linearized(model):
        """Jacobian ``(2n, 5)`` and residuals ``(2n,)`` m of the deviations (east on the known parallel)."""
        jacobian = np.asarray(position_jacobian(model, pixel, scan))[:count]  # (n, 2, 5), east on the model's
        latitude, longitude = (np.asarray(a)[:count] for a in model.forward(jnp.asarray(pixel), jnp.asarray(scan)))
        east_scale = np.cos(known_latitude) / np.cos(latitude)
        north = (latitude - known_latitude) * radius
        east = np.angle(np.exp(1j * (longitude - known_longitude))) * radius * np.cos(known_latitude)
        return (np.concatenate([jacobian[:, 0], jacobian[:, 1] * east_scale[:, None]]),
                np.concatenate([north, east]))

    model = fit.model
    for _ in range(iterations):
        jacobian, residual = linearized(model)
        step = -np.linalg.solve(jacobian.T @ weight @ jacobian, jacobian.T @ weight @ residual)
        model = with_scan_unknowns(model, scan_unknowns(model) + jnp.asarray(step))
    jacobian, residual = linearized(model)
    cofactor = np.linalg.inv(jacobian.T @ weight @ jacobian)
    dof = adjustment.degrees_of_freedom
    sigma0 = float(np.sqrt(residual @ weight @ residual / dof)) if dof else float("nan")
    hat = jacobian @ cofactor @ jacobian.T @ weight  # J Q Jᵀ Σ⁻¹
    tested = np.concatenate([weighted, weighted])
    redundancy = np.where(tested, 1.0 - np.diag(hat), 0.0)
    quadratic = weight - weight @ hat  # Σ⁻¹ Q_vv Σ⁻¹
    scale = np.sqrt(np.where(tested, np.maximum(np.diag(quadratic), 1e-300), 1.0))
    gradient = weight @ residual
    w = np.where(tested, gradient / scale, 0.0)
    mdb = np.where(tested, float(noncentrality()) / scale, np.inf)
    blunder = np.where(tested, -gradient / scale**2, np.nan)
    correlation = np.abs(quadratic) / np.outer(scale, scale)
    correlation[~tested, :], correlation[:, ~tested] = 0.0, 0.0
    np.fill_diagonal(correlation, 0.0)
    partner = np.where(correlation.max(axis=1) > 0, np.argmax(correlation, axis=1), -1)
    per_axis = np.concatenate([np.full(count, radius), radius * np.cos(known_latitude)])

    def groups(values, metres: bool = False):
        values = values / per_axis if metres else values
        return {"latitude": values[:count], "longitude": values[count:]}

    adjustment = dataclasses.replace(
        adjustment, parameters=model, cofactor=cofactor, covariance=sigma0**2 * cofactor, sigma0=np.asarray(sigma0),
        residuals=groups(residual, metres=True), redundancy=groups(redundancy), standardized_residuals=groups(w),
        minimal_detectable_bias=groups(mdb, metres=True), estimated_errors=groups(blunder, metres=True),
        w_correlation=groups(correlation.max(axis=1)), w_partner=groups(partner))
    return dataclasses.replace(fit, model=model, adjustment=adjustment)


def fit_with_snooping(control: ControlPoints, model: ScanModel, alpha: float = 0.001, max_rejected: float = 0.3,
                      final: bool = True, window: float = 0.0, errors: CoastErrors = CoastErrors(),
                      shared=None) -> tuple[OrbitFit, tuple[str, ...]]:
    """Fit the scan model (direction and image size of ``model``) and remove, one at a time, the point with the
    largest |w| beyond the critical value of ``alpha``, refitting, until none is beyond it or ``max_rejected`` (a
    fraction) of the points are gone. Returns the last fit and the removed ids.

    Every fit has the coastline points' correlated errors in their covariance (:func:`coast_point_covariance` of
    ``window``, the side in pixels of the windows they were matched with, and ``errors``; fitted by
    :func:`correlated_fit`), so the w-tests, σ̂0 and the covariance account for them; the fit's global test uses
    ``errors.kurtosis``. ``shared``: ``(n,)`` bool, the coastline points (default all); manual points joined to
    them are not.

    The loop fits padded point sets (:data:`PAD`) in which a removed point keeps its place with no weight; with
    ``final`` the kept points are fitted once more on their own, so that the returned fit's σ̂0, redundancies and
    covariance are those of exactly these points."""
    size = PAD * -(-len(control) // PAD)
    padding = size - len(control)
    pixel, scan, latitude, longitude, sigma = (np.concatenate([np.asarray(a), np.full(padding, np.asarray(a)[0])])
                                               for a in (control.pixel, control.scan, control.latitude,
                                                         control.longitude, control.sigma))
    active = np.arange(size) < len(control)
    shared = np.ones(len(control), bool) if shared is None else np.asarray(shared, bool)
    shared_padded = np.concatenate([shared, np.zeros(padding, bool)])
    ids = [*control.ids, *(f"pad{k}" for k in range(padding))]
    radius = float(model.orbit.radius)

    def fitted(points: ControlPoints, coastal) -> OrbitFit:
        fit = fit_scan_model(points, model.orbit, direction=model.direction, n_pixels=model.n_pixels,
                             n_scans=model.n_scans)
        covariance = coast_point_covariance(points.sigma, points.pixel, points.scan, points.latitude,
                                            points.longitude, window, errors, coastal, radius)
        return dataclasses.replace(correlated_fit(fit, covariance), error_kurtosis=errors.kurtosis)

    rejected: list[str] = []
    while True:
        fit = fitted(ControlPoints(pixel, scan, latitude, longitude, np.where(active, sigma, _NO_WEIGHT), ids),
                     shared_padded)
        adjustment = fit.adjustment  # a Gauss-Newton fit: always there
        worst = [] if adjustment is None else adjustment.worst(lambda flag: flag.row if active[flag.row] else None,
                                                               alpha, groups=("latitude", "longitude"))
        if not worst or len(rejected) + 1 > max_rejected * len(control):
            break
        drop = worst[0]
        rejected.append(ids[drop])
        active[drop] = False
    if final:
        kept = active[:len(control)]
        fit = fitted(control.subset(kept), shared[kept])
    return fit, tuple(rejected)


def coast_control(image, start: ScanModel, land: LandTest, search: int = 32,
                  levels: tuple[MatchLevel, ...] = DEFAULT_LEVELS, minimum_points: int = 6,
                  alpha: float = 0.001, match_sigma_scale: float = MATCH_SIGMA_SCALE,
                  errors: CoastErrors = CoastErrors()) -> CoastControl:
    """Fit an image's scan model to control points found on the coastline, from a rough ``start``.

    Args:
        image: ``(n_scans, n_pixels)`` brightness (row = scan line − 1, column = pixel − 1); NaN: no data.
        start: the rough model (node and pass time as known; direction, size and sensor geometry right).
        land: the land test (e.g. ``Coastline.contains`` of a box covering the image).
        search: ± pixels of the first level's whole-image search (cover the start's error: 20 km is ~17 pixels
            of a 1.2 km image). levels: the coarse-to-fine levels. minimum_points: fewer matches than this at a
            level is an error. alpha: the w-test's significance. match_sigma_scale: factor on each match's σ from
            its peak (default: the calibrated :data:`MATCH_SIGMA_SCALE`). errors: the points' correlated errors
            (:class:`CoastErrors`; default the calibrated ones; :data:`INDEPENDENT_POINTS`: each its own σ only).

    Raises:
        SeaiceError: the image is not ``(start.n_scans, start.n_pixels)``; no coast is predicted in the image;
            too few matches at a level.
    """
    if not levels:
        raise SeaiceError("automatic control: no matching levels given")
    image = np.asarray(image, float)
    if image.shape != (start.n_scans, start.n_pixels):
        raise SeaiceError(f"automatic control: the image is {image.shape[1]} pixels x {image.shape[0]} scan lines, "
                          f"the model {start.n_pixels} x {start.n_scans} (--pixels, --scans)")
    finite = np.isfinite(image)
    if not finite.any():
        raise SeaiceError("automatic control: the image has no data (all NaN)")
    image = np.where(finite, image, float(np.mean(image[finite])))
    if float(np.std(image)) == 0.0:
        raise SeaiceError("automatic control: the image is flat (one value everywhere); no coast to match")
    model = start
    shift = global_shift(image, predicted_land(start, land), search, levels[0].smoothing)
    rejected, matched, fits = [], [], []
    for k, level in enumerate(levels):
        prediction = predicted_land(model, land)
        matches = match_coast(image, prediction, level, shift if k == 0 else (0.0, 0.0),
                              sigma_scale=match_sigma_scale)
        if matches.pixel.size < minimum_points:
            raise SeaiceError(f"automatic control: only {matches.pixel.size} coastline matches at level {k + 1} "
                              f"(at least {minimum_points} needed): too little coast in the image, or the start is "
                              "too far off for the search")
        control = proposed_control(matches, model, prefix=f"C{k + 1}-")
        fit, dropped = fit_with_snooping(control, model, alpha, final=k == len(levels) - 1, window=level.window,
                                         errors=errors)
        model = fit.model
        fits.append(fit)
        rejected.append(dropped)
        matched.append(len(control))
    return CoastControl(model, fits[-1], tuple(rejected), tuple(matched), shift, levels[-1].window)
