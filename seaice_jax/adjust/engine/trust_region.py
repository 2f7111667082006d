"""Trust-region control of the dense backend's step (Moré 1978; MINPACK ``lmder``, in the SVD form).

The step Δ minimises ‖e + JΔ‖² subject to ‖DΔ‖ ≤ r (D: Moré's column scales, the running maximum of the column
norms, so the region is a ball in units the parameters' own size drops out of). With J D⁻¹ = (QU) S Vᵀ and
g = (QU)ᵀe (the dense backend's factors), the step for damping λ is DΔ = −V S (S² + λ)⁻¹ g, of norm

    ‖DΔ(λ)‖² = Σᵢ sᵢ² gᵢ² / (sᵢ² + λ)²,

falling from the Gauss-Newton step's norm at λ = 0 to 0. λ = 0 when the Gauss-Newton step fits in the region,
else the root of the secular equation 1/‖DΔ(λ)‖ = 1/r, found by Newton's method (nearly linear in λ: Hebden's
form) with Moré's safeguarding bracket, a fixed number of iterations (vmappable). The radius follows the gain
ratio ρ = actual / predicted decrease of the square sum (:func:`updated_radius`); it starts at
``factor`` · ‖D x₀‖ (MINPACK; scipy's ``trf`` takes factor 1), or at the Gauss-Newton step when x₀ = 0.
"""

import jax
import jax.numpy as jnp

SECULAR_ITERATIONS = 12
"""Newton iterations on the secular equation (Moré's ±10 % of the radius is reached in 2-4 from the bracket)."""


def step_norm(singular, projected, kept, damping):
    """‖DΔ(λ)‖ of the damped step, from the singular values ``(N,)`` of J D⁻¹ and g = (QU)ᵀe ``(N,)`` over the
    kept (determined) directions."""
    numerator = jnp.where(kept, singular * projected, 0.0)
    return jnp.sqrt(jnp.sum((numerator / jnp.where(kept, singular**2 + damping, 1.0)) ** 2))


def damping_for_radius(singular, projected, kept, radius, iterations: int = SECULAR_ITERATIONS):
    """λ ≥ 0 of the step of norm ``radius`` (0 when the Gauss-Newton step is shorter).

    Args:
        singular: ``(N,)`` singular values of the column-scaled Jacobian J D⁻¹ (any order).
        projected: ``(N,)`` g = (QU)ᵀe, the whitened residuals in its left singular vectors.
        kept: ``(N,)`` the determined directions (dropped ones take no step).
        radius: r > 0, in the scaled unknowns DΔ.
    """
    s = jnp.where(kept, singular, 1.0)
    weighted = jnp.where(kept, singular * projected, 0.0)  # s g, the scaled gradient

    def norm_and_slope(damping):
        denominator = s**2 + damping
        norm = step_norm(singular, projected, kept, damping)
        slope = -jnp.sum(weighted**2 / denominator**3) / jnp.maximum(norm, 1e-300)
        return norm, slope

    newton_norm, newton_slope = norm_and_slope(0.0)
    # bracket: the Newton step on φ(λ) = ‖DΔ(λ)‖ − r from 0 (φ is convex: it stays below the root), and
    # ‖s g‖ / r (where ‖DΔ‖ ≤ ‖s g‖ / λ = r)
    lower = jnp.maximum(0.0, -(newton_norm - radius) / jnp.minimum(newton_slope, -1e-300))
    upper = jnp.sqrt(jnp.sum(weighted**2)) / radius

    def restart(lower, upper):
        return jnp.maximum(1e-3 * upper, jnp.sqrt(lower * upper))

    def iteration(_, state):
        damping, lower, upper = state
        damping = jnp.where((damping < lower) | (damping > upper), restart(lower, upper), damping)
        norm, slope = norm_and_slope(damping)
        phi = norm - radius
        upper = jnp.where(phi < 0, damping, upper)
        ratio = phi / jnp.minimum(slope, -1e-300)
        lower = jnp.maximum(lower, damping - ratio)
        return damping - (norm / radius) * ratio, lower, upper

    damping, lower, upper = jax.lax.fori_loop(0, iterations, iteration, (restart(lower, upper), lower, upper))
    damping = jnp.clip(damping, lower, upper)
    return jnp.where(newton_norm <= radius, 0.0, damping)


def initial_radius(scaled_start_norm, factor: float, newton_norm):
    """r₀ = factor · ‖D x₀‖; where x₀ = 0 (no size of the start to keep the first step within) the Gauss-Newton
    step's scaled norm ``newton_norm``: a linear problem started at 0 is then solved in one step."""
    return jnp.where(scaled_start_norm > 0, factor * scaled_start_norm, jnp.maximum(newton_norm, 1e-300))


def updated_radius(radius, ratio, norm, damping):
    """The next radius after a step of scaled norm ``norm`` with gain ratio ρ, taken with damping λ (λ > 0: on the
    boundary).

    Nielsen's λ update carried over to the radius (the step shrinks as 1/λ when damped): a step that lowered the
    square sum scales the radius by 1/max(1/3, 1 − (2ρ − 1)³), from ½ (ρ → 0) through 1 (ρ = ½) to 3 (ρ ≥ 1),
    smoothly, so a long curved valley (NIST's Bennett5, MGH17) is followed at the radius where the model holds
    rather than in a cycle of quartering and doubling; a step inside the region leaves it at least as large; a
    step that did not lower it quarters the region about that step.
    """
    factor = 1.0 / jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * jnp.clip(ratio, 0.0, 1.0) - 1.0) ** 3)
    return jnp.where(ratio <= 0, 0.25 * norm,
                     jnp.where(damping > 0, factor * norm, jnp.maximum(radius, factor * norm)))
