"""Least squares on a parameter pytree: the engine's dense backend behind a model-and-groups interface.

The user writes a model ``model(parameters, args) -> {group: predicted values}`` in JAX; observations come in named
groups with standard deviations; each parameter leaf is free or fixed and may carry a prior (value, σ) that enters
as a pseudo-observation (group ``"prior"``). The problem becomes one residual block of all groups (and one of the
priors) for :mod:`seaice_jax.adjust.engine`: a trust region or damped Gauss-Newton, covariance from the SVD of the
column-scaled Jacobian, quality control of every observation.

Residual convention: v = computed − observed (as the 1985 DLAT/DLONG). The covariance of the estimates is
σ̂0² (JᵀWJ)⁻¹ (``covariance``) and (JᵀWJ)⁻¹ (``cofactor``, the covariance if the a priori σ are right).

Two ways in: :func:`least_squares` (eager, one problem from any start: the trust region by default, an error that
names the parameters of a rank deficiency and one for a fit that did not converge) and :func:`make_solver`, which
returns a pure function of the observed values for ``jit``/``vmap`` (Monte Carlo, batches of images, from a start
near the answer: the damped loop by default). Solvers are compiled once per structure (model, parameter shapes,
groups): a second solver of the same shape compiles nothing.
"""

import dataclasses
import functools
from collections.abc import Callable, Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, Float, PyTree

from seaice_jax._shapes import is_traced
from seaice_jax.adjust.engine import dense, gauss_newton
from seaice_jax.adjust.engine.dense import RANK_TOLERANCE
from seaice_jax.adjust.engine.gauss_newton import Adjustment, EngineOptions
from seaice_jax.adjust.engine.problem import Problem, ResidualBlock, linearize_all
from seaice_jax.errors import RankDeficiencyError, SeaiceError

__all__ = ["Adjustment", "Observations", "Solver", "checked_solve", "least_squares", "make_solver",
           "undetermined_parameters"]


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


def _leaf_names(tree) -> list[str]:
    """One name per scalar of the raveled pytree: the leaf's path, with ``[i]`` for array elements."""
    names = []
    for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]:
        base = jax.tree_util.keystr(path).lstrip(".").replace("['", "").replace("']", "") or "parameter"
        size = int(np.size(leaf))
        names += [base] if np.ndim(leaf) == 0 else [f"{base}[{i}]" for i in range(size)]
    return names


@functools.lru_cache(maxsize=256)
def _block_functions(model, free_structure, fixed_structure, groups):
    """The residual functions of a model's groups and of its priors, built once per structure (so the engine's
    compiled solve is reused: jit caches on these function objects)."""
    free_def, shapes = free_structure
    template = jax.tree_util.tree_unflatten(free_def, [jnp.zeros(s, d) for s, d in shapes])
    unravel = ravel_pytree(template)[1]

    def observed(theta, _, row):
        fixed = jax.tree_util.tree_unflatten(fixed_structure, row["fixed"])
        predicted = model(eqx.combine(unravel(theta), fixed), row["args"])
        return jnp.concatenate([jnp.reshape(predicted[g], -1) for g in groups]) - row["observed"]

    def prior(theta, _, row):
        return theta - row["value"]

    return observed, prior, unravel


@jax.jit
def _system(problem: Problem):
    """Whitened residuals ``(m,)`` and Jacobian ``(m, u)`` at the problem's start (compiled once per structure)."""
    return dense.assemble(problem, linearize_all(problem, problem.start, problem.points))


class Solver(eqx.Module):
    """A set-up adjustment (from :func:`make_solver`): call it with observed values to adjust.

    A pytree (its arrays are leaves, its structure static): the call is one compiled function per structure, so a
    second solver of the same structure (other values of the fixed parameters, of σ, of the degrees of freedom:
    rows of σ = ∞ are padding) compiles nothing.

    Attributes:
        parameter_names: names of the free scalar unknowns.
        start: ``(u,)`` the free unknowns' initial values.
    """

    parameter_names: tuple = eqx.field(static=True)
    start: Float[Array, " u"]
    _dof: Array
    _functions: tuple = eqx.field(static=True)
    _free: tuple = eqx.field(static=True)
    _fixed_part: PyTree
    _groups: tuple = eqx.field(static=True)
    _sigmas: dict
    _prior: tuple
    _options: EngineOptions = eqx.field(static=True)
    _splits: tuple = eqx.field(static=True)
    _partner_map: np.ndarray

    def __init__(self, functions, parts, groups, sigmas, prior, names, dof, start, options):
        free, self._fixed_part = parts
        self._functions = functions
        self._free = (jax.tree_util.tree_structure(free), tuple(jax.tree_util.tree_leaves(free)))
        self._groups, self._sigmas, self._prior = groups, sigmas, prior
        self.parameter_names, self._dof, self.start = names, jnp.asarray(dof), start
        self._options = options
        sizes = [int(np.size(sigmas[g])) for g in groups]
        self._splits = tuple(int(k) for k in np.cumsum(sizes)[:-1])
        # the engine counts observations in sorted block order ("observations", then "prior"); results are
        # keyed by group, sorted: map the engine's flat index of a w-partner to the groups' flat order
        keys = sorted([*groups, "prior"])
        sizes_by_key = dict(zip(groups, sizes, strict=True)) | {"prior": int(np.size(prior[0]))}
        offsets = dict(zip(keys, np.concatenate([[0], np.cumsum([sizes_by_key[k] for k in keys])])[:-1],
                           strict=True))
        engine_order = [(g, i) for g in groups for i in range(sizes_by_key[g])] + [
            ("prior", i) for i in range(sizes_by_key["prior"])]
        self._partner_map = np.array([offsets[g] + i for g, i in engine_order] + [-1], int)

    @property
    def degrees_of_freedom(self) -> int:
        """Observations (rows of finite σ) + priors − unknowns (host side: not of a solver traced under ``jit``)."""
        return int(self._dof)

    def problem(self, observed, args=None, start=None) -> Problem:
        """The engine's :class:`~seaice_jax.adjust.engine.problem.Problem` for these observed values."""
        observed = jnp.concatenate([jnp.reshape(jnp.asarray(observed[g], float), -1) for g in self._groups])
        sigma = jnp.concatenate([jnp.reshape(self._sigmas[g], -1) for g in self._groups])
        x = self.start if start is None else self.flatten(start)
        args = jax.tree_util.tree_map(lambda a: jnp.asarray(a)[None], args)
        observed_function, prior_function, _ = self._functions
        row = {"fixed": [jnp.asarray(leaf)[None] for leaf in jax.tree_util.tree_leaves(self._fixed_part)],
               "args": args, "observed": observed[None]}
        n = x.shape[0]
        blocks = {"observations": ResidualBlock(observed_function, row, sigma[None],
                                                jnp.broadcast_to(jnp.arange(n), (1, n)))}
        prior_index, prior_sigma, prior_value = self._prior
        if prior_index.size:
            blocks["prior"] = ResidualBlock(prior_function, {"value": prior_value}, prior_sigma[:, None],
                                            jnp.asarray(prior_index)[:, None])
        return Problem(blocks, x)

    def flatten(self, tree):
        """The free unknowns ``(u,)`` of a parameter pytree."""
        return ravel_pytree(eqx.partition(tree, jax.tree_util.tree_unflatten(*self._free))[0])[0]

    def __call__(self, observed, args=None, start=None) -> Adjustment:
        """Adjust to ``observed`` (``{group: values}``), from ``start`` (a parameter pytree) or the initial values."""
        result = _adjust(self, observed, args, start)
        return result if is_traced(self._dof) else dataclasses.replace(result,
                                                                         degrees_of_freedom=self.degrees_of_freedom)

    def _run(self, observed, args, start) -> Adjustment:
        result = gauss_newton.solve(self.problem(observed, args, start), self._options, self.parameter_names,
                              layout=None, dof=self._dof, throw=False)
        return self._by_group(result)

    def _by_group(self, result: Adjustment) -> Adjustment:
        def split(table, prior_fill):
            pieces = jnp.split(table["observations"][0], self._splits)
            out = {g: p.reshape(self._sigmas[g].shape) for g, p in zip(self._groups, pieces, strict=True)}
            out["prior"] = table["prior"][:, 0] if "prior" in table else jnp.zeros(0, jnp.asarray(prior_fill).dtype)
            return out

        partner = {k: jnp.asarray(self._partner_map)[v] for k, v in split(result.w_partner, 0).items()}
        parameters = eqx.combine(self._functions[2](result.parameters["theta"]), self._fixed_part)
        return eqx.tree_at(
            lambda r: (r.parameters, r.residuals, r.redundancy, r.standardized_residuals, r.minimal_detectable_bias,
                       r.estimated_errors, r.w_correlation, r.w_partner), result,
            (parameters, split(result.residuals, 0.0), split(result.redundancy, 0.0),
             split(result.standardized_residuals, 0.0), split(result.minimal_detectable_bias, 0.0),
             split(result.estimated_errors, 0.0), split(result.w_correlation, 0.0), partner),
            is_leaf=lambda x: x is None)

    def residuals(self, x, observed, args=None):
        """``(m,)`` whitened residuals (computed − observed)/σ, priors last, at the free-unknown vector ``x``."""
        return _system(self._at(x, observed, args))[0]

    def jacobian_at(self, x, observed, args=None):
        """``(m, u)`` Jacobian of the whitened residuals at the free-unknown vector ``x``."""
        return _system(self._at(x, observed, args))[1]

    def _at(self, x, observed, args):
        problem = self.problem(observed, args)
        return Problem(problem.blocks, jnp.asarray(x, float))

    def check_rank(self, x, observed, args=None, where="at the initial values"):
        """Raise :class:`RankDeficiencyError` naming the parameters the observations cannot determine at ``x``."""
        undetermined = undetermined_parameters(self.jacobian_at(x, observed, args), self.parameter_names)
        if undetermined:
            raise RankDeficiencyError(f"rank-deficient adjustment {where}: the observations cannot determine "
                                      f"{', '.join(undetermined)}", undetermined)


@jax.jit
def _adjust(solver: Solver, observed, args, start) -> Adjustment:
    """:meth:`Solver.__call__` compiled: setting up the problem, the engine's solve and the results by group in one
    function (eager, they would compile a dozen small functions of their own)."""
    return solver._run(observed, args, start)


def make_solver(
    model: Callable[[PyTree, object], Mapping[str, Array]],
    parameters: PyTree,
    observations: Mapping[str, Observations],
    *,
    free: PyTree | None = None,
    prior_sigma: PyTree | None = None,
    prior_value: PyTree | None = None,
    max_steps: int = 100,
    tolerance: float = 1e-10,
    decrease_tolerance: float | None = None,
    strategy: str = "damped",
    factorization: str = "lapack",
    args=None,
):
    """Set up an adjustment and return its :class:`Solver`.

    ``solver(observed: {group: values}, args=None, start=None) -> Adjustment`` is pure: jit it, vmap it over
    Monte Carlo realizations (the observation σ, priors and the structure are fixed here; the values vary).

    Args:
        model: ``model(parameters, args) -> {group: predicted values}``, one entry per observation group, each
            shaped like that group's values.
        parameters: initial values (any pytree of float arrays, e.g. an ``eqx.Module``).
        observations: ``{group: Observations}``; only their σ and shapes are used here. A row of σ = ∞ is no
            observation (padding: the same solver serves problems padded to one size, see :mod:`.orbit_fit`).
        free: pytree of bools like ``parameters`` (``True`` = estimated); default all free.
        prior_sigma: pytree like ``parameters`` of prior standard deviations (``inf`` or ``None`` leaves for
            none); priors are pseudo-observations of the free unknowns.
        prior_value: the prior values (default: ``parameters``).
        max_steps: iterations of the engine's loop. tolerance: relative and absolute, on the step.
        decrease_tolerance: or converged when the Gauss-Newton step is below this many a posteriori standard
            deviations (:class:`~seaice_jax.adjust.gauss_newton.EngineOptions`; default ``tolerance``).
        strategy: ``"damped"`` (the default here: from a start near the answer, as a vmapped batch of
            realizations has, plain Gauss-Newton steps until one fails, the fewest iterations) or
            ``"trust-region"`` (the default of :func:`least_squares`: far starts too;
            :class:`~seaice_jax.adjust.gauss_newton.EngineOptions`).
        factorization: the dense backend's (:class:`~seaice_jax.adjust.gauss_newton.EngineOptions`): ``"jacobi"`` for a
            solver to be vmapped over many problems of a few unknowns.
        args: model arguments for diagnosing a problem with fewer observations than unknowns (the
            :class:`RankDeficiencyError` then names the undetermined parameters).
    """
    if free is None:
        free = jax.tree_util.tree_map(lambda _: True, parameters)
    free_part, fixed_part = eqx.partition(parameters, free)
    x0, _ = ravel_pytree(free_part)
    names = tuple(_leaf_names(free_part))
    groups = tuple(sorted(observations))
    sigmas = {g: observations[g].sigma for g in groups}
    for g in groups:
        if not bool(np.all(np.asarray(sigmas[g]) > 0)):
            raise SeaiceError(f"observation group {g!r}: every standard deviation must be > 0")
    if prior_sigma is None:
        prior_index, prior_sigma_vector, prior_vector = np.zeros(0, int), jnp.zeros(0), jnp.zeros(0)
    else:
        filled = jax.tree_util.tree_map(lambda s, p: jnp.full(jnp.shape(p), jnp.inf if s is None else s, float),
                                        prior_sigma, parameters, is_leaf=lambda s: s is None)
        sigma_vector, _ = ravel_pytree(eqx.partition(filled, free)[0])
        prior_index = np.nonzero(np.isfinite(np.asarray(sigma_vector)))[0]
        prior_sigma_vector = sigma_vector[prior_index]
        reference = parameters if prior_value is None else prior_value
        prior_vector = ravel_pytree(eqx.partition(reference, free)[0])[0][prior_index]
    n_observations = sum(int(np.isfinite(np.asarray(sigmas[g])).sum()) for g in groups)  # σ = ∞: padding
    dof = n_observations + prior_index.size - x0.size
    free_leaves, free_def = jax.tree_util.tree_flatten(free_part)
    fixed_def = jax.tree_util.tree_structure(fixed_part)
    structure = (free_def, tuple((tuple(np.shape(a)), jnp.asarray(a).dtype) for a in free_leaves))
    functions = _block_functions(model, structure, fixed_def, groups)
    decrease = tolerance if decrease_tolerance is None else decrease_tolerance
    options = EngineOptions("dense", max_steps, tolerance, tolerance, decrease, strategy=strategy,
                            factorization=factorization)
    solver = Solver(functions, (free, fixed_part), groups, sigmas, (prior_index, prior_sigma_vector, prior_vector),
                    names, dof, x0, options)
    if dof < 0:
        observed = {g: observations[g].values for g in groups}
        undetermined = undetermined_parameters(solver.jacobian_at(x0, observed, args), names)
        raise RankDeficiencyError(
            f"{x0.size} unknowns but only {n_observations} observations and {prior_index.size} priors: "
            f"the observations cannot determine {', '.join(undetermined)}", undetermined)
    return solver


def undetermined_parameters(jacobian, names, relative_threshold=RANK_TOLERANCE) -> list[str]:
    """Names of the parameters in the null space of the column-scaled Jacobian; empty if full rank.

    Column scaling makes the test independent of units (radians next to pixels next to metres); a direction is
    undetermined when its singular value is below ``relative_threshold`` times the largest (float64: a
    well-posed problem with a column-scaled condition of 1e10 is kept).
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
        if value <= relative_threshold * singular_values[0]:
            involved |= set(np.nonzero(np.abs(vector) > 0.1)[0].tolist())
    return [names[k] for k in sorted(involved)]


LEAST_SQUARES_MAX_STEPS = 1000
""":func:`least_squares`' default step limit: NIST's StRD from both certified starts takes up to 653 trust-region
steps (Bennett5 from start 1; MGH17 from start 1 554; tests/test_nist.py)."""


def least_squares(model, parameters, observations, *, args=None, strategy: str = "trust-region",
                  max_steps: int = LEAST_SQUARES_MAX_STEPS, throw: bool = True, **options) -> Adjustment:
    """Adjust ``parameters`` to ``observations`` (see :func:`make_solver` for the arguments).

    The defaults are for one problem from any start: the trust region (``strategy="trust-region"``, MINPACK's
    scheme: every problem of NIST's StRD nonlinear-regression suite from both certified starts, where the damped
    loop runs away from or creeps along the far ones) for up to :data:`LEAST_SQUARES_MAX_STEPS` steps;
    ``strategy="damped"`` takes fewer steps from a start near the answer.

    Args:
        throw: raise :class:`~seaice_jax.errors.NotConvergedError` for a fit that did not converge (the
            default); ``False`` returns it, with ``converged`` False (as optimistix's ``throw=False``).

    Raises:
        RankDeficiencyError: naming the parameters the observations cannot determine at the solution (or with
            fewer observations than unknowns), never a silent pseudo-inverse.
        NotConvergedError: the fit stopped unconverged (``throw=True``), naming its steps, σ̂0 and the parameter
            its last step moved most.
        SeaiceError: naming the group and index of a non-finite observation.
    """
    for group, given in ({} if is_traced(observations) else observations).items():
        values = np.asarray(given.values).reshape(-1)
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise SeaiceError(f"observation group {group!r}[{int(bad[0])}]: value {values[bad[0]]} is not finite "
                              f"({bad.size} such)")
    solver = make_solver(model, parameters, observations, args=args, strategy=strategy, max_steps=max_steps,
                         **options)
    observed = {g: observations[g].values for g in observations}
    return checked_solve(solver, observed, args, throw=throw)


def checked_solve(solver: Solver, observed, args=None, start=None, throw: bool = True) -> Adjustment:
    """``solver(observed, args, start)`` with the rank checked at the solution, and its convergence unless
    ``throw=False`` (eager use).

    A singular Jacobian at the start is no reason to refuse (the damped steps leave it); the decision is taken
    where the answer is.

    Raises:
        RankDeficiencyError: naming the parameters the observations cannot determine at the solution.
        NotConvergedError: the solve stopped unconverged (``throw=True``).
    """
    result = solver(observed, args, start)
    undetermined = result.undetermined_parameters()
    if undetermined:
        raise RankDeficiencyError(f"rank-deficient adjustment at the solution: the observations cannot determine "
                                  f"{', '.join(undetermined)}", undetermined)
    if throw and not bool(result.converged):
        raise gauss_newton.not_converged_error(result, "the least-squares fit", "raise max_steps, start closer to the "
                                         "answer, or pass throw=False to get the unconverged fit")
    return result
