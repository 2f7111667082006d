"""The simultaneous block adjustment against simulations whose truth is known."""

from dataclasses import replace

import numpy as np
import pytest

from seaice_jax.adjust.radar.block import BlockOptions, simultaneous_block
from seaice_jax.adjust.radar.layout import layout_block
from seaice_jax.errors import RankDeficiencyError, SeaiceError
from seaice_jax.geometry.earth import MEAN_RADIUS
from seaice_jax.sensors.strips import Measurements
from seaice_jax.simulate.aircraft import ErrorModel, FlightPlan, aidjex_scenario

# systematic errors only: INS drift, Schuler oscillation, turn perturbations, radar constants
SYSTEMATIC = ErrorModel().only("drift_rate", "schuler_amplitude", "turn_perturbation", "sweep_delay_error",
                               "range_scale_error")
# those a linear navigation-error model and the nadir calibration represent exactly
LINEAR = SYSTEMATIC.only("drift_rate", "turn_perturbation", "sweep_delay_error")
IMAGE_SIGMA = 0.04  # mm


@pytest.fixture(scope="module")
def exact():
    """Two coverages of three strips; no random errors at all, stations known to 1 cm."""
    return aidjex_scenario(11, plan=FlightPlan(strips=3), errors=LINEAR, features=120, station_sigma=0.01)


def errors_of(result, scenario):
    return [result.positions[c] - truth.positions for c, truth in enumerate(scenario.truth)]


def test_noise_free_block_returns_the_truth_from_the_navigation_only_start(exact):
    """INS drift, turn perturbations and a sweep-delay error, no noise, range scale known, no navigation priors:
    the solve recovers every point, the navigation-error curves and the sweep delay."""
    options = BlockOptions(solver="schur", navigation_model="linear", offset_prior=None, shape_prior=None,
                           turn_prior=None, range_scale_prior=1e-9)
    result = simultaneous_block(exact.coverages, exact.plane, len(exact.kinds), options)
    assert result.converged and result.solver == "schur"
    layout = layout_block(exact.coverages, len(exact.kinds), exact.plane, options, MEAN_RADIUS)
    start_error = np.array([layout.start_points[u] - exact.truth[c].positions[p]
                            for u, (c, p) in enumerate(layout.point_key) if c >= 0])  # the start: navigation only
    error = np.concatenate([e[np.isfinite(e).all(1)] for e in errors_of(result, exact)])
    assert np.abs(start_error).max() > 1000.0  # the navigation errors put the start kilometres off
    assert error.shape[0] > 150 and np.abs(error).max() < 1.0
    strips = [s for c in exact.coverages for s in c.strips]
    truths = [s for c in exact.truth for s in c.strips]
    for estimate, strip, truth in zip(result.strips, strips, truths, strict=True):
        curve, sigma = estimate.navigation_error(strip.record_times)
        assert np.abs(curve - truth.navigation_error).max() < 1.0  # the INS error curve, north and east
        assert np.all(sigma > 0)
        assert estimate.sweep_delay == pytest.approx(truth.sweep_delay, abs=1e-3)
        assert estimate.range_scale == pytest.approx(truth.range_scale, rel=1e-5)


def noisy(scenario, rng, sigma=IMAGE_SIGMA, noise=1.0):
    """The scenario with fresh image-measurement, nadir and control noise of the σ the adjustment assumes
    (``noise=0``: none, but the stations' σ is still the 100 m of a satellite fix)."""
    coverages = []
    for coverage in scenario.coverages:
        m = coverage.measurements
        measured = Measurements(m.point, m.strip, m.x + noise * rng.normal(0, sigma, m.x.size),
                                m.y + noise * rng.normal(0, sigma, m.y.size))
        strips = [replace(s, nadir_y=s.nadir_y + noise * rng.normal(0, sigma, s.nadir_y.size))
                  for s in coverage.strips]
        control = {p: (x + noise * rng.normal(0, 100.0), y + noise * rng.normal(0, 100.0), 100.0)
                   for p, (x, y, _) in coverage.control.items()}
        coverages.append(replace(coverage, measurements=measured, strips=strips, control=control))
    return replace(scenario, coverages=tuple(coverages))


@pytest.fixture(scope="module")
def small():
    # one pair of radar constants for the block (radar_constants="shared") while the simulation's calibration
    # errors are drawn per strip: the small block's strips are recorded without them (the shared pair is exact)
    errors = replace(SYSTEMATIC, sweep_delay_error=0.0, range_scale_error=0.0)
    scenario = aidjex_scenario(12, plan=FlightPlan(strips=2), errors=errors, features=70, station_sigma=0.01)
    options = BlockOptions(image_sigma=(IMAGE_SIGMA, IMAGE_SIGMA), time_mark_sigma=0.0, altimeter_sigma=0.0,
                           radar_constants="shared")  # noisy() draws the reading noise only: exact time marks
    return scenario, options


@pytest.mark.slow
def test_schur_complement_equals_the_dense_engine(small):
    scenario, options = small
    data = noisy(scenario, np.random.default_rng(3))
    dense = simultaneous_block(data.coverages, data.plane, len(data.kinds), replace(options, solver="dense"))
    schur = simultaneous_block(data.coverages, data.plane, len(data.kinds), replace(options, solver="schur"))
    assert (dense.solver, schur.solver) == ("dense", "schur")
    for c in range(2):
        np.testing.assert_allclose(schur.positions[c], dense.positions[c], atol=1e-3)
        np.testing.assert_allclose(schur.covariances[c], dense.covariances[c], rtol=1e-6, atol=1e-3)  # m²
    np.testing.assert_allclose(schur.drift_covariance[0], dense.drift_covariance[0], rtol=1e-6, atol=1e-3)
    np.testing.assert_allclose(schur.redundancy, dense.redundancy, atol=1e-6)
    controlled = schur.redundancy > 1e-3  # points on one strip only have r = 0: nothing to test there
    np.testing.assert_allclose(schur.w[controlled], dense.w[controlled], atol=1e-4)
    assert schur.sigma0 == pytest.approx(dense.sigma0, rel=1e-6)
    assert schur.degrees_of_freedom == dense.degrees_of_freedom
    assert -1e-9 < schur.redundancy.min() and schur.redundancy.max() < 1.0 and controlled.mean() > 0.15


@pytest.mark.slow
@pytest.mark.parametrize("runs", [100, 300])
def test_predicted_sigma_matches_monte_carlo_for_stations_and_drift(small, runs):
    """``runs`` noise realizations: the empirical RMS about the noise-free solution equals the predicted σ (shared
    radar constants correlate the two coverages, so the drift covariance needs its cross terms).

    No priors here but the flight model's small deviation prior: a prior is a pseudo-observation whose value the
    Monte Carlo would have to draw too (its σ is in the predicted covariance); the stations and the nadir returns
    determine everything else of the linear model.

    Tolerances from the Monte Carlo error: the RMS of ``runs`` draws of one component has a relative standard error
    s = 1/√(2 runs) (7.1 % at 100, 4.1 % at 300). Each station component within 5 s; the median over the drift
    components within 1.2 s (the median of |N(0, s)| is 0.67 s); the ratios pooled over all components within 10 %.
    """
    scenario, options = small
    options = replace(options, solver="schur", navigation_model="linear", offset_prior=None, shape_prior=None,
                      turn_prior=None, sweep_delay_prior=None, range_scale_prior=None)
    rng = np.random.default_rng(4)
    exact = noisy(scenario, rng, noise=0.0)
    reference = simultaneous_block(exact.coverages, exact.plane, len(exact.kinds), options)
    station, drift = [], []
    for _ in range(runs):
        data = noisy(scenario, rng)
        result = simultaneous_block(data.coverages, data.plane, len(data.kinds), options)
        station.append(np.stack([result.positions[c][:3] - reference.positions[c][:3] for c in range(2)]))
        drift.append(result.drift[0] - reference.drift[0])
    station, drift = np.array(station), np.array(drift)
    predicted_station = np.stack([np.diagonal(reference.covariances[c][:3], axis1=1, axis2=2) for c in range(2)])
    ratio = np.sqrt(np.mean(station**2, axis=0) / predicted_station)
    error = 1.0 / np.sqrt(2 * runs)
    assert np.all(np.abs(ratio - 1.0) < 5 * error)  # each station and component
    assert np.sqrt(np.mean(station**2) / np.mean(predicted_station)) == pytest.approx(1.0, abs=0.1)
    seen = np.isfinite(reference.drift[0]).all(axis=1)
    predicted_drift = np.diagonal(reference.drift_covariance[0][seen], axis1=1, axis2=2)
    ratio = np.sqrt(np.nanmean(drift[:, seen] ** 2, axis=0) / predicted_drift)
    assert seen.sum() > 30 and np.median(np.abs(ratio - 1.0)) < 1.2 * error
    assert np.sqrt(np.nanmean(drift[:, seen] ** 2) / np.mean(predicted_drift)) == pytest.approx(1.0, abs=0.1)
    correlation = np.abs(reference.drift_covariance[0][seen][:, 0, 0] - sum(
        np.diagonal(reference.covariances[c][seen], axis1=1, axis2=2)[:, 0] for c in range(2)))
    assert correlation.max() > 0.0  # the cross term is there (and the Monte Carlo says it is right)


@pytest.mark.slow
def test_a_planted_blunder_is_flagged_and_named(small):
    scenario, options = small
    data = noisy(scenario, np.random.default_rng(5))
    m = data.coverages[0].measurements
    tie = next(p for p in np.unique(m.point) if np.sum(m.point == p) == 2 and p >= 3)
    row = np.nonzero(m.point == tie)[0][1]
    x = m.x.copy()
    planted = 1000.0 / (FlightPlan().speed / FlightPlan().film_rate)  # 1 km along track, in film mm
    x[row] += planted
    bad = replace(data.coverages[0], measurements=replace(m, x=x))
    result = simultaneous_block((bad, data.coverages[1]), data.plane, len(data.kinds), options)
    assert result.blunders and result.blunders[0].point == tie and result.blunders[0].coverage == 0
    assert result.blunders[0].component == "x" and abs(result.blunders[0].w) > 10
    # measured on two strips only: both measurements fail alike and the report says which cannot be told apart
    pair = [b for b in result.blunders if b.point == tie and b.component == "x"]
    assert len(pair) == 2 and not any(b.separable for b in pair) and abs(abs(pair[0].w) - abs(pair[1].w)) < 0.5
    assert all(f"point {tie} " in b.confounded_with for b in pair)
    mine = next(b for b in pair if b.strip == m.strip[row])
    assert mine.estimated_error == pytest.approx(planted, rel=0.1)  # observed − true: the sign of the planted error
    rows = np.nonzero((result.coverage_of == 0) & (result.point_of == tie) & (result.strip_of == m.strip[row]))[0]
    assert result.residuals[rows[0], 0] < 0  # computed − observed
    clean = simultaneous_block(data.coverages, data.plane, len(data.kinds), options)
    assert tie not in {b.point for b in clean.blunders}


def test_a_control_point_one_kilometre_off_is_flagged_and_named(small):
    scenario, options = small
    data = noisy(scenario, np.random.default_rng(6))
    coverage = data.coverages[1]
    x, y, sigma = coverage.control[1]
    moved = replace(coverage, control={**coverage.control, 1: (x + 1000.0, y, sigma)})
    result = simultaneous_block((data.coverages[0], moved), data.plane, len(data.kinds), options)
    worst = result.blunders[0]
    assert (worst.group, worst.point, worst.coverage, worst.component) == ("control", 1, 1, "x")
    assert worst.description == f"control x of point 1 ({coverage.name})"
    # measured on one strip of that day: its image measurement is the only other observation of the point, and the
    # report says the two cannot be told apart
    assert worst.separable or worst.confounded_with.startswith(f"image x of point 1 on {coverage.name}/")
    adjustment = result.adjustment
    assert adjustment is not None
    flag = next(f for f in adjustment.flagged() if f.group == "control")
    redundancy = float(adjustment.redundancy["control"][flag.row, flag.component])
    assert worst.estimated_error == pytest.approx(1000.0, abs=4 * sigma / np.sqrt(redundancy))


def test_without_control_or_priors_the_datum_defect_is_named(small):
    """Strip by strip, nothing ties the strips' errors together: one control point leaves the block free to turn
    about it. One error curve per flight (the INS drift and Schuler oscillation run on through the turns, while
    the strips alternate direction) fixes the rotation; only the shift is left to the control (the next test, in
    make test-slow). (Without control,
    a flight's north/east offset is held only by the meridians' convergence across the block, ~2° at 75°N: not
    an exact defect, but its σ says the block is free.)"""
    scenario, options = small
    free = replace(options, navigation_model="linear", navigation_scope="strip", offset_prior=None, shape_prior=None,
                   turn_prior=None, solver="schur")
    none = tuple(replace(c, control={}) for c in scenario.coverages)
    with pytest.raises(RankDeficiencyError, match=r"datum defect: nothing fixes the block's .*shift") as error:
        simultaneous_block(none, scenario.plane, len(scenario.kinds), free)
    assert any("navigation north offset" in name for name in error.value.parameters)
    one = tuple(replace(c, control={0: c.control[0]}) for c in scenario.coverages)
    with pytest.raises(RankDeficiencyError, match=r"datum defect: nothing fixes the block's rotation"):
        simultaneous_block(one, scenario.plane, len(scenario.kinds), free)
    simultaneous_block(scenario.coverages, scenario.plane, len(scenario.kinds), free)  # three stations fix it


@pytest.mark.slow
def test_one_error_curve_per_flight_fixes_the_rotation_and_leaves_the_free_block_loose(small):
    """The flight-scope half of the datum test above (four more block structures to compile): without control the
    block solves but its σ says it is free; one control point fixes it; the Schur backend agrees."""
    scenario, options = small
    none = tuple(replace(c, control={}) for c in scenario.coverages)
    one = tuple(replace(c, control={0: c.control[0]}) for c in scenario.coverages)
    flight = replace(options, navigation_model="linear", navigation_scope="flight", offset_prior=None,
                     shape_prior=None, turn_prior=None, solver="dense")
    loose = simultaneous_block(none, scenario.plane, len(scenario.kinds), flight)
    seen = np.isfinite(loose.positions[0]).all(axis=1)
    assert np.sqrt(np.diagonal(loose.covariances[0][seen], axis1=1, axis2=2)).min() > 100_000.0  # metres
    result = simultaneous_block(one, scenario.plane, len(scenario.kinds), flight)
    sigma = np.sqrt(np.diagonal(result.covariances[0][seen], axis1=1, axis2=2))
    assert result.converged and np.isfinite(sigma).all() and sigma.max() < 1000.0
    # the Schur backend (normal equations, damped steps) reaches the same weakly held solution
    schur = simultaneous_block(none, scenario.plane, len(scenario.kinds), replace(flight, solver="schur"))
    np.testing.assert_allclose(np.diagonal(schur.covariances[0][seen], axis1=1, axis2=2),
                               np.diagonal(loose.covariances[0][seen], axis1=1, axis2=2), rtol=1e-3)


def test_flight_scope_shares_the_drift_and_schuler_terms_of_a_coverage(small):
    scenario, options = small
    result = simultaneous_block(scenario.coverages, scenario.plane, len(scenario.kinds), options)
    first, second = result.strips[0], result.strips[1]  # the two strips of day 0
    np.testing.assert_array_equal(first.coefficients[1:-1], second.coefficients[1:-1])  # drift and Schuler
    assert not np.allclose(first.coefficients[0], second.coefficients[0])  # the turn between them: own offsets
    assert not np.allclose(first.coefficients[-1], second.coefficients[-1])  # and own small deviations
    assert (first.flight_start, first.flight_end) == (second.flight_start, second.flight_end) == (
        first.start_time, second.end_time)
    with pytest.raises(SeaiceError, match="spline navigation model is per strip"):
        BlockOptions(navigation_model="spline")


def test_a_control_point_without_ground_solution_is_named_not_dropped(small):
    """A control point whose every measurement lies inside the flying height's range holds nothing; silently
    dropping it would leave the block on its priors alone."""
    scenario, options = small
    coverage = scenario.coverages[0]
    m = coverage.measurements
    y = np.where(m.point == 0, 0.0, m.y)  # slant range (0 + c) f = 2.5 km < 10 km altitude
    bad = replace(coverage, measurements=replace(m, y=y))
    with pytest.raises(SeaiceError, match=r"coverage 'day 0': control point 0 is measured \(strip S0\d\) but has no "
                                          r"ground solution"):
        simultaneous_block((bad, scenario.coverages[1]), scenario.plane, len(scenario.kinds), options)


def test_from_take_off_the_flight_basis_holds_the_simulated_ins_error_with_no_offset():
    """The simulator's INS error (drift from take-off plus a Schuler oscillation under way) is the flight basis
    from take-off exactly, with a zero offset (no alignment error) and the Schuler terms carrying the error at
    take-off; a take-off after the first strip is refused by name."""
    from seaice_jax.adjust.radar.block import navigation_basis
    from seaice_jax.simulate.aircraft import navigation_error

    times = np.linspace(3600.0, 3600.0 + 7200.0, 400)  # s after take-off
    truth, _ = navigation_error(times, SYSTEMATIC, np.zeros(2), drift_direction=0.3, schuler_phase=1.1)
    basis, _ = navigation_basis("schuler", times, (times[0], times[-1]), (0.0, times[-1]))
    flight = basis[:, 1:5]  # the flight's offset, drift, Schuler sine and cosine (not the strip's own terms)
    coefficients, *_ = np.linalg.lstsq(flight, truth, rcond=None)
    np.testing.assert_allclose(flight @ coefficients, truth, atol=1e-6)
    np.testing.assert_allclose(coefficients[0], 0.0, atol=1e-6)  # no alignment error at take-off
    np.testing.assert_allclose(flight[0, 1], 3600.0 / 10800.0)  # the drift grows from zero at take-off
    assert np.abs(coefficients[2:4]).max() > 100.0  # the Schuler terms hold the error at take-off


def test_a_take_off_after_the_first_strip_is_refused(small):
    scenario, options = small
    late = scenario.coverages[0].strips[0].start_time + 1.0
    with pytest.raises(SeaiceError, match=r"coverage 'day 0': take_off_time .* is after its first strip starts"):
        simultaneous_block(scenario.coverages, scenario.plane, len(scenario.kinds),
                           replace(options, take_off_time=late))
