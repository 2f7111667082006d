"""The sequence block's observation model: residuals vanish at the truth, Jacobians match finite differences, the
prior is whitened right, and a noise-free sequence adjusted through these residuals returns the true models."""

from dataclasses import replace
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from seaice_jax.adjust.engine.problem import block_residuals
from seaice_jax.adjust.sequence.model import (
    global_index,
    scan_unknowns,
    sequence_observations,
    with_scan_unknowns,
)
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.earth import MEAN_RADIUS
from seaice_jax.sensors.control import ControlPoints
from seaice_jax.simulate.satellite import noaa_pass
from tests.helpers import lattice_ties, sequence_rows, whitened, whitened_jacobians

SIZE = 256
LATITUDE, LONGITUDE = np.radians(74.0), np.radians(-85.0)


@pytest.fixture(scope="module")
def truth():
    """Three passes (south, north, south) ~40 km apart, ties on a ground lattice seen by two or three of them
    (exact pixel and scan by the true models), four exact control points per image."""
    offsets = [(0.0, 0.0), (0.3, 0.8), (-0.25, -0.6)]
    models = [noaa_pass(direction, SIZE, LATITUDE + np.radians(a), LONGITUDE + np.radians(b))
              for direction, (a, b) in zip(("south", "north", "south"), offsets, strict=True)]
    lat, lon = np.meshgrid(LATITUDE + np.radians(np.linspace(-1.5, 1.5, 7)),
                           LONGITUDE + np.radians(np.linspace(-5.0, 5.0, 7)), indexing="ij")
    lat, lon = lat.ravel(), lon.ravel()
    ties = lattice_ties(models, lat, lon, SIZE, 0.3, 1.5 * 0.3)
    rng = np.random.default_rng(7)
    controls = []
    for model in models:
        pixel, scan = rng.uniform(10, SIZE - 10, (2, 4))
        a, b = (np.asarray(v) for v in model.forward(pixel, scan))
        controls.append(ControlPoints(pixel, scan, a, b, 500.0))
    return models, ties, controls


PRIOR_SIGMA = np.array([1e-3, 2.0, 1e-3, 1e-3, 1e-3])


def observations(truth, start_models=None):
    models, ties, controls = truth
    mean = np.stack([np.asarray(scan_unknowns(m)) for m in models])
    return sequence_observations(start_models or models, ties, controls, prior_mean=mean,
                                 prior_covariance=np.tile(PRIOR_SIGMA, (len(models), 1)))


def test_groups_cover_every_observation_once(truth):
    models, ties, controls = truth
    obs = observations(truth)
    assert set(obs.groups) == {"ties south 256x256", "ties north 256x256", "control south 256x256",
                               "control north 256x256", "prior"}
    assert sum(g.rows for n, g in obs.groups.items() if n.startswith("ties")) == ties.image.size
    assert sum(g.rows for n, g in obs.groups.items() if n.startswith("control")) == 12
    assert np.any(np.bincount(ties.tie) == 3), "the lattice should give ties seen in all three images"
    assert obs.n_ties == ties.latitude.size
    np.testing.assert_array_equal(np.asarray(global_index(jnp.array([0, 2]))), [[0, 1, 2, 3, 4], [10, 11, 12, 13, 14]])


def test_reference_image_of_each_tie(truth):
    """The image of each tie's reference observation: the table's ``reference`` flags, or without them the tie's
    first observation."""
    models, ties, _ = truth
    moved = np.zeros(ties.tie.size, bool)
    last = ties.tie.size - 1 - np.unique(ties.tie[::-1], return_index=True)[1]  # each tie's last observation
    moved[last] = True
    expected = np.full(ties.latitude.size, -1)
    expected[ties.tie[last]] = ties.image[last]
    flagged = sequence_observations(models, replace(ties, reference=moved))
    np.testing.assert_array_equal(np.asarray(flagged.reference_image), expected)
    first = np.unique(ties.tie, return_index=True)[1]
    assert not np.array_equal(ties.image[first], ties.image[last[np.argsort(ties.tie[last])]])
    table = SimpleNamespace(**{key: getattr(ties, key) for key in (  # a tie table without reference flags
        "image", "tie", "pixel", "scan", "sigma_pixel", "sigma_scan", "latitude", "longitude")})
    plain = sequence_observations(models, table)
    np.testing.assert_array_equal(np.asarray(plain.reference_image)[ties.tie[first]], ties.image[first])


def test_residuals_vanish_at_the_truth(truth):
    obs = observations(truth)
    points = jnp.zeros((obs.n_ties, 2))
    for name, group in obs.groups.items():
        residuals = whitened(group, obs.start, points)
        assert np.all(np.isfinite(residuals)), name
        np.testing.assert_allclose(residuals, 0.0, atol=1e-7, err_msg=name)


def test_tie_residual_is_the_pixel_error_in_units_of_sigma(truth):
    """Moving a tie's ground point east by d metres moves it in every image by d / (east pixel size): the
    whitened residual is that displacement over σ (finite difference of the independent forward model)."""
    models, ties, _ = truth
    obs = observations(truth)
    group = obs.groups["ties south 256x256"]
    row = 0
    image, tie = int(sequence_rows(group)[0][row]), int(group.point_index[row])
    points = jnp.zeros((obs.n_ties, 2)).at[tie, 1].set(200.0)
    residual = whitened(group, obs.start, points)[row]
    lat, lon = ties.latitude[tie], ties.longitude[tie] + 200.0 / (MEAN_RADIUS * np.cos(ties.latitude[tie]))
    pixel, scan = (float(a) for a in models[image].inverse(lat, lon))
    expected = np.array([pixel - float(group.data["pixel"][row]), scan - float(group.data["scan"][row])])
    np.testing.assert_allclose(residual * np.asarray(group.sigma[row]), expected, atol=1e-9)
    assert 0.03 < np.hypot(*expected) < 0.2  # 200 m is a tenth of a ~2.5 km pixel: the move is real


def test_jacobians_match_finite_differences(truth, rng):
    models, _, _ = truth
    start = [with_scan_unknowns(m, scan_unknowns(m) + rng.normal(0, 0.3) * PRIOR_SIGMA) for m in models]
    obs = observations(truth, start)
    points = jnp.asarray(rng.normal(0, 500.0, (obs.n_ties, 2)))
    theta = obs.start
    steps = np.array([1e-7, 1e-4, 1e-7, 1e-7, 1e-7])
    for name, group in obs.groups.items():
        _, j_theta, j_point = whitened_jacobians(group, theta, points)
        rows = np.arange(group.rows)
        for k in range(5):
            delta = np.zeros(theta.shape)
            delta[:, k] = steps[k]
            plus = whitened(group, theta + delta, points)
            minus = whitened(group, theta - delta, points)
            numeric = (plus - minus) / (2 * steps[k])
            scale = np.abs(numeric).max() + 1e-12
            np.testing.assert_allclose(j_theta[rows, :, k] / scale, numeric / scale, atol=1e-6, err_msg=f"{name} {k}")
        if group.point_index is not None:
            for k in range(2):
                delta = np.zeros((obs.n_ties, 2))
                delta[:, k] = 0.5
                numeric = (whitened(group, theta, points + delta)
                           - whitened(group, theta, points - delta)) / 1.0
                np.testing.assert_allclose(j_point[rows, :, k], numeric, rtol=1e-6, atol=1e-9, err_msg=name)


def test_prior_is_whitened_by_its_covariance(truth, rng):
    """θ = mean + L z with L the Cholesky factor of a full prior covariance gives the residual z."""
    models, _, _ = truth
    mean = np.stack([np.asarray(scan_unknowns(m)) for m in models])
    a = rng.normal(size=(3, 5, 5)) * PRIOR_SIGMA[None, :, None]
    covariance = a @ np.transpose(a, (0, 2, 1)) + np.diag(PRIOR_SIGMA**2)[None]
    obs = sequence_observations(models, prior_mean=mean, prior_covariance=covariance)
    z = rng.normal(size=(3, 5))
    theta = mean + np.einsum("nij,nj->ni", np.linalg.cholesky(covariance), z)
    np.testing.assert_allclose(whitened(obs.groups["prior"], theta, None), z, rtol=1e-9)


def test_residuals_vmap_over_monte_carlo_draws(truth, rng):
    obs = observations(truth)
    group = obs.groups["ties north 256x256"]
    points = jnp.zeros((obs.n_ties, 2))
    draws = obs.start[None] + jnp.asarray(rng.normal(0, 1, (4, 3, 5)) * PRIOR_SIGMA[None, None, :])
    batched = np.asarray(jax.vmap(lambda t: block_residuals(group, jnp.ravel(t), points))(draws))
    for k in range(4):
        np.testing.assert_allclose(batched[k], whitened(group, draws[k], points), rtol=1e-12)


def _gauss_newton(obs, theta, points, steps=6):
    """Dense Gauss-Newton on all groups (the tests' own, independent of the engine)."""
    n_theta, n_points = theta.size, points.size
    for _ in range(steps):
        jacobians, residuals = [], []
        for group in obs.groups.values():
            e, j_theta, j_point = whitened_jacobians(group, theta, points)
            m, c = e.shape
            full = np.zeros((m, c, n_theta + n_points))
            index = np.asarray(group.global_index)
            for k in range(5):
                full[np.arange(m), :, index[:, k]] = j_theta[:, :, k]
            if group.point_index is not None:
                for k in range(2):
                    full[np.arange(m), :, n_theta + 2 * np.asarray(group.point_index) + k] = j_point[:, :, k]
            jacobians.append(full.reshape(m * c, -1))
            residuals.append(e.ravel())
        jacobian, residual = np.concatenate(jacobians), np.concatenate(residuals)
        scale = np.linalg.norm(jacobian, axis=0)
        step = np.linalg.lstsq(jacobian / scale, -residual, rcond=None)[0] / scale
        theta = theta + step[:n_theta].reshape(theta.shape)
        points = points + step[n_theta:].reshape(points.shape)
    return theta, points


def test_noise_free_sequence_returns_the_true_models(truth, rng):
    """Start 0.3 prior σ off in every unknown and kilometres off in every tie: Gauss-Newton on the model's
    residuals and Jacobians returns the true unknowns and tie positions (no priors: ties and control only)."""
    models, ties, controls = truth
    start = [with_scan_unknowns(m, scan_unknowns(m) + rng.normal(0, 0.3, 5) * PRIOR_SIGMA) for m in models]
    obs = sequence_observations(start, ties, controls)
    theta, points = _gauss_newton(obs, np.asarray(obs.start), rng.normal(0, 2000.0, (obs.n_ties, 2)))
    true_theta = np.stack([np.asarray(scan_unknowns(m)) for m in models])
    assert np.all(np.abs(theta - true_theta) <= 1e-9 * np.maximum(np.abs(true_theta), 1.0)), theta - true_theta
    np.testing.assert_allclose(points, 0.0, atol=1e-3)
    latitude, longitude = (np.asarray(a) for a in obs.ground_at(points))
    np.testing.assert_allclose(latitude, ties.latitude, rtol=0, atol=1e-9)
    np.testing.assert_allclose(longitude, ties.longitude, rtol=0, atol=1e-9)
    for model, fitted in zip(models, obs.models_at(theta), strict=True):
        p, s = np.meshgrid(np.linspace(1, SIZE, 5), np.linspace(1, SIZE, 5))
        np.testing.assert_allclose(np.asarray(fitted.forward(p, s)), np.asarray(model.forward(p, s)), atol=1e-9)


def test_bad_input_names_the_culprit(truth):
    models, ties, controls = truth
    bad_sigma = replace(ties, sigma_pixel=np.where(np.arange(ties.image.size) == 5, 0.0, ties.sigma_pixel))
    with pytest.raises(SeaiceError, match=f"tie {ties.tie[5]} in image {ties.image[5]}"):
        sequence_observations(models, bad_sigma)
    bad_image = replace(ties, image=ties.image + 3)
    with pytest.raises(SeaiceError, match="image index out of range"):
        sequence_observations(models, bad_image)
    covariance = np.tile(np.diag(PRIOR_SIGMA**2), (3, 1, 1))
    covariance[1, 0, 0] = -1.0
    with pytest.raises(SeaiceError, match="prior of image 1"):
        sequence_observations(models, prior_covariance=covariance)
