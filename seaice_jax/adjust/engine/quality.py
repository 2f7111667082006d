"""Quality control of a least-squares adjustment (Baarda's B-method; Teunissen, *Testing Theory*, 2000).

All functions are pure and jit/vmap-able. Residuals follow the convention of the engine: v = computed − observed;
"whitened" means divided by the observation's a priori standard deviation σ.
"""

import jax.numpy as jnp
from jax.scipy.special import ndtri
from jax.scipy.stats import chi2

DEFAULT_ALPHA = 0.001
"""Significance level of the w-test (data snooping), as in Baarda's B-method."""
DEFAULT_POWER = 0.80
"""Power 1 − β of the w-test for a bias of minimal detectable size."""


def critical_value(alpha=DEFAULT_ALPHA):
    """Two-sided critical value of the standard normal w-test: z(1 − α/2) (3.29 for α = 0.001)."""
    return ndtri(1.0 - 0.5 * jnp.asarray(alpha, float))


def noncentrality(alpha=DEFAULT_ALPHA, power=DEFAULT_POWER):
    """λ0^½ = z(1 − α/2) + z(power): the bias, in units of the w-statistic's σ, detected with that power (4.13)."""
    return critical_value(alpha) + ndtri(jnp.asarray(power, float))


def global_test(sigma0_squared, degrees_of_freedom, alpha=0.05, kurtosis=3.0):
    """Chi-square test of the a posteriori variance factor: σ̂0² r ~ χ²_r when the model and σ are right.

    For errors of kurtosis κ ≠ 3 (E z⁴ / (E z²)² of the whitened errors) σ̂0² varies (κ − 1)/r about 1, not 2/r:
    the test then takes σ̂0² r' ~ χ²_r' with r' = 2r/(κ − 1) degrees of freedom (a scaled χ² of the right mean and
    variance, Satterthwaite's approximation).

    Args:
        sigma0_squared: σ̂0² = vᵀPv / r.
        degrees_of_freedom: r (> 0; with r = 0 there is nothing to test).
        alpha: two-sided significance level.
        kurtosis: κ (> 1; 3: normal errors, r' = r).

    Returns:
        ``(statistic, p_value, accepted)``: statistic = σ̂0² r'; two-sided p-value; accepted = p_value ≥ α.
    """
    dof = 2.0 * jnp.asarray(degrees_of_freedom, float) / (kurtosis - 1.0)
    statistic = sigma0_squared * dof
    lower = chi2.cdf(statistic, dof)
    p_value = 2.0 * jnp.minimum(lower, 1.0 - lower)
    return statistic, p_value, p_value >= alpha


def group_test(whitened, jacobian, cofactor, systematic=None, tolerance=1e-6):
    """Test of a group of observations without unknowns of their own (e.g. control points) against the rest of an
    adjustment, their σ taken as given (Teunissen, *Testing Theory*, 2000: the test of an arbitrary bias in the
    group): T = ṽᵀ C⁺ ṽ ~ χ²(q) when the model and every σ are right.

    C = R = I − J Q Jᵀ is the group's block of the redundancy matrix; with ``systematic`` S, the part of the
    unknowns' covariance due to errors of the other observations that their weights leave out (independent of the
    group's errors), C = R + J S Jᵀ. C may be singular: a direction of the unknowns that only the group determines
    leaves its residuals none along it, so T is taken on C's rank (eigenvalues above ``tolerance`` times the
    largest) and q is that rank.

    Args:
        whitened: ``(q0,)`` the group's whitened residuals ṽ. jacobian: ``(q0, n)`` their whitened Jacobian J.
        cofactor: ``(n, n)`` Q of the unknowns. systematic: ``(n, n)`` S or ``None``.

    Returns:
        ``(T, q, diag R (q0,))``: the statistic, its degrees of freedom (C's rank) and the redundancy numbers.
    """
    whitened, jacobian = jnp.asarray(whitened, float), jnp.asarray(jacobian, float)
    redundancy = jnp.eye(whitened.size) - jacobian @ jnp.asarray(cofactor, float) @ jacobian.T
    covariance = redundancy if systematic is None else redundancy + jacobian @ jnp.asarray(systematic) @ jacobian.T
    values, vectors = jnp.linalg.eigh(0.5 * (covariance + covariance.T))
    keep = values > tolerance * values.max()
    projected = vectors.T @ whitened
    statistic = jnp.sum(jnp.where(keep, projected**2 / jnp.where(keep, values, 1.0), 0.0))
    return statistic, jnp.sum(keep), jnp.diag(redundancy)


def w_test(whitened_residuals, redundancy):
    """Baarda's w-statistic per observation: v_i / (σ_i √r_i), standard normal without a blunder.

    Observations with no redundancy (r_i ≈ 0, uncontrolled) get w = 0: nothing can be tested there.
    """
    controlled = redundancy > 1e-12
    return jnp.where(controlled, whitened_residuals / jnp.sqrt(jnp.where(controlled, redundancy, 1.0)), 0.0)


def minimal_detectable_bias(sigma, redundancy, alpha=DEFAULT_ALPHA, power=DEFAULT_POWER):
    """Smallest blunder in observation i detected by the w-test with the given power: σ_i λ0^½ / √r_i.

    Infinite for uncontrolled observations (r_i ≈ 0).
    """
    controlled = redundancy > 1e-12
    return jnp.where(controlled, sigma * noncentrality(alpha, power) / jnp.sqrt(jnp.where(controlled, redundancy, 1.0)),
                     jnp.inf)


def estimated_blunder(residuals, redundancy):
    """Estimated gross error ∇̂_i = −v_i / r_i (observation units) if observation i alone were wrong."""
    controlled = redundancy > 1e-12
    return jnp.where(controlled, -residuals / jnp.where(controlled, redundancy, 1.0), jnp.nan)
