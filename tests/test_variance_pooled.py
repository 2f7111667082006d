"""Variance components of groups that only meet in differences: their split is not determined, their pooled
factor is (seaice_jax.adjust.engine.variance, ``pooled``)."""

import jax.numpy as jnp
import numpy as np
import pytest

from seaice_jax.adjust.engine.problem import Problem, ResidualBlock
from seaice_jax.adjust.engine.variance import variance_components
from seaice_jax.errors import SeaiceError

PAIRS = 200


def _value(theta, _, row):
    return jnp.atleast_1d(theta[0] - row["y"])


def paired_problem(rng, sigma_a, sigma_b, stated=0.1, repeats=0):
    """Every unknown x_i seen once in group "a" and once in "b" (as a tie in two images): only the differences
    y_a − y_b carry redundancy, so only σa² + σb² is estimable; ``repeats`` unknowns seen a second time in "a" (as
    control points of one image) determine the split, weakly. Both groups are given σ ``stated``."""
    truth = rng.normal(0, 1, PAIRS)
    seen = {"a": np.r_[np.arange(PAIRS), np.arange(repeats)], "b": np.arange(PAIRS)}
    blocks = {g: ResidualBlock(_value, {"y": jnp.asarray(truth[seen[g]] + rng.normal(0, s, seen[g].size))},
                               jnp.full((seen[g].size, 1), stated), jnp.asarray(seen[g])[:, None])
              for g, s in (("a", sigma_a), ("b", sigma_b))}
    return Problem(blocks, jnp.zeros(PAIRS))


def test_separate_factors_of_a_weakly_determined_split_do_not_settle():
    """Five repeated observations in "a" against 200 pairs, every σ right: the iteration moves the split by a few
    per cent a round for 50 rounds, as the two-image Lancaster Sound sequence of seed 2 did with its control
    points (``seaice simulate lancaster --images 2 --seed 2``, then ``seaice adjust``)."""
    with pytest.raises(SeaiceError, match="did not settle"):
        variance_components(paired_problem(np.random.default_rng(1), 0.1, 0.1, repeats=5), tolerance=0.01,
                            max_rounds=50)


def test_pooled_factor_recovers_the_sum_of_the_variances():
    """σa 0.1, σb 0.2 stated 0.1 each: the pooled factor of the 200 pairs is (0.01 + 0.04) / 0.02 = 2.5 (the five
    repeats add their own, 1, to its redundancy: (2.5 · 200 + 5)/205 = 2.46); 30 realizations average to it and
    scatter by its reported σ."""
    rng = np.random.default_rng(2)
    values, sigmas = [], []
    for _ in range(30):
        result = variance_components(paired_problem(rng, 0.1, 0.2, repeats=5), pooled=[("a", "b")])
        component = result.variance_components["a+b"]
        values.append(component.value)
        sigmas.append(component.sigma)
        assert component.redundancy == pytest.approx(PAIRS + 5, rel=1e-6)
    assert set(result.variance_components) == {"a+b"}
    np.testing.assert_allclose(np.mean(values), (2.5 * PAIRS + 5) / (PAIRS + 5), atol=3 * np.mean(sigmas) / np.sqrt(30))
    np.testing.assert_allclose(np.std(values, ddof=1) / np.mean(sigmas), 1.0, atol=0.35)
    with pytest.raises(SeaiceError, match="pooled: 'c'"):
        variance_components(paired_problem(rng, 0.1, 0.2), pooled=[("a", "c")])
