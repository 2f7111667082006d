"""The dense backend's Jacobi factorization (small problems, batches at vector speed) against LAPACK's, numpy's SVD
and NIST's certified values; the scan model's closed-form Jacobian against autodiff; a vmapped batch of image fits
against single fits and against the LAPACK path with the autodiff Jacobian."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from nist_strd import NAMES, log_relative_error, model_function, read

from seaice_jax.adjust.engine import EngineOptions, dense, solve
from seaice_jax.adjust.engine.lsq import make_solver
from seaice_jax.adjust.engine.problem import Problem, ResidualBlock
from seaice_jax.adjust.orbit.fit import (
    DECREASE_TOLERANCE,
    _observations,
    control_args,
    free_mask,
    initial_guess,
    orbit_solver,
)
from seaice_jax.geometry.earth import wrap_angle
from seaice_jax.simulate.satellite import noaa_image, perturb_known_positions, simulate_control_points
from tests.helpers import FIT_LANES, vmapped_fits


def _matrices(rng):
    """Well conditioned; columns scaled over 12 decades (κ ~ 1e12 before column scaling); a nearly dependent pair;
    an exactly dependent column; a zero column."""
    plain = rng.normal(size=(14, 5))
    scaled = rng.normal(size=(30, 6)) * np.logspace(-6, 6, 6)
    near = rng.normal(size=(20, 4))
    near[:, 3] = near[:, 1] + 1e-7 * rng.normal(size=20)
    dependent = rng.normal(size=(12, 5))
    dependent[:, 4] = dependent[:, 0] - 2.0 * dependent[:, 2]
    zero = rng.normal(size=(9, 3))
    zero[:, 1] = 0.0
    return {"plain": plain, "scaled": scaled, "near": near, "dependent": dependent, "zero": zero}


@pytest.mark.parametrize("kind", ["plain", "scaled", "near", "dependent", "zero"])
def test_jacobi_svd_is_an_svd_with_numpys_singular_values(rng, kind):
    matrix = _matrices(rng)[kind]
    left, singular, vt = (np.asarray(a) for a in jax.jit(dense.jacobi_svd)(jnp.asarray(matrix)))
    expected = np.linalg.svd(matrix, compute_uv=False)
    largest = expected[0]
    np.testing.assert_allclose(np.sort(singular)[::-1], expected, rtol=1e-12, atol=1e-14 * largest)
    np.testing.assert_allclose((left * singular) @ vt, matrix, rtol=0, atol=1e-14 * largest)
    np.testing.assert_allclose(vt @ vt.T, np.eye(vt.shape[0]), rtol=0, atol=1e-14)
    kept = singular > 1e-12 * largest
    np.testing.assert_allclose(left[:, kept].T @ left[:, kept], np.eye(kept.sum()), rtol=0, atol=1e-13)
    # started from another orthogonal V (an earlier iteration's), the same decomposition
    start = np.linalg.qr(rng.normal(size=vt.shape))[0]
    left2, singular2, vt2 = (np.asarray(a) for a in dense.jacobi_svd(jnp.asarray(matrix), jnp.asarray(start)))
    np.testing.assert_allclose(np.sort(singular2)[::-1], expected, rtol=1e-12, atol=1e-14 * largest)
    np.testing.assert_allclose((left2 * singular2) @ vt2, matrix, rtol=0, atol=1e-14 * largest)


def _factor_outputs(factors, residuals, damping):
    kept = np.asarray(factors.kept)
    return {"step": factors.step(residuals, damping), "gauss_newton": factors.step(residuals, 0.0),
            "decrease": factors.gauss_newton_decrease(residuals), "cofactor": factors.cofactor(),
            "hat": factors.hat_diagonal(), "undetermined": factors.undetermined(), "rank": kept.sum()}


@pytest.mark.parametrize("kind", ["plain", "scaled", "near", "dependent"])
def test_jacobi_factors_agree_with_lapacks(rng, kind):
    """Steps (damped and not), the Gauss-Newton decrease, cofactor, hat diagonal, rank and the undetermined
    unknowns: the same from both factorizations (what the statistics of an adjustment are made of)."""
    jacobian = jnp.asarray(_matrices(rng)[kind])
    residuals = jnp.asarray(rng.normal(size=jacobian.shape[0]))
    scale = dense.column_norms(jacobian) * jnp.asarray(rng.uniform(1.0, 1.5, jacobian.shape[1]))
    jacobi = _factor_outputs(dense.Factors(jacobian, scale, "jacobi"), residuals, 1e-2)
    lapack = _factor_outputs(dense.Factors(jacobian, scale, "lapack"), residuals, 1e-2)
    assert jacobi["rank"] == lapack["rank"] == (jacobian.shape[1] - (kind == "dependent"))
    for key in ("step", "gauss_newton", "decrease", "cofactor", "hat", "undetermined"):
        a, b = np.asarray(jacobi[key]), np.asarray(lapack[key])
        # the nearly dependent pair (κ ~ 1e7 after scaling) leaves ~κε of relative agreement
        np.testing.assert_allclose(a, b, rtol=1e-7 if kind == "near" else 1e-10, atol=1e-12 * np.abs(b).max(),
                                   err_msg=key)
    if kind == "dependent":
        np.testing.assert_array_equal(np.asarray(jacobi["undetermined"]) > 0.1, [True, False, True, False, True])


NIST_OPTIONS = EngineOptions("dense", max_steps=2000, strategy="trust-region", factorization="jacobi")


@pytest.mark.parametrize("name", ["MGH09", "Thurber", *(pytest.param(n, marks=pytest.mark.slow)
                                                          for n in ("BoxBOD", "Eckerle4"))])
def test_the_jacobi_factorization_reaches_nists_certified_values(name):
    """Hard problems of NIST's StRD suite (both certified starts, the trust region): the certified estimates to 6
    digits and standard deviations to 4 (the criteria of tests/test_nist.py, where the padded 9-unknown problems
    take LAPACK's factorization)."""
    assert name in NAMES
    problem = read(name)
    model = model_function(problem.expression, problem.parameters, problem.predictors)

    def residual(theta, _, row):
        return jnp.atleast_1d(model(theta, row["x"]) - row["y"])

    rows, unknowns = problem.y.size, len(problem.parameters)
    block = ResidualBlock(residual, {"x": jnp.asarray(problem.x), "y": jnp.asarray(problem.observed)},
                          jnp.ones((rows, 1)), jnp.broadcast_to(jnp.arange(unknowns), (rows, unknowns)))
    dof = rows - unknowns
    starts = jnp.asarray(problem.starts)  # (2, p): both certified starts
    result = jax.vmap(lambda s: solve(Problem({"y": block}, s), NIST_OPTIONS, problem.parameters, dof=dof))(starts)
    sigmas = np.sqrt(np.diagonal(np.asarray(result.covariance), axis1=1, axis2=2))
    for s in range(2):
        assert bool(result.converged[s]) and float(np.max(np.asarray(result.undetermined)[s])) <= 0.1
        assert log_relative_error(np.asarray(result.parameters["theta"])[s], problem.certified).min() >= 6.0
        assert log_relative_error(sigmas[s], problem.certified_sigma).min() >= 4.0


def _rotation_forward(model, pixel, scan):
    """The scan model's ground point written independently for autodiff: the sub-satellite and orbit-normal unit
    vectors as rotation matrices applied to the axes (about x by the inclination, about z by the node), g =
    cos β u − sin β n, latitude = arcsin g_z, longitude = atan2(g_y, g_x) − (T_s/T_e) η (source 001 eqs 3.3-8 to
    3.3-10)."""
    orbit = model.orbit
    beta = orbit.central_angle(model.scanner_angle(pixel))
    eta = model.orbital_angle(scan)
    c, s = jnp.cos(orbit.inclination), jnp.sin(orbit.inclination)
    tilt = jnp.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    in_plane = jnp.stack([jnp.cos(eta), jnp.sin(eta), jnp.zeros_like(eta)], axis=-1)
    along = in_plane @ tilt.T
    normal = tilt @ jnp.array([0.0, 0.0, 1.0])
    g = jnp.cos(beta)[..., None] * along - jnp.sin(beta)[..., None] * normal[None, :]
    longitude = model.ascending_node + jnp.arctan2(g[..., 1], g[..., 0]) - orbit.rotation_ratio * eta
    return jnp.arcsin(g[..., 2]), wrap_angle(longitude)


@pytest.mark.parametrize("direction", ["south", "north"])
@pytest.mark.parametrize("altitude", [0.0, 850e3])
def test_the_scan_models_closed_form_jacobian_is_autodiffs(rng, direction, altitude):
    """The scan model's JVP (closed-form partials of the great-circle geometry, ``geometry.scan``) against
    forward-mode autodiff of an independent formulation of the model (rotation matrices), for the five unknowns,
    the orbit's own parameters and the image positions; reverse mode against reverse mode; the positions
    themselves equal."""
    model = eqx.tree_at(lambda m: m.orbit.altitude, noaa_image(direction), jnp.asarray(altitude))
    pixel, scan = (jnp.asarray(rng.uniform(1.0, 512.0, 9)) for _ in range(2))

    def closed(m, p, s):
        return jnp.stack(m.forward_unchecked(p, s))

    def plain(m, p, s):
        return jnp.stack(_rotation_forward(m, p, s))

    np.testing.assert_allclose(closed(model, pixel, scan), plain(model, pixel, scan), rtol=0, atol=1e-13)
    ours = jax.tree_util.tree_leaves(jax.jit(jax.jacfwd(closed, argnums=(0, 1, 2)))(model, pixel, scan))
    autodiff = jax.tree_util.tree_leaves(jax.jit(jax.jacfwd(plain, argnums=(0, 1, 2)))(model, pixel, scan))
    assert len(ours) == len(autodiff) == 10 + 2  # five unknowns, five orbit parameters, pixel, scan
    for a, b in zip(ours, autodiff, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-13 * float(jnp.max(jnp.abs(b))))
    weights = jnp.asarray(rng.normal(size=(2, 9)))
    gradient = jax.jit(jax.grad(lambda m: jnp.sum(weights * closed(m, pixel, scan))))(model)
    expected = jax.jit(jax.grad(lambda m: jnp.sum(weights * plain(m, pixel, scan))))(model)
    for a, b in zip(jax.tree_util.tree_leaves(gradient), jax.tree_util.tree_leaves(expected), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-11, atol=1e-12 * float(jnp.max(jnp.abs(b))))


def _autodiff_predict(model, args):
    """The control points' positions with autodiff's Jacobian (the independent formulation above)."""
    pixel, scan, reference = args
    latitude, longitude = _rotation_forward(model, jnp.asarray(pixel, float), jnp.asarray(scan, float))
    return {"latitude": latitude, "longitude": reference + wrap_angle(longitude - reference)}


def test_a_vmapped_batch_of_fits_matches_single_fits_and_the_lapack_autodiff_path(rng):
    """Forty images (independent noisy control positions): the vmapped batch gives each image's single fit, and
    the statistics of the LAPACK factorization with the autodiff Jacobian (the path before Jacobi): estimates to
    1e-9 σ, cofactor, σ̂0, redundancy numbers and w-statistics to 1e-8 relative."""
    truth = noaa_image("south")
    control, latitude, longitude = simulate_control_points(truth, 7, rng, 1000.0)
    args = control_args(control)
    guess = initial_guess(control, truth.orbit, "south", truth.n_pixels, truth.n_scans)
    solver = orbit_solver(control, guess)
    lats, lons = (jnp.asarray(a) for a in perturb_known_positions(latitude, longitude, 1000.0, rng, FIT_LANES))
    batch = vmapped_fits(solver, args, lats, lons)
    assert bool(jnp.all(batch.converged))
    reference_solver = make_solver(_autodiff_predict, guess, _observations(control, truth.orbit.radius),
                                   free=free_mask(guess))
    lapack = EngineOptions("dense", 100, 1e-10, 1e-10, DECREASE_TOLERANCE, factorization="lapack")  # the fit's
    reference = jax.jit(jax.vmap(lambda a, b: solve(
        reference_solver.problem({"latitude": a, "longitude": b}, args), lapack, dof=solver.degrees_of_freedom)))(
        lats, lons)
    names = solver.parameter_names
    batched = np.stack([np.asarray(getattr(batch.parameters, n)) for n in names], 1)
    expected = np.asarray(reference.parameters["theta"])
    sigma = np.sqrt(np.diagonal(np.asarray(reference.covariance), axis1=1, axis2=2))
    assert np.max(np.abs(batched - expected) / sigma) < 1e-9
    np.testing.assert_allclose(batch.cofactor, reference.cofactor, rtol=1e-8)
    np.testing.assert_allclose(batch.sigma0, reference.sigma0, rtol=1e-8)
    flat_w = np.concatenate([np.asarray(batch.standardized_residuals[g]) for g in ("latitude", "longitude")], 1)
    flat_r = np.concatenate([np.asarray(batch.redundancy[g]) for g in ("latitude", "longitude")], 1)
    np.testing.assert_allclose(flat_w, np.asarray(reference.standardized_residuals["observations"])[:, 0],
                               rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(flat_r, np.asarray(reference.redundancy["observations"])[:, 0], rtol=1e-8)
    for k in (0, 19, 39):  # one image at a time: the batch's lane
        one = solver({"latitude": lats[k], "longitude": lons[k]}, args)
        single = np.array([float(getattr(one.parameters, n)) for n in names])
        assert np.max(np.abs(batched[k] - single) / sigma[k]) < 1e-10
        assert int(one.steps) == int(batch.steps[k])
