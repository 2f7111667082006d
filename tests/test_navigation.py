import jax
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
