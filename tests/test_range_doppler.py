import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.optimize import least_squares

from seaice_jax import CircularTrajectory, GeometryError, NavigationSpline
from seaice_jax.geometry.earth import MEAN_RADIUS
from seaice_jax.geometry.range_doppler import (
    doppler_residual,
    ground_point,
    imaging_time_and_range,
    incidence_angle,
)
from tests.helpers import assert_jacobian_matches

R = MEAN_RADIUS
AIRCRAFT = dict(altitude=10_000.0, speed=170.0)
SATELLITE = dict(altitude=800_000.0, speed=7_450.0)


def sensor_state(altitude, speed, climb=0.0, latitude=72.0, longitude=-150.0, heading=80.0):
    """Sensor position and velocity; ``climb`` tilts the velocity out of the horizontal (m/s upward)."""
    track = CircularTrajectory.from_heading(np.radians(latitude), np.radians(longitude), np.radians(heading),
                                            altitude, speed)
    s, v = (np.asarray(a) for a in track(0.0))
    return s, v + climb * s / np.linalg.norm(s)


def slant_range_at_look_angle(s_len, radius, look_angle):
    """Slant range to the sphere of ``radius`` at off-nadir ``look_angle`` (law of cosines, near root)."""
    return s_len * np.cos(look_angle) - np.sqrt(radius**2 - (s_len * np.sin(look_angle)) ** 2)


def independent_solve(s, v, r, radius, side, wavelength_doppler=0.0):
    """Root of the three defining equations by scipy from a flat-Earth start on the look side."""
    up = s / np.linalg.norm(s)
    right = np.cross(v, s)
    right /= np.linalg.norm(right)
    height = np.linalg.norm(s) - radius
    start = radius * up + side * np.sqrt(max(r**2 - height**2, 1.0)) * right

    def equations(p):
        d = p - s
        return [
            np.linalg.norm(p) - radius,
            np.linalg.norm(d) - r,
            (d @ v - 0.5 * wavelength_doppler * np.linalg.norm(d)) / np.linalg.norm(v),
        ]

    return least_squares(equations, start, xtol=1e-15, ftol=1e-15, gtol=1e-15).x


CASES = list(itertools.product(
    [AIRCRAFT, SATELLITE],
    [1.0, 10.0, 30.0, 45.0, 60.0],
    [-100.0, 0.0, 5000.0],
    ["right", "left"],
))


@pytest.mark.parametrize("platform, look_deg, height, side", CASES,
                         ids=[f"{'aircraft' if p is AIRCRAFT else 'satellite'}-{a}deg-{h}m-{s}"
                              for p, a, h, s in CASES])
def test_point_satisfies_the_three_conditions_and_matches_a_numerical_solve(platform, look_deg, height, side):
    s, v = sensor_state(**platform, climb=0.5)  # tilts the Doppler plane by 0.17° (aircraft)
    radius = R + height
    r = slant_range_at_look_angle(np.linalg.norm(s), radius, np.radians(look_deg))
    p = np.asarray(ground_point(s, v, r, radius, side))
    assert abs(np.linalg.norm(p) - radius) < 1e-6
    assert abs(np.linalg.norm(p - s) - r) < 1e-6
    assert abs((p - s) @ v / np.linalg.norm(v)) < 1e-6
    sign = 1.0 if side == "right" else -1.0
    expected = independent_solve(s, v, r, radius, sign)
    assert np.linalg.norm(p - expected) < 1e-3


def test_non_zero_doppler_condition_and_numerical_solve():
    s, v = sensor_state(**SATELLITE)
    wavelength, doppler = 0.235, 1500.0  # L band, a squinted beam
    r = slant_range_at_look_angle(np.linalg.norm(s), R, np.radians(35.0))
    p = np.asarray(ground_point(s, v, r, R, "left", wavelength, doppler))
    d = p - s
    assert abs(d @ v - 0.5 * wavelength * doppler * r) / np.linalg.norm(v) < 1e-6
    assert np.linalg.norm(p - independent_solve(s, v, r, R, -1.0, wavelength * doppler)) < 1e-3
    zero = np.asarray(ground_point(s, v, r, R, "left"))
    assert np.linalg.norm(p - zero) > 100.0  # the squint really moves the point


def test_look_side_w_points_right_of_flight():
    # Flying north along the 0° meridian on the equator: right of flight is east (+y).
    s = np.array([R + 10_000.0, 0.0, 0.0])
    v = np.array([0.0, 0.0, 200.0])
    right = np.asarray(ground_point(s, v, 20_000.0, R, "right"))
    left = np.asarray(ground_point(s, v, 20_000.0, R, "left"))
    assert right[1] > 10_000.0 and left[1] < -10_000.0


def test_broadcasts_over_batch_shapes():
    s, v = sensor_state(**AIRCRAFT)
    ranges = np.linspace(11_000.0, 40_000.0, 12).reshape(3, 4)
    p = ground_point(s, v, ranges)
    assert p.shape == (3, 4, 3)
    one = ground_point(s, v, ranges[1, 2])
    np.testing.assert_allclose(p[1, 2], one, rtol=0, atol=1e-9)


def test_impossible_ranges_raise_naming_indices_and_are_nan_under_jit():
    s, v = sensor_state(**AIRCRAFT)
    horizon = np.sqrt(np.linalg.norm(s) ** 2 - R**2)
    ranges = np.array([20_000.0, 9_000.0, 30_000.0, horizon * 1.01])
    with pytest.raises(GeometryError, match=r"index \[\(1,\), \(3,\)\]") as info:
        ground_point(s, v, ranges)
    np.testing.assert_array_equal(info.value.indices[0], [1, 3])
    jitted = np.asarray(jax.jit(lambda r: ground_point(s, v, r))(ranges))
    assert np.isnan(jitted[[1, 3]]).all() and np.isfinite(jitted[[0, 2]]).all()


def test_unknown_look_side_is_named():
    s, v = sensor_state(**AIRCRAFT)
    with pytest.raises(ValueError, match="look_side"):
        ground_point(s, v, 20_000.0, R, "up")


@pytest.mark.parametrize("platform", [AIRCRAFT, SATELLITE])
def test_inverse_recovers_time_and_range(platform):
    track = CircularTrajectory.from_heading(np.radians(70.0), np.radians(-140.0), np.radians(250.0),
                                            platform["altitude"], platform["speed"])
    times = np.linspace(-50.0, 50.0, 7)
    s, v = track(times)
    look = np.radians(np.linspace(5.0, 55.0, 7))
    ranges = slant_range_at_look_angle(np.linalg.norm(np.asarray(s), axis=-1), R + 200.0, look)
    points = ground_point(s, v, ranges, R + 200.0, "right")
    time, slant = imaging_time_and_range(points, track, -60.0, 60.0)
    np.testing.assert_allclose(time, times, atol=1e-6, rtol=0)
    np.testing.assert_allclose(slant, ranges, atol=1e-3, rtol=0)


def test_inverse_with_a_navigation_spline_and_doppler():
    truth = CircularTrajectory.from_heading(np.radians(74.0), np.radians(-145.0), np.radians(10.0), 9_000.0, 160.0)
    record_times = np.arange(-600.0, 601.0, 10.0)
    positions, velocities = truth(record_times)
    navigation = NavigationSpline(record_times, positions, velocities)
    times = np.array([-433.3, -10.0, 0.0, 123.4, 577.7])
    s, v = navigation(times)
    ranges = np.array([12_000.0, 20_000.0, 25_000.0, 33_000.0, 15_000.0])
    points = ground_point(s, v, ranges, R, "left", 0.235, -40.0)
    time, slant = imaging_time_and_range(points, navigation, -600.0, 600.0, 0.235, -40.0, grid_points=121)
    np.testing.assert_allclose(time, times, atol=1e-6, rtol=0)
    np.testing.assert_allclose(slant, ranges, atol=1e-3, rtol=0)
    residual = jax.vmap(lambda t, p: doppler_residual(t, p, navigation, 0.235, -40.0))(time, points)
    speed = np.linalg.norm(np.asarray(v), axis=-1)
    assert np.max(np.abs(np.asarray(residual)) / speed) < 1e-6  # metres along the track


@given(st.floats(0.5, 60.0), st.floats(-100.0, 5000.0), st.floats(-80.0, 80.0), st.booleans(),
       st.floats(-30.0, 30.0))
def test_round_trip_property(look_deg, height, latitude, right, time):
    track = CircularTrajectory.from_heading(np.radians(latitude), 0.3, 1.1, 10_000.0, 180.0)
    s, v = track(time)
    r = slant_range_at_look_angle(float(jnp.linalg.norm(s)), R + height, np.radians(look_deg))
    p = ground_point(s, v, r, R + height, "right" if right else "left")
    t_back, r_back = imaging_time_and_range(p, track, -40.0, 40.0)
    assert abs(float(t_back) - time) < 1e-6
    assert abs(float(r_back) - r) < 1e-3


@pytest.mark.parametrize("platform, look_deg", [(AIRCRAFT, 20.0), (AIRCRAFT, 50.0), (SATELLITE, 23.0)])
def test_layover_matches_first_order_formula_of_source_004(platform, look_deg):
    """Source 004 eqs 5-8: an elevated point is displaced toward the sensor by D ≈ Δh · cot θ."""
    s, v = sensor_state(**platform)
    r = slant_range_at_look_angle(np.linalg.norm(s), R, np.radians(look_deg))
    on_ground = np.asarray(ground_point(s, v, r, R))  # where the radar image puts the echo
    theta = float(incidence_angle(on_ground, s))
    for dh in [1.0, 5.0, 10.0]:
        elevated = np.asarray(ground_point(s, v, r, R + dh))  # the true elevated point with the same echo
        footprint = elevated * R / np.linalg.norm(elevated)
        shift = on_ground - footprint
        expected = dh / np.tan(theta)
        assert np.linalg.norm(shift) == pytest.approx(expected, rel=0.01)
        # toward the sensor's track, across the flight direction
        nadir = s * R / np.linalg.norm(s)
        assert np.linalg.norm(on_ground - nadir) < np.linalg.norm(footprint - nadir)
        assert abs(shift @ v) / (np.linalg.norm(shift) * np.linalg.norm(v)) < 1e-3


def test_forward_jacobian_matches_finite_differences():
    s, v = sensor_state(**AIRCRAFT, climb=2.0)

    def f(x):
        return ground_point(x[0:3], x[3:6], x[6], x[7], "right", 0.235, x[8])

    x0 = np.concatenate([s, v, [25_000.0, R + 30.0, 20.0]])
    steps = np.array([1.0, 1.0, 1.0, 1e-2, 1e-2, 1e-2, 1.0, 1.0, 0.5])
    assert_jacobian_matches(f, x0, rtol=1e-6, steps=steps)


def test_inverse_jacobian_matches_finite_differences():
    track = CircularTrajectory.from_heading(np.radians(72.0), np.radians(-150.0), np.radians(80.0), 10_000.0, 170.0)
    s, v = track(3.0)
    p0 = np.asarray(ground_point(s, v, 22_000.0))

    def f(p):
        time, slant = imaging_time_and_range(p, track, -30.0, 30.0)
        return jnp.stack([time, slant])

    assert_jacobian_matches(f, p0, rtol=1e-6, steps=np.full(3, 0.5))


def test_jit_vmap_grad():
    s, v = sensor_state(**AIRCRAFT)
    ranges = jnp.linspace(12_000.0, 30_000.0, 5)
    eager = ground_point(s, v, ranges)
    jitted = jax.jit(ground_point, static_argnames="look_side")(s, v, ranges)
    mapped = jax.vmap(lambda r: ground_point(s, v, r))(ranges)
    np.testing.assert_allclose(jitted, eager, rtol=0, atol=1e-9)
    np.testing.assert_allclose(mapped, eager, rtol=0, atol=1e-9)
    # d|p - s|/dr = 1 exactly: a scalar function of the output, differentiated by grad
    slope = jax.grad(lambda r: jnp.linalg.norm(ground_point(s, v, r) - s))(20_000.0)
    assert float(slope) == pytest.approx(1.0, abs=1e-9)


def test_on_failure_nan_marks_impossible_points_without_raising():
    s, v = sensor_state(**AIRCRAFT)
    p = np.asarray(ground_point(s, v, np.array([20_000.0, 9_000.0]), on_failure="nan"))
    assert np.isfinite(p[0]).all() and np.isnan(p[1]).all()
    with pytest.raises(ValueError, match="on_failure"):
        ground_point(s, v, 20_000.0, on_failure="ignore")


def test_trajectories_share_the_abstract_interface():
    """Analytic and navigated trajectories are both :class:`Trajectory` s, and the interface itself is abstract."""
    from seaice_jax import Trajectory

    track = CircularTrajectory.from_heading(1.3, -2.6, 1.4, 10_000.0, 170.0)
    times = np.arange(0.0, 101.0, 10.0)
    position, velocity = (np.asarray(a) for a in track(times))
    spline = NavigationSpline(times, position, velocity)
    assert isinstance(track, Trajectory) and isinstance(spline, Trajectory)
    np.testing.assert_allclose(np.asarray(spline(55.0)[0]), np.asarray(track(55.0)[0]), atol=1.0)
    with pytest.raises(TypeError):
        Trajectory()
