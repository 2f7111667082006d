import numpy as np
import pytest

from seaice_jax.drift.kinematics import drift_vectors, fit_transform
from seaice_jax.errors import RankDeficiencyError, SeaiceError


def procrustes(a, b, scaling):
    """Umeyama's closed form: the similarity (or rigid) transform taking a onto b."""
    ca, cb = a.mean(0), b.mean(0)
    u, d, vt = np.linalg.svd((b - cb).T @ (a - ca))
    sign = np.diag([1.0, np.sign(np.linalg.det(u @ vt))])
    rotation = u @ sign @ vt
    scale = (d * np.diag(sign)).sum() / np.sum((a - ca) ** 2) if scaling else 1.0
    return rotation, scale, cb - ca


@pytest.mark.parametrize("kind", ["rigid", "similarity"])
def test_fits_match_the_closed_form(kind, rng):
    a = rng.uniform(-50_000, 50_000, (12, 2))
    angle, scale = 0.02, 1.03 if kind == "similarity" else 1.0
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    b = (a @ rotation.T) * scale + [30_000.0, -5_000.0] + rng.normal(0, 100.0, a.shape)
    fit = fit_transform(a, b, kind, sigma=100.0)
    expected_rotation, expected_scale, expected_shift = procrustes(a, b, kind == "similarity")
    assert float(fit.parameters["rotation"]) == pytest.approx(np.arctan2(expected_rotation[1, 0],
                                                                         expected_rotation[0, 0]), abs=1e-9)
    np.testing.assert_allclose(fit.parameters["shift"], expected_shift, atol=1e-6)
    if kind == "similarity":
        assert float(fit.parameters["scale"]) == pytest.approx(expected_scale, rel=1e-9)
    np.testing.assert_allclose(fit(a) + fit.residuals, b, atol=1e-6)


def test_affine_recovers_a_ten_percent_deformation_exactly():
    rng = np.random.default_rng(3)
    a = rng.uniform(-40_000, 40_000, (10, 2))
    matrix = np.array([[1.10, 0.03], [-0.02, 0.95]])
    b = (a - a.mean(0)) @ matrix.T + a.mean(0) + [-30_400.0, 1_000.0]
    fit = fit_transform(a, b, "affine")
    np.testing.assert_allclose(fit.parameters["matrix"], matrix, atol=1e-12)
    np.testing.assert_allclose(fit.parameters["shift"], [-30_400.0, 1_000.0], atol=1e-6)
    assert fit.rms < 1e-6


def test_parameter_sigma_matches_monte_carlo():
    rng = np.random.default_rng(4)
    a = rng.uniform(-20_000, 20_000, (8, 2))
    estimates, sigma = [], None
    for _ in range(300):
        fit = fit_transform(a, a + [1000.0, 500.0] + rng.normal(0, 200.0, a.shape), "rigid", sigma=200.0)
        estimates.append([*fit.parameters["shift"], float(fit.parameters["rotation"])])
        sigma = [fit.sigma["shift[0]"], fit.sigma["shift[1]"], fit.sigma["rotation"]]
    np.testing.assert_allclose(np.std(estimates, axis=0, ddof=1) / sigma, 1.0, atol=0.12)
    assert sigma[0] == pytest.approx(200.0 / np.sqrt(8))  # the centroid shift: σ/√n


def test_drift_vectors_and_errors():
    drift = drift_vectors([[0.0, 0.0], [1000.0, 0.0]], [[-1900.0, 0.0], [1000.0, 1000.0]], 86_400.0)
    np.testing.assert_allclose(drift.direction, [270.0, 0.0])
    assert drift.speed[0] * 86_400 == pytest.approx(1900.0)  # 1.9 km/day westward, as in AIDJEX
    with pytest.raises(SeaiceError, match="interval"):
        drift_vectors([[0, 0]], [[1, 1]], 0.0)
    with pytest.raises(SeaiceError, match="point 1: position is not finite"):
        fit_transform([[0, 0], [np.nan, 1], [2, 2]], [[0, 0], [1, 1], [2, 2]])
    with pytest.raises(SeaiceError, match="affine fit needs at least 3 points"):
        fit_transform([[0, 0], [1, 1]], [[0, 0], [1, 1]], "affine")
    with pytest.raises(RankDeficiencyError):
        line = np.stack([np.linspace(0, 1000, 5), np.linspace(0, 2000, 5)], 1)
        fit_transform(line, line + 10.0, "affine")


def test_error_ellipses_hold_their_confidence_in_monte_carlo(rng):
    """95 % ellipses from 2 x 2 covariances: the fraction of Gaussian samples inside each is 0.95, the axes are the
    scaled square roots of the eigenvalues, and a covariance with NaN gives NaN axes."""
    from seaice_jax.drift.kinematics import error_ellipses

    covariances = np.array([[[4.0, 1.5], [1.5, 1.0]], [[1.0, 0.0], [0.0, 9.0]], [[np.nan, 0.0], [0.0, 1.0]]])
    major, minor, angle = error_ellipses(covariances, 0.95)
    assert np.isnan(major[2]) and np.isnan(minor[2])
    scale = np.sqrt(5.991464547107979)  # χ²(2) at 0.95
    for k in range(2):
        values = np.linalg.eigvalsh(covariances[k])
        np.testing.assert_allclose([major[k], minor[k]], np.sqrt(values[::-1]) * scale, rtol=1e-12)
        samples = rng.multivariate_normal([0.0, 0.0], covariances[k], 20_000)
        c, s = np.cos(angle[k]), np.sin(angle[k])
        along, across = samples @ np.array([c, s]), samples @ np.array([-s, c])
        inside = (along / major[k]) ** 2 + (across / minor[k]) ** 2 <= 1.0
        assert inside.mean() == pytest.approx(0.95, abs=0.006)  # 4σ of a binomial of 20 000
