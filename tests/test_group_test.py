"""The test of a group of observations without unknowns of their own against the rest of an adjustment
(``group_test``): Monte Carlo over a linear model whose truth is known, with a direction of the unknowns only the
group determines (C singular) and with errors of the other observations that their weights leave out."""

import jax
import numpy as np
import pytest
from scipy.stats import binom, chi2

from seaice_jax.adjust.engine.quality import group_test

DRAWS = 2000
ALPHA = 0.05


def _design(rng):
    """Whitened rows: 40 'tie' rows on unknowns 0-1, 6 'control' rows on unknowns 0-2 (unknown 2 only by them)."""
    ties = np.concatenate([rng.normal(size=(40, 2)), np.zeros((40, 1))], axis=1)
    control = rng.normal(size=(6, 3))
    return ties, control


def _statistics(shared_sigma: float, with_systematic: bool):
    rng = np.random.default_rng(29)
    ties, control = _design(rng)
    design = np.concatenate([ties, control])
    cofactor = np.linalg.inv(design.T @ design)
    direction = ties[:, 0]  # an error all tie rows share, the pattern a shift of unknown 0 makes
    # its part in the unknowns' covariance: the estimate moves by K direction g, K = Q A_tᵀ, g ~ N(0, shared²)
    moved = cofactor @ ties.T @ direction
    systematic = shared_sigma**2 * np.outer(moved, moved) if with_systematic else None
    errors = rng.normal(size=(DRAWS, 46))
    errors[:, :40] += shared_sigma * rng.normal(size=(DRAWS, 1)) * direction
    estimates = errors @ design @ cofactor  # the least-squares estimates (truth 0), Q Aᵀ e per draw
    residuals = estimates @ control.T - errors[:, 40:]
    statistic, count, redundancy = jax.vmap(group_test, in_axes=(0, None, None, None))(residuals, control, cofactor,
                                                                                         systematic)
    hat = design @ np.linalg.pinv(design)  # the redundancy numbers by the hat matrix, another path
    np.testing.assert_allclose(np.asarray(redundancy[0]), 1.0 - np.diag(hat)[40:], atol=1e-12)
    return np.stack([np.asarray(statistic), np.asarray(count)], axis=1)


@pytest.mark.parametrize("shared_sigma", [0.0, 1.0])
def test_the_group_test_rejects_at_its_level_on_its_rank(shared_sigma):
    """T ~ χ²(q) with q = 5: six control rows less the direction only they determine (its residuals vanish).
    With errors the tie rows share (σ 1 along the pattern a shift of one unknown makes) the test is right when
    their covariance S is given, and rejects far more than α without it."""
    values = _statistics(shared_sigma, with_systematic=True)
    statistic, count = values[:, 0], values[:, 1]
    assert np.all(count == 5)
    assert np.mean(statistic) == pytest.approx(5.0, abs=4 * np.sqrt(2 * 5 / DRAWS))
    lower = chi2.cdf(statistic, 5)
    rejected = int(np.sum(2 * np.minimum(lower, 1 - lower) < ALPHA))
    low, high = binom.ppf([0.001, 0.999], DRAWS, ALPHA)
    assert low <= rejected <= high, rejected
    if shared_sigma:
        plain = _statistics(shared_sigma, with_systematic=False)[:, 0]
        lower = chi2.cdf(plain, 5)
        assert np.sum(2 * np.minimum(lower, 1 - lower) < ALPHA) > 2 * high
