"""The library's public geometry functions check what they are given and say the real cause (not a downstream
symptom such as "range shorter than the sensor's height")."""

import jax
import numpy as np
import pytest

from seaice_jax.errors import GeometryError, SeaiceError
from seaice_jax.geometry.earth import MEAN_RADIUS
from seaice_jax.geometry.range_doppler import ground_point
from seaice_jax.geometry.scan import Orbit

POSITION = np.array([MEAN_RADIUS + 10_000.0, 0.0, 0.0])
VELOCITY = np.array([0.0, 150.0, 0.0])


def test_ground_point_names_a_nan_or_zero_velocity_and_a_nan_range():
    positions = np.stack([POSITION] * 3)
    velocities = np.stack([VELOCITY, [np.nan, 150.0, 0.0], VELOCITY])
    with pytest.raises(GeometryError, match=r"velocity not finite at index \[\(1,\)\]"):
        ground_point(positions, velocities, np.full(3, 20_000.0))
    velocities[1] = 0.0
    with pytest.raises(GeometryError, match=r"velocity zero \(the sensor must move.*at index \[\(1,\)\]"):
        ground_point(positions, velocities, np.full(3, 20_000.0))
    with pytest.raises(GeometryError, match=r"slant range not finite at index \[\(2,\)\]"):
        ground_point(positions, np.stack([VELOCITY] * 3), np.array([20_000.0, 20_000.0, np.inf]))


def test_ground_point_still_marks_nan_under_jit_and_solves_good_input():
    point = ground_point(POSITION, VELOCITY, 20_000.0)
    assert np.linalg.norm(np.asarray(point)) == pytest.approx(MEAN_RADIUS, abs=1e-6)
    assert np.linalg.norm(np.asarray(point) - POSITION) == pytest.approx(20_000.0, abs=1e-6)
    traced = jax.jit(lambda v: ground_point(POSITION, v, 20_000.0))(np.zeros(3))
    assert np.all(np.isnan(np.asarray(traced)))


def test_look_side_must_be_a_side():
    with pytest.raises(ValueError, match=r"look_side must be 'right', 'left' or \+1 \(right\) / -1 \(left\), got "
                                         r"\[0.0\]"):
        ground_point(POSITION, VELOCITY, 20_000.0, look_side=0)
    right = np.asarray(ground_point(POSITION, VELOCITY, 20_000.0, look_side=1))
    left = np.asarray(ground_point(POSITION, VELOCITY, 20_000.0, look_side=-1))
    # the two sides mirror each other across the plane of the position and velocity (normal: z)
    np.testing.assert_allclose(right[:2], left[:2], atol=1e-6)
    assert right[2] == pytest.approx(-left[2], abs=1e-6) and abs(right[2]) > 1000.0


@pytest.mark.parametrize(("arguments", "message"), [
    ({"period": 0.0}, r"Orbit: period \(s\) must be finite and > 0, got 0.0"),
    ({"period": -6000.0}, r"Orbit: period \(s\) must be finite and > 0, got -6000.0"),
    ({"earth_day": -86164.0}, r"Orbit: earth_day \(s\) must be > 0"),
    ({"altitude": -1.0}, r"Orbit: altitude \(m\) must be finite and >= 0"),
    ({"inclination": 0.0}, r"Orbit: inclination \(radians\) must be within \(0, π\)"),
])
def test_orbit_parameters_are_checked(arguments, message):
    good = {"inclination": np.radians(99.0), "period": 6000.0, "altitude": 850_000.0, "earth_day": 86164.0}
    Orbit(**good)
    with pytest.raises(SeaiceError, match=message):
        Orbit(**{**good, **arguments})


def test_maximum_latitude_beyond_the_pole_is_refused():
    assert float(Orbit.from_max_latitude(np.radians(81.0), 6000.0).max_latitude) == pytest.approx(np.radians(81.0))
    with pytest.raises(SeaiceError, match=r"maximum latitude must be within \(0°, 90°\], got 95.0"):
        Orbit.from_max_latitude(np.radians(95.0), 6000.0)
    assert Orbit(np.radians(99.0), 6000.0, earth_day=np.inf).rotation_ratio == 0.0


def test_least_squares_names_a_nan_observation_by_group_and_index():
    from seaice_jax.adjust.engine.lsq import Observations, least_squares

    def line(parameters, x):
        return {"y": parameters["slope"] * x}

    x = np.arange(5.0)
    good = least_squares(line, {"slope": 1.0}, {"y": Observations(2.0 * x, 0.1)}, args=x)
    assert float(good.parameters["slope"]) == pytest.approx(2.0, abs=1e-9)
    with pytest.raises(SeaiceError, match=r"observation group 'y'\[2\]: value nan is not finite"):
        least_squares(line, {"slope": 1.0}, {"y": Observations(np.where(x == 2, np.nan, 2.0 * x), 0.1)}, args=x)
