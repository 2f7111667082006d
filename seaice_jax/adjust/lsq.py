"""The one least-squares engine: weighted Gauss-Newton (Levenberg-Marquardt fallback) on a parameter pytree.

The user writes a model ``model(parameters, args) -> {group: predicted values}`` in JAX; observations come in named
groups with standard deviations; each parameter leaf is free or fixed and may carry a prior (value, σ) that enters
as a pseudo-observation. Jacobians are by autodiff; the nonlinear solve is optimistix's ``GaussNewton`` with
``LevenbergMarquardt`` as the fallback when Gauss-Newton does not converge.

Residual convention: v = computed − observed (as the 1985 DLAT/DLONG). The covariance of the estimates is
σ̂0² (JᵀWJ)⁻¹ (``covariance``) and (JᵀWJ)⁻¹ (``cofactor``, the covariance if the a priori σ are right).

Two ways in: :func:`least_squares` (eager, with rank-deficiency errors that name parameters) and
:func:`make_solver`, which returns a pure function of the observed values for ``jit``/``vmap`` (Monte Carlo,
batches of images).
"""

from collections.abc import Callable, Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, Bool, Float, PyTree

from seaice_jax.adjust.quality import w_test
from seaice_jax.errors import RankDeficiencyError, SeaiceError


class Observations(eqx.Module):
    """One group of observations: values and their a priori standard deviations (same units).

    Attributes:
        values: any shape.
        sigma: broadcastable to ``values``; every entry > 0.
    """

    values: Float[Array, "..."]
    sigma: Float[Array, "..."]

    def __init__(self, values, sigma):
        self.values = jnp.asarray(values, float)
        self.sigma = jnp.broadcast_to(jnp.asarray(sigma, float), self.values.shape)


class Adjustment(eqx.Module):
    """Result of an adjustment (arrays only, so it can come out of ``vmap``).

    Attributes:
        parameters: the estimated parameter pytree (fixed leaves unchanged).
        parameter_names: names of the free scalar unknowns, in the order of ``covariance``.
        covariance: ``(u, u)`` σ̂0² (JᵀWJ)⁻¹ of the free unknowns.
        cofactor: ``(u, u)`` (JᵀWJ)⁻¹: the covariance when the a priori σ are right.
        sigma0: a posteriori σ̂0 = √(vᵀPv / r) (NaN when r = 0: no redundancy, nothing to estimate it from).
        degrees_of_freedom: r = observations + priors − unknowns.
        residuals: ``{group: v}`` computed − observed, observation units (``"prior"`` for the priors).
        redundancy: ``{group: r_i}`` redundancy numbers (they sum to r).
        standardized_residuals: ``{group: w_i}`` Baarda's w-statistics.
        steps: nonlinear iterations taken.
        converged: whether the solver met its tolerance.
    """

    parameters: PyTree
    parameter_names: tuple[str, ...] = eqx.field(static=True)
    covariance: Float[Array, "u u"]
    cofactor: Float[Array, "u u"]
    sigma0: Float[Array, ""]
    degrees_of_freedom: int = eqx.field(static=True)
    residuals: dict
    redundancy: dict
    standardized_residuals: dict
    steps: Array
    converged: Bool[Array, ""]

    def standard_deviations(self, a_priori: bool = False) -> dict[str, Array]:
        """``{parameter name: σ}`` from ``covariance`` (or from ``cofactor`` with ``a_priori=True``)."""
        matrix = self.cofactor if a_priori else self.covariance
        sigma = jnp.sqrt(jnp.diagonal(matrix, axis1=-2, axis2=-1))
        return {name: sigma[..., k] for k, name in enumerate(self.parameter_names)}


def _leaf_names(tree) -> list[str]:
    """One name per scalar of the raveled pytree: the leaf's path, with ``[i]`` for array elements."""
    names = []
    for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]:
        base = jax.tree_util.keystr(path).lstrip(".").replace("['", "").replace("']", "") or "parameter"
        size = int(np.size(leaf))
        names += [base] if np.ndim(leaf) == 0 else [f"{base}[{i}]" for i in range(size)]
    return names


class Solver:
    """A set-up adjustment (from :func:`make_solver`): call it with observed values to adjust.

    Attributes:
        parameter_names: names of the free scalar unknowns.
        degrees_of_freedom: observations + priors − unknowns.
        start: ``(u,)`` the free unknowns' initial values.
    """

    def __init__(self, solve, whitened, flatten, parameter_names, degrees_of_freedom, start):
        # compiled once per solver: eager dispatch of the solve and its Jacobians costs seconds
        self._solve, self._whitened, self.flatten = jax.jit(solve), whitened, flatten
        self._jacobian = jax.jit(jax.jacfwd(whitened))
        self.parameter_names, self.degrees_of_freedom, self.start = parameter_names, degrees_of_freedom, start

    def __call__(self, observed, args=None, start=None) -> "Adjustment":
        """Adjust to ``observed`` (``{group: values}``), from ``start`` (a parameter pytree) or the initial values."""
        return self._solve(observed, args, start)

    def residuals(self, x, observed, args=None):
        """``(m,)`` whitened residuals (computed − observed)/σ, priors last, at the free-unknown vector ``x``."""
        return self._whitened(x, ({g: jnp.asarray(v, float) for g, v in observed.items()}, args))

    def jacobian_at(self, x, observed, args=None):
        """``(m, u)`` Jacobian of the whitened residuals at the free-unknown vector ``x``."""
        return self._jacobian(x, ({g: jnp.asarray(v, float) for g, v in observed.items()}, args))

    def check_rank(self, x, observed, args=None, where="at the initial values"):
        """Raise :class:`RankDeficiencyError` naming the parameters the observations cannot determine at ``x``."""
        undetermined = undetermined_parameters(self.jacobian_at(x, observed, args), self.parameter_names)
        if undetermined:
            raise RankDeficiencyError(f"rank-deficient adjustment {where}: the observations cannot determine "
                                      f"{', '.join(undetermined)}", undetermined)


def make_solver(
    model: Callable[[PyTree, object], Mapping[str, Array]],
    parameters: PyTree,
    observations: Mapping[str, Observations],
    *,
    free: PyTree | None = None,
    prior_sigma: PyTree | None = None,
    prior_value: PyTree | None = None,
    max_steps: int = 64,
    tolerance: float = 1e-10,
    args=None,
):
    """Set up an adjustment and return its :class:`Solver`.

    ``solver(observed: {group: values}, args=None, start=None) -> Adjustment`` is pure: jit it, vmap it over
    Monte Carlo realizations (the observation σ, priors and the structure are fixed here; the values vary).

    Args:
        model: ``model(parameters, args) -> {group: predicted values}``, one entry per observation group, each
            shaped like that group's values.
        parameters: initial values (any pytree of float arrays, e.g. an ``eqx.Module``).
        observations: ``{group: Observations}``; only their σ and shapes are used here.
        free: pytree of bools like ``parameters`` (``True`` = estimated); default all free.
        prior_sigma: pytree like ``parameters`` of prior standard deviations (``inf`` or ``None`` leaves for
            none); priors are pseudo-observations of the free unknowns.
        prior_value: the prior values (default: ``parameters``).
        max_steps, tolerance: of the nonlinear solver (relative and absolute, on the step).
        args: model arguments for diagnosing a problem with fewer observations than unknowns (the
            :class:`RankDeficiencyError` then names the undetermined parameters).
    """
    if free is None:
        free = jax.tree_util.tree_map(lambda _: True, parameters)
    free_part, fixed_part = eqx.partition(parameters, free)
    x0, unravel = ravel_pytree(free_part)
    names = tuple(_leaf_names(free_part))
    groups = sorted(observations)
    sigmas = {g: observations[g].sigma for g in groups}
    for g in groups:
        if not bool(jnp.all(sigmas[g] > 0)):
            raise SeaiceError(f"observation group {g!r}: every standard deviation must be > 0")
    if prior_sigma is None:
        prior_index = np.zeros(0, int)
        prior_sigma_vector = jnp.zeros(0)
        prior_vector = jnp.zeros(0)
    else:
        filled = jax.tree_util.tree_map(lambda s, p: jnp.full(jnp.shape(p), jnp.inf if s is None else s, float),
                                        prior_sigma, parameters, is_leaf=lambda s: s is None)
        sigma_vector, _ = ravel_pytree(eqx.partition(filled, free)[0])
        prior_index = np.nonzero(np.isfinite(np.asarray(sigma_vector)))[0]
        prior_sigma_vector = sigma_vector[prior_index]
        reference = parameters if prior_value is None else prior_value
        prior_vector = ravel_pytree(eqx.partition(reference, free)[0])[0][prior_index]
    n_observations = sum(int(np.size(sigmas[g])) for g in groups)
    dof = n_observations + prior_index.size - x0.size
    def whitened(x, data):
        observed, args = data
        predicted = model(eqx.combine(unravel(x), fixed_part), args)
        parts = [((predicted[g] - observed[g]) / sigmas[g]).reshape(-1) for g in groups]
        parts.append((x[prior_index] - prior_vector) / prior_sigma_vector)
        return jnp.concatenate(parts)

    def flatten(tree):
        return ravel_pytree(eqx.partition(tree, free)[0])[0]

    def solve(observed, args=None, start=None):
        observed = {g: jnp.asarray(observed[g], float) for g in groups}
        x_start = x0 if start is None else flatten(start)
        data = (observed, args)
        gauss_newton = optx.least_squares(whitened, optx.GaussNewton(tolerance, tolerance), x_start, data,
                                          max_steps=max_steps, throw=False)
        gn_ok = gauss_newton.result == optx.RESULTS.successful

        def fallback():
            # under vmap both branches run: lanes where Gauss-Newton converged restart from its solution (one
            # step), the others from the original start
            restart = jnp.where(gn_ok, gauss_newton.value, x_start)
            marquardt = optx.least_squares(whitened, optx.LevenbergMarquardt(tolerance, tolerance), restart, data,
                                           max_steps=4 * max_steps, throw=False)
            return (marquardt.value, marquardt.stats["num_steps"] + gauss_newton.stats["num_steps"],
                    marquardt.result == optx.RESULTS.successful)

        x, steps, converged = jax.lax.cond(
            gn_ok, lambda: (gauss_newton.value, gauss_newton.stats["num_steps"], gn_ok), fallback)
        jacobian = jax.jacfwd(whitened)(x, data)
        cofactor = jnp.linalg.inv(jacobian.T @ jacobian)
        v = whitened(x, data)
        redundancy = 1.0 - jnp.sum((jacobian @ cofactor) * jacobian, axis=1)
        sigma0_squared = jnp.sum(v**2) / dof if dof > 0 else jnp.nan
        w = w_test(v, redundancy)
        sizes = [int(np.size(sigmas[g])) for g in groups] + [prior_index.size]
        split = np.cumsum(sizes)[:-1]
        keys = groups + ["prior"]
        shapes = [sigmas[g].shape for g in groups] + [(prior_index.size,)]
        scales = [sigmas[g] for g in groups] + [prior_sigma_vector]

        def by_group(vector, scale=False):
            pieces = jnp.split(vector, split)
            return {k: (p.reshape(s) * sc if scale else p.reshape(s))
                    for k, p, s, sc in zip(keys, pieces, shapes, scales, strict=True)}

        return Adjustment(
            parameters=eqx.combine(unravel(x), fixed_part),
            parameter_names=names,
            covariance=sigma0_squared * cofactor,
            cofactor=cofactor,
            sigma0=jnp.sqrt(sigma0_squared),
            degrees_of_freedom=dof,
            residuals=by_group(v, scale=True),
            redundancy=by_group(redundancy),
            standardized_residuals=by_group(w),
            steps=steps,
            converged=converged,
        )

    solver = Solver(solve, whitened, flatten, names, dof, x0)
    if dof < 0:
        observed = {g: observations[g].values for g in groups}
        undetermined = undetermined_parameters(solver.jacobian_at(x0, observed, args), names)
        raise RankDeficiencyError(
            f"{x0.size} unknowns but only {n_observations} observations and {prior_index.size} priors: "
            f"the observations cannot determine {', '.join(undetermined)}", undetermined)
    return solver


def undetermined_parameters(jacobian, names, relative_threshold=1e-10) -> list[str]:
    """Names of the parameters in the null space of the (column-scaled) normal matrix; empty if full rank.

    Column scaling makes the test independent of units (radians next to pixels next to metres).
    """
    jacobian = np.asarray(jacobian)
    scale = np.linalg.norm(jacobian, axis=0)
    dead = scale == 0
    scaled = jacobian / np.where(dead, 1.0, scale)
    singular_values, vt = np.linalg.svd(scaled, full_matrices=True)[1:]
    # fewer observations than unknowns: the missing singular values are zero
    singular_values = np.concatenate([singular_values, np.zeros(vt.shape[0] - singular_values.size)])
    involved = set(np.nonzero(dead)[0].tolist())
    for value, vector in zip(singular_values, vt, strict=True):
        if value <= np.sqrt(relative_threshold) * singular_values[0]:
            involved |= set(np.nonzero(np.abs(vector) > 0.1)[0].tolist())
    return [names[k] for k in sorted(involved)]


def least_squares(model, parameters, observations, *, args=None, **options) -> Adjustment:
    """Adjust ``parameters`` to ``observations`` (see :func:`make_solver` for the arguments).

    Raises:
        RankDeficiencyError: naming the parameters the observations cannot determine (checked at the start and at
            the solution), never a silent pseudo-inverse.
    """
    solver = make_solver(model, parameters, observations, args=args, **options)
    observed = {g: observations[g].values for g in observations}
    return checked_solve(solver, observed, args)


def checked_solve(solver: Solver, observed, args=None, start=None) -> Adjustment:
    """``solver(observed, args, start)`` with the rank checked at the start and at the solution (eager use)."""
    solver.check_rank(solver.start if start is None else solver.flatten(start), observed, args)
    result = solver(observed, args, start)
    solver.check_rank(solver.flatten(result.parameters), observed, args, "at the solution")
    return result
