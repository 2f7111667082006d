"""The adjustment engine: residual blocks over global unknowns and points, one damped Gauss-Newton / trust-region
loop with a dense or a Schur-complement backend, variance components, robust weights and the quality statistics
(σ̂0, global test, w-test, redundancy numbers, minimal detectable bias).

It knows no model and no file format: it imports only the package base (``seaice_jax.errors``, ``seaice_jax._shapes``,
``seaice_jax._small_linalg``), which ``tests/test_structure.py`` checks. The models (``adjust.orbit``,
``adjust.radar``, ``adjust.sequence``) declare their :class:`Problem` and call :func:`solve`, or the generic
:func:`least_squares` for a pytree model.
"""

from seaice_jax import _config  # noqa: F401  (float64 before any of this subpackage's code)
from seaice_jax.adjust.engine.gauss_newton import (
    Adjustment,
    EngineOptions,
    Flag,
    degrees_of_freedom,
    not_converged_error,
    rescaled,
    solve,
)
from seaice_jax.adjust.engine.lsq import Observations, Solver, checked_solve, least_squares, make_solver
from seaice_jax.adjust.engine.problem import Problem, ResidualBlock
from seaice_jax.adjust.engine.quality import DEFAULT_ALPHA, critical_value, global_test
from seaice_jax.adjust.engine.variance import ROBUST, robust_adjustment, variance_components

__all__ = ["DEFAULT_ALPHA", "ROBUST", "Adjustment", "EngineOptions", "Flag", "Observations", "Problem",
           "ResidualBlock", "Solver", "checked_solve", "critical_value", "degrees_of_freedom", "global_test",
           "least_squares", "make_solver", "not_converged_error", "rescaled", "robust_adjustment", "solve",
           "variance_components"]
