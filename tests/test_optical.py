"""Camera-distortion calibration (OPT) against a synthetically distorted grid and image."""

import numpy as np
import pytest

from seaice_jax.errors import SeaiceError
from seaice_jax.imagery.optical import calibrate_camera, correct_image, detect_dots, load_calibration
from seaice_jax.simulate.satellite import CameraDistortion, render_grid_target, simulate_sequence

SIZE, SPACING = 256, 16.0


@pytest.fixture(scope="module")
def camera():
    camera = CameraDistortion.for_image(SIZE, SIZE, radial=0.04)
    frame = render_grid_target(camera, SPACING)
    return camera, frame, calibrate_camera(frame, (SIZE, SIZE), SPACING, {"lens": "16 mm", "zoom": 1.0})


def lattice_residual(image):
    dots = detect_dots(np.nan_to_num(image, nan=0.1))
    centre = 0.5 * (1 + SIZE)
    return dots - (centre + SPACING * np.round((dots - centre) / SPACING)), dots


def test_corrected_grid_lies_on_the_regular_lattice_within_a_tenth_of_a_pixel(camera):
    _, frame, calibration = camera
    residual, dots = lattice_residual(correct_image(frame, calibration))
    assert len(dots) >= (SIZE // SPACING) ** 2 * 0.8
    assert np.abs(residual).max() < 0.1
    assert calibration.lattice_residual < 0.05
    # the distortion was real: the frame's own dots are far from a regular lattice of the image's size
    raw = detect_dots(frame)
    centre = np.array([0.5 * (1 + frame.shape[1]), 0.5 * (1 + frame.shape[0])])
    scaled = (raw - centre) / [4.0 / 3.0, 1.0]
    assert np.abs(scaled - SPACING * np.round(scaled / SPACING)).max() > 1.0


def test_corrected_satellite_frame_matches_the_undistorted_image(camera, tmp_path):
    camera_model, _, calibration = camera
    sequence = simulate_sequence(0, n_images=1, size=SIZE, camera=camera_model)
    image = sequence.images[0]
    frame = image.frame
    assert frame.shape == (camera_model.frame_rows, camera_model.frame_columns)  # 4:3 and a margin
    path = calibration.save(tmp_path / "camera.npz")
    loaded = load_calibration(path)
    assert loaded.settings["lens"] == "16 mm" and loaded.settings["spacing"] == SPACING
    corrected = correct_image(frame, loaded)
    assert corrected.shape == image.data.shape and np.isfinite(corrected).all()
    error = corrected - image.data
    assert np.sqrt(np.mean(error**2)) < 0.03  # resampling twice (frame, then back) at the image's resolution


def test_calibration_errors_are_clear(camera, tmp_path):
    _, frame, calibration = camera
    with pytest.raises(SeaiceError, match="grid dots found"):
        calibrate_camera(np.zeros((100, 100)), (SIZE, SIZE), SPACING)
    with pytest.raises(SeaiceError, match="do not surround the whole image"):
        calibrate_camera(frame, (2 * SIZE, 2 * SIZE), SPACING)
    with pytest.raises(SeaiceError, match="differs from the calibration's"):
        correct_image(frame[:-1], calibration)
    (tmp_path / "junk.npz").write_text("not a calibration")
    with pytest.raises(SeaiceError, match="junk.npz: not a camera calibration"):
        load_calibration(tmp_path / "junk.npz")
