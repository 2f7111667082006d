"""The simultaneous adjustment of a satellite image sequence on the shared engine (issue 13).

Every image's five scan-model unknowns, every tie point's ground position and the control points of all images
in one least-squares adjustment (:mod:`seaice_jax.adjust.sequence_model` gives the observation groups), solved by
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
With ``robust`` the first solve is an iteratively reweighted one (:func:`~seaice_jax.adjust.variance.robust_adjustment`)
and the ties it down-weights below ``robust_cut`` are removed before the snooping.

Stochastic model: the σ of the tie observations is the matcher's guess (:mod:`seaice_jax.imagery.ties`), the σ of
the control points is the user's (map accuracy and pointing). Once no tie is flagged, the variance factor of every
group named in ``variance_groups`` (default: the ties) is estimated (Förstner/Helmert,
:func:`~seaice_jax.adjust.variance.variance_components`), its σ rescaled, and the snooping resumed with the
rescaled σ until both settle. The covariance reported is then Q of the rescaled problem, not σ̂0² Q: one global
σ̂0 is the ties' factor (they hold nearly all the redundancy), and scaling by it the part of the covariance that the
control points carry (the absolute geolocation) made the models' stated position σ 4.3 times too small when σ̂0 was
0.26 (experiments/results/sequence_block.md). The drift σ (the relative part, which the ties carry) is still stated
too small there: see that file.
"""

from collections.abc import Sequence
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from seaice_jax._shapes import bucket
from seaice_jax.adjust import engine
from seaice_jax.adjust.problem import Problem, ResidualBlock
from seaice_jax.adjust.quality import DEFAULT_ALPHA
from seaice_jax.adjust.sequence_model import (
    UNKNOWNS_PER_IMAGE,
    SequenceObservations,
    global_index,
    sequence_observations,
    unknown_names,
)
from seaice_jax.adjust.variance import ROBUST, robust_adjustment, variance_components
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
        robust: ``None`` or a weight function of :data:`~seaice_jax.adjust.variance.ROBUST` for the first solve.
        robust_cut: ties with an observation down-weighted below this factor by the robust solve are removed.
        max_steps: of the engine's damped Gauss-Newton loop per solve.
        variance_groups: prefixes of the observation groups whose variance factors are estimated once no tie is
            flagged (module docstring); ``()``: none, the covariance is then σ̂0² Q.
        variance_tolerance: the factors are iterated until each changes by less than this fraction (their own
            relative σ is √(2/r), 0.06 for r = 500 tie coordinates: the default is well below it).
    """

    alpha: float = DEFAULT_ALPHA
    batch: float = 0.5
    max_rounds: int = 50
    robust: str | None = None
    robust_cut: float = 0.1
    max_steps: int = 64
    variance_groups: tuple[str, ...] = ("ties",)
    variance_tolerance: float = 0.01

    def __post_init__(self):
        if not 0 < self.alpha < 1:
            raise SeaiceError(f"alpha must be in (0, 1), got {self.alpha}")
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
            without (``variance_groups=()``). cofactor: Q (the final σ taken as right).
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
        :func:`~seaice_jax.workflows.image_sequence.displacement_sigma` takes it."""
        index = np.r_[UNKNOWNS_PER_IMAGE * first + np.arange(UNKNOWNS_PER_IMAGE),
                      UNKNOWNS_PER_IMAGE * second + np.arange(UNKNOWNS_PER_IMAGE)]
        return self.covariance[np.ix_(index, index)]

    def flagged(self) -> list[engine.Flag]:
        """Observations of the final adjustment still failing the w-test (control points, priors), worst first."""
        return self.adjustment.flagged(self.alpha)


def _padded_block(group) -> ResidualBlock:
    """The group as a residual block with its rows padded to a bucket size (copies of row 0 with σ = ∞: the
    engine's padding, weight 0), so sequences of similar size share one compiled solve."""
    size = bucket(group.rows)
    extra = size - group.rows
    data = jax.tree_util.tree_map(lambda leaf: jnp.concatenate([leaf, jnp.repeat(leaf[:1], extra, axis=0)]),
                                  group.data)
    sigma = jnp.concatenate([group.sigma, jnp.full((extra, group.sigma.shape[1]), jnp.inf)])
    image = jnp.concatenate([group.image, jnp.repeat(group.image[:1], extra)])
    tie = None if group.tie is None else jnp.concatenate([group.tie, jnp.repeat(group.tie[:1], extra)])
    return ResidualBlock(group.function, data, sigma, global_index(image), tie)


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
    worst: dict[int, float] = {}
    for flag in result.flagged(alpha, tie_groups):
        tie = int(problem.blocks[flag.group].point_index[flag.row])
        worst[tie] = max(worst.get(tie, 0.0), abs(flag.w))
    if not worst:
        return []
    largest = max(worst.values())
    return [t for t, w in sorted(worst.items(), key=lambda item: -item[1]) if w >= batch * largest]


def adjust_sequence(models: Sequence[ScanModel], ties, controls: Sequence[ControlPoints | None] = (),
                    prior_mean=None, prior_covariance=None, options: SequenceOptions = SequenceOptions(),
                    image_names: Sequence[str] | None = None) -> SequenceAdjustment:
    """Adjust all images of a sequence at once; remove mismatched ties by data snooping.

    Args:
        models: the current scan model of every image (starting values; orbit, direction and size fixed).
        ties: :class:`~seaice_jax.imagery.ties.TiePoints` (or any table with its fields), ``None``: none.
        controls: per image its :class:`ControlPoints` or ``None``.
        prior_mean, prior_covariance: per-image priors of the unknowns (``(n, 5)`` and ``(n, 5, 5)`` or σ
            ``(n, 5)``; see :func:`~seaice_jax.adjust.sequence_model.sequence_observations`); ``None``: none.
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
    if options.robust is not None:
        robust = robust_adjustment(problem, options.robust, engine_options, names)
        rounds += 1
        for name, block in problem.blocks.items():
            if block.point_index is not None and robust.robust_weights is not None:
                low = np.asarray(robust.robust_weights[name]).min(axis=1) < options.robust_cut
                new = np.setdiff1d(np.asarray(block.point_index)[low], np.nonzero(removed)[0])
                removed[new] = True
                order += [int(t) for t in new]
    estimated = [n for n in problem.blocks if n.startswith(tuple(options.variance_groups))]
    factors = dict.fromkeys(estimated, 1.0)
    settled = not estimated
    for _ in range(options.max_rounds):
        current = _without(problem, removed)
        result = engine.solve(current, engine_options, names)
        rounds += 1
        if not bool(result.converged):
            raise ComputationError(f"the sequence adjustment did not converge in {options.max_steps} steps "
                                   f"(round {rounds}, {int(removed.sum())} ties removed)")
        worst = _worst_ties(current, result, options.alpha, options.batch)
        if not worst and not settled:
            result = variance_components(current, engine_options, names, groups=estimated,
                                         tolerance=options.variance_tolerance, max_rounds=options.max_rounds)
            change = {n: result.variance_components[n].value for n in estimated}
            factors = {n: factors[n] * change[n] for n in estimated}
            problem = engine.rescaled(problem, {n: np.sqrt(change[n]) for n in estimated})
            current = _without(problem, removed)
            settled = True
            worst = _worst_ties(current, result, options.alpha, options.batch)
        if not worst:
            break
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
    covariance = result.cofactor if estimated else result.covariance
    return SequenceAdjustment(
        tuple(observations.models_at(jnp.asarray(theta))), theta, np.asarray(covariance),
        np.asarray(result.cofactor), float(result.sigma0), result.degrees_of_freedom, latitude, longitude,
        tuple(order), rounds, factors, result, final, names, options.alpha)
