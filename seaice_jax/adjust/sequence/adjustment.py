"""The simultaneous adjustment of a satellite image sequence on the shared engine (issue 13).

Every image's five scan-model unknowns, every tie point's ground position and the control points of all images
in one least-squares adjustment (:mod:`seaice_jax.adjust.sequence.model` gives the observation groups), solved by
the engine's Schur-complement backend: the tie points are eliminated point by point, so the work grows linearly
with the ties and the reduced system has 5 unknowns per image. The result carries the full joint covariance of
all images' unknowns (σ̂0² S⁻¹ of the reduced system), so two images' geolocation errors keep their correlation
(they share ties) when a drift is formed from them.

Mismatched ties (a match on the wrong feature, wrong by pixels) are found by Baarda's data snooping: after each
solve the tie observations failing the w-test at ``alpha`` are ranked by |w|; the ties holding the worst of them
(|w| at least ``batch`` times the largest: a mismatch among hundreds of good ties leaks little into the others'
w) are removed, all of their observations at once (in a tie seen by two images the two w are nearly fully
correlated: which image holds the wrong match cannot be told), and the adjustment is repeated until no tie
observation is flagged. Removal sets σ to ∞ (the engine's padding), so every round reuses the compiled solve; the
rows and tie points are padded to bucket sizes the same way, so sequences of similar size share it too.
With ``robust`` the first solve is an iteratively reweighted one (:func:`~..engine.variance.robust_adjustment`)
and the ties it down-weights below ``robust_cut`` are removed before the snooping.

Stochastic model: the σ of the tie observations is the matcher's guess (:mod:`seaice_jax.imagery.ties`), the σ of
the control points is the user's (map accuracy and pointing). Once no tie is flagged, the variance factor of every
group named in ``variance_groups`` (default: the ties) is estimated (Förstner/Helmert,
:func:`~seaice_jax.adjust.engine.variance.variance_components`), its σ rescaled, and the snooping resumed with the
rescaled σ until both settle. The covariance reported is then Q of the rescaled problem, not σ̂0² Q: one global
σ̂0 is the ties' factor (they hold nearly all the redundancy), and scaling by it the part of the covariance that the
control points carry (the absolute geolocation) made the models' stated position σ 4.3 times too small when σ̂0 was
0.26 (experiments/results/sequence_block.md).

Correlated and systematic tie errors: the matcher's errors are not independent, and what the ties carry (the relative
geometry of the images, hence the drift) is exactly what their correlation spoils. Measured against the truth on
simulated sequences (the simulated images are rendered through the scan model itself, so no model error is left:
best fits to the true geolocation give drift errors below 1e-8 m; with the true correspondents plus independent
noise of the stated σ the stated / empirical drift σ is 1.04 pooled over 10 noise draws), two parts are missing from
a σ per observation:

* **Correlated tie errors**: neighbouring matches share template pixels (about 0.4 within 5 pixels, 0.15-0.2 at
  5-10); their information is that of n / κ ties. The covariance is the weighted estimator's under that model,
  Q (κ N_t + N_o) Q (:func:`correlated_tie_covariance`; ``SequenceOptions.tie_correlation``);
* **Systematic tie errors**: the sub-pixel bias of the matches varies with the sampling phase, so each pair's
  errors carry a common part: the scan-model unknowns absorb it (it never shows in the residuals, and the estimated
  variance factor does not see it) and it moves the relative geometry. Removing each pair's affine field (known from
  the truth) cut the drift error of four sequences from 73-320 m to 14-51 m. The part is not of one size: fitted as
  an affine field to the true errors, its offset is 3 times larger (η_o 45 against 15 in units of the pair's own
  (Xᵀ W X)⁻¹) on ties matched through predicted orbits than on ties matched through per-image fits of the same
  images, because it follows d, the shift the matcher had to find between where the models it matched through put
  the correspondent and where it is: binned by the fractional part of d, the true errors' mean swings by ±0.015-0.02
  pixel, and a predicted orbit errs by nearly a shift (d varies by 0.02-0.3 pixel over a pair's overlap, the pair
  gets one bias), a per-image fit also in rotation and scale (0.05-1.2 pixel, the bias averages out; two of the
  tuning seeds, standard deviations of d over each pair's matches). So per pair and
  axis a field c₁ cos 2πd + c₂ sin 2πd with c ~ N(0, σ_φ²), d from the starting and the adjusted models, propagated
  through the adjustment (:func:`phase_tie_covariance`; ``tie_phase_sigma``).
  The phase term alone leaves the low-order part of the pair fields short, and that is the part the drift sees
  (issue 29): on 33 fresh sequences the stated / empirical drift σ was 0.81 with 12 control points, on the tuning
  seeds 1.05 — ten sequences decide a pooled ratio only to ±15-20 % (one sequence's drift error is a few smooth
  fields; per sequence the ratio ran 0.5-2.0), so the drift ratio on them could not show it. Split on simulated
  sequences (seeds 301-303) into what each error source moves: the drift error due to the ties' true errors
  (pushed through the adjustment's gain, Δθ = Q Āᵀ W e) was 44 m RMS against a stated 37 m (12 control points)
  and 59 against 45 m (2), all of it through the affine part of each pair's errors; the control points' part
  was right (stated 9.9 m, 6.2 m realized; with the simulator's anisotropic pointing instead of one σ: the same
  ±1 %). Fitted per pair axis to the true errors (seeds 300-304, 326-329: 432 pair axes of ≥ 30 matches), the
  affine coefficients' mean square is 1.40 times what the correlated noise and the phase term give them for the
  offset, 1.34-1.40 for the gradient along the pixels and 2.0 along the scan lines, the same for ties matched
  through per-image fits and through predicted orbits. So the affine field is added to the phase term: η_o 8.9
  and η_g 4.5 times the variance (Xᵀ W X)⁻¹ that the pair's own matches give its coefficients, the excess pooled
  over both kinds of ties (:func:`systematic_tie_covariance`; ``tie_offset_factor``, ``tie_gradient_factor``).
  Measured in the drift they cause, the pair fields of different pairs are not positively correlated: their
  cross terms are −2 to −10 % of the sum of the pairs' own (tuning seeds, each control count).

Both are added to the covariance (``SequenceAdjustment.systematic``); the estimates stay those of the weighted
adjustment.
"""

from collections.abc import Sequence
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from seaice_jax._shapes import bucket, pad
from seaice_jax.adjust import engine
from seaice_jax.adjust.engine.problem import Problem, ResidualBlock, linearize, weights
from seaice_jax.adjust.engine.quality import DEFAULT_ALPHA
from seaice_jax.adjust.engine.schur import normal_equations
from seaice_jax.adjust.engine.variance import ROBUST, robust_adjustment, variance_components
from seaice_jax.adjust.sequence.model import (
    UNKNOWNS_PER_IMAGE,
    SequenceObservations,
    sequence_observations,
    unknown_names,
)
from seaice_jax.errors import ComputationError, SeaiceError
from seaice_jax.geometry.scan import ScanModel
from seaice_jax.sensors.control import ControlPoints


@dataclass(frozen=True)
class SequenceOptions:
    """Choices of :func:`adjust_sequence`.

    Attributes:
        alpha: significance level of each w-test (two-sided).
        batch: per round, the ties whose worst |w| is at least this fraction of the round's largest are removed
            (1: one tie per round, Baarda's strict snooping).
        max_rounds: of removal and re-adjustment.
        robust: ``None`` or a weight function of :data:`~seaice_jax.adjust.engine.variance.ROBUST` for the first solve.
        robust_cut: ties with an observation down-weighted below this factor by the robust solve are removed.
        max_steps: of the engine's damped Gauss-Newton loop per solve.
        variance_groups: prefixes of the observation groups whose variance factors are estimated once no tie is
            flagged (module docstring), one factor per prefix shared by its groups (the tie groups of the pass
            directions and image sizes meet only in differences: their split is not determined); ``()``: none, the
            covariance is then σ̂0² Q.
        variance_tolerance: the factors are iterated until each changes by less than this fraction (their own
            relative σ is √(2/r), 0.06 for r = 500 tie coordinates: the default is well below it).
        tie_correlation: variance inflation of the ties' own errors (≥ 1): neighbouring matches share template
            pixels, so their errors are correlated and n ties carry the information of about n / this (module
            docstring, «Correlated tie errors»). The default is measured on :func:`~seaice_jax.imagery.ties.find_ties`
            matches of simulated sequences (10 sequences of 3 images of 256 pixels, 100 pair axes of ≥ 30 ties):
            1 + Σ_j ρ_ij over the other matches within one template width (15 pixels) after each pair's affine
            field is removed, median 2.6, mean 2.6. 1: independent (ties simulated that way).
        tie_offset_factor, tie_gradient_factor: η_o, η_g, the size of a systematic error common to the matches
            of one image pair as an affine field (module docstring, «Systematic tie errors»): per pair and image
            axis an affine field whose offset and gradients have η_o and η_g times the variance that the pair's
            matches would give them were their errors independent of their final σ, added to the covariance.
            The defaults are measured beside ``tie_phase_sigma`` and ``tie_correlation`` (issue 29): per pair
            axis of :func:`~seaice_jax.imagery.ties.find_ties` matches of simulated sequences (tuning seeds
            300-304 and 326-329 of ``experiments/sequence_block.py``, 4 images of 256 pixels; 432 pair axes of
            ≥ 30 matches, through the per-image fits and through predicted orbits) the affine field fitted to the
            true errors, its coefficients' mean square less what ``tie_correlation`` times (Xᵀ W X)⁻¹ and the
            phase term give them, over Σ (Xᵀ W X)⁻¹: offset 8.9 (5.0 through per-image fits, 13.0 through
            predicted orbits), gradients 4.5 (2.2-3.0 along the pixels, 7.6 along the scan lines). 0: none.
        tie_phase_sigma: pixels, σ of the matches' sub-pixel bias as a function of the sampling phase (module
            docstring, «Systematic tie errors»; :func:`phase_tie_covariance`): per pair and axis of the matched
            image, c₁ cos 2πd + c₂ sin 2πd with c ~ N(0, σ²), d the shift between where the starting models put a
            match and where the adjusted models do (the models passed to :func:`adjust_sequence` must be those the
            ties were matched through). The default is measured on :func:`~seaice_jax.imagery.ties.find_ties`
            matches of simulated Lancaster-like sequences (tuning seeds 100-109 of ``experiments/sequence_block.py``,
            4 images of 256 pixels, GSHHG coast; 480 pair axes of ≥ 30 matches, through the per-image fits and
            through predicted orbits) against the true correspondents: the part of each pair axis's true errors
            on cos 2πd, sin 2πd beside the matches' own noise (``tie_correlation`` times the residual variance),
            0.0182 pixel (90 % bootstrap over the sequences 0.0171-0.0194; 0.0155 through the per-image fits,
            0.0205 through the predicted orbits). With it and ``tie_correlation`` alone (no affine fields, before
            issue 29) the stated / empirical drift σ on those seeds was 1.05 / 0.95 / 0.93 / 0.92 with 12 / 4 / 2 /
            0 control points (90 % bootstrap over the sequences 0.94-1.21 / 0.83-1.13 / 0.82-1.07 / 0.80-1.10).
            0: none (ties simulated with independent errors).
    """

    alpha: float = DEFAULT_ALPHA
    batch: float = 0.5
    max_rounds: int = 50
    robust: str | None = None
    robust_cut: float = 0.1
    max_steps: int = 64
    variance_groups: tuple[str, ...] = ("ties",)
    variance_tolerance: float = 0.01
    tie_correlation: float = 2.5
    tie_offset_factor: float = 8.9
    tie_gradient_factor: float = 4.5
    tie_phase_sigma: float = 0.018

    def __post_init__(self):
        if not 0 < self.alpha < 1:
            raise SeaiceError(f"alpha must be in (0, 1), got {self.alpha}")
        if not self.tie_correlation >= 1:
            raise SeaiceError(f"tie_correlation must be >= 1, got {self.tie_correlation}")
        if not (self.tie_offset_factor >= 0 and self.tie_gradient_factor >= 0):
            raise SeaiceError(f"tie_offset_factor and tie_gradient_factor must be >= 0, got "
                              f"{self.tie_offset_factor} and {self.tie_gradient_factor}")
        if not self.tie_phase_sigma >= 0:
            raise SeaiceError(f"tie_phase_sigma must be >= 0 pixels, got {self.tie_phase_sigma}")
        if not 0 < self.batch <= 1:
            raise SeaiceError(f"batch must be in (0, 1], got {self.batch}")
        if self.robust is not None and self.robust not in ROBUST:
            raise SeaiceError(f"robust must be None or one of {', '.join(ROBUST)}, got {self.robust!r}")


class SequenceAdjustment(eqx.Module):
    """The adjusted sequence.

    Attributes:
        models: the adjusted :class:`ScanModel` of every image.
        theta: ``(n_images, 5)`` their unknowns (order of :data:`~seaice_jax.geometry.scan.SCAN_UNKNOWNS`).
        covariance: ``(5 n_images, 5 n_images)`` of all images' unknowns, cross-covariances between images
            included (image i's unknowns are rows 5i..5i+4): Q with the estimated variance factors, or σ̂0² Q
            without (``variance_groups=()``), plus ``systematic``. cofactor: Q (the final σ taken as right).
        systematic: ``(5 n_images, 5 n_images)`` the part of ``covariance`` due to the ties' correlated and
            systematic errors (module docstring; 0 with ``tie_correlation=1`` and both tie factors 0).
        sigma0: a posteriori σ̂0 (with the final σ). degrees_of_freedom: of the final adjustment.
        variance_factors: ``{group: σ̂g²}`` estimated (relative to the a priori σ; empty without).
        tie_latitude, tie_longitude: ``(n_ties,)`` radians, adjusted tie positions (NaN for removed ties).
        removed_ties: ids of the ties removed as mismatches, in the order found. rounds: adjustments solved.
        adjustment: the engine's final :class:`~seaice_jax.adjust.engine.Adjustment` (residuals, w-tests …; its
            groups' rows and points padded: the first ``observations.groups[g].rows`` rows and ``n_ties`` points
            are real).
        observations: the :class:`SequenceObservations` adjusted (removed ties with σ = ∞).
        names: ``(5 n_images,)`` names of the unknowns (``"<image>.<unknown>"``).
        alpha: the w-tests' significance level.
    """

    models: tuple
    theta: np.ndarray
    covariance: np.ndarray
    cofactor: np.ndarray
    systematic: np.ndarray
    sigma0: float
    degrees_of_freedom: int
    tie_latitude: np.ndarray
    tie_longitude: np.ndarray
    removed_ties: tuple
    rounds: int
    variance_factors: dict
    adjustment: engine.Adjustment
    observations: SequenceObservations
    names: tuple
    alpha: float = eqx.field(static=True, default=DEFAULT_ALPHA)

    @property
    def n_removed(self) -> int:
        return len(self.removed_ties)

    def image_covariance(self, first: int, second: int | None = None) -> np.ndarray:
        """``(5, 5)`` covariance of image ``first``'s unknowns with image ``second``'s (default: itself)."""
        second = first if second is None else second
        a, b = UNKNOWNS_PER_IMAGE * first, UNKNOWNS_PER_IMAGE * second
        return self.covariance[a:a + UNKNOWNS_PER_IMAGE, b:b + UNKNOWNS_PER_IMAGE]

    def pair_covariance(self, first: int, second: int) -> np.ndarray:
        """``(10, 10)`` joint covariance of two images' unknowns (``first``'s then ``second``'s), as
        :func:`~seaice_jax.workflows.track.displacement_sigma` takes it."""
        index = np.r_[UNKNOWNS_PER_IMAGE * first + np.arange(UNKNOWNS_PER_IMAGE),
                      UNKNOWNS_PER_IMAGE * second + np.arange(UNKNOWNS_PER_IMAGE)]
        return self.covariance[np.ix_(index, index)]

    def flagged(self) -> list[engine.Flag]:
        """Observations of the final adjustment still failing the w-test (control points, priors), worst first."""
        return self.adjustment.flagged(self.alpha)


def _padded_block(block: ResidualBlock) -> ResidualBlock:
    """The block with its rows padded to a bucket size (copies of row 0 with σ = ∞: the engine's padding, weight 0),
    so sequences of similar size share one compiled solve."""
    extra = bucket(block.rows) - block.rows

    def padded(leaf):
        return jnp.concatenate([leaf, jnp.repeat(leaf[:1], extra, axis=0)])

    sigma = jnp.concatenate([block.sigma, jnp.full((extra, block.components), jnp.inf)])
    point_index = None if block.point_index is None else padded(block.point_index)
    return ResidualBlock(block.function, jax.tree_util.tree_map(padded, block.data), sigma,
                         padded(block.global_index), point_index)


def sequence_problem(observations: SequenceObservations) -> Problem:
    """The engine's :class:`Problem` of a sequence: θ flattened (5 per image), one 2-d point per tie (points
    0..n_ties−1; the rows and the points are padded to bucket sizes, the padding unobserved)."""
    blocks = {name: _padded_block(g) for name, g in observations.groups.items()}
    return Problem(blocks, jnp.ravel(observations.start), jnp.zeros((bucket(observations.n_ties), 2)))


def _without(problem: Problem, removed: np.ndarray) -> Problem:
    """``problem`` with every observation of the ``removed`` ties (boolean ``(n_ties,)``) given σ = ∞."""
    blocks = {}
    for name, block in problem.blocks.items():
        if block.point_index is not None:
            drop = jnp.asarray(removed)[block.point_index]
            block = eqx.tree_at(lambda b: b.sigma, block, jnp.where(drop[:, None], jnp.inf, block.sigma))
        blocks[name] = block
    return Problem(blocks, problem.start, problem.points)


def _worst_ties(problem: Problem, result: engine.Adjustment, alpha: float, batch: float) -> list[int]:
    """Ties whose worst flagged observation has |w| ≥ ``batch`` times the largest flagged tie |w|, worst first."""
    tie_groups = [n for n, b in problem.blocks.items() if b.point_index is not None]
    return result.worst(lambda flag: int(problem.blocks[flag.group].point_index[flag.row]), alpha, batch, tie_groups)


_linearize = eqx.filter_jit(linearize)


def _pair_fields(pixel, scan, pair, sizes, whitened, factors):
    """``(m, 2, 3)`` per matched observation and axis, the whitened values of the three standardized coefficients of
    its pair's affine error field (module docstring): the basis X (offset; gradients along pixel and scan about the
    pair's centroid, per image width) times 1/σ, times L with L Lᵀ = S (Xᵀ W X)⁻¹ S of the pair and axis,
    S = diag(√``factors``) ``(3,)``.

    Args:
        pixel, scan: ``(m,)`` the matched observations. pair: ``(m,)`` pair number 0..P−1. sizes: ``(m, 2)`` the
            matched image's pixels and scan lines. whitened: ``(m, 2)`` 1/σ per axis.
    """
    count = np.bincount(pair)
    centre = [np.bincount(pair, weights=v) / count for v in (pixel, scan)]
    basis = np.stack([np.ones(pixel.shape), (pixel - centre[0][pair]) / sizes[:, 0],
                      (scan - centre[1][pair]) / sizes[:, 1]], 1)
    field = basis[:, None, :] * whitened[:, :, None]  # (m, 2, 3)
    information = np.zeros((count.size, 2, 3, 3))
    np.add.at(information, pair, np.einsum("mac,mad->macd", field, field))
    values, vectors = np.linalg.eigh(information)  # ⁻¹ on the range (a pair of fewer than 3 ties: rank deficient)
    scaled = np.where(values > 1e-12 * values[..., -1:], 1.0 / np.sqrt(np.maximum(values, 1e-300)), 0.0)
    root = np.sqrt(np.asarray(factors))[:, None] * vectors * scaled[..., None, :]  # (P, 2, 3, 3): S info⁺ S
    return np.einsum("mac,macd->mad", field, root[pair])


def _tie_rows(problem: Problem, result: engine.Adjustment, n_ties: int):
    """The live tie rows of ``problem`` at ``result``'s solution (padding and removed ties left out): whitened
    J_θ ``(m, 2, 5)``, J_p ``(m, 2, 2)``, θ indices ``(m, 5)``, tie ``(m,)``, weights ``(m, 2)``, pixel and scan
    ``(m,)``."""
    theta, points = result.parameters["theta"], result.parameters["points"]
    rows = []
    for block in problem.blocks.values():
        if block.point_index is None:
            continue
        linear = _linearize(block, theta, points)
        tie = np.asarray(block.point_index)
        live = (tie < n_ties) & np.asarray(weights(block) > 0).all(axis=1)
        rows.append((np.asarray(linear.theta)[live], np.asarray(linear.point)[live],
                     np.asarray(block.global_index)[live], tie[live], np.asarray(weights(block))[live],
                     np.asarray(block.data["pixel"])[live], np.asarray(block.data["scan"])[live]))
    return tuple(np.concatenate(a) for a in zip(*rows, strict=True))


def _field_pull(rows, n_ties: int, size: int, matched, pair, field) -> np.ndarray:
    """``(size, 2 C P)`` Āᵀ W u per coefficient of the pairs' error fields: ``field (k, 2, C)`` the whitened values
    u/σ of the C coefficients' basis on the ``matched`` rows (per axis of the matched image), ``pair (k,)`` their
    pair 0..P−1 (column (2 pair + axis) C + coefficient). Ā is the tie rows' design with the tie points eliminated
    tie by tie: the field's direct pull J_θᵀ W u on the matched image, less the tie point's response
    (J_pᵀ W J_p)⁻¹ J_pᵀ W u pulling every observation of the tie."""
    j_theta, j_point, index, tie = rows[:4]
    count = field.shape[2]
    column = np.broadcast_to(((2 * pair[:, None, None] + np.arange(2)[:, None]) * count + np.arange(count))[..., None],
                             (matched.size, 2, count, UNKNOWNS_PER_IMAGE))  # (k, axis, coefficient, θ of the image)
    right = np.zeros((size, 2 * count * (int(pair.max()) + 1)))
    np.add.at(right, (np.broadcast_to(index[matched][:, None, None, :], column.shape).reshape(-1),
                      column.reshape(-1)),
              np.einsum("mai,mac->maci", j_theta[matched], field).reshape(-1))
    normal = np.zeros((n_ties, 2, 2))
    np.add.at(normal, tie, np.einsum("mci,mcj->mij", j_point, j_point))
    inverse = np.linalg.pinv(normal)
    shift = np.einsum("mde,mae,mac->mdac", inverse[tie[matched]], j_point[matched], field)  # (k, 2, 2, C)
    coupling = np.einsum("mei,med->mid", j_theta, j_point)  # (m, 5, 2): J_θᵀ W J_p per observation
    order = np.argsort(tie, kind="stable")
    start = np.searchsorted(tie[order], np.arange(n_ties))
    seen = np.bincount(tie, minlength=n_ties)
    for position in range(int(seen.max())):
        has = seen[tie[matched]] > position
        other = order[start[tie[matched[has]]] + position]  # the position-th observation of each matched tie
        values = -np.einsum("mid,mdac->maci", coupling[other], shift[has])
        np.add.at(right, (np.broadcast_to(index[other][:, None, None, :], values.shape).reshape(-1),
                          column[has].reshape(-1)), values.reshape(-1))
    return right


def _matched_pairs(rows, reference_image):
    """The matched rows (image ≠ its tie's reference image), their images, and per row the pair number of
    (reference image, matched image) with the ``(P, 2)`` pairs."""
    index, tie = rows[2], rows[3]
    image = index[:, 0] // UNKNOWNS_PER_IMAGE
    matched = np.nonzero(image != reference_image[tie])[0]
    pairs, pair = np.unique(np.stack([reference_image[tie[matched]], image[matched]], 1), axis=0,
                            return_inverse=True)
    return matched, image, pairs, pair.ravel()


def systematic_tie_covariance(problem: Problem, result: engine.Adjustment, reference_image, sizes, cofactor,
                              offset_factor: float, gradient_factor: float) -> np.ndarray:
    """``(n, n)`` covariance of the estimated θ due to a systematic error field of the tie matches (module
    docstring): for every pair (reference image a, matched image b) and axis of b, an affine field u = X c added to
    b's observations of the ties matched against a, c ~ N(0, S (Xᵀ W X)⁻¹ S), S = diag(√η_o, √η_g, √η_g): η
    times the covariance that the pair's own matches, were their errors independent of the final σ, would give
    the affine part of their errors. θ̂ moves by g = Q Āᵀ W u, Ā the tie rows' design with the tie points
    eliminated tie by tie (Ā = A_θ − A_p (A_pᵀ W A_p)⁻¹ A_pᵀ W A_θ per tie), W the final weights and
    Q = (Āᵀ W Ā + the rest)⁻¹ the ``cofactor``, all at the solution: the covariance is Σ g gᵀ over the
    coefficients (the estimator stays the weighted one; this is its covariance under the wider error model). All
    pairs at once: a sparse scatter per observation and per observation of the same tie, one dense product.

    Args:
        problem: the final problem (removed ties with σ = ∞, padded rows unobserved).
        result: its adjustment. reference_image: ``(n_ties,)``. sizes: ``(n_images, 2)`` pixels and scan lines.
        cofactor: ``(n, n)`` Q of ``problem``. offset_factor, gradient_factor: η_o, η_g
            (:class:`SequenceOptions`).
    """
    size = cofactor.shape[0]
    if not (offset_factor > 0 or gradient_factor > 0):
        return np.zeros((size, size))
    reference_image, n_ties = np.asarray(reference_image), int(np.asarray(reference_image).size)
    rows = _tie_rows(problem, result, n_ties)
    matched, image, pairs, pair = _matched_pairs(rows, reference_image)
    if matched.size == 0:
        return np.zeros((size, size))
    weight, pixel, scan = rows[4:]
    field = _pair_fields(pixel[matched], scan[matched], pair, np.asarray(sizes)[image[matched]],
                         weight[matched], (offset_factor, gradient_factor, gradient_factor))  # (k, 2, 3)
    gain = cofactor @ _field_pull(rows, n_ties, size, matched, pair, field)
    return gain @ gain.T


@eqx.filter_jit
def _carried(source: ScanModel, target: ScanModel, pixel, scan):
    """``(n, 2)`` pixel and scan in ``target`` of the ground that ``source`` sees at ``(n,)`` ``pixel``, ``scan``."""
    return jnp.stack(source.carried_to(target, pixel, scan), -1)


def phase_tie_covariance(problem: Problem, result: engine.Adjustment, observations: SequenceObservations, cofactor,
                         phase_sigma: float) -> np.ndarray:
    """``(n, n)`` covariance of the estimated θ due to the matches' sub-pixel bias as a function of the sampling
    phase (module docstring, «Systematic tie errors»): for every pair (reference image a, matched image b) and axis
    α of b, the field u = c₁ cos 2πd_α + c₂ sin 2πd_α, c ~ N(0, ``phase_sigma``² I) (pixels), on b's observations
    of the ties matched against a; d ``(2,)`` pixels, where the starting models (``observations.models``, those
    the ties were matched through) put the reference observation's correspondent in b, less where the adjusted
    models put it (the shift the matcher had to find). A pair whose d hardly varies over the overlap gets one
    bias of σ ``phase_sigma`` on all its matches; one whose d sweeps through a pixel averages it out. Propagated
    as :func:`systematic_tie_covariance` propagates its fields: Σ g gᵀ, g = Q Āᵀ W u per coefficient.

    Args:
        problem: the final problem. result: its adjustment. observations: the sequence's observations (their
            ``models`` the starting models, ``reference_image``). cofactor: ``(n, n)`` Q of ``problem``.
        phase_sigma: pixels (:class:`SequenceOptions` ``tie_phase_sigma``).
    """
    size = cofactor.shape[0]
    if not phase_sigma > 0:
        return np.zeros((size, size))
    reference_image = np.asarray(observations.reference_image)
    n_ties = int(reference_image.size)
    rows = _tie_rows(problem, result, n_ties)
    matched, image, pairs, pair = _matched_pairs(rows, reference_image)
    if matched.size == 0:
        return np.zeros((size, size))
    tie, weight, pixel, scan = rows[3], rows[4], rows[5], rows[6]
    reference = np.nonzero(image == reference_image[tie])[0]
    reference_pixel, reference_scan = np.zeros(n_ties), np.zeros(n_ties)
    reference_pixel[tie[reference]], reference_scan[tie[reference]] = pixel[reference], scan[reference]
    adjusted = observations.models_at(jnp.asarray(result.parameters["theta"]).reshape(-1, UNKNOWNS_PER_IMAGE))
    where = []
    for models in (observations.models, adjusted):  # q through the reference image's model, then b's inverse
        carried = np.zeros((matched.size, 2))
        for number, (a, b) in enumerate(pairs):
            pick = np.nonzero(pair == number)[0]
            rows_padded = bucket(pick.size)  # pairs of similar overlap share one compiled transfer
            at = [pad(v[tie[matched[pick]]], rows_padded, v[tie[matched[pick[0]]]]) for v in (reference_pixel,
                                                                                           reference_scan)]
            carried[pick] = np.asarray(_carried(models[a], models[b], *at))[:pick.size]
        where.append(carried)
    shift = where[0] - where[1]
    phase = 2 * np.pi * shift
    field = (phase_sigma * np.stack([np.cos(phase), np.sin(phase)], -1)
             * weight[matched][..., None])  # (k, 2, 2)
    gain = cofactor @ _field_pull(rows, n_ties, size, matched, pair, field)
    return gain @ gain.T


def correlated_tie_covariance(problem: Problem, result: engine.Adjustment, cofactor, scale: float,
                              correlation: float) -> np.ndarray:
    """``(n, n)`` covariance of θ̂ added by correlated tie errors whose information is 1/``correlation`` of what
    their σ say: with the tie rows' reduced normal matrix N_t = Q⁻¹ − N_o (N_o of the other rows: control points,
    priors), the estimator's covariance Q (κ N_t + N_o) Q = Q + (κ − 1)(Q − Q N_o Q), times ``scale`` (σ̂0² where
    the covariance is σ̂0² Q, else 1)."""
    size = cofactor.shape[0]
    if correlation == 1:
        return np.zeros((size, size))
    theta, points = result.parameters["theta"], result.parameters["points"]
    others = Problem({k: b for k, b in problem.blocks.items() if b.point_index is None}, theta, points)
    linear = {k: _linearize(b, theta, points) for k, b in others.blocks.items()}
    other = np.asarray(normal_equations(others, linear)[0])  # N_o: control points, priors
    return scale * (correlation - 1.0) * (cofactor - cofactor @ other @ cofactor)


def adjust_sequence(models: Sequence[ScanModel], ties, controls: Sequence[ControlPoints | None] = (),
                    prior_mean=None, prior_covariance=None, options: SequenceOptions = SequenceOptions(),
                    image_names: Sequence[str] | None = None) -> SequenceAdjustment:
    """Adjust all images of a sequence at once; remove mismatched ties by data snooping.

    Args:
        models: the current scan model of every image (starting values; orbit, direction and size fixed).
        ties: :class:`~seaice_jax.imagery.ties.TiePoints` (or any table with its fields), ``None``: none.
        controls: per image its :class:`ControlPoints` or ``None``.
        prior_mean, prior_covariance: per-image priors of the unknowns (``(n, 5)`` and ``(n, 5, 5)`` or σ
            ``(n, 5)``; see :func:`~seaice_jax.adjust.sequence.model.sequence_observations`); ``None``: none.
        options: :class:`SequenceOptions`.
        image_names: for the names of the unknowns (default ``image<i>``).

    Returns:
        :class:`SequenceAdjustment`.

    Raises:
        SeaiceError: bad input (named by :func:`sequence_observations`), an adjustment that does not converge, or
            mismatches still flagged after ``options.max_rounds``.
    """
    observations = sequence_observations(models, ties, controls, prior_mean, prior_covariance)
    names = tuple(unknown_names(observations, image_names))
    problem = sequence_problem(observations)
    engine_options = engine.EngineOptions(backend="schur", max_steps=options.max_steps)
    removed = np.zeros(problem.points.shape[0], bool)
    order: list[int] = []
    rounds = 0
    previous = None  # every round starts from the previous round's estimates (a few ties fewer, or rescaled σ)
    if options.robust is not None:
        robust = previous = robust_adjustment(problem, options.robust, engine_options, names)
        rounds += 1
        for name, block in problem.blocks.items():
            if block.point_index is not None and robust.robust_weights is not None:
                low = np.asarray(robust.robust_weights[name]).min(axis=1) < options.robust_cut
                new = np.setdiff1d(np.asarray(block.point_index)[low], np.nonzero(removed)[0])
                removed[new] = True
                order += [int(t) for t in new]
    estimated = [n for n in problem.blocks if n.startswith(tuple(options.variance_groups))]
    # the groups of one prefix share one factor: a tie of two images is one observation in each image's group, so
    # the ties fix the sum of the groups' variances, not its split (variance_components, ``pooled``)
    pooled = tuple(pool for prefix in options.variance_groups
                   if len(pool := tuple(n for n in estimated if n.startswith(prefix))) > 1)
    factors = dict.fromkeys(estimated, 1.0)
    settled = not estimated
    for _ in range(options.max_rounds):
        current = engine.rescaled(_without(problem, removed), {}, previous)
        result = engine.solve(current, engine_options, names, throw=False)
        rounds += 1
        if not bool(result.converged):
            raise ComputationError(f"the sequence adjustment did not converge in {options.max_steps} steps "
                                   f"(round {rounds}, {int(removed.sum())} ties removed)")
        worst = _worst_ties(current, result, options.alpha, options.batch)
        if not worst and not settled:
            result = variance_components(engine.rescaled(current, {}, result), engine_options, names,
                                         groups=estimated, pooled=pooled, tolerance=options.variance_tolerance,
                                         max_rounds=options.max_rounds)
            change = {n: component.value for label, component in result.variance_components.items()
                      for n in label.split("+")}
            factors = {n: factors[n] * change[n] for n in estimated}
            problem = engine.rescaled(problem, {n: np.sqrt(change[n]) for n in estimated})
            current = _without(problem, removed)
            settled = True
            worst = _worst_ties(current, result, options.alpha, options.batch)
        if not worst:
            break
        previous = result
        removed[worst] = True
        order += worst
        settled = not estimated
    else:
        raise SeaiceError(f"tie observations still flagged after {options.max_rounds} rounds of removal "
                          f"({int(removed.sum())} ties removed); raise max_rounds or check the tie matching")
    final = eqx.tree_at(lambda o: o.groups, observations, {
        name: eqx.tree_at(lambda g: g.sigma, g, current.blocks[name].sigma[:g.rows])
        for name, g in observations.groups.items()})
    theta = np.asarray(result.parameters["theta"]).reshape(-1, UNKNOWNS_PER_IMAGE)
    n_ties = observations.n_ties
    latitude, longitude = (np.where(removed[:n_ties], np.nan, np.asarray(a))
                           for a in observations.ground_at(result.parameters["points"][:n_ties]))
    covariance = np.asarray(result.cofactor if estimated else result.covariance)
    sizes = np.array([(m.n_pixels, m.n_scans) for m in observations.models])
    cofactor = np.asarray(result.cofactor)
    systematic = (correlated_tie_covariance(current, result, cofactor, 1.0 if estimated else float(result.sigma0) ** 2,
                                            options.tie_correlation)
                  + systematic_tie_covariance(current, result, observations.reference_image, sizes, cofactor,
                                              options.tie_offset_factor, options.tie_gradient_factor)
                  + phase_tie_covariance(current, result, observations, cofactor, options.tie_phase_sigma))
    return SequenceAdjustment(
        tuple(observations.models_at(jnp.asarray(theta))), theta, covariance + systematic,
        np.asarray(result.cofactor), systematic, float(result.sigma0), engine.degrees_of_freedom(current), latitude,
        longitude, tuple(order), rounds, factors, result, final, names, options.alpha)
