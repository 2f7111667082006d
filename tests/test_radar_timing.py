"""Azimuth-time and slant-range offsets of two real Sentinel-1 images (IW GRD and IW1 SLC of one product) from
control and tie points simulated on their annotated geometry: offsets recovered, σ̂0 ≈ 1, predicted σ against the
scatter of a Monte Carlo, a blunder found by the w-test, ties without a datum named."""

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from seaice_jax.adjust.radar.timing import (
    GroundPoints,
    RadarMeasurements,
    TimingOptions,
    adjust_radar_timing,
    timing_solver,
)
from seaice_jax.errors import RankDeficiencyError
from seaice_jax.geometry.zero_doppler import ellipsoid_imaging_time_and_range
from seaice_jax.io.sentinel1 import read_annotation

DATA = Path(__file__).with_name("data") / "sentinel1"
PRODUCT = "20210401t052623-20210401t052648-026269-032297"
TRUE_TIME_OFFSET = np.array([2.0e-4, -1.5e-4])  # s: about 1.5 m and 1.1 m along track
TRUE_RANGE_OFFSET = np.array([1.8, -0.7])  # m
TIME_SIGMA, RANGE_SIGMA = 2e-5, 0.5
OPTIONS = TimingOptions(TIME_SIGMA, RANGE_SIGMA)


def _scene():
    grd = read_annotation(DATA / f"s1b-iw-grd-vv-{PRODUCT}-001.xml")
    slc = read_annotation(next(DATA.glob("s1b-iw1-slc-vv-20210401t052624-*.xml")))
    epoch = grd.epoch
    orbits = [grd.orbit(epoch), slc.orbit(epoch)]
    spans = []
    for annotation in (grd, slc):
        grid = annotation.grid
        times = grid.azimuth_time + float((annotation.epoch - epoch) / np.timedelta64(1, "ns")) * 1e-9
        spans.append((times.min(), times.max(), grid.slant_range.min(), grid.slant_range.max()))
    control_rows, tie_rows = [], []
    latitudes, longitudes, heights = [], [], []
    for image, annotation in enumerate((grd, slc)):
        grid = annotation.grid
        take = np.arange(0, grid.line.size, 9)
        for k in take:
            control_rows.append((image, len(latitudes)))
            latitudes.append(np.radians(grid.latitude[k]))
            longitudes.append(np.radians(grid.longitude[k]))
            heights.append(grid.height[k])
    control_points = GroundPoints(np.array(latitudes), np.array(longitudes), np.array(heights))
    # ties: SLC grid points seen by the GRD as well (inside its time and range span)
    slc_grid = slc.grid
    tie_lat, tie_lon, tie_h = [], [], []
    for k in range(0, slc_grid.line.size, 3):
        lat, lon, h = np.radians(slc_grid.latitude[k]), np.radians(slc_grid.longitude[k]), slc_grid.height[k]
        t, r = (float(v) for v in ellipsoid_imaging_time_and_range(orbits[0], lat, lon, h, *orbits[0].time_span))
        if spans[0][0] < t < spans[0][1] and spans[0][2] < r < spans[0][3] and len(tie_lat) < 12:
            tie_lat.append(lat), tie_lon.append(lon), tie_h.append(h)
    tie_points = GroundPoints(np.array(tie_lat), np.array(tie_lon), np.array(tie_h))
    tie_rows = [(image, p) for p in range(len(tie_lat)) for image in (0, 1)]
    return orbits, np.array(control_rows), control_points, np.array(tie_rows), tie_points


def _measured(orbits, rows, points, rng):
    """Radar coordinates of the points, minus the true offsets, plus noise."""
    times, ranges = np.zeros(len(rows)), np.zeros(len(rows))
    for image in (0, 1):
        mine = rows[:, 0] == image
        p = rows[mine, 1]
        t, r = ellipsoid_imaging_time_and_range(orbits[image], points.latitude[p], points.longitude[p],
                                                points.height[p], *orbits[image].time_span)
        times[mine] = np.asarray(t) - TRUE_TIME_OFFSET[image]
        ranges[mine] = np.asarray(r) - TRUE_RANGE_OFFSET[image]
    times += rng.normal(0, TIME_SIGMA, times.shape)
    ranges += rng.normal(0, RANGE_SIGMA, ranges.shape)
    return RadarMeasurements(rows[:, 0], rows[:, 1], times, ranges)


@pytest.fixture(scope="module")
def scene():
    return _scene()


@pytest.mark.slow
def test_offsets_recovered_with_ties(scene):
    orbits, control_rows, control_points, tie_rows, tie_points = scene
    assert tie_points.latitude.size >= 6
    rng = np.random.default_rng(7)
    control = _measured(orbits, control_rows, control_points, rng)
    ties = _measured(orbits, tie_rows, tie_points, rng)
    start = GroundPoints(tie_points.latitude + 2e-5, tie_points.longitude - 3e-5, tie_points.height)  # ~100-200 m
    result = adjust_radar_timing(orbits, control, control_points, ties, start, OPTIONS)
    assert bool(result.converged)
    sigma = result.standard_deviations()
    for image in (0, 1):
        for name, truth in (("azimuth_offset", TRUE_TIME_OFFSET), ("range_offset", TRUE_RANGE_OFFSET)):
            error = float(result.parameters[name][image]) - truth[image]
            assert abs(error) < 4 * float(sigma[f"{name}[{image}]"]), (name, image, error)
    moved = np.hypot(np.asarray(result.parameters["tie_latitude"]) - tie_points.latitude,
                     np.asarray(result.parameters["tie_longitude"]) - tie_points.longitude) * 6.37e6
    assert moved.max() < 20.0  # m: back from ~150 m to the pointing noise's scale
    assert 0.7 < float(result.sigma0) < 1.3


def test_predicted_sigma_matches_monte_carlo_and_w_test(scene):
    """200 noise realizations, one vmapped solver: the offsets' empirical scatter equals the predicted σ (a priori
    cofactor) within 15 %, mean σ̂0² within 5 % of 1, w-test false alarms at α = 0.001 rare."""
    orbits, control_rows, control_points, _, _ = scene
    rng = np.random.default_rng(2024)
    solver, _, args = timing_solver(orbits, _measured(orbits, control_rows, control_points, rng),
                                   control_points, options=OPTIONS)
    runs = 200
    exact = _measured(orbits, control_rows, control_points, _ZeroNoise())
    shape = (runs, exact.azimuth_time.size)
    stacked = {"control_time": jnp.asarray(exact.azimuth_time + rng.normal(0, TIME_SIGMA, shape)),
               "control_range": jnp.asarray(exact.slant_range + rng.normal(0, RANGE_SIGMA, shape)),
               "tie_time": jnp.zeros((runs, 0)), "tie_range": jnp.zeros((runs, 0))}
    results = jax.jit(jax.vmap(lambda o: solver(o, args)))(stacked)
    predicted = np.sqrt(np.diagonal(np.asarray(results.cofactor[0])))
    estimates = np.concatenate([np.asarray(results.parameters["azimuth_offset"]),
                                np.asarray(results.parameters["range_offset"])], axis=1)
    truth = np.concatenate([TRUE_TIME_OFFSET, TRUE_RANGE_OFFSET])
    empirical = np.sqrt(np.mean((estimates - truth) ** 2, axis=0))
    names = list(solver.parameter_names)
    order = [names.index(n) for n in ("azimuth_offset[0]", "azimuth_offset[1]", "range_offset[0]",
                                      "range_offset[1]")]
    np.testing.assert_allclose(empirical / predicted[order], 1.0, atol=0.15)
    assert abs(np.mean(np.asarray(results.sigma0) ** 2) - 1.0) < 0.05
    w = np.concatenate([np.asarray(results.standardized_residuals[g]).reshape(runs, -1)
                        for g in ("control_time", "control_range")], axis=1)
    assert np.mean(np.abs(w) > 3.29) < 0.004


class _ZeroNoise:
    """A random generator that draws zeros: the exact measurements."""

    @staticmethod
    def normal(_mean, _sigma, shape):
        return np.zeros(shape)


def test_blunder_is_flagged(scene):
    orbits, control_rows, control_points, _, _ = scene
    control = _measured(orbits, control_rows, control_points, np.random.default_rng(11))
    ranges = control.slant_range.copy()
    ranges[5] += 12 * RANGE_SIGMA
    blundered = RadarMeasurements(control.image, control.point, control.azimuth_time, ranges)
    result = adjust_radar_timing(orbits, blundered, control_points, options=OPTIONS)
    worst = result.flagged()[0]
    assert (worst.group, worst.row) == ("control_range", 5)


@pytest.mark.slow
def test_ties_alone_have_no_datum_unless_priors(scene):
    orbits, _, _, tie_rows, tie_points = scene
    ties = _measured(orbits, tie_rows, tie_points, np.random.default_rng(3))
    no_control = RadarMeasurements(np.zeros(0, int), np.zeros(0, int), np.zeros(0), np.zeros(0))
    with pytest.raises(RankDeficiencyError, match="offset"):
        adjust_radar_timing(orbits, no_control, GroundPoints(np.zeros(0), np.zeros(0), np.zeros(0)), ties,
                            tie_points, OPTIONS)
    result = adjust_radar_timing(orbits, no_control, GroundPoints(np.zeros(0), np.zeros(0), np.zeros(0)), ties,
                                 tie_points, TimingOptions(TIME_SIGMA, RANGE_SIGMA, 3e-4, 2.0))
    assert bool(result.converged)
