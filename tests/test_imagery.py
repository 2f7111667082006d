"""Remapping and tracking against simulated image sequences whose ground truth is known."""

import cv2
import jax.numpy as jnp
import numpy as np
import pytest

from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.projections import ImageGrid, MapGrid
from seaice_jax.imagery.remap import fill_holes, remap, remap_exact, scan_maps, swath_masks
from seaice_jax.imagery.tracking import GOOD, LOW_CONTRAST, TrackingOptions, track
from seaice_jax.simulate.satellite import simulate_sequence, true_displacement


@pytest.fixture(scope="module")
def sequence():
    return simulate_sequence(3, n_images=3, size=128)


def scene_grid(scene, pixel=4000.0, rows=96, columns=96):
    lat, lon = scene.projection.inverse(*scene.centre)
    return MapGrid.centred(scene.projection, lat, lon, pixel, pixel, rows, columns)


def truth_on(grid, scene, time):
    x, y = grid.xy()
    return np.asarray(scene.brightness(jnp.stack([x, y], -1), time))


def test_remapping_with_the_true_model_reproduces_the_ground_to_subpixel(sequence):
    grid = scene_grid(sequence.scene)
    values, valid = remap([im.data for im in sequence.images], [im.model for im in sequence.images], grid)
    for k, image in enumerate(sequence.images):
        truth = truth_on(grid, sequence.scene, image.time)
        ok = valid[k]
        assert ok.mean() > 0.9  # the passes are centred on the scene
        error = values[k][ok] - truth[ok]
        assert abs(error.mean()) < 0.005 and np.sqrt(np.mean(error**2)) < 0.08  # interpolation of ~5 km pixels
        shift, _ = cv2.phaseCorrelate(np.where(ok, truth, 0).astype(np.float32),
                                      np.where(ok, values[k], 0).astype(np.float32))
        assert np.hypot(shift[0], shift[1]) < 0.1  # registration against truth: sub-pixel


def test_a_wrong_node_shows_as_a_shift(sequence):
    """The registration check can fail: a model whose node is off by one grid pixel's angle misregisters."""
    import equinox as eqx

    grid = scene_grid(sequence.scene)
    image = sequence.images[0]
    shifted = eqx.tree_at(lambda m: m.ascending_node, image.model, replace=image.model.ascending_node + 4000.0 / (
        6_371_000.0 * np.cos(np.radians(74.0))))
    values, valid = remap([image.data], [shifted], grid)
    truth = truth_on(grid, sequence.scene, image.time)
    shift, _ = cv2.phaseCorrelate(np.where(valid[0], truth, 0).astype(np.float32),
                                  np.where(valid[0], values[0], 0).astype(np.float32))
    assert np.hypot(shift[0], shift[1]) > 0.7


def test_vmapped_batch_equals_one_by_one_and_both_pass_directions(sequence):
    grid = scene_grid(sequence.scene, rows=40, columns=50)
    images, models = [im.data for im in sequence.images], [im.model for im in sequence.images]
    assert {m.direction for m in models} == {"south", "north"}
    batch, valid = remap(images, models, grid)
    for k in range(len(images)):
        single, single_valid = remap([images[k]], [models[k]], grid)
        np.testing.assert_array_equal(single[0], batch[k])
        np.testing.assert_array_equal(single_valid[0], valid[k])
    nearest, _ = remap(images, models, grid, method="nearest")
    assert np.nanmax(np.abs(nearest - batch)) > 0.01  # the methods differ
    np.testing.assert_array_equal(valid, swath_masks(models, grid))


def test_outside_the_swath_is_masked_and_bad_input_named(sequence):
    image = sequence.images[0]
    far = MapGrid.centred(sequence.scene.projection, np.radians(60.0), np.radians(-40.0), 4000.0, 4000.0, 8, 8)
    values, valid = remap([image.data], [image.model], far)
    assert not valid.any() and np.isnan(values).all()
    with pytest.raises(SeaiceError, match=r"image 0: shape \(10, 10\) does not match its scan model"):
        remap([np.zeros((10, 10))], [image.model], far)
    with pytest.raises(SeaiceError, match="method must be one of"):
        remap([image.data], [image.model], far, method="cubic")


def test_fill_closes_holes_of_missing_data_with_the_mean_of_neighbours(sequence):
    grid = scene_grid(sequence.scene)
    image = sequence.images[0]
    data = image.data.copy()
    rng = np.random.default_rng(0)
    holes = rng.random(data.shape) < 0.05  # scattered lost pixels (dropouts of the digitizer)
    data[holes] = np.nan
    values, valid = remap([data], [image.model], grid)
    assert (~valid[0] & swath_masks([image.model], grid)[0]).sum() > 100
    filled, filled_valid = remap([data], [image.model], grid, fill=3)
    inside = swath_masks([image.model], grid)[0]
    assert filled_valid[0][inside].all() and not filled_valid[0][~inside].any()
    truth = truth_on(grid, sequence.scene, image.time)
    patched = inside & ~valid[0]
    assert np.sqrt(np.mean((filled[0][patched] - truth[patched]) ** 2)) < 0.15
    # a single hole takes exactly the mean of its eight valid neighbours
    block = jnp.arange(9.0).reshape(3, 3)
    mask = jnp.ones((3, 3), bool).at[1, 1].set(False)
    assert float(fill_holes(block, mask)[1, 1]) == pytest.approx((36.0 - 4.0) / 8.0)


def edge_grid(sequence, rows=60, columns=70):
    """A grid over the scene's centre and off it, so that swath edges cross it."""
    lat, lon = sequence.scene.projection.inverse(*sequence.scene.centre)
    return MapGrid.centred(sequence.scene.projection, lat + 0.03, lon + 0.25, 6000.0, 6000.0, rows, columns)


def test_scan_maps_within_the_threshold_of_the_exact_inverse_for_both_pass_directions(sequence):
    grid = edge_grid(sequence)
    models = [im.model for im in sequence.images]
    assert {m.direction for m in models} == {"south", "north"}
    latitude, longitude = grid.latitude_longitude()
    exact_points = []
    for max_error in (0.05, 0.002):
        maps = scan_maps(models, grid, max_error)
        assert maps.ok.all()
        for k, model in enumerate(models):
            pixel, scan = (np.asarray(a) for a in model.inverse(latitude, longitude))
            error = np.hypot(maps.row[k] - (scan - 1.0), maps.column[k] - (pixel - 1.0))
            assert error.max() <= max_error
        exact_points.append(maps.exact_points)
    assert exact_points[1] > 2 * exact_points[0]  # the tight threshold refined tiles
    assert exact_points[1] < 0.5 * len(models) * grid.n_rows * grid.n_columns
    exact = scan_maps(models, grid, 0.0)
    pixel, scan = (np.asarray(a) for a in models[1].inverse(latitude, longitude))
    np.testing.assert_allclose(exact.row[1], scan - 1.0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(exact.column[1], pixel - 1.0, rtol=0, atol=1e-9)


def test_batches_of_many_images_equal_one_by_one(sequence):
    """More images than one batch of maps (8), both pass directions mixed: each image keeps its own model."""
    import equinox as eqx

    grid = edge_grid(sequence, 24, 28)
    models, images = [], []
    for k in range(20):
        image = sequence.images[k % 3]
        models.append(eqx.tree_at(lambda m: m.ascending_node, image.model,
                                  replace=image.model.ascending_node + 0.002 * k))
        images.append(image.data)
    batch, valid = remap(images, models, grid)
    assert max(sum(m.direction == d for m in models) for d in ("south", "north")) > 8
    for k in range(0, 20, 3):
        single, single_valid = remap([images[k]], [models[k]], grid)
        np.testing.assert_array_equal(single[0], batch[k])
        np.testing.assert_array_equal(single_valid[0], valid[k])


@pytest.mark.parametrize("method", ["bilinear", "nearest"])
def test_fast_remap_has_the_exact_paths_masks_and_close_values(sequence, method):
    grid = edge_grid(sequence)
    images, models = [im.data.copy() for im in sequence.images], [im.model for im in sequence.images]
    images[0][np.random.default_rng(0).random(images[0].shape) < 0.05] = np.nan  # digitizer dropouts
    images[1][40:60, 30:90] = np.nan  # a lost block of scan lines
    exact, exact_valid = remap_exact(images, models, grid, method)
    assert 0.2 < exact_valid.mean() < 0.9  # swath edges and missing data cross the grid
    # neighbouring pixels differ by at most `step`
    step = max(np.nanmax(np.abs(np.diff(image, axis=a))) for image in images for a in (0, 1))
    for max_error in (0.05, 0.3):
        fast, valid = remap(images, models, grid, method, max_error_pixels=max_error)
        np.testing.assert_array_equal(valid, exact_valid)
        assert np.isnan(fast[~valid]).all() and np.isfinite(fast[valid]).all()
        difference = np.abs(fast - exact)[valid]
        if method == "bilinear":  # positions off by the map's error + 1/64 (cv2's 1/32-pixel weights)
            assert difference.max() <= (max_error + 1 / 64) * np.sqrt(2) * step
            assert np.sqrt(np.mean(difference**2)) < 0.01 * step
        else:  # the nearest pixel changes only for positions within the map's error of a half pixel
            assert np.mean(difference > 0) < 2 * 2 * max_error
    # threshold 0 is the exact path
    zero, zero_valid = remap(images, models, grid, method, max_error_pixels=0.0)
    np.testing.assert_array_equal(zero, exact)
    np.testing.assert_array_equal(zero_valid, exact_valid)
    with pytest.raises(SeaiceError, match="max_error_pixels must be >= 0"):
        remap(images, models, grid, max_error_pixels=-1.0)


def test_equirectangular_image_grid_of_source_001():
    grid = ImageGrid(np.radians(74.0), np.radians(-87.0), 50.5, 40.5, 1000.0, 1200.0)
    raster = MapGrid.from_image_grid(grid, 80, 100)
    lat, lon = raster.latitude_longitude()
    pixel, line = grid.forward(lat, lon)
    columns, rows = np.meshgrid(np.arange(100), np.arange(80))
    np.testing.assert_allclose(pixel, columns + 1.0, atol=1e-9)
    np.testing.assert_allclose(line, rows + 1.0, atol=1e-9)


def tracking_truth(sequence, grid, d, first, second):
    """Displacement (grid pixels) of the ground at each start point, and whether the point's surroundings are
    all pack ice or all static (the tracking patch sees one motion)."""
    scene = sequence.scene
    x, y = (np.asarray(a) for a in grid.to_xy(d.row, d.column))
    xy = np.stack([x, y], -1)  # the grid is in the scene's projection
    end = xy + true_displacement(scene, xy, first.time, second.time)
    rows, columns = (np.asarray(a) for a in grid.to_pixel(end[:, 0], end[:, 1]))
    pack = np.asarray(scene.is_pack(xy))
    margin = 12 * float(grid.pixel_width)
    offsets = [np.array([a, b]) for a in (-margin, 0, margin) for b in (-margin, 0, margin)]
    uniform = np.all([np.asarray(scene.is_pack(xy + o)) == pack for o in offsets], axis=0)
    return rows - d.row, columns - d.column, uniform


@pytest.fixture(scope="module")
def clear_pair():
    """Two clear images remapped into one 150 x 150 grid, with their simulation (shared by both first guesses)."""
    sequence = simulate_sequence(1, n_images=2, size=256)
    grid = scene_grid(sequence.scene, 2500.0, 150, 150)
    (a, b), _ = remap([im.data for im in sequence.images], [im.model for im in sequence.images], grid)
    return sequence, grid, a, b


@pytest.mark.parametrize("first_guess", ["zero", "features"])
def test_tracking_recovers_the_motion_field_on_clear_images(clear_pair, first_guess):
    sequence, grid, a, b = clear_pair
    d = track(a, b, TrackingOptions(first_guess=first_guess))
    true_row, true_column, uniform = tracking_truth(sequence, grid, d, *sequence.images)
    good = d.good & uniform
    assert good.sum() > 100  # pack ice between the real coasts (GSHHG) of Lancaster Sound and Baffin Bay
    assert np.abs(true_column[good]).max() > 1.0  # the ice moved more than a pixel
    error = np.hypot(d.d_row[good] - true_row[good], d.d_column[good] - true_column[good])
    assert np.sqrt(np.mean(error**2)) < 0.3


def test_quality_flags_reject_cloud_covered_patches():
    sequence = simulate_sequence(1, n_images=2, size=256, clouds=True)
    grid = scene_grid(sequence.scene, 2500.0, 150, 150)
    (a, b), _ = remap([im.data for im in sequence.images], [im.model for im in sequence.images], grid)
    d = track(a, b)
    clouds = sequence.images[1].clouds
    assert clouds is not None
    centres, radii = clouds
    x, y = (np.asarray(v) for v in grid.to_xy(d.row, d.column))
    distance = np.min(np.hypot(x[:, None] - centres[:, 0], y[:, None] - centres[:, 1]) / radii, axis=1)
    under = distance < 0.7
    assert under.sum() >= 5
    assert not d.good[under].any()
    true_row, true_column, uniform = tracking_truth(sequence, grid, d, *sequence.images)
    # away from the clouds what passes is as right as on clear images; at a cloud's translucent edge (1-1.5
    # radii) some vectors pass the flags with the cloud's motion mixed in (~0.6 pixel here)
    clear = d.good & uniform & (distance > 1.5)
    error = np.hypot(d.d_row[clear] - true_row[clear], d.d_column[clear] - true_column[clear])
    assert clear.sum() > 40 and np.sqrt(np.mean(error**2)) < 0.3  # pack ice between real coasts (GSHHG)
    flat = track(np.full((60, 60), 0.9), np.full((60, 60), 0.9))
    assert (flat.status == LOW_CONTRAST).all() and GOOD not in flat.status


@pytest.mark.slow
def test_radar_strip_orthorectified_through_the_range_doppler_inverse_reproduces_the_ground():
    import jax.numpy as jnp

    from seaice_jax.geometry.earth import latitude_longitude
    from seaice_jax.imagery.remap import orthorectify_strip
    from seaice_jax.sensors.strips import strip_navigation
    from seaice_jax.simulate.aircraft import ErrorModel, FlightPlan, render_strip, simulate_flight
    from seaice_jax.simulate.satellite import ice_scene

    (strip,), (truth_of_strip,) = simulate_flight(FlightPlan(strips=1, strip_duration=120.0), ErrorModel.none(),
                                                  np.random.default_rng(0))
    middle = jnp.asarray(strip.record_positions[len(strip.record_positions) // 2])
    lat, lon = (float(a) for a in latitude_longitude(middle))
    scene = ice_scene(np.random.default_rng(1), np.degrees(lat) - 3, np.degrees(lon), feature_size=2000.0)
    raster = render_strip(scene, strip, truth_of_strip, pixel_size=0.2)  # 50 m of slant range per pixel
    grid = MapGrid.centred(scene.projection, lat, lon, 400.0, 400.0, 80, 80)
    navigation = strip_navigation(strip, None)
    arguments = (strip.mark_x, strip.mark_times, truth_of_strip.sweep_delay, truth_of_strip.range_scale)
    values, valid = orthorectify_strip(raster, navigation, *arguments, strip.look_side, grid)
    x, y = grid.xy()
    truth = np.asarray(scene.brightness(jnp.stack([x, y], -1), 0.0))
    assert 0.2 < valid.mean() < 0.6  # one side of the track, within the strip's time span
    assert np.sqrt(np.mean((values[valid] - truth[valid]) ** 2)) < 0.02
    shift, _ = cv2.phaseCorrelate(np.where(valid, truth, 0).astype(np.float32),
                                  np.where(valid, values, 0).astype(np.float32))
    assert np.hypot(shift[0], shift[1]) < 0.1
    # the default approximate transformer + cv2.remap has the exact path's mask and values within its threshold
    exact, exact_valid = orthorectify_strip(raster, navigation, *arguments, strip.look_side, grid, max_error_pixels=0.0)
    np.testing.assert_array_equal(valid, exact_valid)
    data = np.asarray(raster.data)
    step = max(np.nanmax(np.abs(np.diff(data, axis=a))) for a in (0, 1))
    assert np.abs(values - exact)[valid].max() <= (0.05 + 1 / 64) * np.sqrt(2) * step
    # the wrong look side sees nothing of it where the true side does, and a wrong sweep delay misplaces it
    _, left = orthorectify_strip(raster, navigation, *arguments, "left", grid)
    assert not (left & valid).any()
    shifted, moved = orthorectify_strip(raster, navigation, strip.mark_x, strip.mark_times,
                                        truth_of_strip.sweep_delay + 2.0, truth_of_strip.range_scale, strip.look_side,
                                        grid)
    both = moved & valid
    assert np.sqrt(np.mean((shifted[both] - truth[both]) ** 2)) > 0.05
