"""The control points' test of a sequence adjustment: do the images' control points agree with what the ties and
the other images say, within the σ the product states? The whole adjustment's global test says little here: the
ties' variance factors are estimated, which makes their Σ(v/σ)² equal their redundancy (issue 29)."""

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from seaice_jax.adjust.engine.problem import linearize
from seaice_jax.adjust.engine.quality import global_test, group_test
from seaice_jax.adjust.sequence.adjustment import SequenceAdjustment, sequence_problem


@dataclass(frozen=True)
class ControlTest:
    """The control points' group test (:func:`control_test`).

    Attributes:
        statistic: T = ṽᵀ C⁺ ṽ. degrees_of_freedom: q, C's rank (the control coordinates less the directions of the
            unknowns only they determine). p_value: two-sided. accepted: p ≥ α. alpha: the test's level.
    """

    statistic: float
    degrees_of_freedom: int
    p_value: float
    accepted: bool
    alpha: float


def control_rows(result: SequenceAdjustment) -> tuple[np.ndarray, np.ndarray]:
    """The control-point observations of ``result`` at its solution: their whitened residuals (computed − known
    over σ) ``(q,)`` and their whitened Jacobian with respect to all images' unknowns ``(q, 5 n_images)``, the rows
    of every control group, north and east of each point (padding rows left out)."""
    problem = sequence_problem(result.observations)
    theta, points = result.adjustment.parameters["theta"], result.adjustment.parameters["points"]
    whitened, jacobian = [], []
    for name, block in problem.blocks.items():
        if not name.startswith("control"):
            continue
        linear = linearize(block, theta, points)
        real = np.asarray(jnp.isfinite(block.sigma)).reshape(-1)
        columns = np.asarray(block.global_index)  # (m, k)
        dense = np.zeros(block.sigma.shape + (int(theta.shape[0]),))  # (m, c, n)
        rows = np.arange(block.rows)[:, None, None]
        np.add.at(dense, (rows, np.arange(block.components)[None, :, None], columns[:, None, :]),
                  np.asarray(linear.theta))
        whitened.append(np.asarray(linear.e).reshape(-1)[real])
        jacobian.append(dense.reshape(-1, dense.shape[-1])[real])
    if not whitened:
        return np.zeros(0), np.zeros((0, int(theta.shape[0])))
    return np.concatenate(whitened), np.concatenate(jacobian)


def control_test(result: SequenceAdjustment, alpha: float = 0.05, stated: bool = True) -> ControlTest | None:
    """The control points' test against the rest of the adjustment (:func:`~..engine.quality.group_test`), their σ
    as given: T ~ χ²(q) under the stochastic model the product states — with ``stated`` the ties' correlated and
    systematic errors included (C = R + J S Jᵀ, S = ``result.systematic``; without, C = R: the ties' errors
    independent, as their weights alone say). Two-sided at ``alpha``. On 109 simulated sequences of 4 images it
    rejects 5.5 % (12 points an image) and 6.4 % (2 points) at α = 5 %; with C = R 22 and 39 %
    (``experiments/results/calibration.md``). ``None`` without control points or redundancy among them."""
    whitened, jacobian = control_rows(result)
    if whitened.size == 0:
        return None
    statistic, count, _ = group_test(whitened, jacobian, result.cofactor, result.systematic if stated else None)
    statistic, count = float(statistic), int(count)
    if count == 0:
        return None
    _, p_value, accepted = global_test(statistic / count, count, alpha)
    return ControlTest(statistic, count, float(p_value), bool(accepted), alpha)
