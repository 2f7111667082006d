import jax
import numpy as np
import pytest

from seaice_jax.errors import SeaiceError
from seaice_jax.sensors.slar import (
    ImageFrame,
    check_time_marks,
    imaging_time,
    nadir_calibration,
    slant_range,
)


def test_a1_worked_example():
    # marks at x = 0, 50, 100 mm at t = 10, 20, 31 s: x = 75 lies halfway between the 2nd and 3rd mark
    assert float(imaging_time(75.0, [0.0, 50.0, 100.0], [10.0, 20.0, 31.0])) == pytest.approx(25.5)
    assert float(imaging_time(0.0, [0.0, 50.0, 100.0], [10.0, 20.0, 31.0])) == pytest.approx(10.0)
    assert float(imaging_time(110.0, [0.0, 50.0, 100.0], [10.0, 20.0, 31.0])) == pytest.approx(33.2)  # extends
    grad = jax.grad(lambda x: imaging_time(x, [0.0, 50.0, 100.0], [10.0, 20.0, 31.0]))(30.0)
    assert float(grad) == pytest.approx(0.2)


def test_a2_worked_example():
    # sweep delay 12.5 mm, scale 250 m/mm: y = 47.5 mm -> (47.5 + 12.5) * 250 = 15 000 m
    assert float(slant_range(47.5, 12.5, 250.0)) == pytest.approx(15_000.0)


def test_time_marks_must_increase_and_the_mark_is_named():
    with pytest.raises(SeaiceError, match=r"strip 3 time marks: mark 2 time 19.0 does not increase"):
        check_time_marks([0.0, 50.0, 100.0], [10.0, 20.0, 19.0], "strip 3 time marks")
    with pytest.raises(SeaiceError, match=r"mark 1 position 0.0 does not increase"):
        check_time_marks([0.0, 0.0], [1.0, 2.0])


def test_image_frame_rotation_and_shift():
    angle = np.radians(3.0)
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    offset = np.array([12.0, -4.0])

    def comparator(x, y):
        return (rotation @ np.array([x, y])) + offset

    marks = np.array([comparator(x, -3.0) for x in (0.0, 40.0, 80.0, 120.0)])
    reference = np.array([comparator(x, 0.0) for x in (10.0, 90.0)])
    frame = ImageFrame.from_lines(marks, reference, comparator(50.0, 30.0))
    point = comparator(57.0, 21.0)
    x, y = frame.to_image(point[0], point[1])
    assert float(y) == pytest.approx(21.0, abs=1e-9)
    x0, _ = frame.to_image(*comparator(0.0, 5.0))
    assert float(x) - float(x0) == pytest.approx(57.0, abs=1e-9)


def test_nadir_calibration_recovers_planted_constants_within_sigma():
    rng = np.random.default_rng(5)
    c_true, f_true = 12.0, 251.0  # mm, m/mm
    c0, f0 = 11.0, 248.0  # nominal
    altitude = rng.uniform(6_000.0, 12_000.0, 40)  # the aircraft changed altitude: separable
    y = altitude / f_true - c_true + rng.normal(0, 0.02, 40)
    result = nadir_calibration(y, altitude, c0, f0)
    assert result.scale_estimated
    assert abs(result.sweep_delay - c_true) < 3 * result.sigma_sweep_delay
    assert abs(result.range_scale - f_true) < 3 * result.sigma_range_scale


def test_nadir_calibration_sigma_matches_monte_carlo():
    rng = np.random.default_rng(6)
    altitude = np.linspace(7_000.0, 11_000.0, 25)
    estimates, sigmas = [], []
    for _ in range(300):
        y = altitude / 250.0 - 10.0 + rng.normal(0, 0.05, altitude.size)
        result = nadir_calibration(y, altitude, 9.0, 249.0, sigma_range=0.05 * 250.0)
        estimates.append((result.sweep_delay, result.range_scale))
        sigmas.append((result.sigma_sweep_delay, result.sigma_range_scale))
    scatter = np.std(np.array(estimates), axis=0, ddof=1)
    # the linearisation (A3) holds to first order in Δf: within 10 %
    np.testing.assert_allclose(scatter / np.array(sigmas).mean(axis=0), 1.0, atol=0.10)


def test_constant_altitude_estimates_the_sweep_delay_alone_and_says_so():
    rng = np.random.default_rng(7)
    altitude = 10_000.0 + rng.normal(0, 0.5, 30)  # level flight
    y = altitude / 250.0 - 12.0 + rng.normal(0, 0.02, 30)
    result = nadir_calibration(y, altitude, 11.0, 250.0)
    assert not result.scale_estimated and np.isnan(result.sigma_range_scale)
    assert result.range_scale == 250.0
    assert "cannot be separated" in result.message and "sweep delay alone" in result.message
    assert abs(result.sweep_delay - 12.0) < 3 * result.sigma_sweep_delay
