import jax
import jax.numpy as jnp
import numpy as np
import pytest

from seaice_jax import NavigationSpline, SeaiceError


def cubic(t):
    c = np.array([[1.0e6, 2.0e5, -3.0e6], [170.0, -20.0, 3.0], [0.01, 0.02, -0.03], [1e-5, -2e-5, 3e-6]])
    position = c[0] + c[1] * t[:, None] + c[2] * t[:, None] ** 2 + c[3] * t[:, None] ** 3
    velocity = c[1] + 2 * c[2] * t[:, None] + 3 * c[3] * t[:, None] ** 2
    return position, velocity


def test_hermite_reproduces_a_cubic_and_its_derivative():
    records = np.arange(0.0, 101.0, 10.0)
    navigation = NavigationSpline(records, *cubic(records))
    t = np.array([0.0, 3.3, 47.1, 99.9, 100.0])
    position, velocity = navigation(t)
    expected_position, expected_velocity = cubic(t)
    np.testing.assert_allclose(position, expected_position, atol=1e-8, rtol=0)
    np.testing.assert_allclose(velocity, expected_velocity, atol=1e-10, rtol=0)
    derivative = jax.jacfwd(lambda s: navigation(s)[0])(47.1)
    np.testing.assert_allclose(derivative, velocity[2], atol=1e-10)


def test_bad_records_are_named():
    with pytest.raises(SeaiceError, match=r"navigation record 2: time 10.0 s does not increase"):
        NavigationSpline([0.0, 10.0, 10.0], np.zeros((3, 3)), np.zeros((3, 3)))
    with pytest.raises(SeaiceError, match="at least two records"):
        NavigationSpline([0.0], np.zeros((1, 3)), np.zeros((1, 3)))
    with pytest.raises(SeaiceError, match=r"must be \(3, 3\)"):
        NavigationSpline([0.0, 1.0, 2.0], np.zeros((3, 2)), np.zeros((3, 3)))


def noisy_records(seed=0, position_sigma=30.0, velocity_sigma=0.03):
    """15 min of 10-s records of a cubic flight path, white noise on every coordinate."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 901.0, 10.0)
    position, velocity = cubic(t)
    return (t, position + rng.normal(0, position_sigma, position.shape),
            velocity + rng.normal(0, velocity_sigma, velocity.shape))


def test_fitted_trajectory_reproduces_a_cubic_and_its_velocity_is_the_derivative():
    from seaice_jax.sensors.navigation import fit_navigation

    t = np.arange(0.0, 901.0, 10.0)
    fit = fit_navigation(t, *cubic(t), knot_spacing=90.0)
    s = np.linspace(-5.0, 905.0, 397)
    position, velocity = fit.trajectory(s)
    expected_position, expected_velocity = cubic(s)
    np.testing.assert_allclose(position, expected_position, atol=1e-6, rtol=0)
    np.testing.assert_allclose(velocity, expected_velocity, atol=1e-8, rtol=0)
    _, noisy_position, noisy_velocity = noisy_records()
    trajectory = fit_navigation(t, noisy_position, noisy_velocity, 90.0).trajectory
    step = 1e-3
    s = s[1:-1]
    central = (np.asarray(trajectory(s + step)[0]) - np.asarray(trajectory(s - step)[0])) / (2 * step)
    np.testing.assert_allclose(trajectory(s)[1], central, atol=1e-5, rtol=0)


def test_fitted_velocity_keeps_the_velocity_records_precision():
    """30 m / 0.03 m/s of record noise: the fitted velocity between records errs less than one velocity record
    (the moving polynomial's positions and slopes through a Hermite cubic err by tenths of m/s), its predicted σ
    matches the empirical error, and the records' noise is recovered by the variance components."""
    from seaice_jax.sensors.navigation import fit_navigation, moving_average

    s = np.linspace(0.0, 900.0, 1801)
    _, true_velocity = cubic(s)
    errors, predicted = [], []
    for seed in range(4):
        t, position, velocity = noisy_records(seed)
        fit = fit_navigation(t, position, velocity, 90.0)
        errors.append(np.asarray(fit.trajectory(s)[1]) - true_velocity)
        predicted.append(fit.velocity_error)
        assert fit.position_sigma == pytest.approx(30.0, rel=0.15)
        assert fit.velocity_sigma == pytest.approx(0.03, rel=0.15)
    rms = np.sqrt(np.mean(np.concatenate(errors) ** 2))
    assert rms < 0.5 * 0.03
    assert rms == pytest.approx(np.sqrt(np.mean(np.square(predicted))), rel=0.3)
    hermite = NavigationSpline(t, *moving_average(t, position, 180.0, 2))
    assert np.sqrt(np.mean((np.asarray(hermite(s)[1]) - true_velocity) ** 2)) > 10 * rms
    given = fit_navigation(t, position, velocity, 90.0, position_sigma=30.0, velocity_sigma=0.03)
    assert (given.position_sigma, given.velocity_sigma) == (30.0, 0.03)


def test_fitted_trajectory_bad_input_is_named():
    from seaice_jax.sensors.navigation import fit_navigation

    with pytest.raises(SeaiceError, match="at least four records"):
        fit_navigation([0.0, 10.0, 20.0], np.zeros((3, 3)), np.zeros((3, 3)))
    with pytest.raises(SeaiceError, match="knot_spacing must be positive"):
        fit_navigation(np.arange(5.0), np.zeros((5, 3)), np.zeros((5, 3)), knot_spacing=0.0)
    with pytest.raises(SeaiceError, match=r"navigation record 3: time 1.0 s does not increase"):
        fit_navigation([0.0, 1.0, 2.0, 1.0], np.zeros((4, 3)), np.zeros((4, 3)))


def test_moving_average_reproduces_polynomials_and_removes_noise():
    from seaice_jax.sensors.navigation import moving_average

    t = np.arange(0.0, 1800.0, 10.0)
    quadratic = np.stack([3.0 + 0.5 * t + 1e-4 * t**2, -2.0 * t], 1)
    smooth, velocity = moving_average(t, quadratic, window=180.0, order=2)
    np.testing.assert_allclose(smooth, quadratic, atol=1e-6)
    np.testing.assert_allclose(velocity[:, 0], 0.5 + 2e-4 * t, atol=1e-8)
    noise = np.random.default_rng(1).normal(0, 50.0, t.size)
    filtered, _ = moving_average(t, quadratic[:, :1] + noise[:, None], 180.0, 2)
    assert np.std(filtered[:, 0] - quadratic[:, 0]) < 0.5 * np.std(noise)
    weighted, _ = moving_average(t, quadratic[:, :1] + noise[:, None], 180.0, 2, weighting="inverse_cube")
    # distance⁻³ weights concentrate on the nearest records: less smoothing than flat weights (source 002)
    assert np.std(weighted[:, 0] - quadratic[:, 0]) > np.std(filtered[:, 0] - quadratic[:, 0])
    with pytest.raises(SeaiceError, match="weighting must be"):
        moving_average(t, quadratic, weighting="gauss")


def test_error_models():
    from seaice_jax.sensors.navigation import (
        SCHULER_PERIOD,
        ConstantError,
        LinearError,
        SchulerError,
        SplineError,
    )

    t = np.array([0.0, 600.0, 3600.0])
    np.testing.assert_allclose(ConstantError(jnp.array([1.0, 2.0]))(t), [[1, 2]] * 3)
    linear = LinearError(jnp.array([0.0, 100.0]), jnp.array([0.25, -0.1]), 0.0)  # 0.9 km per hour north
    np.testing.assert_allclose(linear(3600.0), [900.0, -260.0])
    schuler = SchulerError(jnp.zeros(2), jnp.zeros(2), jnp.array([2000.0, 0.0]), jnp.array([0.0, 1000.0]))
    np.testing.assert_allclose(schuler(SCHULER_PERIOD / 4), [2000.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(schuler(SCHULER_PERIOD), schuler(0.0), atol=1e-9)
    # a cubic B-spline reproduces a cubic polynomial exactly with the right control values (partition of unity)
    spline = SplineError(jnp.ones((8, 2)) * 5.0, 0.0, 600.0)
    np.testing.assert_allclose(spline(np.linspace(0, 3000, 7)), 5.0, atol=1e-12)
    knots = np.arange(-1, 7) * 600.0  # control values of a linear function at the knots reproduce it
    line = SplineError(jnp.stack([knots * 0.1, -knots], 1), 0.0, 600.0)
    np.testing.assert_allclose(line(np.array([0.0, 750.0, 2999.0]))[:, 0], [0.0, 75.0, 299.9], atol=1e-9)
    derivative = jax.grad(lambda s: line(s)[0])(1234.0)
    assert float(derivative) == pytest.approx(0.1)
    assert SplineError.zeros(0.0, 3600.0, 600.0).coefficients.shape == (9, 2)
