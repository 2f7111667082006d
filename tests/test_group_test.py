"""The test of a group of observations without unknowns of their own against the rest of an adjustment
(``group_test``): the drop in the square sum when the group may be biased (a closed form), and Monte Carlo over
linear models whose truth is known, with a direction of the unknowns only the group determines (C singular) and with
errors of the other observations that their weights leave out."""

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


def _draws(design, cofactor, observed, rows, systematic=None):
    """T of the first ``rows`` rows for each draw of ``observed`` ``(draws, m)`` (truth 0, σ 1)."""
    residuals = (observed @ design @ cofactor) @ design[:rows].T - observed[:, :rows]
    return np.asarray(jax.vmap(group_test, in_axes=(0, None, None, None))(residuals, design[:rows], cofactor,
                                                                           systematic)[0])


def test_group_test_is_the_drop_in_square_sum_when_the_group_may_be_biased():
    """On a linear model y = A x + e (σ = 1): T = ṽᵀR⁻¹ṽ of the group's rows equals the square sum of all residuals
    less that of the adjustment without the group (the test of an arbitrary bias in it), and diag R is the group's
    redundancy numbers."""
    rng = np.random.default_rng(3)
    design, group = rng.normal(size=(30, 4)), np.arange(6)
    observed = design @ rng.normal(size=4) + rng.normal(size=30)
    cofactor = np.linalg.inv(design.T @ design)
    residual = design @ (cofactor @ design.T @ observed) - observed
    others = design[6:]
    rest = others @ np.linalg.lstsq(others, observed[6:], rcond=None)[0] - observed[6:]
    statistic, count, redundancy = group_test(residual[group], design[group], cofactor)
    assert count == 6
    assert np.isclose(statistic, residual @ residual - rest @ rest, rtol=1e-10)
    hat = design @ cofactor @ design.T
    assert np.allclose(redundancy, 1.0 - np.diag(hat)[group])


def test_group_test_with_errors_the_weights_leave_out_is_chi_square():
    """With errors of the other observations that the weights leave out (y_o += B c, c ~ N(0, I)) and S their
    covariance of the estimates (Q A_oᵀ B Bᵀ A_o Q), T = ṽᵀ(R + J S Jᵀ)⁻¹ṽ has mean q (χ²(q)) over 2000 draws;
    without S it is larger."""
    rng = np.random.default_rng(5)
    design = rng.normal(size=(30, 4))
    shared = np.zeros((30, 2))
    shared[6:] = 3.0 * rng.normal(size=(24, 2))
    cofactor = np.linalg.inv(design.T @ design)
    gain = cofactor @ design.T @ shared
    observed = rng.normal(size=(2000, 30)) + rng.normal(size=(2000, 2)) @ shared.T
    stated = _draws(design, cofactor, observed, 6, gain @ gain.T)
    plain = _draws(design, cofactor, observed, 6)
    assert abs(np.mean(stated) / 6 - 1) < 0.05
    assert np.mean(plain) / 6 > 1.2


def test_group_test_takes_the_rank_where_the_group_alone_fixes_an_unknown():
    """Where an unknown is fixed by the group's rows alone (the datum the sequences' ties leave free), R = I − J Q Jᵀ
    is singular: the group's residuals have none along that direction, T is taken on R's rank, q − 1, and its mean
    over 2000 draws is q − 1 (against χ²(q) it would read low)."""
    rng = np.random.default_rng(7)
    design = rng.normal(size=(30, 4))
    design[6:, 3] = 0.0  # the fourth unknown is seen by the group's six rows only
    cofactor = np.linalg.inv(design.T @ design)
    observed = rng.normal(size=(2000, 30))
    _, count, _ = group_test(observed[0, :6], design[:6], cofactor)
    assert count == 5
    assert abs(np.mean(_draws(design, cofactor, observed, 6)) / 5 - 1) < 0.05
