import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import least_squares as scipy_least_squares
from scipy.stats import binom

from seaice_jax.adjust.engine.lsq import Observations, least_squares, make_solver
from seaice_jax.adjust.engine.quality import critical_value, estimated_blunder, global_test, minimal_detectable_bias
from seaice_jax.errors import ComputationError, NotConvergedError, RankDeficiencyError

T = np.linspace(0.0, 2.0, 15)
SIGMA = np.linspace(0.05, 0.2, 15)


def line(p, _):
    return {"y": p["a"] + p["b"] * T}


def decay(p, _):
    return {"y": p["amplitude"] * jnp.exp(-p["rate"] * T) + p["offset"]}


DECAY_TRUTH = {"amplitude": 3.0, "rate": 1.3, "offset": 0.5}


def as_params(d):
    return {k: jnp.asarray(v, float) for k, v in d.items()}


def test_weighted_line_matches_closed_form(rng):
    y = 1.0 + 2.0 * T + rng.normal(0, SIGMA)
    result = least_squares(line, as_params({"a": 0.0, "b": 0.0}), {"y": Observations(y, SIGMA)})
    A = np.stack([np.ones_like(T), T], 1)
    W = np.diag(1 / SIGMA**2)
    Q = np.linalg.inv(A.T @ W @ A)
    x = Q @ A.T @ W @ y
    v = A @ x - y
    s0 = np.sqrt(v @ W @ v / (T.size - 2))
    assert float(result.parameters["a"]) == pytest.approx(x[0], abs=1e-10)
    assert float(result.parameters["b"]) == pytest.approx(x[1], abs=1e-10)
    np.testing.assert_allclose(result.cofactor, Q, rtol=1e-10)
    np.testing.assert_allclose(result.covariance, s0**2 * Q, rtol=1e-10)
    np.testing.assert_allclose(result.residuals["y"], v, atol=1e-10)
    redundancy = np.diag(np.eye(T.size) - A @ Q @ A.T @ W)
    np.testing.assert_allclose(result.redundancy["y"], redundancy, atol=1e-12)
    assert float(np.sum(result.redundancy["y"])) == pytest.approx(result.degrees_of_freedom)
    assert result.parameter_names == ("a", "b")


def test_nonlinear_fit_matches_scipy(rng):
    y = np.asarray(decay(as_params(DECAY_TRUTH), None)["y"]) + rng.normal(0, SIGMA)
    result = least_squares(decay, as_params({"amplitude": 1.0, "rate": 0.5, "offset": 0.0}),
                           {"y": Observations(y, SIGMA)})

    def whitened(x):
        return (x[0] * np.exp(-x[2] * T) + x[1] - y) / SIGMA  # names sort: amplitude, offset, rate

    reference = scipy_least_squares(whitened, [1.0, 0.0, 0.5], xtol=1e-15, ftol=1e-15, gtol=1e-15)
    ours = np.array([float(result.parameters[k]) for k in ("amplitude", "offset", "rate")])
    sigma = np.sqrt(np.diag(np.asarray(result.cofactor)))
    np.testing.assert_allclose(ours, reference.x, rtol=0, atol=1e-6 * sigma.min())
    np.testing.assert_allclose(result.cofactor, np.linalg.inv(reference.jac.T @ reference.jac), rtol=1e-6)
    assert bool(result.converged)


def test_fixed_parameters_and_priors_match_the_augmented_closed_form(rng):
    y = 1.0 + 2.0 * T + rng.normal(0, SIGMA)
    fixed = least_squares(line, as_params({"a": 1.5, "b": 0.0}), {"y": Observations(y, SIGMA)},
                          free={"a": False, "b": True})
    assert float(fixed.parameters["a"]) == 1.5 and fixed.parameter_names == ("b",)
    w = 1 / SIGMA**2
    assert float(fixed.parameters["b"]) == pytest.approx(np.sum(w * T * (y - 1.5)) / np.sum(w * T * T), rel=1e-10)

    prior = least_squares(line, as_params({"a": 0.8, "b": 0.0}), {"y": Observations(y, SIGMA)},
                          prior_sigma={"a": 0.01, "b": None})
    A = np.vstack([np.stack([np.ones_like(T), T], 1), [1.0, 0.0]])
    b = np.append(y, 0.8)
    W = np.diag(np.append(w, 1 / 0.01**2))
    x = np.linalg.solve(A.T @ W @ A, A.T @ W @ b)
    assert float(prior.parameters["a"]) == pytest.approx(x[0], abs=1e-10)
    assert float(prior.parameters["b"]) == pytest.approx(x[1], abs=1e-10)
    assert prior.degrees_of_freedom == T.size + 1 - 2
    assert prior.residuals["prior"].shape == (1,)


def test_rank_deficiency_names_the_parameters():
    y = 3.0 * T

    def sum_only(p, _):
        return {"y": (p["a"] + p["b"]) * T + 0.0 * p["c"]}

    with pytest.raises(RankDeficiencyError, match="cannot determine a, b, c") as info:
        least_squares(sum_only, as_params({"a": 1.0, "b": 1.0, "c": 0.0}), {"y": Observations(y, 0.1)})
    assert info.value.parameters == ("a", "b", "c")
    with pytest.raises(RankDeficiencyError, match="3 unknowns but only 2 observations .* determine b, c"):
        least_squares(lambda p, _: {"y": p["a"] * T[:2] + p["b"] + p["c"]}, as_params({"a": 0, "b": 0, "c": 0}),
                      {"y": Observations(y[:2], 0.1)})


def test_bad_sigma_is_named():
    with pytest.raises(ValueError, match="observation group 'y'.*> 0"):
        least_squares(line, as_params({"a": 0.0, "b": 0.0}), {"y": Observations(T, np.where(T > 1, 0.0, 1.0))})


@pytest.mark.parametrize("model, truth, noise_scale", [(line, {"a": 1.0, "b": 2.0}, 1.0), (decay, DECAY_TRUTH, 0.1)])
def test_monte_carlo_statistics_match_predictions(model, truth, noise_scale):
    """Predicted σ vs empirical scatter, χ² global test false alarms ≈ α, w-test false alarms ≈ α (vmapped).

    The nonlinear model is run at a noise level where its linearization holds (at SIGMA itself the decay's
    amplitude/offset scatter exceeds the linear prediction by ~11 %: a property of the model, not the engine).
    """
    n_runs = 600
    truth = as_params(truth)
    sigma = SIGMA * noise_scale
    clean = np.asarray(model(truth, None)["y"])
    solve = make_solver(model, truth, {"y": Observations(clean, sigma)})
    names, dof = solve.parameter_names, solve.degrees_of_freedom
    noise = np.random.default_rng(7).normal(0, sigma, (n_runs, T.size))
    results = jax.jit(jax.vmap(lambda y: solve({"y": y})))(clean + noise)
    assert bool(jnp.all(results.converged))
    estimates = np.stack([np.asarray(results.parameters[k]) for k in names], 1)
    predicted = np.sqrt(np.diag(np.asarray(results.cofactor[0])))
    empirical = estimates.std(axis=0, ddof=1)
    np.testing.assert_allclose(empirical / predicted, 1.0, atol=0.10)
    bias = estimates.mean(axis=0) - np.array([float(truth[k]) for k in names])
    assert np.all(np.abs(bias) < 4 * predicted / np.sqrt(n_runs)), (bias, predicted / np.sqrt(n_runs))
    alpha = 0.05
    _, _, accepted = global_test(results.sigma0**2, dof, alpha)
    rejections = int(np.sum(~np.asarray(accepted)))
    low, high = binom.ppf([0.001, 0.999], n_runs, alpha)
    assert low <= rejections <= high
    w = np.asarray(results.standardized_residuals["y"])
    false_alarms = int(np.sum(np.abs(w) > float(critical_value(alpha))))
    low, high = binom.ppf([0.001, 0.999], w.size, alpha)
    assert low <= false_alarms <= high


def test_the_global_test_for_heavy_tailed_errors_rejects_at_its_level():
    """Line fits with Laplace errors (kurtosis κ = 6): σ̂0² varies (κ − 1)/r about 1, so the χ² test with r
    degrees of freedom rejects far more than α; with ``kurtosis=6`` (r' = 2r/(κ − 1)) it rejects α of the fits
    (within the binomial 0.1-99.9 % range of 2000 fits), and normal errors with ``kurtosis=3`` are the plain test."""
    n_runs, alpha = 2000, 0.05
    times = np.linspace(0.0, 2.0, 60)
    design = np.stack([np.ones_like(times), times], 1)
    rng = np.random.default_rng(29)
    errors = rng.laplace(0.0, 1.0 / np.sqrt(2.0), (n_runs, times.size))  # unit variance
    residuals = errors - errors @ (design @ np.linalg.pinv(design)).T
    dof = times.size - 2
    sigma0_squared = np.sum(residuals**2, axis=1) / dof
    low, high = binom.ppf([0.001, 0.999], n_runs, alpha)
    plain = int(np.sum(~np.asarray(global_test(sigma0_squared, dof, alpha)[2])))
    heavy = int(np.sum(~np.asarray(global_test(sigma0_squared, dof, alpha, kurtosis=6.0)[2])))
    assert plain > 3 * high / 2 and low <= heavy <= high, (plain, heavy)
    same = global_test(sigma0_squared, dof, alpha, kurtosis=3.0)
    np.testing.assert_array_equal(np.asarray(same[1]), np.asarray(global_test(sigma0_squared, dof, alpha)[1]))


def test_planted_blunder_is_flagged_and_estimated(rng):
    truth = as_params(DECAY_TRUTH)
    y = np.asarray(decay(truth, None)["y"]) + rng.normal(0, SIGMA)
    y[6] += 10 * SIGMA[6]
    result = least_squares(decay, truth, {"y": Observations(y, SIGMA)})
    w = np.asarray(result.standardized_residuals["y"])
    assert int(np.argmax(np.abs(w))) == 6 and abs(w[6]) > float(critical_value())
    blunder = float(estimated_blunder(result.residuals["y"], result.redundancy["y"])[6])
    mdb = float(minimal_detectable_bias(SIGMA, result.redundancy["y"])[6])
    assert blunder == pytest.approx(10 * SIGMA[6], abs=3 * SIGMA[6] / np.sqrt(float(result.redundancy["y"][6])))
    assert mdb < 10 * SIGMA[6]


def test_no_redundancy_gives_no_invented_sigma0():
    result = least_squares(lambda p, _: {"y": p["a"] + p["b"] * T[:2]}, as_params({"a": 0.0, "b": 0.0}),
                           {"y": Observations(T[:2] * 2.0, 0.1)})
    assert result.degrees_of_freedom == 0 and np.isnan(float(result.sigma0))
    np.testing.assert_allclose(result.redundancy["y"], 0.0, atol=1e-12)


def test_an_unconverged_fit_raises_unless_asked_not_to(rng):
    """Stopped at its step limit short of the minimum, the fit raises a NotConvergedError (exit code 1 in the
    ``seaice`` command) naming the steps and σ̂0; ``throw=False`` returns it, marked unconverged."""
    y = np.asarray(decay(as_params(DECAY_TRUTH), None)["y"]) + rng.normal(0, SIGMA)
    start = as_params({"amplitude": 1.0, "rate": 0.5, "offset": 0.0})
    converged = least_squares(decay, start, {"y": Observations(y, SIGMA)})
    assert int(converged.steps) > 2
    with pytest.raises(NotConvergedError, match=r"did not converge in 2 steps \(σ̂0 = .*\): its last step moved "
                                                r"(amplitude|offset|rate) by .*throw=False") as info:
        least_squares(decay, start, {"y": Observations(y, SIGMA)}, max_steps=2)
    assert info.value.steps == 2 and isinstance(info.value, ComputationError)
    stopped = least_squares(decay, start, {"y": Observations(y, SIGMA)}, max_steps=2, throw=False)
    assert not bool(stopped.converged) and int(stopped.steps) == 2
    # stopped more than a standard deviation short of the minimum
    assert abs(float(stopped.parameters["rate"] - converged.parameters["rate"])) > float(
        converged.standard_deviations()["rate"])
