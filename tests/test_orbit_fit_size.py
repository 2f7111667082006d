"""The image's size is an input of the orbit fit (no silent 512 x 512): it is required, it is used (the fitted angle
spans run from the first to the last pixel and scan line of the image given), and a size the control points do not
fit in is refused by name."""

import jax.numpy as jnp
import numpy as np
import pytest

from seaice_jax.adjust.orbit.fit import fit_scan_model
from seaice_jax.errors import SeaiceError
from seaice_jax.simulate.satellite import noaa_image, simulate_control_points


def _control():
    truth = noaa_image("south")  # 512 x 512
    control, _, _ = simulate_control_points(truth, 8, np.random.default_rng(11), 500.0)
    return truth, control


def test_the_size_is_required():
    truth, control = _control()
    with pytest.raises(TypeError, match="n_pixels"):
        fit_scan_model(control, truth.orbit, direction="south")  # pyright: ignore[reportCallIssue]


def test_the_size_is_used():
    """The same points fitted as a 512 x 512 image and as the top-left corner of a 1024 x 768 one: the same ground
    mapping at every pixel of the small image, with spans over 1023 and 767 steps instead of 511."""
    truth, control = _control()
    small = fit_scan_model(control, truth.orbit, direction="south", n_pixels=512, n_scans=512).model
    large = fit_scan_model(control, truth.orbit, direction="south", n_pixels=1024, n_scans=768).model
    assert (large.n_pixels, large.n_scans) == (1024, 768)
    assert float(large.scanner_angle_span) / float(small.scanner_angle_span) == pytest.approx(1023 / 511, rel=1e-6)
    assert float(large.orbital_angle_span) / float(small.orbital_angle_span) == pytest.approx(767 / 511, rel=1e-6)
    assert float(large.subtrack_pixel) == pytest.approx(float(small.subtrack_pixel), abs=1e-6)
    pixel, scan = (jnp.asarray(a.ravel()) for a in np.meshgrid(np.linspace(1, 512, 7), np.linspace(1, 512, 7)))
    np.testing.assert_allclose(np.asarray(large.forward(pixel, scan)), np.asarray(small.forward(pixel, scan)),
                               atol=1e-9)  # radians: 6 mm on the ground


def test_a_size_the_points_do_not_fit_in_is_refused_by_name():
    truth, control = _control()
    beyond = np.flatnonzero(np.asarray(control.pixel) > 256.5)
    first = control.ids[beyond[0]]
    with pytest.raises(SeaiceError, match=rf"control point\(s\) {first} \(pixel [\d.]+, scan [\d.]+\).* lie outside "
                                          r"the image of 256 pixels x 512 scan lines \(n_pixels, n_scans\)"):
        fit_scan_model(control, truth.orbit, direction="south", n_pixels=256, n_scans=512)
    for size, message in [((512.5, 512), r"n_pixels must be a whole number of at least 2 \(the image's size\), got "
                                         r"512.5"),
                          ((512, 1), r"n_scans must be a whole number of at least 2 \(the image's size\), got 1"),
                          ((True, 512), r"n_pixels must be a whole number .* got True")]:
        with pytest.raises(SeaiceError, match=message):
            fit_scan_model(control, truth.orbit, direction="south", n_pixels=size[0], n_scans=size[1])
