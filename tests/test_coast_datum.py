"""The coastline control points' correlated errors in the fit's covariance (issue 29): :func:`correlated_fit` with
:func:`coast_point_covariance` against a direct generalized least-squares solution with the full covariance of the
points (dense, Cholesky-whitened), and the global test's degrees of freedom for heavy-tailed errors."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import chi2

from seaice_jax.adjust.orbit.fit import FREE_PARAMETERS, fit_scan_model, position_uncertainty
from seaice_jax.geometry.scan import Direction
from seaice_jax.imagery.coast_control import (
    CoastErrors,
    coast_point_covariance,
    correlated_fit,
    fit_with_snooping,
    window_overlap,
)
from seaice_jax.simulate.satellite import noaa_image, simulate_control_points

POINTS = 12
SIGMA = 1000.0  # m per coordinate
ERRORS = CoastErrors(overlap_correlation=0.6, datum_sigma=700.0, datum_gradient_sigma=2e-3, kurtosis=4.0)
"""Large against the fit's own position σ (~400 m), so that the shared terms must show."""
WINDOW = 150.0  # pixels: the random points' windows overlap now and then


def tiny_fit(direction: Direction, seed: int = 5):
    """12 control points (σ 1 km; those of the first 8 share one datum) of a NOAA-7-like image; a 500 m shift is
    added to the shared points' known positions."""
    model = noaa_image(direction)
    rng = np.random.default_rng(seed)
    control, _, _ = simulate_control_points(model, POINTS, rng, SIGMA)
    shared = np.arange(POINTS) < 8
    radius = float(model.orbit.radius)
    latitude = np.asarray(control.latitude) + np.where(shared, 500.0 / radius, 0.0)
    control = type(control)(control.pixel, control.scan, latitude, control.longitude, control.sigma, control.ids)
    return fit_scan_model(control, model.orbit, direction=direction, n_pixels=model.n_pixels,
                          n_scans=model.n_scans), shared


def direct_covariance(control, shared):
    """``(n, n)`` m² per axis written out element by element from the model's definition."""
    n = len(control)
    radius = 6_371_000.0
    lat, lon = np.asarray(control.latitude), np.asarray(control.longitude)
    centre_lat, centre_lon = lat[shared].mean(), lon[shared].mean()
    x = np.stack([radius * (lat - centre_lat), radius * np.cos(centre_lat) * (lon - centre_lon)], 1)
    block = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            if i == j:
                block[i, j] = SIGMA**2
            if shared[i] and shared[j]:
                overlap = (max(0.0, 1 - abs(control.pixel[i] - control.pixel[j]) / WINDOW)
                           * max(0.0, 1 - abs(control.scan[i] - control.scan[j]) / WINDOW))
                block[i, j] += (ERRORS.overlap_correlation * overlap * SIGMA**2 * (i != j)
                                + ERRORS.datum_sigma**2 + ERRORS.datum_gradient_sigma**2 * x[i] @ x[j])
    return block


def direct_gls(fit, block):
    """Gauss-Newton on the whitened residuals L⁻¹v (Σ = L Lᵀ, the dense 2n x 2n covariance: north block, east
    block) with the autodiff Jacobian of the forward model: ``(unknowns (5,), cofactor (5, 5), σ̂0)``."""
    control, start = fit.control, fit.model
    n = len(control)
    whiten = np.linalg.inv(np.linalg.cholesky(np.kron(np.eye(2), block)))
    radius = float(start.orbit.radius)
    known_lat, known_lon = np.asarray(control.latitude), np.asarray(control.longitude)

    def whitened(values):
        model = eqx.tree_at(lambda m: tuple(getattr(m, name) for name in FREE_PARAMETERS), start,
                            replace=tuple(values))
        lat, lon = model.forward(jnp.asarray(control.pixel), jnp.asarray(control.scan))
        north = radius * (lat - known_lat)
        east = radius * np.cos(known_lat) * (lon - known_lon)
        return jnp.asarray(whiten) @ jnp.concatenate([north, east])

    values = jnp.array([getattr(start, name) for name in FREE_PARAMETERS])
    for _ in range(4):
        jacobian = jax.jacfwd(whitened)(values)
        values = values - jnp.linalg.lstsq(jacobian, whitened(values))[0]
    jacobian = np.asarray(jax.jacfwd(whitened)(values))
    residual = np.asarray(whitened(values))
    return np.asarray(values), np.linalg.inv(jacobian.T @ jacobian), float(np.sqrt(residual @ residual / (2 * n - 5)))


@pytest.mark.parametrize("direction", ["south", "north"])
def test_correlated_fit_is_the_gls_solution_with_the_full_covariance(direction):
    fit, shared = tiny_fit(direction)
    control = fit.control
    covariance = coast_point_covariance(control.sigma, control.pixel, control.scan, control.latitude,
                                        control.longitude, WINDOW, ERRORS, shared)
    block = direct_covariance(control, shared)
    np.testing.assert_allclose(covariance, block, rtol=1e-9, atol=1e-6)
    assert np.sum(window_overlap(control.pixel, control.scan, WINDOW)[np.outer(shared, shared)] > 0) > 8 + 2
    result = correlated_fit(fit, covariance)
    values, cofactor, sigma0 = direct_gls(fit, block)
    assert result.adjustment is not None and fit.adjustment is not None
    got = np.array([float(getattr(result.model, name)) for name in FREE_PARAMETERS])
    scale = np.sqrt(np.diag(cofactor))
    np.testing.assert_allclose((got - values) / scale, 0.0, atol=1e-6)  # the estimates, in their σ
    np.testing.assert_allclose((np.asarray(result.adjustment.cofactor) - cofactor) / np.outer(scale, scale), 0.0,
                               atol=1e-6)
    assert float(result.adjustment.sigma0) == pytest.approx(sigma0, rel=1e-8)
    # the stated position σ include the shared terms: well above the independent points' at every check pixel
    pixel, scan = np.array([100.0, 256.0, 400.0]), np.array([80.0, 256.0, 450.0])
    before = np.hypot(*(np.asarray(s) for s in position_uncertainty(fit, pixel, scan, a_priori=True)))
    after = np.hypot(*(np.asarray(s) for s in position_uncertainty(result, pixel, scan, a_priori=True)))
    assert np.all(after > 1.1 * before)


def test_independent_points_give_the_engine_fit_back():
    fit, _ = tiny_fit("south")
    result = correlated_fit(fit, np.diag(np.asarray(fit.control.sigma, float) ** 2 * np.ones(POINTS)))
    assert result.adjustment is not None and fit.adjustment is not None
    np.testing.assert_allclose(np.asarray(result.adjustment.cofactor), np.asarray(fit.adjustment.cofactor),
                               rtol=1e-4)
    assert float(result.adjustment.sigma0) == pytest.approx(float(fit.adjustment.sigma0), rel=1e-6)
    for group in ("latitude", "longitude"):
        np.testing.assert_allclose(result.adjustment.standardized_residuals[group],
                                   fit.adjustment.standardized_residuals[group], atol=1e-4)
        np.testing.assert_allclose(result.adjustment.redundancy[group], fit.adjustment.redundancy[group], atol=1e-5)


def test_the_snooping_fit_uses_the_model_and_its_kurtosis_in_the_global_test():
    fit, shared = tiny_fit("south")
    snooped, removed = fit_with_snooping(fit.control, fit.model, window=WINDOW, errors=ERRORS, shared=shared)
    assert removed == ()
    control = fit.control
    expected = correlated_fit(fit, coast_point_covariance(control.sigma, control.pixel, control.scan,
                                                          control.latitude, control.longitude, WINDOW, ERRORS, shared))
    assert snooped.adjustment is not None and expected.adjustment is not None
    np.testing.assert_allclose(np.asarray(snooped.adjustment.cofactor), np.asarray(expected.adjustment.cofactor),
                               rtol=1e-6)
    # the global test: χ² with r' = 2r/(κ − 1) degrees of freedom
    dof = snooped.adjustment.degrees_of_freedom
    assert dof is not None
    effective = 2 * dof / (ERRORS.kurtosis - 1)
    statistic = float(snooped.adjustment.sigma0) ** 2 * effective
    lower = chi2.cdf(statistic, effective)
    tested = snooped.global_test()
    assert snooped.error_kurtosis == ERRORS.kurtosis and tested is not None
    assert tested[0] == pytest.approx(2 * min(lower, 1 - lower), rel=1e-9)
