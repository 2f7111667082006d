"""Scenes on the real coast, and control points found on it (issue 15, items 3 and 4)."""

import dataclasses

import cv2
import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from seaice_jax.cli import main
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.earth import MEAN_RADIUS
from seaice_jax.imagery.coast_control import (
    DEFAULT_LEVELS,
    MatchLevel,
    coast_control,
    match_coast,
    predicted_land,
    profile_fit,
)
from seaice_jax.io.coastline import coastline, coastline_of_grid
from seaice_jax.io.sequence import MODEL_KEYS, read_sequence
from seaice_jax.simulate.satellite import ice_scene, noaa_pass, place_pass, render
from seaice_jax.workflows.remap import rectify_images

CENTRE = (73.9, -80.5)  # degrees: the mouth of Lancaster Sound (Devon Island north, Bylot Island south-east)
SIZE = 240
LEVELS = (MatchLevel(4, 48, 16, 1.5), MatchLevel(2, 32, 16, 1.0))


@pytest.fixture(scope="module")
def scene():
    return ice_scene(np.random.default_rng(3), *CENTRE, extent=500_000.0)


@pytest.fixture(scope="module")
def coast(scene):
    return coastline_of_grid(scene.land)


def small_pass(direction, size=SIZE, subtrack=None):
    """A NOAA-7-like pass sampled by ``size`` pixels over half the swath (~1.6 km pixels), centred on CENTRE."""
    template = noaa_pass(direction, size, np.radians(CENTRE[0]), np.radians(CENTRE[1]), subtrack)
    template = eqx.tree_at(lambda m: (m.scanner_angle_span, m.orbital_angle_span), template,
                           replace=(0.5 * template.scanner_angle_span, 0.5 * template.orbital_angle_span))
    return place_pass(template, np.radians(CENTRE[0]), np.radians(CENTRE[1]))


def check_rms(fitted, true, size):
    """RMS (pixels) of the fitted model's image position of the true ground of a 12 x 12 grid of pixels."""
    pixel, scan = (a.ravel() for a in np.meshgrid(np.linspace(4, size - 4, 12), np.linspace(4, size - 4, 12)))
    p, s = (np.asarray(a) for a in fitted.inverse(*true.forward(jnp.asarray(pixel), jnp.asarray(scan))))
    return float(np.sqrt(np.mean((p - pixel) ** 2 + (s - scan) ** 2)))


def test_scene_land_is_the_gshhg_land(scene, coast):
    """The scene's land agrees with Coastline.contains away from the coast (the raster is 1 km); the named islands
    are land and the sound between them is pack ice."""
    rng = np.random.default_rng(0)
    latitude, longitude = rng.uniform(72.5, 75.2, 3000), rng.uniform(-87.0, -74.0, 3000)
    xy = jnp.stack(scene.projection.forward(np.radians(latitude), np.radians(longitude)), -1)
    offset = np.asarray(scene.coast_offset(xy))
    land = coast.contains(latitude, longitude)
    clear = np.abs(offset) > 1500.0  # farther from the scene's coast than the raster's diagonal
    assert clear.mean() > 0.85
    np.testing.assert_array_equal(offset[clear] > 0, land[clear])
    assert 0.3 < land.mean() < 0.8
    islands = {"Devon": (75.0, -86.0), "Bylot": (73.3, -78.5), "Baffin (Borden Peninsula)": (72.8, -83.0)}
    for name, (lat, lon) in islands.items():
        point = jnp.stack(scene.projection.forward(np.radians(lat), np.radians(lon)))
        assert coast.contains(lat, lon) and float(scene.coast_offset(point)) > 5000.0, name
    sound = jnp.stack(scene.projection.forward(np.radians(74.2), np.radians(-82.0)))
    assert not coast.contains(74.2, -82.0) and bool(scene.is_pack(sound))


def rough_start(truth):
    """The pass time 20 km along the track off and the node 0.5° off (~15 pixels of ~1.6 km)."""
    return eqx.tree_at(lambda m: (m.ascending_node, m.orbital_angle_first), truth,
                       replace=(truth.ascending_node - np.radians(0.5),
                                truth.orbital_angle_first + 20_000.0 / MEAN_RADIUS))


def test_automatic_control_recovers_the_true_model_from_20_km_off(scene, coast):
    truth = small_pass("south")
    image = np.asarray(render(scene, truth, 0.0))
    start = rough_start(truth)
    assert check_rms(start, truth, SIZE) > 10.0
    pixel, scan = np.meshgrid(np.arange(1.0, SIZE + 1), np.arange(1.0, SIZE + 1))  # rows are scan lines
    latitude, longitude = (np.degrees(np.asarray(a)) for a in truth.forward(pixel, scan))
    np.testing.assert_array_equal(predicted_land(truth, coast.contains),
                                  coast.contains(latitude, longitude).astype(float))
    result = coast_control(image, start, coast.contains, search=24, levels=LEVELS)
    # two levels on a small image: well under the 1.5 pixel of the acceptance (512 x 512, three levels: ~0.2)
    assert check_rms(result.model, truth, SIZE) < 1.0
    assert np.hypot(*result.shift) > 5.0  # the whole-image search found the start's offset
    assert len(result.fit.control) >= 20
    assert result.fit.adjustment is not None
    assert 0.5 < float(result.fit.adjustment.sigma0) < 3.0  # the matches' stated σ is about right


def test_automatic_control_refuses_a_wrong_size_and_an_image_without_coast(coast):
    truth = small_pass("south")
    with pytest.raises(SeaiceError, match="--pixels, --scans"):
        coast_control(np.zeros((100, SIZE)), truth, coast.contains, search=24, levels=LEVELS)
    # the same pass 60° of longitude west: the Canada Basin at 74°N, 300 km from the nearest land (Banks Island)
    open_sea = eqx.tree_at(lambda m: m.ascending_node, truth, replace=truth.ascending_node - np.radians(60.0))
    beaufort = coastline(-165.0, 68.0, -115.0, 80.0)
    assert predicted_land(open_sea, beaufort.contains).sum() == 0 and len(beaufort.polygons) > 0
    with pytest.raises(SeaiceError, match="does not cross the image"):
        coast_control(np.random.default_rng(0).random((SIZE, SIZE)), open_sea, beaufort.contains, search=24,
                      levels=LEVELS)


def test_rectify_auto_control_errors_are_usage_errors(tmp_path, capsys):
    image = tmp_path / "image.npy"
    np.save(image, np.zeros((64, 80)))
    common = ["rectify", "--satellite", "NOAA-7", "--image", str(image), "--auto-control"]
    assert main([*common, "--node", "60", "--pass-minutes", "30"]) == 2
    assert "image.npy: the image is 80 pixels x 64 scan lines, not 512 x 512 (--pixels, --scans)" in \
        capsys.readouterr().err
    assert main([*common, "--pixels", "80", "--scans", "64"]) == 2
    assert "--auto-control needs --image and the rough orbit (--node, --pass-minutes)" in capsys.readouterr().err
    assert main(["rectify", "--satellite", "NOAA-7"]) == 2
    assert "MEASUREMENTS" in capsys.readouterr().err


def write_coastline_project(folder, images, satellite_altitude):
    """A sequence project of ``images`` ``[(name, data, rough model)]`` with ``control = "coastline"``."""
    lines = ['epoch = "1983-03-08T00:00:00Z"', "[grid]", 'projection = "nsidc-north"',
             f"centre_deg = {list(CENTRE)}", "pixel_m = [4000.0, 4000.0]", "shape = [60, 60]"]
    for k, (name, data, rough) in enumerate(images):
        np.save(folder / f"{name}.npy", data)
        lines += ["[[image]]", f'name = "{name}"', f'time = "1983-03-08T0{k + 1}:00:00Z"', f'file = "{name}.npy"',
                  'satellite = "NOAA-7"', f"altitude_m = {satellite_altitude!r}", f'direction = "{rough.direction}"',
                  'control = "coastline"', "control_search = 24"]
        lines += [f"{key} = {float(value)!r}" for key, value in zip(MODEL_KEYS, (
            np.degrees(float(rough.scanner_angle_span)), float(rough.subtrack_pixel),
            np.degrees(float(rough.orbital_angle_first)), np.degrees(float(rough.orbital_angle_span)),
            np.degrees(float(rough.ascending_node))), strict=True)]
    path = folder / "sequence.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_sequence_coastline_control_recovers_the_true_model_from_20_km_off(scene, tmp_path):
    """``control = "coastline"`` in a sequence project, through the rectification ``seaice remap`` (and its Dask
    path) runs: the fitted model is the true one, recorded like a control-point fit."""
    truth = small_pass("south")
    image = np.asarray(render(scene, truth, 0.0))
    start = rough_start(truth)
    assert check_rms(start, truth, SIZE) > 10.0
    path = write_coastline_project(tmp_path, [("A", image, start)], float(truth.orbit.altitude))
    project = read_sequence(path)
    assert project.images[0].model is None and project.images[0].control_search == 24
    (rectification,), covariance = rectify_images(project)
    assert check_rms(rectification.model, truth, SIZE) < 1.0
    assert rectification.control >= 12 and len(rectification.point_ids) == rectification.control
    assert 0.5 < rectification.sigma0 < 3.0
    assert np.all(np.diag(covariance) > 0) and np.allclose(covariance, covariance.T)


def test_sequence_coastline_control_errors_name_the_file_and_image(tmp_path):
    truth = small_pass("south")
    path = write_coastline_project(tmp_path, [("A", np.zeros((SIZE, SIZE)), truth)], float(truth.orbit.altitude))
    text = path.read_text()
    path.write_text("\n".join(line for line in text.splitlines() if not line.startswith("ascending_node_deg")))
    with pytest.raises(SeaiceError, match=r"sequence.toml: image 'A': control = 'coastline' needs the rough scan "
                                          r"model .*missing ascending_node_deg"):
        read_sequence(path)
    # the same pass 60° of longitude west: the Canada Basin, no coast to match
    open_sea = eqx.tree_at(lambda m: m.ascending_node, truth, replace=truth.ascending_node - np.radians(60.0))
    path = write_coastline_project(tmp_path, [("A", np.random.default_rng(0).random((SIZE, SIZE)), open_sea)],
                                   float(truth.orbit.altitude))
    with pytest.raises(SeaiceError, match=r"sequence.toml: image 'A': control = 'coastline': automatic control"):
        rectify_images(read_sequence(path))


def _disc(size, centre, radius, island):
    """``(size, size)`` float 0/1: land sampled at the pixel centres (column, row = pixel − 1, scan − 1) inside
    (``island``) or outside a circle of ``radius`` pixels around ``centre`` (column, row)."""
    row, column = np.mgrid[0:size, 0:size].astype(float)
    inside = np.hypot(column - centre[0], row - centre[1]) < radius
    return (inside if island else ~inside).astype(float)


def _landward(matches, centre, shift, island):
    """``(n,)`` pixels: each match's error (position found less the known ``shift``) along the circle's normal
    toward the land (around ``centre``, column/row; an island's land inside, a lake's outside)."""
    error = np.stack([matches.pixel - matches.predicted_pixel, matches.scan - matches.predicted_scan], 1) - shift
    outward = np.stack([matches.predicted_pixel - 1.0 - centre[0], matches.predicted_scan - 1.0 - centre[1]], 1)
    return np.sum(error * outward, axis=1) / np.hypot(*outward.T) * (-1.0 if island else 1.0)


@pytest.mark.parametrize("island", [True, False])
def test_last_level_finds_a_curved_coast_without_landward_bias(island):
    """An island's and a lake's coast displaced by a known sub-pixel shift: the last level's matches find the shift
    with no bias along the coast's normal (issue 29: the banded profile put them 0.3-0.4 pixel landward here, and
    kept fewer than half the matches)."""
    size, centre, radius = 200, np.array([100.3, 99.6]), 60.0
    shift = np.array([0.3, -0.2])  # pixel, scan: where the image shows the predicted coast
    prediction = _disc(size, centre, radius, island)
    land = _disc(size, centre + shift, radius, island)
    image = 0.3 * land + 0.9 * (1.0 - land) + np.random.default_rng(5).normal(0.0, 0.05, land.shape)
    matches = match_coast(image, prediction, DEFAULT_LEVELS[-1])
    landward = _landward(matches, centre, shift, island)
    assert abs(float(np.mean(landward))) < 0.05
    assert float(np.sqrt(np.mean(landward**2))) < 0.15
    assert matches.pixel.size >= 20


@pytest.mark.parametrize("island", [True, False])
def test_last_level_is_not_pulled_landward_by_a_band_of_fast_ice(island):
    """A coast with a band of fast ice 11 pixels wide, brighter than the land, with pack beyond: fitted over the
    whole window the step profile's peak leans landward (issue 29: one baseline for fast ice and pack); the last
    level fits within COAST_EDGE of the predicted coast, where the sea side is the fast ice alone, and finds the
    true shift (flat land here; textured land: the next test)."""
    size, centre, radius = 200, np.array([100.3, 99.6]), 55.0
    shift = np.array([0.3, -0.2])
    prediction = _disc(size, centre, radius, island)
    land = _disc(size, centre + shift, radius, island)
    fast = _disc(size, centre + shift, radius + 11.0 if island else radius - 11.0, island) - land
    image = 0.5 * land + 0.86 * fast + 0.45 * (1.0 - land - fast)
    image = image + np.random.default_rng(6).normal(0.0, 0.05, land.shape)

    whole = _landward(match_coast(image, prediction, dataclasses.replace(DEFAULT_LEVELS[-1], edge=None)), centre,
                      shift, island)
    edge = _landward(match_coast(image, prediction, DEFAULT_LEVELS[-1]), centre, shift, island)
    assert float(np.mean(whole)) > 0.2
    assert abs(float(np.mean(edge))) < 0.05
    assert float(np.sqrt(np.mean(edge**2))) < 0.15
    assert edge.size >= 20


@pytest.mark.parametrize("island", [True, False])
def test_last_level_is_not_pushed_seaward_by_textured_land(island):
    """Land with relief (textured, σ 0.3 against a contrast of 0.6) beside quiet sea: a band moving with the
    template preferred shifts that put it over the quiet pixels, the matches 0.16-0.25 pixel seaward here with
    f6d2c78's matcher (on the simulated scenes 0.068, issue 29); the band fixed in the image frame fits the same pixels
    at every shift and has no such preference."""
    size, centre, radius = 200, np.array([100.3, 99.6]), 60.0
    shift = np.array([0.3, -0.2])
    prediction = _disc(size, centre, radius, island)
    land = _disc(size, centre + shift, radius, island)
    rng = np.random.default_rng(5)
    relief = cv2.GaussianBlur(rng.normal(0.0, 1.0, land.shape), (0, 0), 1.5)
    image = land * (0.3 + 0.3 * relief / relief.std()) + 0.9 * (1.0 - land) + rng.normal(0.0, 0.02, land.shape)
    landward = _landward(match_coast(image, prediction, DEFAULT_LEVELS[-1]), centre, shift, island)
    assert abs(float(np.mean(landward))) < 0.08
    assert float(np.sqrt(np.mean(landward**2))) < 0.25
    assert landward.size >= 12


def test_weighted_profile_fit_is_the_weighted_regression_over_fixed_pixels():
    """profile_fit's R² at every shift, with a weight fixed in the image frame, against a weighted least-squares
    fit of those pixels on an intercept and the shifted templates (numpy's lstsq on √w-scaled rows):
    R² = 1 − Σw(y − ŷ)² / Σw(y − ȳ_w)²; a weight reaching outside the pixels every shift covers is refused."""
    rng = np.random.default_rng(8)
    templates = rng.random((2, 12, 10))
    region = rng.random((15, 14))
    weight = np.zeros(region.shape)
    weight[3:12, 4:10] = rng.random((9, 6))  # the pixels all 4 x 5 shifts cover
    surface = profile_fit(region, templates, weight)
    assert surface.shape == (4, 5)
    root = np.sqrt(weight.ravel())
    y = region.ravel()
    mean = np.sum(weight * region) / weight.sum()
    for i in range(4):
        for j in range(5):
            shifted = np.zeros((2, *region.shape))
            shifted[:, i:i + 12, j:j + 10] = templates
            design = np.column_stack([np.ones(y.size), shifted.reshape(2, -1).T])
            coefficients = np.linalg.lstsq(design * root[:, None], y * root, rcond=None)[0]
            expected = 1.0 - np.sum(weight.ravel() * (y - design @ coefficients) ** 2) / np.sum(
                weight.ravel() * (y - mean) ** 2)
            assert surface[i, j] == pytest.approx(expected, abs=2e-5)
    weight[2, 5] = 0.1
    with pytest.raises(ValueError, match="templates' cover"):
        profile_fit(region, templates, weight)
