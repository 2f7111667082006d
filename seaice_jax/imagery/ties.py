"""Tie points between the overlapping images of a sequence, found automatically on what does not move (land, fast
ice) by normalised cross-correlation through the images' current scan models (issue 13).

Method:

1. **Candidates**: a lattice of ground points (``spacing`` pixels apart, in the plane tangent to the sphere at the
   sequence's centre) where the static surface (land and fast ice: a mask or any ``(latitude, longitude) -> bool``)
   covers the footprint of the patch, and which at least two images see (inverse scan model of the current
   models) far enough from their edges.
2. **Reference**: of the images that see a candidate, the one whose patch there has the most contrast (clouds are
   flat); its template is the ``patch`` x ``patch`` pixels around the nearest pixel centre q (no interpolation); q
   is the tie's observation in the reference image. A candidate that matches in no other image tries the next
   reference (an image of unrelated texture has contrast too).
3. **Matching** in every other image o: the window of o is resampled into the reference's frame through the
   current models, T(q) = inverse_o(forward_r(q)) (bicubic, ``cv2.remap``), which takes out the rotation and
   scale between a southbound and a northbound pass; the models' errors leave a shift d of a few pixels (their
   rotation and scale errors are negligible over a patch). NCC (``cv2.matchTemplate``, TM_CCOEFF_NORMED) over
   ±``search`` pixels, sub-pixel peak by the quadratic fit of :func:`~seaice_jax.imagery.tracking.quadratic_peak`,
   then the window resampled again through T at q + d and the (sub-pixel) residual shift found the same way and
   added: the quadratic fit is biased towards whole pixels by up to a tenth of a pixel, a bias that varies
   smoothly with the two images' sampling phase over the overlap (neighbouring ties' errors correlated over tens of
   pixels, no σ of independent errors describes it); at a residual shift near zero it vanishes;
   quality flags as in tracking (contrast, correlation, peak sharpness, peak at the window's edge) and the
   normalised median test on d (the models' errors are smooth over an image: a mismatch disagrees with its
   neighbours). The observation in o is T(q + d): to first order the true correspondent of q, whatever the errors
   of the models used to resample (they only move the point through which the warp passes).
4. **Search window** from the models' uncertainty: with their covariances (of the five unknowns), ``n_sigma``
   times the largest predicted σ of T over the overlap (autodiff Jacobian of T with respect to both images'
   unknowns), plus one pixel; without, ``search``.
5. **σ** of each observation (pixel, scan): σ² = ``pointing_sigma``² + ½ C_d, with C_d = 2 (1 − ρ)/N_eff (−H)⁻¹
   the match covariance from the peak's correlation ρ and curvature H (least-squares matching with noise in both
   images: 1 − ρ ≈ σ_noise²/σ_signal², Σ∇I∇Iᵀ ≈ −N σ_signal² H), carried into each image's axes by the Jacobian of
   T; half of the match variance goes to each image of the pair, so the difference of the two observations has the
   match's variance plus 2 ``pointing_sigma``². N_eff = N/``correlation_area`` is the number of independent samples
   among the N template pixels: what decorrelates the two patches (the changes of texture between passes, the
   sensor's blur, the bicubic resampling) is not white but correlated over neighbouring pixels, so the N pixels
   carry fewer independent differences (the formula with N understates the error by √3). ``pointing_sigma``
   covers what the correlation cannot see at all. Both are measured on the simulated Lancaster Sound sequences
   (GSHHG coast, 3 images of 256 pixels, models 1 pixel off) against the true models, over 4900 matches of seeds
   0-2: fitting the squared error of the difference of a tie's two observations as 2 f² + κ C_d gives κ = 3.0 and
   f² ≈ 0 (the error grows with C_d: RMS 0.04 to 0.07 pixel from the quartile of least to most C_d, hardly at all
   with ρ), hence ``correlation_area`` 3 and a ``pointing_sigma`` of 0.01 pixel, a safeguard below the fit's
   resolution. The former model (N, ``pointing_sigma`` 0.05, measured on the former invented coastline) stated σ
   1.3-1.7 times the error on this scene (normalised RMS 0.59-0.65 pixel axis, 0.73-0.76 scan
   axis); now 0.91-1.01 on seeds 0-2 (pixel, scan: 0.91, 1.01 on seed 0 of tests/test_ties.py) and 0.92-1.09 on
   the held-out seeds 3 and 4 (1.09, 1.03; 0.92, 1.06).
   Neighbouring ties' errors are correlated (overlapping templates: about 0.4 within 5 pixels, 0.15-0.2 at 5-10,
   none beyond 10), which no σ here describes; the adjustment estimates the ties' variance factor from their
   residuals (:mod:`seaice_jax.adjust.sequence.adjustment`).

6. **Runs**: a ground point seen in k images is one tie with k observations (all matched against one reference)
   while k ≤ ``max_images``; seen in more (a season of one area: up to every image), it gives several ties, each
   over a run of at most ``max_images`` of its images consecutive in sequence order (:func:`image_runs`), with its
   own reference chosen and matched within the run, consecutive runs sharing one image so that the whole
   sequence stays connected through the ties. The adjustment's work per tie grows with k² (the Schur complement's
   blocks between a tie's observations), and matching a day-1 template into day 200 relies on a texture the
   season has changed; bounded runs keep both per tie whatever the season's length, and the number of ties grows
   with the images. The shared image holds two observations of the point, one per run (each matched against its
   own run's reference, or the same pixel centre where it is the reference of both).
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from seaice_jax._shapes import pad
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.earth import great_circle_distance
from seaice_jax.geometry.projections import MapGrid, TangentPlane
from seaice_jax.geometry.scan import SCAN_UNKNOWNS, ScanModel, scan_unknowns, with_scan_unknowns
from seaice_jax.imagery.tracking import (
    AT_EDGE,
    FLAT_PEAK,
    GOOD,
    LOW_CONTRAST,
    LOW_CORRELATION,
    NO_DATA,
    STATUS,
    Displacements,
    TrackingOptions,
    correlation_peak,
    median_test,
    peak_covariance,
    quadratic_peak,
)

_REMAP_ROWS = 32_000
"""Rows of one ``cv2.remap`` output (OpenCV refuses 32767 or more): windows are resampled in chunks below it."""
_POINTS = 4096
"""Points per call of the compiled geometry kernels (the last call padded)."""
_REFINE = 3
"""± pixels of the second, sub-pixel search around the first match (sharpness needs more than 2)."""


@dataclass(frozen=True)
class TieOptions:
    """Choices of :func:`find_ties`.

    Attributes:
        patch: side of the square template, pixels (odd). spacing: pixels between candidate ground points.
        search: ± pixels searched when no covariances are given. n_sigma: with covariances, the window covers
            this many predicted σ of the models' disagreement (plus one pixel), at most ``max_search``.
        min_correlation, min_sharpness, min_contrast: quality thresholds (as
            :class:`~seaice_jax.imagery.tracking.TrackingOptions`).
        median_threshold, neighbours: the normalised median test of the shifts.
        pointing_sigma: pixels, the σ floor of each observation (module docstring).
        correlation_area: template pixels per independent sample in the match covariance, N_eff = patch² /
            correlation_area (module docstring).
        max_images: most images (observations) per tie (module docstring, 6.): a ground point seen in more gives
            ⌈(k − 1)/(max_images − 1)⌉ ties over consecutive runs of its images sharing one image each. 6 leaves
            the 3-4 image sequences of the experiments one tie per point and bounds the adjustment's work per tie
            (k² ≤ 36 pairs of observations, against 40 000 for a point seen by a season's 200 images).
    """

    patch: int = 15
    spacing: float = 4.0
    search: int = 6
    n_sigma: float = 4.0
    max_search: int = 30
    min_correlation: float = 0.7
    min_sharpness: float = 0.05
    min_contrast: float = 0.03
    median_threshold: float = 3.0
    neighbours: int = 8
    pointing_sigma: float = 0.01
    correlation_area: float = 3.0
    max_images: int = 6

    def __post_init__(self):
        if self.patch < 5 or self.patch % 2 == 0:
            raise SeaiceError(f"patch must be an odd number of pixels >= 5, got {self.patch}")
        if not self.spacing > 0:
            raise SeaiceError(f"spacing must be > 0 pixels, got {self.spacing}")
        if self.search < 2 or self.max_search < 2:
            raise SeaiceError(f"search and max_search must be at least 2 pixels, got {self.search}, "
                              f"{self.max_search}")
        if not self.pointing_sigma > 0:
            raise SeaiceError(f"pointing_sigma must be > 0 pixels, got {self.pointing_sigma}")
        if not self.correlation_area >= 1:
            raise SeaiceError(f"correlation_area must be >= 1 pixel, got {self.correlation_area}")
        if self.max_images < 2:
            raise SeaiceError(f"max_images must be at least 2 (a tie joins two images), got {self.max_images}")


@dataclass(frozen=True)
class TiePoints:
    """Tie observations of a sequence.

    Attributes:
        image, tie: ``(m,)`` image index and tie id of each observation (ids 0..n_ties−1, shared across images).
        pixel, scan: ``(m,)`` fractional 1-based image coordinates.
        sigma_pixel, sigma_scan: ``(m,)`` pixels.
        correlation: ``(m,)`` peak NCC of the match (NaN for the tie's reference observation).
        reference: ``(m,)`` True for the observation the others were matched against.
        latitude, longitude: ``(n_ties,)`` radians, the tie's position by the reference image's current model.
        candidates: ``{(reference image, other image): (len(STATUS),) counts}`` of every match tried, by
            :data:`~seaice_jax.imagery.tracking.STATUS` code.
        search: ``{(reference image, other image): ± pixels searched}``.
    """

    image: np.ndarray
    tie: np.ndarray
    pixel: np.ndarray
    scan: np.ndarray
    sigma_pixel: np.ndarray
    sigma_scan: np.ndarray
    correlation: np.ndarray
    reference: np.ndarray
    latitude: np.ndarray
    longitude: np.ndarray
    candidates: dict
    search: dict

    @classmethod
    def measured(cls, image, tie, pixel, scan, sigma_pixel, sigma_scan, latitude, longitude) -> "TiePoints":
        """Tie observations measured elsewhere (by hand, by another matcher, or simulated): the arrays as in the
        attributes; no correlation (NaN), the first observation of each tie its reference, nothing searched."""
        image, tie = np.asarray(image, int), np.asarray(tie, int)
        first = np.zeros(tie.size, bool)
        first[np.unique(tie, return_index=True)[1]] = True
        return cls(image=image, tie=tie, pixel=np.asarray(pixel, float), scan=np.asarray(scan, float),
                   sigma_pixel=np.asarray(sigma_pixel, float), sigma_scan=np.asarray(sigma_scan, float),
                   correlation=np.full(tie.size, np.nan), reference=first, latitude=np.asarray(latitude, float),
                   longitude=np.asarray(longitude, float), candidates={}, search={})

    @property
    def n_ties(self) -> int:
        return int(self.latitude.size)

    @property
    def n_observations(self) -> int:
        return int(self.image.size)

    def pair_counts(self) -> dict[tuple[int, int], int]:
        """``{(a, b): ties observed in both}`` for every pair a < b of images sharing a tie."""
        counts: dict[tuple[int, int], int] = {}
        order = np.argsort(self.tie, kind="stable")
        ties, images = self.tie[order], self.image[order]
        starts = np.r_[0, np.nonzero(np.diff(ties))[0] + 1, ties.size]
        for begin, end in zip(starts[:-1], starts[1:], strict=True):
            seen = np.unique(images[begin:end])
            for x, a in enumerate(seen):
                for b in seen[x + 1:]:
                    counts[(int(a), int(b))] = counts.get((int(a), int(b)), 0) + 1
        return dict(sorted(counts.items()))


def grid_mask(grid: MapGrid, mask) -> Callable:
    """A static-surface function ``(latitude, longitude) -> bool`` from a raster ``mask (n_rows, n_columns)`` of
    ``grid`` (nearest cell; False off the grid)."""
    mask = np.asarray(mask, bool)
    if mask.shape != grid.shape:
        raise SeaiceError(f"mask shape {mask.shape} differs from the grid's {grid.shape}")

    def static(latitude, longitude):
        x, y = grid.projection.forward(jnp.asarray(latitude, float), jnp.asarray(longitude, float))
        row, column = (np.rint(np.asarray(a)) for a in grid.to_pixel(x, y))
        inside = (row >= 0) & (row < grid.n_rows) & (column >= 0) & (column < grid.n_columns)
        out = np.zeros(row.shape, bool)
        out[inside] = mask[row[inside].astype(int), column[inside].astype(int)]
        return out

    return static


def _southbound(model: ScanModel) -> ScanModel:
    """The same model as a southbound one with a signed orbital-angle span: :class:`ScanModel` uses only
    sign · span, so forward and inverse are the same functions, and every kernel compiles once whatever the passes'
    directions."""
    if model.direction == "south":
        return model
    return ScanModel(model.scanner_angle_span, model.subtrack_pixel, model.orbital_angle_first,
                     -model.orbital_angle_span, model.ascending_node, model.orbit, "south", model.n_pixels,
                     model.n_scans)


@eqx.filter_jit
def _transfer_kernel(source, target, pixel, scan):
    """T at ``(n,)`` points and its ``(n, 2, 2)`` Jacobian ∂(target pixel, scan)/∂(source pixel, scan)."""

    def one(p, s):
        def point(q):
            return jnp.stack(source.carried_to(target, q[0], q[1]))

        q = jnp.stack([p, s])
        return point(q), jax.jacfwd(point)(q)

    values, jacobian = jax.vmap(one)(pixel, scan)
    return values[:, 0], values[:, 1], jacobian


@eqx.filter_jit
def _inverse_kernel(model, latitude, longitude):
    return model.inverse(latitude, longitude)


@eqx.filter_jit
def _forward_kernel(model, pixel, scan):
    return model.forward_unchecked(pixel, scan)


@eqx.filter_jit
def _plane_forward(plane, latitude, longitude):
    return plane.forward(latitude, longitude)


@eqx.filter_jit
def _plane_inverse(plane, x, y):
    return plane.inverse(x, y)


def _chunked(kernel, modules, *arrays):
    """``kernel(*modules, *arrays)`` over the arrays flattened, in chunks of :data:`_POINTS` (padded: one
    compilation per kernel); outputs shaped like the arrays (plus trailing axes), numpy."""
    modules = tuple(_southbound(m) if isinstance(m, ScanModel) else m for m in modules)
    arrays = [np.asarray(a, float) for a in arrays]
    shape = np.broadcast_shapes(*(a.shape for a in arrays))
    flat = [np.broadcast_to(a, shape).ravel() for a in arrays]
    parts = []
    for start in range(0, max(flat[0].size, 1), _POINTS):
        chunk = [jnp.asarray(pad(a[start:start + _POINTS], _POINTS, 1.0)) for a in flat]
        parts.append([np.asarray(out) for out in kernel(*modules, *chunk)])
    return tuple(np.concatenate(outs)[:flat[0].size].reshape(shape + outs[0].shape[1:]) for outs in
                 zip(*parts, strict=True))


def transfer(source: ScanModel, target: ScanModel, pixel, scan):
    """``(pixel, scan)`` in ``target`` of the ground seen at ``(pixel, scan)`` (numpy, any shape) in ``source``,
    by the two models."""
    return _chunked(_transfer_kernel, (source, target), pixel, scan)[:2]


@eqx.filter_jit
def _transfer_sensitivity(source, target, pixel, scan):
    """``(2, n, 10)`` ∂T/∂(source unknowns, target unknowns) at ``(n,)`` source points."""

    def moved(values):
        return jnp.stack(with_scan_unknowns(source, values[:5]).carried_to(with_scan_unknowns(target, values[5:]),
                                                                            pixel, scan))

    return jax.jacfwd(moved)(jnp.concatenate([scan_unknowns(source), scan_unknowns(target)]))


def _span_sign(model: ScanModel):
    """``(5,)`` factors from the unknowns of ``model`` to those of :func:`_southbound` ``(model)``."""
    factors = np.ones(5)
    factors[SCAN_UNKNOWNS.index("orbital_angle_span")] = 1.0 if model.direction == "south" else -1.0
    return factors


def _inside(model: ScanModel, pixel, scan, margin):
    return ((pixel >= 1 + margin) & (pixel <= model.n_pixels - margin) & (scan >= 1 + margin)
            & (scan <= model.n_scans - margin))


def _pair_search(source, target, covariances, options: TieOptions, margin):
    """± pixels searched from ``source`` into ``target``, or 0 when they do not overlap."""
    scan, pixel = (a.ravel() for a in np.meshgrid(np.linspace(1, source.n_scans, 9),
                                                  np.linspace(1, source.n_pixels, 9), indexing="ij"))
    p, s = transfer(source, target, pixel, scan)
    overlap = _inside(target, p, s, margin) & np.isfinite(p)
    if not overlap.any():
        return 0
    if covariances is None:
        return options.search
    jacobian = np.asarray(_transfer_sensitivity(_southbound(source), _southbound(target), jnp.asarray(pixel),
                                                jnp.asarray(scan)))[:, overlap]
    covariance = np.zeros((10, 10))
    for block, model, matrix in ((slice(0, 5), source, covariances[0]), (slice(5, 10), target, covariances[1])):
        factors = _span_sign(model)
        covariance[block, block] = factors[:, None] * matrix * factors[None, :]
    sigma = np.sqrt(np.max(np.einsum("cnk,kl,cnl->cn", jacobian, covariance, jacobian)))
    return int(np.clip(np.ceil(options.n_sigma * sigma) + 1, 2, options.max_search))


def _pixel_size(model: ScanModel):
    """m, mean ground size of a pixel and a scan line at the image's centre."""
    p, s = 0.5 * (1 + model.n_pixels), 0.5 * (1 + model.n_scans)
    lat, lon = _chunked(_forward_kernel, (model,), [p, p + 1, p], [s, s, s + 1])
    radius = float(model.orbit.radius)
    step = radius * np.hypot(lat[1:] - lat[0], np.angle(np.exp(1j * (lon[1:] - lon[0]))) * np.cos(lat[0]))
    return float(np.mean(step))


def _centres(models):
    """``(n, 2)`` latitude, longitude (radians) of the images' centres."""
    return np.array([_chunked(_forward_kernel, (m,), [0.5 * (1 + m.n_pixels)], [0.5 * (1 + m.n_scans)])
                     for m in models])[:, :, 0]


def _may_overlap(models, sizes):
    """``(n, n)`` bool: the images' centres are closer than the sum of their half diagonals (plus 20 %)."""
    centres = _centres(models)
    reach = np.array([0.6 * np.hypot(m.n_pixels, m.n_scans) * size for m, size in zip(models, sizes, strict=True)])
    distance = np.asarray(great_circle_distance(centres[:, None, 0], centres[:, None, 1], centres[None, :, 0],
                                                centres[None, :, 1], float(models[0].orbit.radius)))
    return distance < reach[:, None] + reach[None, :]


def _lattice(models, spacing_m):
    """Ground points ``(latitude, longitude)`` every ``spacing_m`` over the union of the images, and the plane."""
    centres = _centres(models)
    plane = TangentPlane(np.mean(centres[:, 0]), np.angle(np.mean(np.exp(1j * centres[:, 1]))))
    xs, ys = [], []
    for m in models:
        edge_p = np.r_[np.linspace(1, m.n_pixels, 17), np.full(17, m.n_pixels), np.linspace(1, m.n_pixels, 17),
                       np.ones(17)]
        edge_s = np.r_[np.ones(17), np.linspace(1, m.n_scans, 17), np.full(17, m.n_scans),
                       np.linspace(1, m.n_scans, 17)]
        x, y = _chunked(_plane_forward, (plane,), *_chunked(_forward_kernel, (m,), edge_p, edge_s))
        xs.append(x)
        ys.append(y)
    x, y = np.concatenate(xs), np.concatenate(ys)
    gx, gy = np.meshgrid(np.arange(x.min(), x.max() + spacing_m, spacing_m),
                         np.arange(y.min(), y.max() + spacing_m, spacing_m))
    return plane, gx.ravel(), gy.ravel()


def _static_footprint(static, plane, x, y, half_width):
    """True where ``static`` holds on a 5 x 5 grid of points over ±``half_width`` m around every ``(x, y)``."""
    ok = np.ones(x.size, bool)
    for dx in np.linspace(-half_width, half_width, 5):
        for dy in np.linspace(-half_width, half_width, 5):
            ok &= np.asarray(static(*_chunked(_plane_inverse, (plane,), x + dx, y + dy)), bool)
    return ok


def _patches(data, pixel, scan, half):
    """``(n, 2h+1, 2h+1)`` patches of ``data`` around integer 1-based ``(pixel, scan)`` (inside the image)."""
    offsets = np.arange(-half, half + 1)
    rows = (scan.astype(int) - 1)[:, None, None] + offsets[None, :, None]
    columns = (pixel.astype(int) - 1)[:, None, None] + offsets[None, None, :]
    return data[rows, columns]


def _windows(data, source, target, pixel, scan, half):
    """Windows ``(n, 2h+1, 2h+1)`` of ``data`` (image of ``target``) resampled on the pixel grid of ``source``
    around integer ``(pixel, scan)``; and whether each lies inside ``target`` (bicubic needs one more pixel)."""
    offsets = np.arange(-half, half + 1, dtype=float)
    shape = (pixel.size, offsets.size, offsets.size)
    grid_p = np.broadcast_to(pixel[:, None, None] + offsets[None, None, :], shape)
    grid_s = np.broadcast_to(scan[:, None, None] + offsets[None, :, None], shape)
    p, s = transfer(source, target, grid_p, grid_s)
    valid = (np.isfinite(p) & np.isfinite(s) & (p >= 2) & (p <= target.n_pixels - 1) & (s >= 2)
             & (s <= target.n_scans - 1)).all(axis=(1, 2))
    size = 2 * half + 1
    out = np.empty(p.shape, np.float32)
    image = np.asarray(data, np.float32)
    chunk = _REMAP_ROWS // size
    for start in range(0, pixel.size, chunk):
        part = slice(start, start + chunk)
        map_x = np.nan_to_num(p[part] - 1.0, nan=-10.0).astype(np.float32).reshape(-1, size)
        map_y = np.nan_to_num(s[part] - 1.0, nan=-10.0).astype(np.float32).reshape(-1, size)
        resampled = cv2.remap(image, map_x, map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
        out[part] = resampled.reshape(-1, size, size)
    return out, valid & np.isfinite(out).all(axis=(1, 2))


@dataclass(frozen=True)
class _Matches:
    """Matches from a reference image into another, for ``n`` candidates."""

    candidate: np.ndarray
    pixel: np.ndarray
    scan: np.ndarray
    sigma: np.ndarray  # (n, 2) pixel, scan in the other image
    sigma_reference: np.ndarray  # (n, 2) in the reference image
    correlation: np.ndarray
    status: np.ndarray


def _peak(template, window, radius, samples):
    """The NCC peak of ``template`` in ``window`` (searched ±``radius``): ``(status, shift (d_scan, d_pixel),
    correlation, sharpness, covariance (2, 2))`` (quadratic sub-pixel fit; covariance of the shift from
    ``samples`` = N_eff independent template pixels, module docstring), or a failure status with NaN values."""
    surface, i, j, correlation, sharpness = correlation_peak(template, window)
    failed = (np.full(2, np.nan), correlation, sharpness, np.zeros((2, 2)))
    if i in (0, surface.shape[0] - 1) or j in (0, surface.shape[1] - 1):
        return AT_EDGE, *failed
    offset, hessian = quadratic_peak(surface, i, j)
    if np.linalg.det(hessian) <= 0 or hessian[0, 0] >= 0:
        return FLAT_PEAK, *failed
    covariance = peak_covariance(correlation, hessian, samples)
    return GOOD, np.array([i - radius + offset[0], j - radius + offset[1]]), correlation, sharpness, covariance


def _match_pair(data_r, data_o, model_r, model_o, candidate, pixel, scan, search, options: TieOptions) -> _Matches:
    """Match the reference patches at integer ``(pixel, scan)`` of image r in image o: an integer-window search,
    then the window resampled again at the match found and the residual shift added (module docstring, 3.)."""
    half = options.patch // 2
    samples = options.patch**2 / options.correlation_area
    templates = _patches(np.asarray(data_r, np.float32), pixel, scan, half)
    windows, valid = _windows(data_o, model_r, model_o, pixel, scan, half + search)
    n = pixel.size
    status = np.full(n, GOOD)
    shift = np.zeros((n, 2))  # (d_scan, d_pixel) in the reference frame
    correlation, sharpness = np.full(n, np.nan), np.full(n, np.nan)
    covariance = np.zeros((n, 2, 2))
    for k in range(n):
        if not (valid[k] and np.isfinite(templates[k]).all()):
            status[k] = NO_DATA
        elif templates[k].std() < options.min_contrast:
            status[k] = LOW_CONTRAST
        else:
            status[k], shift[k], correlation[k], sharpness[k], covariance[k] = _peak(
                templates[k], windows[k], search, samples)
    refine = np.nonzero(status == GOOD)[0]
    if refine.size:
        again, inside = _windows(data_o, model_r, model_o, pixel[refine] + shift[refine, 1],
                                 scan[refine] + shift[refine, 0], half + _REFINE)
        for w, k in enumerate(refine):
            if not inside[w]:
                status[k] = NO_DATA
                continue
            code, residual, rho, _, matrix = _peak(templates[k], again[w], _REFINE, samples)
            if code != GOOD:
                status[k] = code
                continue
            shift[k] += residual
            correlation[k], covariance[k] = rho, matrix
    shift = np.nan_to_num(shift)
    status[(status == GOOD) & (correlation < options.min_correlation)] = LOW_CORRELATION
    status[(status == GOOD) & (sharpness < options.min_sharpness)] = FLAT_PEAK
    tested = median_test(Displacements(scan, pixel, shift[:, 0], shift[:, 1], correlation, sharpness, status,
                                       np.sqrt(covariance[:, 0, 0]), np.sqrt(covariance[:, 1, 1])),
                         TrackingOptions(median_threshold=options.median_threshold, neighbours=options.neighbours))
    status = tested.status
    matched_p, matched_s = pixel + shift[:, 1], scan + shift[:, 0]
    p, s, jacobian = _chunked(_transfer_kernel, (model_r, model_o), matched_p, matched_s)
    covariance = covariance[:, ::-1, ::-1]  # (pixel, scan) order
    in_other = np.einsum("nij,njk,nlk->nil", jacobian, covariance, jacobian)
    floor = options.pointing_sigma**2
    sigma = np.sqrt(floor + 0.5 * np.diagonal(in_other, axis1=1, axis2=2))
    sigma_reference = np.sqrt(floor + 0.5 * np.diagonal(covariance, axis1=1, axis2=2))
    return _Matches(candidate, p, s, sigma, sigma_reference, correlation, status)


def image_runs(images, max_images: int) -> list[np.ndarray]:
    """The runs of a ground point's images that become its ties (module docstring, 6.).

    Args:
        images: indices of the images that see the point (any order). max_images: most images per run (≥ 2).

    Returns:
        The images sorted in sequence order as one run when there are at most ``max_images``; else the fewest runs
        of at most ``max_images`` consecutive ones, of near-equal length, each run's last image the next run's first.
    """
    images = np.sort(np.asarray(images, int))
    if images.size <= max_images:
        return [images]
    count = -(-(images.size - 1) // (max_images - 1))
    bounds = np.rint(np.linspace(0, images.size - 1, count + 1)).astype(int)
    return [images[first:last + 1] for first, last in zip(bounds[:-1], bounds[1:], strict=True)]


def _runs(seen, max_images: int):
    """``(point (n,), member (n_images, n))``: per run of :func:`image_runs` over the points' ``seen
    (n_images, n_points)`` columns, its point's column and its images (one run per point seen by at most
    ``max_images``: then ``point`` is ``arange`` and ``member`` is ``seen``)."""
    if not (seen.sum(axis=0) > max_images).any():
        return np.arange(seen.shape[1]), seen
    point, columns = [], []
    for j in range(seen.shape[1]):
        for run in image_runs(np.nonzero(seen[:, j])[0], max_images):
            column = np.zeros(seen.shape[0], bool)
            column[run] = True
            point.append(j)
            columns.append(column)
    return np.array(point), np.stack(columns, axis=1)


def find_ties(images: Sequence, models: Sequence[ScanModel], static: Callable, covariances=None,
              options: TieOptions = TieOptions()) -> TiePoints:
    """Tie points between all overlapping images of a sequence, on the static surface.

    Args:
        images: ``(n_scans, n_pixels)`` arrays (row = scan line − 1, column = pixel − 1; NaN: no data).
        models: the current :class:`ScanModel` of every image (e.g. fitted to its control points).
        static: ``static(latitude, longitude) -> bool`` arrays (radians): land and fast ice; :func:`grid_mask`
            makes one from a raster mask.
        covariances: ``(5, 5)`` per image (order of :data:`~seaice_jax.geometry.scan.SCAN_UNKNOWNS`), the models'
            uncertainty, sizing each pair's search window; ``None``: ``options.search``.
        options: :class:`TieOptions`.

    Returns:
        :class:`TiePoints` (GOOD matches only; :attr:`TiePoints.candidates` counts every match tried by status).
    """
    models = list(models)
    images = [np.asarray(a, float) for a in images]
    if len(images) != len(models):
        raise SeaiceError(f"{len(images)} images but {len(models)} models")
    for k, (image, model) in enumerate(zip(images, models, strict=True)):
        if image.shape != (model.n_scans, model.n_pixels):
            raise SeaiceError(f"image {k}: shape {image.shape} differs from its model's (n_scans, n_pixels) = "
                              f"({model.n_scans}, {model.n_pixels})")
    if covariances is not None:
        covariances = [np.asarray(c, float) for c in covariances]
        if len(covariances) != len(models) or any(c.shape != (5, 5) for c in covariances):
            raise SeaiceError(f"covariances: one (5, 5) matrix per image ({len(models)}) expected")
    n_images = len(models)
    half = options.patch // 2
    sizes = [_pixel_size(m) for m in models]
    plane, x, y = _lattice(models, options.spacing * float(np.mean(sizes)))
    latitude, longitude = _chunked(_plane_inverse, (plane,), x, y)
    seen = np.zeros((n_images, x.size), bool)
    pixels, scans = np.zeros((n_images, x.size)), np.zeros((n_images, x.size))
    for i, model in enumerate(models):
        p, s = _chunked(_inverse_kernel, (model,), latitude, longitude)
        pixels[i], scans[i] = np.rint(p), np.rint(s)
        seen[i] = _inside(model, pixels[i], scans[i], half + 2)
    keep = seen.sum(axis=0) >= 2
    keep[keep] = _static_footprint(static, plane, x[keep], y[keep], (half + 1) * max(sizes))
    kept = np.nonzero(keep)[0]
    contrast_kept = np.full((n_images, kept.size), -np.inf)
    for i in range(n_images):
        visible = seen[i, kept]
        if visible.any():
            patches = _patches(images[i], pixels[i, kept[visible]], scans[i, kept[visible]], half)
            contrast_kept[i, visible] = np.nan_to_num(patches.std(axis=(1, 2)), nan=-1.0)
    point, member = _runs(seen[:, kept], options.max_images)  # the candidates: one per run of a point's images
    pixels, scans = pixels[:, kept[point]], scans[:, kept[point]]
    contrast = np.where(member, contrast_kept[:, point], -np.inf)
    candidates = np.arange(point.size)
    near = _may_overlap(models, sizes) & (member.astype(float) @ member.T.astype(float) > 0)  # in one run
    searches = {}
    for r in range(n_images):
        for o in range(n_images):
            if r != o and near[r, o] and (search := _pair_search(
                    models[r], models[o], None if covariances is None else (covariances[r], covariances[o]), options,
                    half + 2)):
                searches[(r, o)] = search
    found: list[tuple[tuple[int, int], _Matches]] = []
    active = np.ones(candidates.size, bool)
    for _ in range(n_images - 1):  # a candidate whose reference matched nowhere tries the next best reference
        reference = np.where(active, np.argmax(contrast, axis=0), -1)
        tied = np.zeros(candidates.size, bool)
        for r in range(n_images):
            referenced = np.nonzero(reference == r)[0]
            for o in range(n_images):
                if (r, o) not in searches or referenced.size == 0:
                    continue
                window_inside = _inside(models[o], pixels[o, referenced], scans[o, referenced],
                                        half + searches[(r, o)] + 3)
                chosen = referenced[window_inside & member[o, referenced]]
                if chosen.size == 0:
                    continue
                matches = _match_pair(images[r], images[o], models[r], models[o], candidates[chosen],
                                      pixels[r, chosen], scans[r, chosen], searches[(r, o)], options)
                found.append(((r, o), matches))
                tied[chosen[matches.status == GOOD]] = True
        contrast[reference[active & ~tied], np.nonzero(active & ~tied)[0]] = -np.inf
        active &= ~tied & (np.isfinite(contrast).sum(axis=0) >= 2)
        if not active.any():
            break
    return _assemble(found, models, pixels, scans, searches)


def _assemble(found, models, pixels, scans, searches) -> TiePoints:
    """Number the candidates with at least one good match and list their observations."""
    rows: dict[str, list] = {key: [] for key in ("image", "candidate", "pixel", "scan", "sigma_pixel", "sigma_scan",
                                                 "correlation", "reference")}
    reference_sigma: dict[int, list] = {}
    owner: dict[int, int] = {}
    for (r, o), m in found:
        good = m.status == GOOD
        for key, values in (("image", np.full(good.sum(), o)), ("candidate", m.candidate[good]),
                            ("pixel", m.pixel[good]), ("scan", m.scan[good]), ("sigma_pixel", m.sigma[good, 0]),
                            ("sigma_scan", m.sigma[good, 1]), ("correlation", m.correlation[good]),
                            ("reference", np.zeros(good.sum(), bool))):
            rows[key].append(values)
        for c, sigma in zip(m.candidate[good], m.sigma_reference[good], strict=True):
            reference_sigma.setdefault(int(c), []).append(sigma)
            owner[int(c)] = r
    tied = np.array(sorted(owner), int)
    if tied.size:
        owners = np.array([owner[c] for c in tied])
        sigma = np.array([np.mean(reference_sigma[c], axis=0) for c in tied])
        for key, values in (("image", owners), ("candidate", tied), ("pixel", pixels[owners, tied]),
                            ("scan", scans[owners, tied]), ("sigma_pixel", sigma[:, 0]),
                            ("sigma_scan", sigma[:, 1]), ("correlation", np.full(tied.size, np.nan)),
                            ("reference", np.ones(tied.size, bool))):
            rows[key].append(values)
    table = {key: np.concatenate(v) if v else np.zeros(0) for key, v in rows.items()}
    order = np.lexsort((table["image"], ~table["reference"].astype(bool), table["candidate"]))
    table = {key: v[order] for key, v in table.items()}
    tie = np.searchsorted(tied, table["candidate"].astype(int))
    lat, lon = np.zeros(tied.size), np.zeros(tied.size)
    if tied.size:
        for r in np.unique(owners):
            members = owners == r
            lat[members], lon[members] = _chunked(_forward_kernel, (models[r],), pixels[r, tied[members]],
                                                  scans[r, tied[members]])
    candidates: dict[tuple[int, int], np.ndarray] = {}
    for pair, m in found:
        candidates[pair] = candidates.get(pair, 0) + np.bincount(m.status, minlength=len(STATUS))
    return TiePoints(table["image"].astype(int), tie, table["pixel"], table["scan"], table["sigma_pixel"],
                     table["sigma_scan"], table["correlation"], table["reference"].astype(bool), lat, lon,
                     dict(sorted(candidates.items())), {pair: searches[pair] for pair in sorted(candidates)})
