"""The simultaneous block starts from the sweep delay the nadir returns give, so the near-range edge of a strip has
a ground point whatever the radar's nominal constants: the Prudhoe simulations run through both methods for every
seed (with the nominal constants a sweep-delay error of a few tenths of a mm put the strip's first kilometre inside the
flying height, and a control point there stopped the block); a measurement really off the film's ground range (slant
range 1 m shorter than the flying height) is refused by name by both methods, never dropped."""

from dataclasses import replace

import numpy as np
import pytest

from seaice_jax.adjust.radar.block import BlockOptions
from seaice_jax.adjust.radar.layout import layout_block
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.earth import MEAN_RADIUS
from seaice_jax.io.project import read_project, write_project
from seaice_jax.sensors.slar import imaging_time, nadir_calibration
from seaice_jax.sensors.strips import nadir_altitudes, strip_navigation
from seaice_jax.simulate.aircraft import FlightPlan, aidjex_scenario, prudhoe_scenario
from seaice_jax.workflows.radar_block import adjust_block


@pytest.mark.parametrize("seed", [1, 2, 5, 7])  # 1, 5, 7: control points the nominal start lost
def test_every_prudhoe_measurement_has_a_start_and_the_start_sweep_delay_fits_the_truth(seed):
    scenario = prudhoe_scenario(seed)
    measured = sum(c.measurements.x.size for c in scenario.coverages)
    layout = layout_block(scenario.coverages, len(scenario.kinds), scenario.plane, BlockOptions(), MEAN_RADIUS)
    assert layout.observations["point"].size == measured  # nothing dropped, no control point refused
    delays = [k for k, name in enumerate(layout.names) if name.endswith("sweep delay")]
    for index, truth in zip(delays, (t.strips[0] for t in scenario.truth), strict=True):
        # the sweep delay that puts the true nadir range (the flying height H) at the nadir line with f0:
        # H/f0 - y_n - c0 with y_n = H/f - c (eq. A3)
        altitude, plan = scenario.plan.altitude, scenario.plan
        expected = altitude / plan.range_scale - altitude / truth.range_scale + truth.sweep_delay - plan.sweep_delay
        assert layout.start_theta[index] == pytest.approx(expected, abs=0.025)  # 5 σ of 91 nadir returns


@pytest.fixture(scope="module")
def prudhoe_project(tmp_path_factory):
    """Seed 1: with the nominal constants two control points of day 5 had no ground point and the block stopped."""
    return read_project(write_project(prudhoe_scenario(1), tmp_path_factory.mktemp("prudhoe") / "project"))


@pytest.mark.parametrize("method", [pytest.param("simultaneous", marks=pytest.mark.slow), "sequential"])
def test_prudhoe_seed_1_runs_through_both_methods(prudhoe_project, method):
    scenario = prudhoe_scenario(1)
    analysis = adjust_block(prudhoe_project, method)
    measured = np.unique(scenario.coverages[0].measurements.point)
    rows = [prudhoe_project.point_ids.index(f"P{p + 1:04d}") for p in measured]  # the project's ids: P0001, ...
    error = np.linalg.norm(analysis.positions[0][rows] - scenario.truth[0].positions[measured], axis=1)
    assert np.all(np.isfinite(error))
    # 20 control points of ±50 m: the simultaneous block predicts ~30 m per point; the sequential method is cruder
    assert np.sqrt(np.mean(error**2)) < (60.0 if method == "simultaneous" else 300.0)  # measured: 28 m, 132 m


def _off_film(coverage, k, margin, calibration):
    """Film y (mm) of measurement ``k`` whose slant range with the given (sweep delay, range scale) is the flying
    height at its imaging time plus ``margin`` metres."""
    m = coverage.measurements
    strip = coverage.strips[m.strip[k]]
    time = imaging_time(m.x[k], strip.mark_x, strip.mark_times)
    position, _ = strip_navigation(strip)(time)
    height = float(np.linalg.norm(np.asarray(position))) - MEAN_RADIUS
    sweep_delay, range_scale = calibration(strip)
    return (height + margin) / range_scale - sweep_delay


def _moved(project, k, y):
    coverage = project.coverages[0]
    moved = replace(coverage, measurements=replace(coverage.measurements,
                                                   y=np.where(np.arange(coverage.measurements.y.size) == k, y,
                                                              coverage.measurements.y)))
    return replace(project, coverages=(moved, *project.coverages[1:]))


@pytest.fixture(scope="module")
def aidjex_project(tmp_path_factory):
    scenario = aidjex_scenario(seed=1, plan=FlightPlan(strips=2), features=40)
    project = read_project(write_project(scenario, tmp_path_factory.mktemp("aidjex") / "project"))
    coverage = project.coverages[0]
    k = int(np.flatnonzero(np.array(project.point_kinds)[coverage.measurements.point] == "tie")[0])
    return project, k, project.point_ids[coverage.measurements.point[k]]


def _start_constants(strip):
    """The simultaneous block's start: the nominal range scale, the sweep delay that fits the nadir returns."""
    offset = np.mean(nadir_altitudes(strip) / strip.range_scale - strip.nadir_y - strip.sweep_delay)
    return strip.sweep_delay + offset, strip.range_scale


def _calibrated(strip):
    calibration = nadir_calibration(strip.nadir_y, nadir_altitudes(strip), strip.sweep_delay, strip.range_scale)
    return calibration.sweep_delay, calibration.range_scale


def test_a_point_1_m_off_the_film_is_refused_by_the_simultaneous_block(aidjex_project):
    project, k, name = aidjex_project
    coverage = project.coverages[0]
    n = len(project.point_ids)
    inside = _moved(project, k, _off_film(coverage, k, 1.0, _start_constants))
    layout = layout_block(inside.coverages, n, inside.plane, BlockOptions(), MEAN_RADIUS)
    assert layout.observations["point"].size == sum(c.measurements.x.size for c in project.coverages)
    outside = _moved(project, k, _off_film(coverage, k, -1.0, _start_constants))
    strip = coverage.strips[coverage.measurements.strip[k]].name
    with pytest.raises(SeaiceError, match=rf"coverage 'day 0': point {name} is measured \(strip {strip}\) but has no "
                                          r"ground solution .* slant range is shorter than the flying height, off "
                                          r"the film's ground range; correct or remove its measurement"):
        layout_block(outside.coverages, n, outside.plane, BlockOptions(), MEAN_RADIUS, outside.point_ids)


def test_a_point_1_m_off_the_film_is_refused_by_the_sequential_method(aidjex_project):
    project, k, name = aidjex_project
    coverage = project.coverages[0]
    outside = _moved(project, k, _off_film(coverage, k, -1.0, _calibrated))
    with pytest.raises(SeaiceError, match=rf"coverage 'day 0': point {name} is measured \(strip S0\d\) but has no "
                                          r"ground solution with the nadir-calibrated radar constants"):
        adjust_block(outside, "sequential")
