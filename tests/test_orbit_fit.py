import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import binom

from seaice_jax.adjust.engine.lsq import least_squares
from seaice_jax.adjust.engine.quality import global_test
from seaice_jax.adjust.orbit.fit import (
    DECREASE_TOLERANCE,
    ControlPoints,
    _observations,
    _predict,
    control_args,
    fit_scan_model,
    free_mask,
    initial_guess,
    orbit_solver,
    position_uncertainty,
)
from seaice_jax.errors import RankDeficiencyError, SeaiceError
from seaice_jax.geometry.earth import SOLAR_DAY
from seaice_jax.geometry.scan import Orbit
from seaice_jax.simulate.satellite import noaa_image, perturb_known_positions, simulate_control_points
from tests.helpers import FIT_LANES, vmapped_fits

DEG = np.pi / 180

# Source 001, Figure 3-3 (station number, pixel, scan, latitude, longitude in degrees and minutes)
STATIONS = [(3030, 164, 123, 75, 43, -78, 37), (3031, 114, 172, 75, 51, -81, 55), (3032, 165, 400, 73, 47, -84, 50),
            (3034, 348, 281, 72, 59, -75, 42), (3035, 199, 204, 74, 52, -79, 14)]


def figure_3_3_control():
    s = np.array(STATIONS, float)
    return ControlPoints.from_degrees(s[:, 1], s[:, 2], s[:, 3] + s[:, 4] / 60, s[:, 5] - s[:, 6] / 60, 1.0,
                                      [str(int(i)) for i in s[:, 0]])


FIGURE_3_3_ORBIT = Orbit.from_max_latitude(81.10 * DEG, 102.03 * 60.0, 0.0, earth_day=SOLAR_DAY)


def check_near_printed_solution(fit, rms_limit):
    model = fit.model
    assert fit.model.direction == "south"
    assert abs(float(model.subtrack_pixel) - 112) <= 5
    assert abs(float(model.ascending_node) / DEG - 66.65) <= 0.5
    assert abs(float(model.orbital_angle_first) / DEG - 99.47) <= 0.1
    assert abs(float(model.orbital_angle_last) / DEG - 104.08) <= 0.1
    assert fit.rms_km <= rms_limit


def test_figure_3_3_from_no_prior_knowledge():
    fit = fit_scan_model(figure_3_3_control(), FIGURE_3_3_ORBIT, direction="auto", n_pixels=512, n_scans=512)
    check_near_printed_solution(fit, rms_limit=1.25)
    assert set(fit.alternatives) == {"south", "north"}
    assert fit.alternatives["south"] < fit.alternatives["north"]
    # the printout's DEV 0.5687'/0.6017' is ~1.1 km; ours is as good within the rounding of the stations
    assert max(fit.dev_arcmin) < 0.9
    assert not fit.flagged_1985.any() and not fit.flagged_w_test().any()


def test_figure_3_3_appendix_c_baseline_reaches_a_solution():
    fit = fit_scan_model(figure_3_3_control(), FIGURE_3_3_ORBIT, direction="south", method="appendix_c",
                         n_pixels=512, n_scans=512)
    check_near_printed_solution(fit, rms_limit=1.5)
    assert fit.adjustment is None and fit.iterations > 1000


@pytest.mark.parametrize("direction", ["south", "north"])
@pytest.mark.parametrize("altitude", [0.0, 850_000.0])
def test_noise_free_simulation_recovers_the_truth_and_auto_finds_the_direction(direction, altitude):
    truth = noaa_image(direction, altitude)
    control, lat, lon = simulate_control_points(truth, 6, np.random.default_rng(3), 1000.0)
    exact = ControlPoints(control.pixel, control.scan, lat, lon, 1000.0, control.ids)
    fit = fit_scan_model(exact, truth.orbit, direction="auto", n_pixels=truth.n_pixels, n_scans=truth.n_scans)
    assert fit.model.direction == direction
    for name in ("scanner_angle_span", "orbital_angle_first", "orbital_angle_span", "ascending_node"):
        assert float(getattr(fit.model, name)) == pytest.approx(float(getattr(truth, name)), abs=1e-8)
    assert float(fit.model.subtrack_pixel) == pytest.approx(float(truth.subtrack_pixel), abs=1e-5)
    assert fit.rms_km < 1e-6


def test_appendix_c_on_a_simulation():
    """Following the manual (program estimates, and 1,1) the search reaches the simulated truth; from the
    program's C-1/C-2 estimates alone it diverges on this image."""
    truth = noaa_image("south")
    control, lat, lon = simulate_control_points(truth, 6, np.random.default_rng(5), 300.0)
    fit = fit_scan_model(control, truth.orbit, direction="south", method="appendix_c",
                         n_pixels=truth.n_pixels, n_scans=truth.n_scans)
    estimates_only = fit_scan_model(control, truth.orbit, direction="south", method="appendix_c",
                                    n_pixels=truth.n_pixels, n_scans=truth.n_scans,
                                    search_options={"initial_spans": None})
    assert estimates_only.rms_km > 100.0
    gauss_newton = fit_scan_model(control, truth.orbit, direction="south",
                                  n_pixels=truth.n_pixels, n_scans=truth.n_scans)
    assert abs(float(fit.model.subtrack_pixel) - float(truth.subtrack_pixel)) < 15
    assert fit.rms_km < 1.0
    assert gauss_newton.rms_km <= fit.rms_km + 1e-9  # least squares minimises exactly what RMS measures


def test_monte_carlo_scatter_matches_predicted_sigma():
    """>= 500 vmapped realizations: parameters and positions across the image within 10 %; global test ≈ α."""
    runs = 600
    truth = noaa_image("south")
    rng = np.random.default_rng(11)
    control, lat, lon = simulate_control_points(truth, 7, rng, 1500.0)
    solver = orbit_solver(control, truth)
    noisy_lat, noisy_lon = perturb_known_positions(lat, lon, 1500.0, rng, runs)
    args = control_args(ControlPoints(control.pixel, control.scan, lat, lon, 1500.0, control.ids))
    # in batches of the lanes the other tests' fits take: one compiled batch for all of them
    chunks = [vmapped_fits(solver, args, jnp.asarray(noisy_lat[k:k + FIT_LANES]),
                           jnp.asarray(noisy_lon[k:k + FIT_LANES])) for k in range(0, runs, FIT_LANES)]
    results = jax.tree_util.tree_map(lambda *parts: jnp.concatenate(parts), *chunks)
    assert bool(jnp.all(results.converged))
    names = solver.parameter_names
    estimates = np.stack([np.asarray(getattr(results.parameters, n)) for n in names], 1)
    predicted = np.sqrt(np.diag(np.asarray(results.cofactor).mean(axis=0)))
    ratio = estimates.std(axis=0, ddof=1) / predicted
    assert np.all(np.abs(ratio - 1) < 0.10), dict(zip(names, ratio, strict=True))
    # positions across the image: predicted σ (north, east) by propagation vs the scatter of the positions
    grid_p, grid_s = np.meshgrid(np.linspace(1, 512, 4), np.linspace(1, 512, 4))
    from seaice_jax.adjust.orbit.fit import OrbitFit
    first = jax.tree_util.tree_map(lambda x: x[0], results)
    fit = OrbitFit(truth, control, "gauss-newton", 0, first)
    sigma_north, sigma_east = (np.asarray(a) for a in
                               position_uncertainty(fit, grid_p, grid_s, a_priori=True))
    lat_runs, lon_runs = jax.vmap(lambda m: m.forward(jnp.asarray(grid_p), jnp.asarray(grid_s)))(results.parameters)
    radius = float(truth.orbit.radius)
    scatter_north = np.asarray(lat_runs).std(axis=0, ddof=1) * radius
    scatter_east = np.asarray(lon_runs).std(axis=0, ddof=1) * radius * np.cos(np.asarray(lat_runs).mean(0))
    np.testing.assert_allclose(scatter_north / sigma_north, 1.0, atol=0.10)
    np.testing.assert_allclose(scatter_east / sigma_east, 1.0, atol=0.10)
    _, _, accepted = global_test(np.asarray(results.sigma0) ** 2, solver.degrees_of_freedom, 0.05)
    low, high = binom.ppf([0.001, 0.999], runs, 0.05)
    assert low <= int(np.sum(~np.asarray(accepted))) <= high


def test_quality_control_redundancy_and_a_planted_blunder():
    truth = noaa_image("south")
    rng = np.random.default_rng(21)
    control, lat, lon = simulate_control_points(truth, 8, rng, 500.0)
    fit = fit_scan_model(control, truth.orbit, direction="south", n_pixels=truth.n_pixels, n_scans=truth.n_scans)
    assert fit.adjustment is not None
    total = sum(float(np.sum(r)) for r in fit.adjustment.redundancy.values())
    assert total == pytest.approx(fit.adjustment.degrees_of_freedom, abs=1e-9)
    blundered_lat = np.asarray(control.latitude).copy()
    blundered_lat[4] += 10 * 500.0 / float(truth.orbit.radius)
    bad = ControlPoints(control.pixel, control.scan, blundered_lat, control.longitude, 500.0, control.ids)
    fit = fit_scan_model(bad, truth.orbit, direction="south", n_pixels=truth.n_pixels, n_scans=truth.n_scans)
    w = np.maximum(*(np.abs(a) for a in fit.w_statistics()))
    assert fit.flagged_w_test()[4] and int(np.argmax(w)) == 4  # data snooping names P5 first
    assert not fit_scan_model(control, truth.orbit, direction="south",
                              n_pixels=truth.n_pixels, n_scans=truth.n_scans).flagged_w_test().any()


def test_two_control_points_name_the_undetermined_parameters():
    truth = noaa_image("south")
    control, _, _ = simulate_control_points(truth, 2, np.random.default_rng(1))
    with pytest.raises(RankDeficiencyError, match="cannot determine") as info:
        fit_scan_model(control, truth.orbit, direction="south", n_pixels=truth.n_pixels, n_scans=truth.n_scans)
    assert set(info.value.parameters) <= {"scanner_angle_span", "subtrack_pixel", "orbital_angle_first",
                                          "orbital_angle_span", "ascending_node"}
    assert len(info.value.parameters) >= 2


def test_collinear_control_points_name_the_undetermined_parameters():
    truth = noaa_image("south")
    pixel = np.array([50.0, 150.0, 250.0, 350.0, 450.0])
    scan = np.full(5, 256.0)  # all on one scan line: the orbital-angle rate is not determined
    lat, lon = (np.asarray(a) for a in truth.forward(pixel, scan))
    control = ControlPoints(pixel, scan, lat, lon, 500.0)
    with pytest.raises(RankDeficiencyError) as info:
        fit_scan_model(control, truth.orbit, direction="south", n_pixels=truth.n_pixels, n_scans=truth.n_scans)
    assert "orbital_angle_span" in info.value.parameters


def test_bad_control_points_are_named():
    with pytest.raises(SeaiceError, match="control point B: duplicate id"):
        ControlPoints([1, 2, 3], [1, 2, 3], [0.1, 0.2, 0.3], [0, 0, 0], 1000.0, ["A", "B", "B"])
    with pytest.raises(SeaiceError, match=r"control point C: latitude 114.5916° is outside"):
        ControlPoints([1, 2, 3], [1, 2, 3], [0.1, 0.2, 2.0], [0, 0, 0], 1000.0, ["A", "B", "C"])
    with pytest.raises(SeaiceError, match="control point 2: scan is not a finite number"):
        ControlPoints([1, 2, 3], [1, np.nan, 3], [0.1, 0.2, 0.3], [0, 0, 0])
    with pytest.raises(SeaiceError, match="direction must be"):
        fit_scan_model(figure_3_3_control(), FIGURE_3_3_ORBIT, direction="east", n_pixels=512, n_scans=512)


def test_control_points_join_and_subset_keep_every_field_and_refuse_a_repeated_id():
    control = figure_3_3_control()
    both = control.joined(control, "again ")
    assert len(both) == 10 and both.ids[5] == "again 3030"
    np.testing.assert_array_equal(np.asarray(both.latitude), np.tile(np.asarray(control.latitude), 2))
    part = both.subset(np.arange(10) % 3 == 1)
    assert part.ids == ("3031", "3035", "again 3032")
    for name in ("pixel", "scan", "latitude", "longitude", "sigma"):
        np.testing.assert_array_equal(np.asarray(getattr(part, name)), np.asarray(getattr(both, name))[[1, 4, 7]])
    with pytest.raises(SeaiceError, match="control point 3030: duplicate id"):
        control.joined(control)


@pytest.fixture(scope="module")
def noisy_batch():
    """A simulated southbound image, 7 control points (σ 1 km), the solver from the fit's own start and 40 noisy
    realizations of the known positions."""
    truth = noaa_image("south")
    rng = np.random.default_rng(18)
    control, lat, lon = simulate_control_points(truth, 7, rng, 1000.0)
    solver = orbit_solver(control, fit_scan_model(control, truth.orbit, direction="south",
                                                  n_pixels=truth.n_pixels, n_scans=truth.n_scans).model)
    lats, lons = perturb_known_positions(lat, lon, 1000.0, rng, FIT_LANES)
    return solver, control_args(control), jnp.asarray(lats), jnp.asarray(lons)


def test_vmapped_fits_equal_the_single_fits(noisy_batch):
    """A lane of the vmapped solver is the single solver on the same data: the estimates equal to 1e-6 of their σ
    and the covariances to 1e-9 (the converged lanes keep their state while the others iterate)."""
    solver, args, lats, lons = noisy_batch
    batch = vmapped_fits(solver, args, lats, lons)
    single = jax.jit(lambda a, b: solver({"latitude": a, "longitude": b}, args))
    for k in range(0, lats.shape[0], 4):
        one = single(lats[k], lons[k])
        sigma = np.sqrt(np.diag(np.asarray(one.covariance)))
        for i, name in enumerate(solver.parameter_names):
            difference = float(getattr(batch.parameters, name)[k]) - float(getattr(one.parameters, name))
            assert abs(difference) <= 1e-6 * sigma[i], (k, name, difference / sigma[i])
        np.testing.assert_allclose(np.asarray(batch.covariance[k]), np.asarray(one.covariance), rtol=1e-9)


def test_rounding_of_the_square_sum_does_not_start_the_damping(noisy_batch):
    """Residuals of longitudes (≈ 1.5 rad) with σ ≈ 1.6e-4 rad carry 1e-12 of the square sum as rounding: a last
    Gauss-Newton step within it is taken, not refused and damped for ten more steps. Every fit ends at a
    stationary point (the gradient Jᵀe at rounding level) within a few steps."""
    solver, args, lats, lons = noisy_batch
    batch = vmapped_fits(solver, args, lats, lons)
    assert bool(jnp.all(batch.converged))
    assert int(jnp.max(batch.steps)) <= 6
    for k in range(0, lats.shape[0], 8):
        observed = {"latitude": lats[k], "longitude": lons[k]}
        x = solver.flatten(jax.tree_util.tree_map(lambda leaf, k=k: leaf[k], batch.parameters))
        jacobian = np.asarray(solver.jacobian_at(x, observed, args))
        residuals = np.asarray(solver.residuals(x, observed, args))
        gradient = jacobian.T @ residuals / np.linalg.norm(jacobian, axis=0)  # per column-scaled unknown
        assert np.max(np.abs(gradient)) < 1e-7 * np.linalg.norm(residuals)


def test_the_fits_stop_within_a_billionth_of_sigma_of_the_minimum():
    """The fits stop when the Gauss-Newton step left is below DECREASE_TOLERANCE (1e-6) of the estimates' σ;
    Gauss-Newton gains about three decades an iteration on these fits, so from the control points' own start the
    estimates agree with fits iterated to the engine's tightest test (1e-12 σ, or the square sum's rounding) to
    1e-8 σ, and never take more iterations."""
    truth = noaa_image("south")
    rng = np.random.default_rng(7)
    control, lat, lon = simulate_control_points(truth, 7, rng, 1000.0)
    start = initial_guess(control, truth.orbit, "south", truth.n_pixels, truth.n_scans)
    lats, lons = (jnp.asarray(a) for a in perturb_known_positions(lat, lon, 1000.0, rng, FIT_LANES))
    stopped, strict = (vmapped_fits(orbit_solver(control, start, decrease_tolerance=tolerance), control_args(control),
                              lats, lons) for tolerance in (DECREASE_TOLERANCE, 1e-12))
    assert bool(jnp.all(stopped.converged)) and bool(jnp.all(strict.converged))
    assert int(jnp.max(stopped.steps)) <= int(jnp.max(strict.steps))
    sigma = np.sqrt(np.diagonal(np.asarray(strict.covariance), axis1=1, axis2=2))
    for i, name in enumerate(strict.parameter_names):
        difference = np.asarray(getattr(stopped.parameters, name)) - np.asarray(getattr(strict.parameters, name))
        assert np.max(np.abs(difference) / sigma[:, i]) <= 1e-8, name


def test_padding_the_control_points_changes_no_result():
    """The fit pads its 6 control points to 8 rows (σ = ∞: no observation, one compiled fit for 5-8 points); its
    adjustment is the one set up on the 6 points alone: estimates, covariance, σ̂0, degrees of freedom, and each
    point's residual, redundancy number, w-statistic, MDB and w-partner."""
    truth = noaa_image("south")
    control, _, _ = simulate_control_points(truth, 6, np.random.default_rng(9), 800.0)
    fit = fit_scan_model(control, truth.orbit, direction="south",
                         n_pixels=truth.n_pixels, n_scans=truth.n_scans).adjustment
    start = initial_guess(control, truth.orbit, "south", truth.n_pixels, truth.n_scans)
    alone = least_squares(_predict, start, _observations(control, truth.orbit.radius), args=control_args(control),
                          free=free_mask(start), decrease_tolerance=DECREASE_TOLERANCE, strategy="damped")
    assert fit is not None and fit.degrees_of_freedom == alone.degrees_of_freedom == 2 * 6 - 5
    sigma = np.sqrt(np.diag(np.asarray(alone.covariance)))
    for i, name in enumerate(alone.parameter_names):
        assert abs(float(getattr(fit.parameters, name)) - float(getattr(alone.parameters, name))) < 1e-9 * sigma[i]
    np.testing.assert_allclose(fit.covariance, alone.covariance, rtol=1e-9)
    assert float(fit.sigma0) == pytest.approx(float(alone.sigma0), rel=1e-9)
    for table in ("residuals", "redundancy", "standardized_residuals", "minimal_detectable_bias", "w_correlation"):
        for group in ("latitude", "longitude"):
            ours, theirs = (np.asarray(getattr(a, table)[group]) for a in (fit, alone))
            assert ours.shape == (6,)
            np.testing.assert_allclose(ours, theirs, rtol=1e-7, atol=1e-12 * np.max(np.abs(theirs)))
    for group in ("latitude", "longitude"):
        np.testing.assert_array_equal(fit.w_partner[group], alone.w_partner[group])


def test_northbound_fit_is_the_direct_northbound_adjustment():
    """The fit runs both directions as one southbound problem (the span's sign carries the direction); its
    northbound answer, covariance included, equals the adjustment set up with the northbound model itself, started
    from the control points' own northbound start (not from the answer)."""
    truth = noaa_image("north")
    control = simulate_control_points(truth, 8, np.random.default_rng(5), 800.0)[0]
    fit = fit_scan_model(control, truth.orbit, direction="north", n_pixels=truth.n_pixels, n_scans=truth.n_scans)
    assert fit.model.direction == "north" and float(fit.model.orbital_angle_span) > 0
    assert fit.adjustment is not None
    start = initial_guess(control, truth.orbit, "north",
                          truth.n_pixels, truth.n_scans)  # the northbound model itself, from the control's start
    assert start.direction == "north"
    direct = orbit_solver(control, start)({"latitude": control.latitude, "longitude": control.longitude},
                                          control_args(control))
    for name in direct.parameter_names:
        assert float(getattr(fit.model, name)) == pytest.approx(float(getattr(direct.parameters, name)), rel=1e-9,
                                                                abs=1e-11)
    sigma = np.sqrt(np.diag(np.asarray(direct.covariance)))
    np.testing.assert_allclose(np.asarray(fit.adjustment.covariance) / np.outer(sigma, sigma),
                               np.asarray(direct.covariance) / np.outer(sigma, sigma), atol=1e-6)
