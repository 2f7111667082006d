import numpy as np
import pytest

from seaice_jax.adjust.orbit.fit import ControlPoints
from seaice_jax.adjust.orbit.multi_image import joint_fit, monte_carlo_comparison, sequential_fit
from seaice_jax.errors import SeaiceError
from seaice_jax.simulate.satellite import overlapping_pair


def exact_images(images, truths):
    """The same measurements with the known positions set to the truth."""
    from dataclasses import replace

    out = []
    for image, truth in zip(images, truths, strict=True):
        lat, lon = truth.forward(image.primary.pixel, image.primary.scan)
        primary = ControlPoints(image.primary.pixel, image.primary.scan, lat, lon, image.primary.sigma,
                                image.primary.ids)
        out.append(replace(image, primary=primary))
    return out


def test_noise_free_joint_and_sequential_fits_recover_both_images():
    images, truths = overlapping_pair(np.random.default_rng(4))
    images = exact_images(images, truths)
    joint = joint_fit(images)
    for model, truth in zip(joint.models, truths, strict=True):
        assert float(model.subtrack_pixel) == pytest.approx(float(truth.subtrack_pixel), abs=1e-5)
        assert float(model.ascending_node) == pytest.approx(float(truth.ascending_node), abs=1e-9)
    fits, _ = sequential_fit(images)
    assert fits[1].rms_km < 1e-6
    assert joint.point_ids == tuple(f"S{k}" for k in range(1, 7))


def test_an_image_without_enough_control_is_named():
    images, _ = overlapping_pair(np.random.default_rng(4), primary_first=2, primary_second=1)
    with pytest.raises(SeaiceError, match="images A, B never reach three control points"):
        sequential_fit(images)


@pytest.mark.slow
def test_joint_sigma_matches_monte_carlo_and_the_1985_practice_is_overconfident():
    """Vmapped Monte Carlo of both methods with the same noise: known positions (500 m) and pointing (300 m).

    400 realizations: the relative standard error of an RMS horizontal error is between 1/(2√N) (isotropic) and
    1/√(2N) (one direction dominant), 2.5-3.5 %, so the 10 % tolerance on the joint σ is 2.8-4 standard errors.
    """
    rng = np.random.default_rng(12)
    images, truths = overlapping_pair(rng)
    images = exact_images(images, truths)
    pixel, scan = (a.ravel() for a in np.meshgrid(np.linspace(50, 460, 3), np.linspace(50, 460, 3)))
    result = monte_carlo_comparison(images, truths, 400, rng, pixel, scan)
    assert result.runs == 400
    np.testing.assert_allclose(result.joint_scatter / result.joint_predicted, 1.0, atol=0.10)
    assert np.all(result.sequential_scatter > 1.3 * result.sequential_claimed)  # A's errors are hidden
    assert np.mean(result.joint_scatter) < np.mean(result.sequential_scatter)
