import numpy as np
import pytest

from seaice_jax.geometry.earth import MEAN_RADIUS, north_east, unit_vector
from seaice_jax.sensors.strips import strip_ground_points
from seaice_jax.simulate.aircraft import (
    ErrorModel,
    FlightPlan,
    aidjex_scenario,
    image_points,
    simulate_flight,
)

PLAN = FlightPlan(strips=2, strip_duration=600.0)


def features(count=120, seed=1):
    rng = np.random.default_rng(seed)
    lat = np.radians(rng.uniform(74.75, 75.05, count))
    lon = np.radians(rng.uniform(-150.1, -146.5, count))
    return np.asarray(unit_vector(lat, lon)) * MEAN_RADIUS


def errors_of(errors, plan=PLAN, seed=0, axes="north-east", **rectify_options):
    """Ground errors of rectified points along ``axes`` ("north-east", or "across-along" the true track), their
    imaging times and strips, the measurements, the strips and their truth (points without a solution dropped)."""
    rng = np.random.default_rng(seed)
    strips, truths = simulate_flight(plan, errors, rng)
    points = features()
    m = image_points(points, strips, truths, plan, errors, rng)
    rectified = strip_ground_points(strips, m, **rectify_options)
    assert np.isfinite(rectified).all(axis=1).mean() > 0.9  # a few near-nadir points may have no solution
    truth = points[m.point]
    times = np.array([np.interp(x, strips[j].mark_x, strips[j].mark_times) for x, j in zip(m.x, m.strip,
                                                                                             strict=True)])
    if axes == "north-east":
        first, second = (np.asarray(a) for a in north_east(truth))
    else:
        velocity = np.stack([np.asarray(truths[j].trajectory(t)[1]) for t, j in zip(times, m.strip, strict=True)])
        up = truth / np.linalg.norm(truth, axis=1, keepdims=True)
        second = velocity - np.sum(velocity * up, 1, keepdims=True) * up
        second /= np.linalg.norm(second, axis=1, keepdims=True)
        first = np.cross(second, up)
    difference = rectified - truth
    keep = np.isfinite(rectified).all(axis=1)
    error = np.stack([np.sum(difference * first, 1), np.sum(difference * second, 1)], 1)
    return error[keep], times[keep], m.strip[keep], m, strips, truths


def test_noise_free_with_perfect_navigation_is_exact_to_a_metre():
    error, _, _, m, _, _ = errors_of(ErrorModel.none(), filter_window=None)
    assert m.x.size > 50 and np.bincount(np.bincount(m.point))[2:].sum() >= 3  # overlaps exist
    assert np.max(np.abs(error)) < 1.0


@pytest.mark.parametrize("name", ["schuler_amplitude", "drift_rate"])
def test_navigation_errors_move_the_ground_points_by_the_ins_error(name):
    """Sources 000/002: the inertial position error maps one to one onto the ground; its rate (the velocity
    error) also tilts the zero-Doppler plane, moving points along track by about (v_err / v) x ground range."""
    errors = ErrorModel().only(name)
    error, times, strip_of, _, strips, truths = errors_of(errors, filter_window=None)
    expected = np.stack([[np.interp(t, strips[j].record_times, truths[j].navigation_error[:, c])
                          for c in range(2)] for t, j in zip(times, strip_of, strict=True)])
    rate = np.stack([[np.interp(t, strips[j].record_times,
                                np.gradient(truths[j].navigation_error[:, c], strips[j].record_times))
                      for c in range(2)] for t, j in zip(times, strip_of, strict=True)])
    scale = np.max(np.abs(expected))
    assert scale > 100.0
    # the strips fly east or west: north is across track, east along track
    np.testing.assert_allclose(error[:, 0], expected[:, 0], atol=0.01 * scale + 10.0)
    far_ground = PLAN.altitude * np.tan(np.radians(PLAN.far_angle))
    tilt = np.abs(rate[:, 0]) / PLAN.speed * far_ground
    assert np.all(np.abs(error[:, 1] - expected[:, 1]) <= tilt + 0.01 * scale + 10.0)


def test_schuler_signature_has_the_84_minute_period():
    """Rectified errors over 108 min of flight: a sinusoid fitted with free period finds the Schuler period."""
    plan = FlightPlan(strips=6, strip_duration=900.0)
    error, times, *_ = errors_of(ErrorModel().only("schuler_amplitude"), plan=plan, filter_window=None)
    periods = np.linspace(40.0, 150.0, 221) * 60.0
    misfit = []
    for period in periods:
        design = np.stack([np.ones_like(times), np.sin(2 * np.pi * times / period),
                           np.cos(2 * np.pi * times / period)], 1)
        misfit.append(np.linalg.lstsq(design, error[:, 0], rcond=None)[1][0])
    assert periods[int(np.argmin(misfit))] / 60.0 == pytest.approx(84.4, rel=0.03)


def test_sweep_delay_and_scale_errors_shift_points_across_track_only():
    for name in ("sweep_delay_error", "range_scale_error"):
        error, *_ = errors_of(ErrorModel().only(name), axes="across-along", filter_window=None)
        assert np.max(np.abs(error[:, 1])) < 0.01 * np.max(np.abs(error[:, 0]))
        assert np.max(np.abs(error[:, 0])) > 50.0


def test_time_mark_jitter_shifts_points_along_track_only():
    error, *_ = errors_of(ErrorModel().only("time_mark_jitter"), axes="across-along", filter_window=None)
    assert np.max(np.abs(error[:, 0])) < 0.05 * np.max(np.abs(error[:, 1]))
    assert np.max(np.abs(error[:, 1])) > 2.0


def test_recording_noise_is_reduced_by_the_filter():
    noisy, *_ = errors_of(ErrorModel().only("record_noise"), filter_window=None)
    filtered, *_ = errors_of(ErrorModel().only("record_noise"), filter_window=180.0)
    assert np.sqrt(np.mean(filtered**2)) < 0.6 * np.sqrt(np.mean(noisy**2))


def test_recorded_velocities_carry_their_own_white_noise():
    """The INS velocity record: the truth (plus the error model's rate) and white north/east noise of
    ``velocity_noise``; the positions are untouched by it."""
    errors = ErrorModel().only("velocity_noise")
    strips, truths = simulate_flight(PLAN, errors, np.random.default_rng(4))
    noise = []
    for strip, truth in zip(strips, truths, strict=True):
        position, velocity = (np.asarray(a) for a in truth.trajectory(strip.record_times))
        np.testing.assert_allclose(strip.record_positions, position, atol=1e-6, rtol=0)
        north, east = (np.asarray(a) for a in north_east(position))
        difference = strip.record_velocities - velocity
        noise.append(np.stack([np.sum(difference * north, 1), np.sum(difference * east, 1)], 1))
        np.testing.assert_allclose(np.sum(difference * position, 1) / np.linalg.norm(position, axis=1), 0.0,
                                   atol=1e-9)
    noise = np.concatenate(noise)
    assert np.std(noise, axis=0) == pytest.approx([errors.velocity_noise] * 2, rel=0.2)
    assert np.abs(np.mean(noise, axis=0)).max() < 4 * errors.velocity_noise / np.sqrt(noise.shape[0])


def test_filtered_navigation_keeps_the_velocity_records_precision():
    """Records with their white noise (30 m, 0.03 m/s): the filtered velocity errs less than one velocity record
    between the records, and far-range points move a few metres along track, not the tens of metres a velocity
    differentiated from the positions gives (issue 12)."""
    from seaice_jax.sensors.strips import strip_navigation

    errors = ErrorModel().only("record_noise", "velocity_noise")
    strips, truths = simulate_flight(PLAN, errors, np.random.default_rng(0))
    for strip, truth in zip(strips, truths, strict=True):
        t = np.linspace(strip.start_time, strip.end_time, 601)
        velocity = np.asarray(strip_navigation(strip, 180.0)(t)[1])
        error = velocity - np.asarray(truth.trajectory(t)[1])
        assert np.sqrt(np.mean(error**2)) < errors.velocity_noise
    error, *_ = errors_of(errors, axes="across-along", filter_window=180.0)
    image_sigma = ErrorModel().image_noise / PLAN.film_rate * PLAN.speed  # m along track (13 m)
    assert np.sqrt(np.mean(error[:, 1] ** 2)) < 0.5 * image_sigma


def test_aidjex_scenario_has_overlapping_strips_drift_and_stations():
    from seaice_jax.drift.kinematics import fit_transform
    from seaice_jax.simulate.aircraft import aidjex_scenario

    scenario = aidjex_scenario(seed=3, plan=FlightPlan(strips=4), features=300)
    assert len(scenario.coverages) == 2 and list(scenario.kinds[:3]) == ["station"] * 3
    for coverage in scenario.coverages:
        m = coverage.measurements
        on = [set(m.point[m.strip == j]) for j in range(4)]
        assert all(len(on[j] & on[j + 1]) >= 5 for j in range(3))  # ties in every overlap
        assert set(coverage.control) == {0, 1, 2}
    first, second = (c.positions for c in scenario.truth)
    fit = fit_transform(first, second, "affine", sigma=100.0)
    np.testing.assert_allclose(fit.parameters["shift"], [-1900.0 * 16, 0.0], atol=300.0)  # 1.9 km/day west
    np.testing.assert_allclose(fit.parameters["matrix"], [[1.10, 0.03], [0.0, 0.95]], atol=0.01)
    assert scenario.coverages[1].epoch == 16 * 86400.0


def test_floes_turn_rigidly_about_their_centres():
    """Within one floe the motion left after the block's affine drift is a rigid rotation by that floe's angle.

    Each floe's rotation is fitted to four of its points (one shape: the solver compiles once) and must carry every
    point of the floe."""
    from seaice_jax.drift.kinematics import fit_transform
    from seaice_jax.simulate.aircraft import aidjex_scenario

    scenario = aidjex_scenario(seed=5, plan=FlightPlan(strips=4), features=400, floe_rotation=2.0)
    first, second = (c.positions for c in scenario.truth)
    matrix = np.array([[1.1, 0.03], [0.0, 0.95]])
    sizes = np.bincount(scenario.floe)
    assert sizes.size > 5 and np.std(np.degrees(scenario.floe_rotation)) > 0.5
    for floe in np.nonzero(sizes >= 4)[0][:5]:
        on = scenario.floe == floe
        four = np.nonzero(on)[0][:4]
        fit = fit_transform(first[four] @ matrix.T, second[four], "rigid", sigma=1.0)
        assert float(fit.parameters["rotation"]) == pytest.approx(scenario.floe_rotation[floe], abs=1e-9)
        assert fit.rms < 1e-6
        assert np.abs(fit(first[on] @ matrix.T) - second[on]).max() < 1e-6  # metres, every point of the floe


def test_prudhoe_scenario_single_control_point_removes_most_of_the_error():
    """Source 002, Table 2: one ground control point reduces km-level errors to a few hundred metres."""
    from seaice_jax.adjust.radar.sequential import sequential_block
    from seaice_jax.simulate.aircraft import prudhoe_scenario

    scenario = prudhoe_scenario(seed=1)
    coverage = scenario.coverages[0]
    m, truth = coverage.measurements, scenario.truth[0].positions
    none = sequential_block(coverage.strips, m, scenario.plane)
    one = sequential_block(coverage.strips, m, scenario.plane, control={0: np.array(coverage.control[0][:2])})
    rms_none = np.sqrt(np.nanmean((none.point_positions(m, truth.shape[0]) - truth) ** 2))
    rms_one = np.sqrt(np.nanmean((one.point_positions(m, truth.shape[0]) - truth) ** 2))
    assert rms_none > 1000.0 and rms_one < 0.3 * rms_none


def test_no_simulated_mark_lies_inside_the_nadir_return():
    """Fresh seed 52511 of the AIDJEX block (issue 29) drew a near-edge point's mark 4 m of slant range inside the
    flying height, which the block adjustment refuses: the film shows nothing there, so the simulator reads no
    mark inside the nadir return's trace (``FlightPlan.nadir_trace``)."""
    scenario = aidjex_scenario(52511, plan=FlightPlan(strips=10), features=600)
    plan = scenario.plan
    for coverage, truth in zip(scenario.coverages, scenario.truth, strict=True):
        m = coverage.measurements
        sweep_delay = np.array([s.sweep_delay for s in truth.strips])[m.strip]
        range_scale = np.array([s.range_scale for s in truth.strips])[m.strip]
        beyond = m.y - (plan.altitude / range_scale - sweep_delay)  # mm of film beyond the true nadir line
        assert beyond.min() >= plan.nadir_trace
        assert m.x.size > 700  # only the rare near-edge mark is left out
