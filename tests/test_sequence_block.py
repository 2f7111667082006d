"""The simultaneous adjustment of a sequence on the engine: the truth returned from noise-free observations,
planted mismatched ties found and removed, and the joint covariance (across images) checked by Monte Carlo."""

from dataclasses import replace

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest
import xarray as xr

from seaice_jax.adjust import engine
from seaice_jax.adjust.engine import schur
from seaice_jax.adjust.engine.problem import Problem
from seaice_jax.adjust.sequence.adjustment import (
    SequenceOptions,
    adjust_sequence,
    correlated_tie_covariance,
    phase_tie_covariance,
    sequence_problem,
    systematic_tie_covariance,
)
from seaice_jax.adjust.sequence.control_test import control_test
from seaice_jax.adjust.sequence.model import (
    scan_unknowns,
    sequence_observations,
    with_scan_unknowns,
)
from seaice_jax.cli import main
from seaice_jax.errors import SeaiceError
from seaice_jax.io.remapped import load_models, load_remapped, save_models
from seaice_jax.io.sequence import read_sequence
from seaice_jax.sensors.control import ControlPoints
from seaice_jax.simulate.satellite import noaa_pass
from tests.helpers import lattice_ties, sequence_rows, whitened_jacobians

SIZE = 256
LATITUDE, LONGITUDE = np.radians(74.0), np.radians(-85.0)
START_SIGMA = np.array([2e-4, 0.5, 2e-4, 2e-4, 3e-4])
"""σ of the starting models' unknowns (radians, pixel): 1-2 pixels of geolocation error."""
POINTING = 0.3  # pixels, σ of a tie observation
INDEPENDENT = SequenceOptions(tie_correlation=1.0, tie_offset_factor=0.0, tie_gradient_factor=0.0,
                              tie_phase_sigma=0.0)
"""The simulated ties here have independent errors: no terms for the matcher's correlated ones."""


def make_sequence(lattice=13):
    """Three passes (south, north, south) ~40 km apart; ties on a ground lattice seen by two or three of them
    (exact pixel and scan by the true models); six exact control points per image at σ 500 m."""
    offsets = [(0.0, 0.0), (0.3, 0.8), (-0.25, -0.6)]
    models = [noaa_pass(direction, SIZE, LATITUDE + np.radians(a), LONGITUDE + np.radians(b))
              for direction, (a, b) in zip(("south", "north", "south"), offsets, strict=True)]
    lat, lon = np.meshgrid(LATITUDE + np.radians(np.linspace(-1.8, 1.8, lattice)),
                           LONGITUDE + np.radians(np.linspace(-6.0, 6.0, lattice)), indexing="ij")
    lat, lon = lat.ravel(), lon.ravel()
    ties = lattice_ties(models, lat, lon, SIZE, POINTING, POINTING)
    rng = np.random.default_rng(7)
    controls = []
    for model in models:
        pixel, scan = rng.uniform(10, SIZE - 10, (2, 6))
        a, b = (np.asarray(v) for v in model.forward(pixel, scan))
        controls.append(ControlPoints(pixel, scan, a, b, 500.0))
    return models, ties, controls


@pytest.fixture(scope="module")
def truth():
    return make_sequence()


def perturbed(models, rng, scale=1.0):
    return [with_scan_unknowns(m, scan_unknowns(m) + rng.normal(0, scale * START_SIGMA)) for m in models]


def true_theta(models):
    return np.stack([np.asarray(scan_unknowns(m)) for m in models])


def noisy(ties, rng, sigma=POINTING):
    return replace(ties, pixel=ties.pixel + rng.normal(0, sigma, ties.pixel.size),
                   scan=ties.scan + rng.normal(0, sigma, ties.scan.size))


def test_noise_free_sequence_returns_the_true_models(truth, rng):
    models, ties, controls = truth
    # exact data: no variance factor to estimate (every residual vanishes)
    result = adjust_sequence(perturbed(models, rng), ties, controls, options=replace(INDEPENDENT, variance_groups=()))
    assert result.n_removed == 0 and result.rounds == 1
    theta = true_theta(models)
    assert np.all(np.abs(result.theta - theta) <= 1e-8 * np.maximum(np.abs(theta), 1.0)), result.theta - theta
    np.testing.assert_allclose(result.tie_latitude, ties.latitude, atol=1e-10)
    np.testing.assert_allclose(result.tie_longitude, ties.longitude, atol=1e-10)
    p, s = np.meshgrid(np.linspace(1, SIZE, 5), np.linspace(1, SIZE, 5))
    for model, fitted in zip(models, result.models, strict=True):
        np.testing.assert_allclose(np.asarray(fitted.forward(p, s)), np.asarray(model.forward(p, s)), atol=1e-9)
    assert result.covariance.shape == (15, 15)
    assert result.sigma0 < 1e-5  # noise free
    assert result.names[5] == "image1." + result.names[0].split(".")[1]


def _plant(ties, rng, fraction=0.05):
    """Shift one observation of ``fraction`` of the ties by 5-20 pixels in a random direction."""
    count = max(1, round(fraction * ties.latitude.size))
    chosen = rng.choice(ties.latitude.size, count, replace=False)
    pixel, scan = ties.pixel.copy(), ties.scan.copy()
    for t in chosen:
        row = rng.choice(np.nonzero(ties.tie == t)[0])
        length, angle = rng.uniform(5, 20), rng.uniform(0, 2 * np.pi)
        pixel[row] += length * np.cos(angle)
        scan[row] += length * np.sin(angle)
    return replace(ties, pixel=pixel, scan=scan), set(int(t) for t in chosen)


@pytest.mark.parametrize("robust", [None, "danish"])
def test_planted_mismatches_are_all_removed(truth, rng, robust):
    models, ties, controls = truth
    clean = noisy(ties, rng)
    bad, planted = _plant(clean, rng)
    start = perturbed(models, rng)
    reference = adjust_sequence(start, clean, controls, options=INDEPENDENT)
    result = adjust_sequence(start, bad, controls, options=replace(INDEPENDENT, robust=robust))
    removed = set(result.removed_ties)
    assert planted <= removed, planted - removed
    # at α = 0.001 over ~1000 tie components a false removal or two is expected, not more
    assert len(removed - planted) <= 0.02 * ties.latitude.size + 1, removed - planted
    assert not [f for f in result.flagged() if f.group.startswith("ties")]
    sigma = np.sqrt(np.diag(reference.covariance)).reshape(-1, 5)
    assert np.all(np.abs(result.theta - reference.theta) <= sigma), (result.theta - reference.theta) / sigma
    assert np.all(np.isnan(result.tie_latitude[sorted(removed)]))


def test_joint_covariance_matches_monte_carlo(truth):
    """300 noise draws of ties and control points, each adjusted (the compiled solve reused): the empirical
    covariance of the estimates, whitened by the stated cofactor, is the identity — the blocks between images
    included — and those cross-image correlations are large enough for the test to see them."""
    models, ties, controls = truth
    problem = sequence_problem(sequence_observations(models, ties, controls))
    options = engine.EngineOptions(backend="schur")
    cofactor = np.asarray(engine.solve(problem, options).cofactor)
    correlation = cofactor / np.sqrt(np.outer(np.diag(cofactor), np.diag(cofactor)))
    assert np.abs(correlation[:5, 5:]).max() > 0.3, "the images' errors should be correlated through the ties"
    layout = schur.schur_layout(problem)
    dof = engine.degrees_of_freedom(problem)
    draws = 300
    noise_rng = np.random.default_rng(5)
    estimates = []
    for _ in range(draws):
        blocks = {}
        for name, block in problem.blocks.items():
            sigma = np.asarray(block.sigma)
            noise = np.where(np.isfinite(sigma), noise_rng.normal(size=sigma.shape) * sigma, 0.0)  # not padding
            data = dict(block.data)
            if name.startswith("ties"):
                data["pixel"], data["scan"] = data["pixel"] + noise[:, 0], data["scan"] + noise[:, 1]
            else:  # control: the known position moved by (north, east) metres
                radius = data["orbit"].radius
                data["longitude"] = data["longitude"] + noise[:, 1] / (radius * jnp.cos(data["latitude"]))
                data["latitude"] = data["latitude"] + noise[:, 0] / radius
            blocks[name] = eqx.tree_at(lambda b: b.data, block, data)
        solved = engine.solve(Problem(blocks, problem.start, problem.points), options, layout=layout, dof=dof)
        estimates.append(np.asarray(solved.parameters["theta"]))
    errors = np.array(estimates) - np.ravel(true_theta(models))
    z = errors @ np.linalg.inv(np.linalg.cholesky(cofactor)).T
    empirical = z.T @ z / draws
    # each entry of a Wishart(I)/N has σ ≈ 1/√N (diagonal √2/√N)
    assert np.abs(empirical - np.eye(15)).max() < 5.0 / np.sqrt(draws), np.round(empirical, 2)
    # the cross-image block on its own, in correlation units
    sample = np.cov(errors.T)
    sample_correlation = sample / np.sqrt(np.outer(np.diag(sample), np.diag(sample)))
    assert np.abs(sample_correlation[:5, 5:] - correlation[:5, 5:]).max() < 4.5 / np.sqrt(draws)


def test_the_ties_variance_factor_is_estimated_and_carried_into_the_covariance(truth, rng):
    """Ties three times better than their stated σ (0.1 against 0.3 pixel), control points noisy by their stated
    σ: the ties' variance factor comes out (1/3)² within 3 of its σ and the covariance is the cofactor of the problem
    with the ties' true σ (which the Monte Carlo test above shows to be the estimates' covariance) within 10 %. The
    global σ̂0² Q instead shrinks the control points' part with the ties' factor: off by more than 30 %."""
    models, ties, controls = truth
    observed = noisy(ties, rng, POINTING / 3)
    radius = float(models[0].orbit.radius)
    noisy_controls = [noisy_control(c, rng, radius) for c in controls]
    start = perturbed(models, rng)
    result = adjust_sequence(start, observed, noisy_controls, options=INDEPENDENT)
    assert len(result.variance_factors) == 2  # one per pass direction's tie group, no control group
    components = result.adjustment.variance_components
    assert components is not None
    (label, pooled), = components.items()  # the two tie groups share one factor (they meet only in differences)
    assert set(label.split("+")) == set(result.variance_factors)
    for group, factor in result.variance_factors.items():
        assert factor == pytest.approx(pooled.value, rel=1e-12)
        assert abs(factor - 1 / 9) < 3 * factor * np.sqrt(2 / pooled.redundancy), (group, factor, pooled.redundancy)
    right = replace(observed, sigma_pixel=observed.sigma_pixel / 3, sigma_scan=observed.sigma_scan / 3)
    expected = np.asarray(engine.solve(sequence_problem(sequence_observations(result.models, right, noisy_controls)),
                                       engine.EngineOptions(backend="schur")).cofactor)
    ratio = np.sqrt(np.diag(result.covariance) / np.diag(expected))
    assert np.all(np.abs(ratio - 1) < 0.1), ratio
    before = adjust_sequence(start, observed, noisy_controls, options=replace(INDEPENDENT, variance_groups=()))
    assert np.abs(np.sqrt(np.diag(before.covariance) / np.diag(expected)) - 1).max() > 0.3


def noisy_control(control: ControlPoints, rng, radius) -> ControlPoints:
    """``control`` with its known positions moved by N(0, σ) metres north and east."""
    north, east = rng.normal(size=(2, len(control))) * np.asarray(control.sigma)
    latitude = np.asarray(control.latitude) + north / radius
    longitude = np.asarray(control.longitude) + east / (radius * np.cos(np.asarray(control.latitude)))
    return ControlPoints(control.pixel, control.scan, latitude, longitude, control.sigma, control.ids)


def _design_line(n_theta, n_ties, image, j_theta, tie, j_point):
    """One whitened row of the dense design over θ (5 per image) and the tie points (2 each; ``tie`` None: none)."""
    line = np.zeros(n_theta + 2 * n_ties)
    line[5 * image:5 * image + 5] = j_theta
    if tie is not None:
        line[n_theta + 2 * tie:n_theta + 2 * tie + 2] = j_point
    return line


def _dense_tie_sandwich(result, correlation, factors):
    """The θ block of (AᵀA)⁻¹ Aᵀ C A (AᵀA)⁻¹ for the whitened dense design A of every unknown (θ and the tie
    points, nothing eliminated) at the solution, C = κ I + Σ_pairs U S (UᵀU)⁻¹ S Uᵀ on the tie rows (U: per pair
    (reference image, matched image) and axis, the whitened offset and the two gradients about the pair's centroid
    per image width, on the matched observations; S = diag(√``factors``)) and I on the others."""
    observations = result.observations
    n_theta, n_ties = result.covariance.shape[0], observations.n_ties
    points = result.adjustment.parameters["points"][:n_ties]
    design, noise, fields = [], [], {}
    for group in observations.groups.values():
        _, j_theta, j_point = whitened_jacobians(group, result.theta, points)
        sigma, image = np.asarray(group.sigma), sequence_rows(group)[0]
        for row in range(group.rows):
            for axis in range(group.sigma.shape[1]):
                tie = None if group.point_index is None else int(group.point_index[row])
                line = _design_line(n_theta, n_ties, int(image[row]), j_theta[row, axis], tie, j_point[row, axis])
                if tie is not None:
                    first = int(observations.reference_image[tie])
                    if first != image[row] and np.isfinite(sigma[row, axis]):
                        fields.setdefault((first, int(image[row]), axis), []).append(
                            (len(design), float(group.data["pixel"][row]), float(group.data["scan"][row]),
                             sigma[row, axis]))
                noise.append(correlation if group.point_index is not None else 1.0)
                design.append(line)
    design, basis = np.array(design), []
    for rows in fields.values():
        index, pixel, scan, sigma = (np.array(a) for a in zip(*rows, strict=True))
        columns = np.zeros((len(design), 3))
        columns[index] = np.stack([np.ones(index.size), (pixel - pixel.mean()) / SIZE,
                                   (scan - scan.mean()) / SIZE], 1) / sigma[:, None]
        scale = np.diag(np.sqrt(factors))
        basis.append(columns @ np.linalg.cholesky(scale @ np.linalg.inv(columns.T @ columns) @ scale))
    basis = np.concatenate(basis, axis=1)
    norms = np.linalg.norm(design, axis=0)  # columns of radians and metres: equilibrated before inverting
    norms = np.where(norms > 0, norms, 1.0)  # removed ties' points are unobserved: pinv leaves them out
    design = design / norms
    inverse = np.linalg.pinv(design.T @ design)
    middle = design.T @ (np.array(noise)[:, None] * design) + (design.T @ basis) @ (basis.T @ design)
    return (inverse @ middle @ inverse)[:n_theta, :n_theta] / np.outer(norms[:n_theta], norms[:n_theta])


@pytest.mark.slow
def test_correlated_and_systematic_tie_errors_give_the_dense_sandwich_covariance(truth, rng):
    """The covariance with correlated (κ = 2) and systematic tie errors (per pair fields, η 30 / 10) against the
    estimator's covariance computed independently on the dense design of every unknown (no Schur elimination;
    :func:`_dense_tie_sandwich`); without both terms the covariance is Q."""
    models, ties, controls = truth
    observed = noisy(ties, rng)
    start = perturbed(models, rng)
    options = SequenceOptions(tie_correlation=2.0, tie_offset_factor=30.0, tie_gradient_factor=10.0,
                              tie_phase_sigma=0.0)
    result = adjust_sequence(start, observed, controls, options=options)
    expected = _dense_tie_sandwich(result, 2.0, (30.0, 10.0, 10.0))
    scale = np.sqrt(np.outer(np.diag(expected), np.diag(expected)))
    # in correlation units: the engine's Q itself agrees with the dense inverse to ~0.2 % (the last step's
    # linearization); the terms checked here are 30 % or more of the diagonal
    assert np.abs((result.covariance - expected) / scale).max() < 0.01
    assert np.all(np.diag(result.systematic) > 0.3 * np.diag(result.cofactor))
    plain = adjust_sequence(start, observed, controls, options=replace(options, tie_correlation=1.0,
                                                                        tie_offset_factor=0.0,
                                                                        tie_gradient_factor=0.0))
    np.testing.assert_array_equal(plain.systematic, 0.0)
    np.testing.assert_allclose(plain.covariance, plain.cofactor)


def test_bad_options_are_named():
    with pytest.raises(SeaiceError, match="batch"):
        SequenceOptions(batch=0.0)
    with pytest.raises(SeaiceError, match="robust"):
        SequenceOptions(robust="tukey")
    with pytest.raises(SeaiceError, match="tie_correlation"):
        SequenceOptions(tie_correlation=0.5)
    with pytest.raises(SeaiceError, match="tie_offset_factor"):
        SequenceOptions(tie_gradient_factor=-0.1)


@pytest.mark.slow
def test_cli_adjust_then_remap_adopts_the_joint_covariance(tmp_path, capsys):
    """``seaice simulate lancaster`` writes the truth (land cells do not move, pack cells do); ``seaice adjust``
    writes models whose covariance couples the images (per image: block diagonal) and reports the control points'
    test against the ties; ``seaice remap --models`` adopts them, and a models file of other images is refused
    naming the file."""
    project = tmp_path / "seq" / "sequence.toml"
    assert main(["--no-compile-cache", "simulate", "lancaster", "--out", str(project.parent), "--images", "2",
                 "--size", "256"]) == 0
    with xr.open_dataset(project.parent / "truth" / "drift_IMG01_IMG02.nc") as truth_drift:
        dx = truth_drift["dX"].values[0]
    land = np.load(project.parent / "land_mask.npy")
    assert np.abs(dx[land]).max() < 1e-3 and np.abs(dx[~np.load(project.parent / "static_mask.npy")]).max() > 1000.0
    for method in ("simultaneous", "per-image"):
        assert main(["--no-compile-cache", "adjust", str(project), "--out", str(tmp_path / method), "--method",
                     method]) == 0
        reported = capsys.readouterr().out
        assert ("control points against the ties and the other images" in reported) == (method == "simultaneous")
    sequence = read_sequence(project)
    _, joint, _ = load_models(tmp_path / "simultaneous" / "models.npz", sequence)
    _, separate, _ = load_models(tmp_path / "per-image" / "models.npz", sequence)
    assert np.abs(joint[:5, 5:]).max() > 0 and np.all(separate[:5, 5:] == 0)
    correlation = joint / np.sqrt(np.outer(np.diag(joint), np.diag(joint)))
    assert np.abs(correlation[:5, 5:]).max() > 0.1
    assert main(["--no-compile-cache", "remap", str(project), "--models",
                 str(tmp_path / "simultaneous" / "models.npz"), "--out", str(tmp_path / "remapped"), "--quiet"]) == 0
    np.testing.assert_array_equal(load_remapped(tmp_path / "remapped").covariance, joint)
    models, _, _ = load_models(tmp_path / "simultaneous" / "models.npz", sequence)
    save_models(tmp_path / "other.npz", ["A", "B"], models, joint, 1.0, "simultaneous")
    with pytest.raises(SeaiceError, match="other.npz: images"):
        load_models(tmp_path / "other.npz", sequence)


@pytest.mark.slow
def test_warm_started_rounds_reach_the_final_problems_own_solution(truth, rng):
    """Every round of removal and variance estimation starts from the previous round's estimates: the result is
    the solution of the final problem (its ties removed, its σ rescaled) solved afresh from the original start (1-2
    pixels off), to 1e-3 of its σ (the last variance factors' update, below ``variance_tolerance``, moves it by
    about 1e-5 σ), and the same ties are removed from a start twice as far."""
    models, ties, controls = truth
    bad, planted = _plant(noisy(ties, rng), rng)
    start = perturbed(models, rng)
    result = adjust_sequence(start, bad, controls, options=INDEPENDENT)
    assert result.rounds >= 3 and planted <= set(result.removed_ties)
    cold = engine.solve(sequence_problem(result.observations), engine.EngineOptions(backend="schur"), result.names)
    sigma = np.sqrt(np.diag(result.cofactor))
    np.testing.assert_array_less(np.abs(result.theta.ravel() - np.asarray(cold.parameters["theta"])), 1e-3 * sigma)
    farther = adjust_sequence(perturbed(models, rng, 2.0), bad, controls, options=INDEPENDENT)
    assert farther.removed_ties == result.removed_ties
    np.testing.assert_array_less(np.abs(farther.theta - result.theta).ravel(), 1e-3 * sigma)


def _dense_phase_sandwich(result, start, phase_sigma):
    """The θ block of (AᵀA)⁻¹ Aᵀ (I + Σ V Vᵀ) A (AᵀA)⁻¹ for the whitened dense design A of every unknown (θ and the
    tie points, nothing eliminated) at the solution, V per pair (reference image a, matched image b) and axis of b
    the whitened ``phase_sigma`` (cos 2πd, sin 2πd) on b's observations of the ties matched against a, d the shift
    of the tie's reference observation carried from a to b through the ``start`` models less through the adjusted
    ones (through the models' forward and inverse, elementwise: one call per pair of images)."""
    observations = result.observations
    n_theta, n_ties = result.covariance.shape[0], observations.n_ties
    points = result.adjustment.parameters["points"][:n_ties]
    reference = {}
    for group in observations.groups.values():
        if group.point_index is not None:
            for row in range(group.rows):
                tie, image = int(group.point_index[row]), int(sequence_rows(group)[0][row])
                if image == int(observations.reference_image[tie]):
                    reference[tie] = (float(group.data["pixel"][row]), float(group.data["scan"][row]))
    wanted = {}  # (first, second): [(group, row, tie)] of the observations in second of ties referenced in first
    for name, group in observations.groups.items():
        if group.point_index is not None:
            for row in range(group.rows):
                tie = int(group.point_index[row])
                first, second = int(observations.reference_image[tie]), int(sequence_rows(group)[0][row])
                if first != second:
                    wanted.setdefault((first, second), []).append((name, row, tie))
    shifts = {}
    for (first, second), rows in wanted.items():
        pixel, scan = (np.array([reference[tie][axis] for _, _, tie in rows]) for axis in (0, 1))
        carried = [np.stack([np.asarray(v) for v in models[second].inverse(*models[first].forward(pixel, scan))],
                            axis=1) for models in (start, result.models)]
        shifts.update({(name, row): (first, second, d) for (name, row, _), d in zip(rows, carried[0] - carried[1],
                                                                                   strict=True)})
    design, fields = [], {}
    for name, group in observations.groups.items():
        _, j_theta, j_point = whitened_jacobians(group, result.theta, points)
        sigma, image = np.asarray(group.sigma), sequence_rows(group)[0]
        for row in range(group.rows):
            first, second, shift = shifts.get((name, row), (None, None, None))
            for axis in range(group.sigma.shape[1]):
                tie = None if group.point_index is None else int(group.point_index[row])
                line = _design_line(n_theta, n_ties, int(image[row]), j_theta[row, axis], tie, j_point[row, axis])
                if shift is not None and np.isfinite(sigma[row, axis]):
                    phase = 2 * np.pi * shift[axis]
                    fields.setdefault((first, second, axis), []).append(
                        (len(design), phase_sigma * np.array([np.cos(phase), np.sin(phase)]) / sigma[row, axis]))
                design.append(line)
    design = np.array(design)
    basis = []
    for rows in fields.values():
        columns = np.zeros((len(design), 2))
        for index, values in rows:
            columns[index] = values
        basis.append(columns)
    basis = np.concatenate(basis, axis=1)
    norms = np.linalg.norm(design, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    design = design / norms
    inverse = np.linalg.pinv(design.T @ design)
    middle = design.T @ design + (design.T @ basis) @ (basis.T @ design)
    return (inverse @ middle @ inverse)[:n_theta, :n_theta] / np.outer(norms[:n_theta], norms[:n_theta])


def test_phase_dependent_tie_bias_gives_the_dense_sandwich_covariance(truth, rng):
    """The covariance with the matches' phase-dependent sub-pixel bias (per pair and axis c₁ cos 2πd + c₂ sin 2πd,
    σ 0.3 pixel, d from the starting and the adjusted models) against the estimator's covariance computed
    independently on the dense design (no Schur elimination, d carried point by point;
    :func:`_dense_phase_sandwich`); the term is a large part of it, and it is 0 with ``tie_phase_sigma=0``."""
    models, ties, controls = truth
    observed = noisy(ties, rng)
    start = perturbed(models, rng)
    options = replace(INDEPENDENT, tie_phase_sigma=0.3)
    result = adjust_sequence(start, observed, controls, options=options)
    expected = _dense_phase_sandwich(result, start, 0.3)
    scale = np.sqrt(np.outer(np.diag(expected), np.diag(expected)))
    assert np.abs((result.covariance - expected) / scale).max() < 0.01
    assert np.all(np.diag(result.systematic) > 0.3 * np.diag(result.cofactor))
    plain = adjust_sequence(start, observed, controls, options=INDEPENDENT)
    np.testing.assert_array_equal(plain.systematic, 0.0)


def test_the_default_covariance_carries_all_three_tie_error_terms(truth, rng):
    """With the default options (issue 29: the affine pair fields beside the phase term) the systematic part of the
    covariance is the sum of the correlated-tie, the affine pair-field and the phase term, each at its default and
    none of them zero, recomputed from the final problem."""
    models, ties, controls = truth
    result = adjust_sequence(perturbed(models, rng), noisy(ties, rng), controls)
    options, observations = SequenceOptions(), result.observations
    assert options.tie_offset_factor > 0 and options.tie_gradient_factor > 0 and options.tie_phase_sigma > 0
    problem, cofactor = sequence_problem(observations), np.asarray(result.cofactor)
    sizes = np.array([(m.n_pixels, m.n_scans) for m in observations.models])
    parts = [correlated_tie_covariance(problem, result.adjustment, cofactor, 1.0, options.tie_correlation),
             systematic_tie_covariance(problem, result.adjustment, observations.reference_image, sizes, cofactor,
                                       options.tie_offset_factor, options.tie_gradient_factor),
             phase_tie_covariance(problem, result.adjustment, observations, cofactor, options.tie_phase_sigma)]
    assert all(np.all(np.diag(part) > 0) for part in parts)
    scale = np.sqrt(np.outer(np.diag(result.systematic), np.diag(result.systematic)))
    assert np.abs((result.systematic - sum(parts)) / scale).max() < 1e-8


@pytest.mark.slow
def test_the_control_test_names_a_control_point_that_disagrees_with_the_ties(truth, rng):
    """The control points' test against the ties (``control_test``, their σ as given): control points drawn with
    their σ (500 m) agree with the ties (accepted), and the same with one moved by 5 km are rejected; the test is on
    C's rank, fewer than the 36 control coordinates (a direction only the control points fix). The exact points of
    the fixture are rejected too — as too good (T far below q)."""
    models, ties, controls = truth
    start, observed = perturbed(models, rng), noisy(ties, rng)
    exact = control_test(adjust_sequence(start, observed, controls, options=INDEPENDENT))
    assert exact is not None and not exact.accepted and exact.statistic < 0.5 * exact.degrees_of_freedom
    radius = 6.371e6
    drawn = [replace(c, latitude=c.latitude + rng.normal(0, 500.0, 6) / radius,
                     longitude=c.longitude + rng.normal(0, 500.0, 6) / (radius * np.cos(c.latitude)))
             for c in controls]
    tested = control_test(adjust_sequence(start, observed, drawn, options=INDEPENDENT))
    assert tested is not None and tested.accepted and 30 <= tested.degrees_of_freedom < 36
    moved = replace(drawn[1], latitude=drawn[1].latitude + np.where(np.arange(6) == 2, 5000.0 / radius, 0.0))
    tested = control_test(adjust_sequence(start, observed, [drawn[0], moved, drawn[2]], options=INDEPENDENT))
    assert tested is not None and not tested.accepted and tested.p_value < 1e-6
