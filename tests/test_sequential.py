import numpy as np
import pytest

from seaice_jax.adjust.radar.sequential import PiecewiseCubic, fit_piecewise_cubic, piece_coefficients
from seaice_jax.errors import SeaiceError


def cubic(x):
    return np.stack([0.3 - 0.02 * x + 1e-4 * x**2 - 2e-7 * x**3, 1.0 + 0.001 * x**2 * 1e-2], 1)


def cubic_slope(x):
    return np.stack([-0.02 + 2e-4 * x - 6e-7 * x**2, 2e-5 * x], 1)


def test_b3_b4_pieces_reproduce_a_cubic_exactly():
    joints = np.array([0.0, 40.0, 95.0, 150.0, 200.0])  # unequal intervals: Δ != 1
    spline = PiecewiseCubic(joints, cubic(joints), cubic_slope(joints))
    x = np.linspace(-10.0, 210.0, 101)
    np.testing.assert_allclose(spline(x), cubic(x), atol=1e-12)


def test_values_and_tangents_match_at_the_joints():
    rng = np.random.default_rng(1)
    joints = np.array([0.0, 30.0, 70.0, 100.0])
    values, slopes = rng.normal(size=(4, 2)), rng.normal(size=(4, 2))
    spline = PiecewiseCubic(joints, values, slopes)
    h = 1e-6
    for k, x in enumerate(joints):
        np.testing.assert_allclose(spline(x)[0], values[k], atol=1e-12)
        left, right = spline(x - h)[0], spline(x + h)[0]
        np.testing.assert_allclose((right - left) / (2 * h), slopes[k], atol=1e-5)
    a0, a1, a2, a3 = piece_coefficients(1.0, 0.5, 2.0, -1.0, 1.0)  # the printed B4 for Δ = 1
    assert (a2, a3) == (3 * (2.0 - 1.0) - 2 * 0.5 + 1.0, 0.5 - 1.0 + 2 * (1.0 - 2.0))


def test_fit_from_tie_point_discrepancies():
    rng = np.random.default_rng(2)
    x = np.sort(rng.uniform(0, 200, 60))
    fitted = fit_piecewise_cubic(x, cubic(x), joints=np.linspace(0, 200, 5), degree=3)
    np.testing.assert_allclose(fitted(x), cubic(x), atol=1e-9)  # local cubic regressions are exact on a cubic
    quadratic = fit_piecewise_cubic(x, cubic(x), joints=np.linspace(0, 200, 5))
    assert np.max(np.abs(quadratic(x) - cubic(x))) < 0.01  # the default local quadratics approximate it
    noisy = fit_piecewise_cubic(x, cubic(x) + rng.normal(0, 0.05, (60, 2)), joints=np.linspace(0, 200, 5))
    assert np.std(noisy(x) - cubic(x)) < 0.05
    with pytest.raises(SeaiceError, match="joint at x = 500: only 0 tie points"):
        fit_piecewise_cubic(x, cubic(x), joints=[0.0, 200.0, 500.0], half_width=50.0)


def simulated_block(errors, strips=3, seed=0, count=600):
    from seaice_jax.simulate.aircraft import FlightPlan, aidjex_scenario

    scenario = aidjex_scenario(seed, plan=FlightPlan(strips=strips), errors=errors, features=count)
    coverage = scenario.coverages[0]
    return coverage.strips, coverage.measurements, scenario.plane, scenario.truth[0].positions


def test_sequential_block_is_exact_without_errors():
    from seaice_jax.adjust.radar.sequential import sequential_block
    from seaice_jax.simulate.aircraft import ErrorModel

    block, m, plane, truth = simulated_block(ErrorModel.none())
    result = sequential_block(block, m, plane, control={0: truth[0]} if (m.point == 0).any() else None)
    error = result.point_positions(m, truth.shape[0]) - truth
    assert np.nanmax(np.abs(error)) < 1.0
    assert result.tie_before.shape[0] > 10


def test_internal_adjustment_removes_tie_discrepancies_and_control_fixes_the_datum():
    from seaice_jax.adjust.radar.sequential import sequential_block
    from seaice_jax.simulate.aircraft import ErrorModel

    block, m, plane, truth = simulated_block(ErrorModel())
    result = sequential_block(block, m, plane)
    before = np.sqrt(np.mean(result.tie_before**2))
    after = np.sqrt(np.mean(result.tie_after**2))
    assert before > 500.0 and after < 0.15 * before  # source 000: ±2.74/±1.75 km -> ±0.07 km
    assert not any(c.scale_estimated for c in result.calibrations)  # level flight: sweep delay alone
    measured = np.unique(m.point)
    one = {int(measured[0]): truth[measured[0]]}
    shifted = sequential_block(block, m, plane, control=one)
    np.testing.assert_allclose(shifted.point_positions(m, truth.shape[0])[measured[0]], truth[measured[0]],
                               atol=1e-6)  # the single control point is met exactly ...
    shift = shifted.adjusted - shifted.internal
    shift = shift[np.isfinite(shift).all(axis=1)]  # points with no rectified solution stay NaN
    np.testing.assert_allclose(shift, np.broadcast_to(shift[0], shift.shape), atol=1e-6)  # ... by a pure shift
    no_control = np.sqrt(np.nanmean(np.sum((result.point_positions(m, truth.shape[0]) - truth) ** 2, 1)))
    with_control = np.sqrt(np.nanmean(np.sum((shifted.point_positions(m, truth.shape[0]) - truth) ** 2, 1)))
    assert with_control < no_control
