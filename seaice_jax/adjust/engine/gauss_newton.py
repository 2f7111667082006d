"""The adjustment engine: every least-squares problem of the project is solved here.

A :class:`~seaice_jax.adjust.engine.problem.Problem` (residual blocks over global unknowns and points) goes through
one nonlinear loop, a damped Gauss-Newton (Levenberg-Marquardt: λ = 0 while steps decrease the square sum,
raised tenfold on a failed step, lowered tenfold on a good one) in a single ``lax.while_loop``, so under ``vmap``
each lane stops when it has converged and no lane pays for another's damping. ``strategy="trust-region"`` (dense
backend) bounds the column-scaled step by a radius instead (:mod:`.trust_region`, MINPACK's scheme): slower from
some far starts a plain Gauss-Newton step would have handled, it solves the hard starts the damped loop runs away
from or creeps along (all of NIST's StRD suite from both starts). The linear algebra is a backend:
``"dense"`` (the SVD of the column-scaled Jacobian, by LAPACK's QR and SVD or, for a handful of unknowns, by Jacobi
rotations in elementwise operations that vectorize across a batch: :mod:`.dense`) or ``"schur"`` (points
eliminated, reduced system by Cholesky, :mod:`.schur`), chosen by the caller (``EngineOptions.backend``). Each iteration
linearizes once, at the trial point: its square sum decides the step, and an accepted step keeps its linearization
for the next iteration (and, at the end, for the statistics), so no residual function is evaluated twice at a point.

The result, :class:`Adjustment`, carries the estimates, their cofactor (JᵀPJ)⁻¹ and covariance σ̂0²(JᵀPJ)⁻¹,
σ̂0, the degrees of freedom, and for every observation of every group: the residual v = computed − observed,
the redundancy number, Baarda's w-statistic, the minimal detectable bias, the estimated error −v/r and the
largest correlation of its w with another observation's (≈ 1: the two cannot be told apart). The solve is
compiled once per structure (the block functions, the shapes and the options): a second problem of the same
shape compiles nothing.
"""

import dataclasses
import functools
from dataclasses import dataclass
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, PyTree

from seaice_jax._shapes import bucket, is_traced, pad
from seaice_jax.adjust.engine import dense, schur, trust_region
from seaice_jax.adjust.engine.problem import Problem, linearize_all, predicted_decrease, unlinearized
from seaice_jax.adjust.engine.quality import (
    DEFAULT_ALPHA,
    critical_value,
    estimated_blunder,
    minimal_detectable_bias,
    w_test,
)
from seaice_jax.errors import NotConvergedError, SeaiceError

BACKENDS = ("dense", "schur")
RESULTS = ("successful", "max_steps_reached", "nonfinite")
"""How a solve ended (``Adjustment.result`` indexes this): converged; stopped at ``max_steps``; a square sum that is
not finite (NaN or ∞ residuals at the start, or no finite trial left)."""
FACTORIZATIONS = dense.FACTORIZATIONS
STRATEGIES = ("damped", "trust-region")
MAX_DAMPING = 1e12
"""λ (relative to the column-scaled normal matrix, whose largest eigenvalue is ≥ 1) at which a point where no step
decreases the square sum is taken as the minimum (steps of 1e-12 of the gradient's)."""
INITIAL_DAMPING = 1e-3
"""λ after the first failed Gauss-Newton step (relative to the column-scaled normal matrix, diagonal 1)."""
ROUNDOFF = 1e-16
"""Relative decrease of the square sum below which a rejected step counts as the end (float64 roundoff)."""
EVALUATION_NOISE = 1e-9
"""Relative decrease of the square sum within which its evaluation's rounding can hide it: a residual computed as
computed − observed loses ε·|observed|/σ (a longitude of 1.5 rad with σ = 1e-4 rad: 1e-12 of the square sum). A
step whose Gauss-Newton decrease is below this is taken even if the evaluated square sum rises, by at most this
fraction (its noise), so that noise does not start the damping (which then creeps for many steps to a minimum
already reached)."""
RUNAWAY = 1e12
"""An unknown whose a priori σ exceeds this many times its value is undetermined (no digit of it is known)."""
INSEPARABLE = 0.98
"""|correlation| of two w-statistics above which a blunder in one cannot be told from a blunder in the other."""


@dataclass(frozen=True)
class EngineOptions:
    """How the engine iterates (hashable: part of the compile-cache key).

    Attributes:
        backend: ``"dense"`` or ``"schur"``.
        max_steps: iterations of the damped Gauss-Newton loop (failed, damped steps included).
        relative_tolerance, absolute_tolerance: converged when every |Δ| ≤ rtol·|x| + atol.
        decrease_tolerance: or when the step is smaller than this many a posteriori standard deviations
            (ΔᵀNΔ ≤ tol² σ̂0²).
        monotone: accept a step only if it lowers the square sum (Levenberg-Marquardt; or if the decrease it
            predicts is within the square sum's rounding, :data:`EVALUATION_NOISE`); ``False`` takes every
            Gauss-Newton step, for models whose weights follow the estimate (the radar block's image whitening),
            where the square sums before and after a step are not comparable.
        initial_damping: λ of the first step, relative to the column-scaled normal matrix (diagonal ≤ 1). 0 (the
            default) takes plain Gauss-Newton steps until one fails: from a reasonable start the fastest, and exact
            for a linear model in one step. Nielsen's τ = 1e-3 keeps a far start (NIST's MGH17 start 1) from leaping
            towards a limit at infinity; but damped steps shrink slowly along weakly determined directions, where
            the step-size test may then stop a few 1e-10 short of the minimum.
        strategy: ``"damped"`` (the default: Levenberg-Marquardt with Nielsen's λ update) or ``"trust-region"``
            (dense backend, monotone: the step bounded by a radius in the column-scaled unknowns, λ solved for
            it, the radius following the gain ratio: MINPACK's scheme, :mod:`.trust_region`). The trust region
            solves far starts the damped loop runs away from or creeps along (NIST's BoxBOD and MGH10 start 1).
        initial_radius: the trust region's first radius in units of ‖D x₀‖ (D: the column norms; where x₀ = 0
            the first step is Gauss-Newton's). 1 (scipy's ``trf``) keeps the first step within the start's own
            size; MINPACK's 100 lets the first Gauss-Newton step through almost always (and BoxBOD start 1 off).
        factorization: the dense backend's SVD (:data:`~seaice_jax.adjust.engine.dense.FACTORIZATIONS`): ``"lapack"``
            (the default: QR and SVD, the fastest for one problem) or ``"jacobi"`` (rotations in elementwise
            operations: a batch of small problems under ``vmap`` at vector speed; up to
            :data:`~seaice_jax.adjust.engine.dense.JACOBI_LIMIT` unknowns, LAPACK beyond).
    """

    backend: str = "dense"
    max_steps: int = 64
    relative_tolerance: float = 1e-10
    absolute_tolerance: float = 1e-10
    decrease_tolerance: float = 1e-10
    monotone: bool = True
    initial_damping: float = 0.0
    strategy: str = "damped"
    initial_radius: float = 1.0
    factorization: str = "lapack"

    def __post_init__(self):
        if self.backend not in BACKENDS:
            raise SeaiceError(f"EngineOptions.backend={self.backend!r}: choose one of {BACKENDS}")
        if self.strategy not in STRATEGIES:
            raise SeaiceError(f"EngineOptions.strategy={self.strategy!r}: choose one of {STRATEGIES}")
        if self.strategy == "trust-region" and (self.backend != "dense" or not self.monotone):
            raise SeaiceError("EngineOptions.strategy='trust-region' needs backend='dense' and monotone=True (the "
                              "radius follows the decrease of the square sum the step predicts)")
        if self.factorization not in FACTORIZATIONS:
            raise SeaiceError(f"EngineOptions.factorization={self.factorization!r}: choose one of {FACTORIZATIONS}")
        if not self.initial_radius > 0:
            raise SeaiceError(f"EngineOptions.initial_radius={self.initial_radius}: must be > 0")


@dataclass(frozen=True)
class Flag:
    """An observation failing the w-test.

    Attributes:
        group, row, component: where it is (block name, row, component of the row).
        w: Baarda's w-statistic. estimated_error: −v/r, observation units, the sign of the error (observed minus
            true). minimal_detectable_bias: observation units.
        separable: False when another observation's w is correlated with this one's beyond
            :data:`INSEPARABLE` (e.g. a point seen on two strips only: the data cannot say which one is wrong).
        confounded_with: that observation ``(group, row, component)``, or ``None``.
    """

    group: str
    row: int
    component: int
    w: float
    estimated_error: float
    minimal_detectable_bias: float
    separable: bool
    confounded_with: tuple | None


class Adjustment(eqx.Module):
    """Result of an adjustment (arrays only: it can come out of ``jit`` and ``vmap``).

    Attributes:
        parameters: the estimates (the engine: ``{"theta": (n,), "points": (P, d)}``; the wrappers give their own
            pytrees).
        parameter_names: names of the global unknowns, in the order of ``cofactor``.
        cofactor: ``(n, n)`` (JᵀPJ)⁻¹ of the global unknowns: their covariance when the a priori σ are right.
        covariance: ``(n, n)`` σ̂0² · cofactor.
        point_cofactor: ``(P, d, d)`` the points' cofactor blocks; point_pair_cofactor: ``(R, d, d)`` the
            requested cross blocks between two points.
        sigma0: σ̂0 = √(vᵀPv / r) (NaN when r = 0). degrees_of_freedom: r (``None`` from a solve under ``jit``
            whose r was traced; :class:`~seaice_jax.adjust.engine.lsq.Solver` sets it on the way out).
        residuals, redundancy, standardized_residuals, minimal_detectable_bias, estimated_errors: ``{group: …}``
            per observation (computed − observed residuals in observation units; redundancy numbers; w; MDB;
            −v/r).
        w_correlation, w_partner: ``{group: …}`` the largest |correlation| of each w with another observation's
            and that observation's flat index (−1: none).
        steps, converged: of the nonlinear loop. result: how it ended, an index into :data:`RESULTS` (traceable:
            under ``vmap`` one per lane); :attr:`result_name` names it.
        last_step: ``(n,)`` the last step the loop computed for the global unknowns (taken, or pending when the loop
            stopped): below the tolerances at convergence by the step test; of an unconverged solve, how far from
            converged it stopped (:func:`not_converged_error`).
        undetermined: ``(n,)`` each global unknown's largest |component| in a direction the observations cannot
            determine at the solution (dense backend: dropped singular values of the column-scaled Jacobian, or a σ
            above :data:`RUNAWAY` times the value; the Schur backend leaves zeros: its datum check comes
            first). :meth:`undetermined_parameters` names them.
        variance_components, robust_weights: ``{group: …}`` when estimated (:func:`variance_components`,
            :func:`robust_adjustment`), else ``None``.
    """

    parameters: PyTree
    parameter_names: tuple = eqx.field(static=True)
    cofactor: Float[Array, "n n"]
    covariance: Float[Array, "n n"]
    sigma0: Float[Array, ""]
    degrees_of_freedom: int | None = eqx.field(static=True)
    residuals: dict
    redundancy: dict
    standardized_residuals: dict
    steps: Array
    converged: Bool[Array, ""]
    result: Array
    point_cofactor: Array | None = None
    point_pair_cofactor: Array | None = None
    minimal_detectable_bias: dict | None = None
    estimated_errors: dict | None = None
    w_correlation: dict | None = None
    w_partner: dict | None = None
    undetermined: Array | None = None
    last_step: Array | None = None
    variance_components: dict | None = None
    robust_weights: dict | None = None

    @property
    def result_name(self) -> str:
        """The name in :data:`RESULTS` of how the solve ended (eager use, one solve)."""
        return RESULTS[int(self.result)]

    def standard_deviations(self, a_priori: bool = False) -> dict[str, Array]:
        """``{parameter name: σ}`` from ``covariance`` (or from ``cofactor`` with ``a_priori=True``)."""
        matrix = self.cofactor if a_priori else self.covariance
        sigma = jnp.sqrt(jnp.diagonal(matrix, axis1=-2, axis2=-1))
        return {name: sigma[..., k] for k, name in enumerate(self.parameter_names)}

    def undetermined_parameters(self) -> list[str]:
        """Names of the global unknowns the observations cannot determine at the solution (eager use)."""
        involvement = np.asarray(self.undetermined)
        return [name for name, value in zip(self.parameter_names, involvement, strict=True) if value > 0.1]

    def flagged(self, alpha: float = DEFAULT_ALPHA, groups=None) -> list[Flag]:
        """Observations whose |w| exceeds the critical value at ``alpha``, worst first (eager use)."""
        limit = float(critical_value(alpha))
        keys = list(self.standardized_residuals)
        sizes = [int(np.size(self.standardized_residuals[k])) for k in keys]
        offsets = np.concatenate([[0], np.cumsum(sizes)])

        def locate(flat):
            g = int(np.searchsorted(offsets, flat, side="right") - 1)
            shape = np.shape(self.standardized_residuals[keys[g]])
            row, component = np.unravel_index(flat - offsets[g], shape if len(shape) == 2 else (int(np.prod(shape)), 1))
            return keys[g], int(row), int(component)

        flags = []
        for key in keys if groups is None else groups:
            w = np.asarray(self.standardized_residuals[key])
            if w.size == 0:
                continue
            w2 = w.reshape(w.shape[0], -1) if w.ndim else w.reshape(1, 1)
            tables = [np.asarray(d[key]).reshape(w2.shape) if d is not None else np.full(w2.shape, np.nan)
                      for d in (self.estimated_errors, self.minimal_detectable_bias, self.w_correlation,
                                self.w_partner)]
            for row, component in zip(*np.nonzero(np.abs(w2) > limit), strict=True):
                correlation, partner = tables[2][row, component], tables[3][row, component]
                separable = not (np.isfinite(correlation) and correlation > INSEPARABLE)
                flags.append(Flag(key, int(row), int(component), float(w2[row, component]),
                                  float(tables[0][row, component]), float(tables[1][row, component]), separable,
                                  None if separable or partner < 0 else locate(int(partner))))
        return sorted(flags, key=lambda f: -abs(f.w))

    def worst(self, unit_of, alpha: float = DEFAULT_ALPHA, batch: float = 1.0, groups=None) -> list:
        """Baarda's data snooping, one round: the units (a point, a tie, a station: whatever ``unit_of(flag)``
        returns for a flagged observation; ``None`` for one that cannot be removed) whose worst |w| beyond the
        critical value of ``alpha`` is at least ``batch`` times the largest, worst first (``batch`` 1: the single
        worst unit, the strict method). Every snooping loop of the package removes what this returns and solves
        again (eager use)."""
        worst: dict = {}
        for flag in self.flagged(alpha, groups):
            unit = unit_of(flag)
            if unit is not None:
                worst[unit] = max(worst.get(unit, 0.0), abs(flag.w))
        if not worst:
            return []
        largest = max(worst.values())
        return [unit for unit, w in sorted(worst.items(), key=lambda item: -item[1]) if w >= batch * largest]


def degrees_of_freedom(problem: Problem) -> int:
    """Real observations − unknowns (points without any real observation are padding, not unknowns)."""
    observations = 0
    touched = np.zeros(problem.points.shape[0], bool)
    for block in problem.blocks.values():
        real = np.isfinite(np.asarray(block.sigma))
        observations += int(real.sum())
        if block.point_index is not None:
            touched[np.asarray(block.point_index)[real.any(axis=1)]] = True
    return observations - int(problem.start.shape[0]) - int(touched.sum()) * int(problem.points.shape[1])


def _square_sum(linear: dict):
    """Σ of the squared whitened residuals of a linearization (NaN if any is NaN)."""
    return sum(jnp.sum(lin.e**2) for lin in linear.values())


def _kept(accept, new, old):
    """``new`` where the step was accepted, else ``old`` (pytrees of arrays)."""
    return jax.tree_util.tree_map(lambda a, b: jnp.where(accept, a, b), new, old)


def _linear_step(problem: Problem, layout, options: EngineOptions, linear, points_shape, damping, scale, rotation):
    """The damped step from the linearization at the current point, the decrease it predicts, the decrease the
    undamped (Gauss-Newton) step predicts (the convergence test), Moré's scales and the dense backend's right
    singular vectors (the next Jacobi rotations start from them)."""
    if options.backend == "dense":
        residuals, jacobian = dense.assemble(problem, linear)
        scale = jnp.maximum(scale, dense.column_norms(jacobian))
        factors = dense.Factors(jacobian, scale, options.factorization, rotation, dense.STEP_ORTHOGONALITY)
        delta = factors.step(residuals, damping)
        n = problem.start.shape[0]
        step_theta, step_points = delta[:n], delta[n:].reshape(points_shape)
        gauss_newton = factors.gauss_newton_decrease(residuals)
        rotation = factors.vt.T
    else:
        step_theta, step_points = schur.step(problem, linear, layout, damping)
        gauss_newton = None
    gain = predicted_decrease(problem, linear, step_theta, step_points)
    return step_theta, step_points, gain, gain if gauss_newton is None else gauss_newton, scale, rotation


def _small(options: EngineOptions, step, value):
    """Every |step| ≤ rtol·|value| + atol."""
    return jnp.all(jnp.abs(step) <= options.relative_tolerance * jnp.abs(value) + options.absolute_tolerance)


def _flat(options: EngineOptions, cost, gauss_newton, dof):
    """The Gauss-Newton step is below the tolerance in a posteriori σ, or the decrease it predicts is at the
    roundoff of the square sum itself (a step that small cannot be taken): the minimum."""
    sigma0_squared = jnp.maximum(cost / jnp.maximum(dof, 1.0), 1e-300)
    return gauss_newton <= jnp.maximum(options.decrease_tolerance**2 * sigma0_squared, ROUNDOFF * cost)


class _Damped(NamedTuple):
    """The damped loop's state: the kept estimates and their linearization, the step pending from them (the next
    trial) with the decreases its linearized model and the undamped one predict, and the damping."""

    theta: Array
    points: Array
    linear: dict
    started: Array  # False until the start itself, the first trial (a pending step of 0), is linearized
    step_theta: Array
    step_points: Array
    gain: Array
    gauss_newton: Array
    small: Array  # the pending step is below the tolerances, or the Gauss-Newton decrease flat: the minimum
    damping: Array
    growth: Array
    scale: Array
    rotation: Array
    steps: Array
    ended: Array
    converged: Array


class _Region(NamedTuple):
    """The trust-region loop's state: the kept estimates (θ and the points, flat) and their linearization, the
    pending step with its scaled norm, damping and predicted decrease, and the radius."""

    x: Array
    linear: dict
    started: Array
    step: Array
    norm: Array
    damping: Array
    gain: Array
    small: Array
    radius: Array
    scale: Array
    rotation: Array
    steps: Array
    ended: Array
    converged: Array


def _loop(problem: Problem, options: EngineOptions, state, trial, proposal):
    """Iterate from ``state`` (nothing linearized yet: the start is the pending trial) until it ends or has taken
    ``max_steps`` steps, an iteration being one trial (a linearization) and one proposal (a factorization).

    The compiled loop evaluates the pending trial, then, unless that ended it, proposes the next step from the
    estimates kept: one linearization in it. Where the dense backend rotates by Jacobi (vmapped batches of small
    fits), the start's linearization, its factorization and the first trial run before the loop, and the loop
    proposes before it evaluates: under ``vmap``, lanes that share the start and the model (a Monte Carlo of the
    observations) share the start's Jacobian, so its factorization is computed once for all of them, and no lane
    factors again after its last trial."""
    jacobi = options.backend == "dense" and dense.uses_jacobi(options.factorization, problem.unknowns)
    if jacobi:
        # the start taken as it is, not through the trial's choice between kept and trial linearization: that
        # choice depends on each lane's residuals and would make the shared Jacobian a per-lane one
        linear = linearize_all(problem, problem.start, problem.points)
        state = trial(proposal(state._replace(linear=linear, started=jnp.ones((), bool),
                                              ended=~jnp.isfinite(_square_sum(linear)))))

    def body(state):
        if jacobi:
            return trial(proposal(state))
        state = trial(state)
        # no proposal after the trial that ends the loop: one factorization saved per solve (under vmap, where the
        # condition differs by lane, both branches run)
        return jax.lax.cond(state.ended, lambda ended: ended, proposal, state)

    return jax.lax.while_loop(lambda s: ~s.ended & ((s.steps < options.max_steps) | ~s.started), body, state)


def _kept_cost(state):
    """The square sum at the kept estimates (∞ before the start is linearized: any finite trial is kept)."""
    return jnp.where(state.started, _square_sum(state.linear), jnp.inf)


def _iterate(problem: Problem, layout, options: EngineOptions, dof):
    """Levenberg-Marquardt with Nielsen's damping update (λ = 0 until a step fails: plain Gauss-Newton): the
    estimates, their linearization, the dense backend's last right singular vectors, the global unknowns' last
    step, the steps and whether converged."""
    if options.strategy == "trust-region":
        return _iterate_trust_region(problem, options, dof)

    def trial(state: _Damped) -> _Damped:
        cost = _kept_cost(state)
        theta, points = state.theta + state.step_theta, state.points + state.step_points
        trial_linear = linearize_all(problem, theta, points)
        trial = _square_sum(trial_linear)
        # a last step whose predicted decrease is within the rounding of the square sum: taken if the square sum
        # rises by no more than that rounding either
        within_noise = (state.gauss_newton <= EVALUATION_NOISE * cost) & (trial <= (1.0 + EVALUATION_NOISE) * cost)
        accept = jnp.isfinite(trial) & ((trial < cost) | within_noise | (not options.monotone))
        ratio = (cost - trial) / jnp.maximum(state.gain, 1e-300)
        damping = jnp.where(accept, state.damping * jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * ratio - 1.0) ** 3),
                            jnp.where(state.damping == 0, INITIAL_DAMPING, state.damping * state.growth))
        damping = jnp.where(state.started, damping, state.damping)
        growth = jnp.where(state.started, jnp.where(accept, 2.0, 2.0 * state.growth), state.growth)
        # damped to nothing and still no decrease: no direction lowers the square sum beyond its roundoff
        converged = jnp.isfinite(cost) & (state.small | (damping > MAX_DAMPING))
        return state._replace(
            theta=jnp.where(accept, theta, state.theta), points=jnp.where(accept, points, state.points),
            linear=_kept(accept | ~state.started, trial_linear, state.linear), started=jnp.ones((), bool),
            damping=damping, growth=growth, steps=state.steps + state.started.astype(int),
            ended=converged | ~(accept | jnp.isfinite(cost)), converged=converged)  # an accepted trial is finite

    def proposal(state: _Damped) -> _Damped:
        cost = _square_sum(state.linear)
        step_theta, step_points, gain, gauss_newton, scale, rotation = _linear_step(
            problem, layout, options, state.linear, state.points.shape, state.damping, state.scale, state.rotation)
        small = ((_small(options, step_theta, state.theta) & _small(options, step_points, state.points))
                 | _flat(options, cost, gauss_newton, dof))
        return state._replace(step_theta=step_theta, step_points=step_points, gain=gain, gauss_newton=gauss_newton,
                              small=small, scale=scale, rotation=rotation)

    # Moré's scaling: the damping measures the step by the largest column norms seen so far
    no, zero = jnp.zeros((), bool), jnp.zeros(())
    start = _Damped(theta=problem.start, points=problem.points, linear=unlinearized(problem), started=no,
                    step_theta=jnp.zeros_like(problem.start), step_points=jnp.zeros_like(problem.points), gain=zero,
                    gauss_newton=zero, small=no, damping=jnp.full((), options.initial_damping),
                    growth=jnp.full((), 2.0), scale=jnp.zeros(problem.unknowns),
                    rotation=jnp.eye(problem.unknowns if options.backend == "dense" else 0),
                    steps=jnp.zeros((), int), ended=no, converged=no)
    end = _loop(problem, options, start, trial, proposal)
    return end.theta, end.points, end.linear, end.rotation, end.step_theta, end.steps, end.converged


def _iterate_trust_region(problem: Problem, options: EngineOptions, dof):
    """The dense backend's step bounded by a radius in the column-scaled unknowns (:mod:`.trust_region`):
    converged when the Gauss-Newton step is below the tolerances, or the region has shrunk to where no step can
    move an unknown beyond them."""
    n = problem.start.shape[0]

    def unpacked(x):
        return x[:n], x[n:].reshape(problem.points.shape)

    def trial(state: _Region) -> _Region:
        cost = _kept_cost(state)
        trial_linear = linearize_all(problem, *unpacked(state.x + state.step))
        trial = _square_sum(trial_linear)
        accept = jnp.isfinite(trial) & (trial < cost)
        ratio = jnp.where(jnp.isfinite(trial), (cost - trial) / jnp.maximum(state.gain, 1e-300), 0.0)
        radius = jnp.where(state.started, trust_region.updated_radius(state.radius, ratio, state.norm,
                                                                       state.damping), state.radius)
        collapsed = _small(options, radius / jnp.where(state.scale > 0, state.scale, 1.0), state.x)
        converged = jnp.isfinite(cost) & (state.small | collapsed)
        return state._replace(
            x=jnp.where(accept, state.x + state.step, state.x), started=jnp.ones((), bool), radius=radius,
            linear=_kept(accept | ~state.started, trial_linear, state.linear),
            steps=state.steps + state.started.astype(int), ended=converged | ~(accept | jnp.isfinite(cost)),
            converged=converged)

    def proposal(state: _Region) -> _Region:
        cost = _square_sum(state.linear)
        residuals, jacobian = dense.assemble(problem, state.linear)
        scale = jnp.maximum(state.scale, dense.column_norms(jacobian))  # Moré's scaling, as the damped loop's
        factors = dense.Factors(jacobian, scale, options.factorization, state.rotation, dense.STEP_ORTHOGONALITY)
        projected = factors.left.T @ residuals
        radius = jnp.where(state.steps == 0, trust_region.initial_radius(
            jnp.linalg.norm(factors.scale * state.x), options.initial_radius,
            trust_region.step_norm(factors.singular, projected, factors.kept, 0.0)), state.radius)
        damping = trust_region.damping_for_radius(factors.singular, projected, factors.kept, radius)
        step = factors.step(residuals, damping)
        small = (_small(options, factors.step(residuals, 0.0), state.x)
                 | _flat(options, cost, factors.gauss_newton_decrease(residuals), dof))
        return state._replace(
            step=step, norm=trust_region.step_norm(factors.singular, projected, factors.kept, damping),
            damping=damping, gain=predicted_decrease(problem, state.linear, *unpacked(step)), small=small,
            radius=radius, scale=scale, rotation=factors.vt.T)

    no, zero = jnp.zeros((), bool), jnp.zeros(())
    start = _Region(x=jnp.concatenate([problem.start, problem.points.reshape(-1)]), linear=unlinearized(problem),
                    started=no, step=jnp.zeros(problem.unknowns), norm=zero, damping=zero, gain=zero, small=no,
                    radius=jnp.ones(()), scale=jnp.zeros(problem.unknowns), rotation=jnp.eye(problem.unknowns),
                    steps=jnp.zeros((), int), ended=no, converged=no)
    end = _loop(problem, options, start, trial, proposal)
    return *unpacked(end.x), end.linear, end.rotation, unpacked(end.step)[0], end.steps, end.converged


def _statistics(problem: Problem, layout, options: EngineOptions, theta, points, linear, rotation, cross_points):
    """Cofactors, hat diagonals and w correlations at the solution, from its linearization ``linear`` (the dense
    backend's Jacobi rotations start from the last iteration's right singular vectors ``rotation``)."""
    n = theta.shape[0]
    count, d = points.shape
    if options.backend == "dense":
        _, jacobian = dense.assemble(problem, linear)
        factors = dense.Factors(jacobian, factorization=options.factorization, rotation=rotation)
        full = factors.cofactor()
        hat_flat = factors.hat_diagonal()
        redundancy_flat = 1.0 - hat_flat
        mask = jnp.concatenate([jnp.isfinite(b.sigma).reshape(-1) for b in problem.blocks.values()])
        correlation, partner = factors.residual_correlation(jnp.where(mask, redundancy_flat, 0.0))
        point_full = full[n:, n:].reshape(count, d, count, d)
        point_cofactor = point_full[jnp.arange(count), :, jnp.arange(count)]
        cross = point_full[cross_points[:, 0], :, cross_points[:, 1]]
        hats, correlations, partners, start = {}, {}, {}, 0
        for name, block in problem.blocks.items():
            size = block.sigma.size
            hats[name] = hat_flat[start:start + size].reshape(block.sigma.shape)
            correlations[name] = correlation[start:start + size].reshape(block.sigma.shape)
            partners[name] = partner[start:start + size].reshape(block.sigma.shape)
            start += size
        # also undetermined: an unknown run off from a non-zero start towards infinity, where it hardly changes the
        # residuals any more (the column-scaled rank cannot see it: scaling restores the column's size); a value
        # near zero with an ordinary σ (an intercept of 1e-17 ± 0.1) has not run off
        start = problem.start
        runaway = ((jnp.sqrt(jnp.diagonal(full)[:n]) > RUNAWAY * jnp.abs(theta)) & (start != 0)
                   & (jnp.abs(theta) > jnp.abs(start)))
        undetermined = jnp.where(runaway, 1.0, factors.undetermined()[:n])
        return full[:n, :n], point_cofactor, cross, hats, correlations, partners, undetermined
    q, couple = schur.cofactors(problem, linear, layout)
    hats = schur.hat_diagonals(problem, linear, layout, q)
    redundancy = {k: jnp.where(jnp.isfinite(problem.blocks[k].sigma), 1.0 - h, 0.0) for k, h in hats.items()}
    top, partner = schur.residual_correlation(couple, layout, q, schur.coupling_redundancy(problem, layout,
                                                                                           redundancy))
    correlations, partners, start = {}, {}, 0
    for name, block in problem.blocks.items():
        correlations[name] = jnp.zeros(block.sigma.shape)
        partners[name] = jnp.full(block.sigma.shape, -1)
        if name in layout.blocks:
            m, c = block.sigma.shape
            correlations[name] = top[start:start + m, :c]
            partners[name] = partner[start:start + m, :c]
            start += m
    return q.theta, q.point, q.cross, hats, correlations, partners, jnp.zeros(n)


@functools.partial(jax.jit, static_argnames=("options",))
def _solve(problem: Problem, layout, cross_points, options: EngineOptions, dof):
    """The compiled solve (the degrees of freedom are traced: problems differing only in them share it); the
    result's names and static degrees of freedom are set by :func:`solve`."""
    theta, points, linear, rotation, last_step, steps, converged = _iterate(problem, layout, options, dof)
    cofactor, point_cofactor, cross, hats, correlations, partners, undetermined = _statistics(
        problem, layout, options, theta, points, linear, rotation, cross_points)
    square = _square_sum(linear)
    sigma0_squared = jnp.where(dof > 0, square / jnp.maximum(dof, 1), jnp.nan)
    out = {k: {} for k in ("v", "r", "w", "mdb", "error")}
    for name, block in problem.blocks.items():
        real = jnp.isfinite(block.sigma)
        sigma = jnp.where(real, block.sigma, 1.0)
        redundancy = jnp.where(real, 1.0 - hats[name], 0.0)
        whitened = linear[name].e
        out["v"][name] = whitened * sigma
        out["r"][name] = redundancy
        out["w"][name] = w_test(whitened, redundancy)
        out["mdb"][name] = jnp.where(real, minimal_detectable_bias(sigma, redundancy), jnp.nan)
        out["error"][name] = jnp.where(real, estimated_blunder(whitened * sigma, redundancy), jnp.nan)
    return Adjustment(
        parameters={"theta": theta, "points": points}, parameter_names=(), cofactor=cofactor,
        covariance=sigma0_squared * cofactor, sigma0=jnp.sqrt(sigma0_squared), degrees_of_freedom=0,
        residuals=out["v"], redundancy=out["r"], standardized_residuals=out["w"], steps=steps, converged=converged,
        result=jnp.where(converged, 0, jnp.where(jnp.isfinite(square), 1, 2)),
        point_cofactor=point_cofactor, point_pair_cofactor=cross, minimal_detectable_bias=out["mdb"],
        estimated_errors=out["error"], w_correlation=correlations, w_partner=partners, undetermined=undetermined,
        last_step=last_step)


def solve(problem: Problem, options: EngineOptions | None = None, names=(), cross_points=None, layout=None,
          dof: int | Array | None = None, throw: bool = True) -> Adjustment:
    """Adjust ``problem`` (eager or under ``jit``/``vmap`` with ``layout`` and ``dof`` given).

    Args:
        options: :class:`EngineOptions` (default: dense backend).
        names: names of the global unknowns (for the result and messages).
        cross_points: ``(R, 2)`` point pairs whose cross-cofactor blocks are wanted (e.g. a feature's position on
            two dates, for its drift).
        layout: the Schur backend's tables (:func:`~seaice_jax.adjust.engine.schur.schur_layout`), built here if
            ``None`` (that needs concrete point indices: build it outside ``vmap``).
        dof: degrees of freedom (counted here if ``None``, which needs concrete σ); traced, it leaves the result's
            ``degrees_of_freedom`` ``None``.
        throw: raise :class:`~seaice_jax.errors.NotConvergedError` when the solve did not converge (eager use; under
            ``jit``/``vmap`` nothing can be raised: read ``result``); ``False`` returns the unconverged result, for
            callers that say themselves what did not converge.

    Raises:
        NotConvergedError: ``throw`` and the solve stopped unconverged (:func:`not_converged_error`).
    """
    options = options or EngineOptions()
    cross_points = np.zeros((0, 2), int) if cross_points is None else np.asarray(cross_points, int).reshape(-1, 2)
    if layout is None:
        layout = schur.schur_layout(problem, cross_points) if options.backend == "schur" else None
    dof = degrees_of_freedom(problem) if dof is None else dof
    # padded to a bucket, so problems differing only in the number of requested pairs share one compile
    requested = pad(cross_points, bucket(cross_points.shape[0]), -1)
    result = _solve(problem, layout, jnp.asarray(requested), options, jnp.asarray(dof, float))
    result = dataclasses.replace(result, parameter_names=tuple(names),
                                 degrees_of_freedom=None if is_traced(dof) else int(dof),
                                 point_pair_cofactor=result.point_pair_cofactor[:cross_points.shape[0]])
    if throw and not is_traced(result.converged) and not bool(result.converged):
        raise not_converged_error(result, f"the adjustment ({RESULTS[int(result.result)]})",
                                  "raise EngineOptions.max_steps, start closer, or pass throw=False to get the result")
    return result


def not_converged_error(result: Adjustment, what: str, advice: str = "") -> NotConvergedError:
    """The error for ``result``, an adjustment that stopped unconverged (eager use): its steps, σ̂0 and the global
    unknown its last step moved most in units of that unknown's a priori σ (from the cofactor: σ̂0 of a solve
    stopped far from the minimum is no measure of it; a converged solve's last step is a small fraction of a σ),
    then ``advice``."""
    steps = int(result.steps)
    step = np.asarray(result.last_step, float)
    sigma = np.sqrt(np.abs(np.diagonal(np.asarray(result.cofactor, float))))
    in_sigma = np.where(np.isfinite(sigma) & (sigma > 0), np.abs(step) / np.where(sigma > 0, sigma, 1.0), np.nan)
    message = f"{what} did not converge in {steps} steps (σ̂0 = {float(result.sigma0):.6g})"
    if np.isfinite(in_sigma).any():
        k = int(np.nanargmax(in_sigma))
        name = result.parameter_names[k] if k < len(result.parameter_names) else f"unknown {k}"
        message += f": its last step moved {name} by {step[k]:.3g} ({in_sigma[k]:.3g} a priori σ)"
    return NotConvergedError(message + (f"; {advice}" if advice else ""), steps)


def rescaled(problem: Problem, factors: dict, start: Adjustment | None = None) -> Problem:
    """``problem`` with each group's σ multiplied by ``factors[group]`` (scalar or per observation), started from
    ``start``'s estimates."""
    blocks = {k: eqx.tree_at(lambda b: b.sigma, b, b.sigma * factors.get(k, 1.0)) for k, b in problem.blocks.items()}
    if start is None:
        return Problem(blocks, problem.start, problem.points)
    return Problem(blocks, start.parameters["theta"], start.parameters["points"])
