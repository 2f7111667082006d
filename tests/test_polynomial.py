import numpy as np
import pytest

from seaice_jax.adjust.orbit.affine import (
    AFFINE_TERMS,
    affine_design,
    fit_affine,
    leave_one_out_errors,
    trust_region,
)
from seaice_jax.errors import RankDeficiencyError, SeaiceError


@pytest.mark.parametrize("n", range(3, 12))
def test_exact_interpolation_through_n_points(n, rng):
    x, y = rng.uniform(1, 512, (2, n))
    xt, yt = x + rng.normal(0, 3, n), y + rng.normal(0, 3, n)
    polynomial = fit_affine(x, y, xt, yt)
    assert polynomial.n_terms == n
    px, py = polynomial(x, y)
    np.testing.assert_allclose(px, xt, atol=1e-6)
    np.testing.assert_allclose(py, yt, atol=1e-6)


def test_table_3_1_terms():
    assert AFFINE_TERMS[:7] == ("1", "x", "y", "xy", "x^2", "y^2", "x^3")
    row = np.asarray(affine_design(2.0, 3.0, 7))
    np.testing.assert_allclose(row, [1, 2, 3, 6, 4, 9, 8])


def test_least_squares_for_more_points_recovers_a_polynomial_and_averages_noise(rng):
    x, y = rng.uniform(1, 512, (2, 40))

    def truth(x, y):
        return 5 + 1.01 * x - 0.02 * y + 1e-5 * x * y, -3 + 0.01 * x + 0.99 * y + 2e-5 * x**2

    xt, yt = truth(x, y)
    polynomial = fit_affine(x, y, xt, yt, n_terms=5)
    gx, gy = np.meshgrid(np.linspace(1, 512, 9), np.linspace(1, 512, 9))
    px, py = polynomial(gx, gy)
    ex, ey = truth(gx, gy)
    np.testing.assert_allclose(px, ex, atol=1e-8)
    np.testing.assert_allclose(py, ey, atol=1e-8)
    noisy = fit_affine(x, y, xt + rng.normal(0, 1.0, 40), yt + rng.normal(0, 1.0, 40), n_terms=3)
    nx, _ = noisy(x, y)
    assert np.std(np.asarray(nx) - xt) < 1.0  # fitted values are closer to the truth than the observations


def test_errors_are_named(rng):
    with pytest.raises(SeaiceError, match="at least 3 control points"):
        fit_affine([1, 2], [1, 2], [1, 2], [1, 2])
    with pytest.raises(SeaiceError, match="7 terms need at least 7"):
        fit_affine(*rng.uniform(0, 1, (4, 5)), n_terms=7)
    x = np.array([1.0, 2.0, 3.0, 4.0])
    with pytest.raises(RankDeficiencyError, match="inversion failed") as info:
        fit_affine(x, 2 * x + 1, x, x)  # collinear
    assert len(info.value.parameters) >= 1


def test_trust_region_and_leave_one_out_expose_extrapolation(rng):
    x, y = rng.uniform(200, 300, (2, 8))
    xt, yt = x + rng.normal(0, 2, 8), y + rng.normal(0, 2, 8)
    gx, gy = np.meshgrid(np.linspace(1, 512, 21), np.linspace(1, 512, 21))
    trusted, distance = trust_region(x, y, gx, gy)
    assert trusted.any() and not trusted.all()
    assert not trusted[0, 0] and distance[0, 0] > 200
    polynomial = fit_affine(x, y, xt, yt)  # exact, 8 terms: wild away from the points
    px, py = polynomial(gx, gy)
    shift = np.hypot(np.asarray(px) - gx, np.asarray(py) - gy)
    assert shift[~trusted].max() > 10 * shift[trusted].max()
    errors = leave_one_out_errors(x, y, xt, yt, n_terms=3)
    assert errors.shape == (8,) and np.all(errors > 0)


def test_affine_touch_up_after_an_orbit_fit_meets_the_control_points(rng):
    from seaice_jax.adjust.orbit.affine import affine_touch_up
    from seaice_jax.adjust.orbit.fit import fit_scan_model
    from seaice_jax.geometry.earth import great_circle_distance
    from seaice_jax.simulate.satellite import noaa_image, simulate_control_points

    truth = noaa_image("south")
    control, _, _ = simulate_control_points(truth, 7, rng, 1000.0)
    fit = fit_scan_model(control, truth.orbit, direction="south", n_pixels=truth.n_pixels, n_scans=truth.n_scans)
    assert fit.rms_km > 0.3  # the orbit fit alone leaves the noise at the points
    correction = affine_touch_up(fit)
    lat, lon = fit.model.forward(*correction(control.pixel, control.scan))
    distance = np.asarray(great_circle_distance(lat, lon, control.latitude, control.longitude))
    assert distance.max() < 1.0  # metres
