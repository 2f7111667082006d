"""Automatic tie points on the static surface of a simulated sequence, scored against the true scan models."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from seaice_jax.adjust.sequence.model import scan_unknowns, with_scan_unknowns
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.projections import MapGrid
from seaice_jax.imagery.ties import TieOptions, find_ties, grid_mask, image_runs, transfer
from seaice_jax.imagery.tracking import AT_EDGE, GOOD, LOW_CORRELATION, NO_DATA
from seaice_jax.simulate.satellite import ice_scene, land_mask, simulate_sequence

MODEL_SIGMA = np.array([2e-4, 0.5, 2e-4, 2e-4, 3e-4])
"""σ of the five unknowns of the 'current' models (radians, pixel): about 1 pixel (2-3 km) of geolocation error,
as per-image fits to 12 control points have."""


def static_surface(scene):
    """Land and fast ice (3 km inside the pack-ice edge), from the scene's coastline."""

    @jax.jit
    def static(latitude, longitude):
        xy = jnp.stack(scene.projection.forward(latitude, longitude), axis=-1)
        return scene.coast_offset(xy) > -scene.fast_ice_width + 3000.0

    return lambda latitude, longitude: np.asarray(static(jnp.asarray(latitude), jnp.asarray(longitude)))


@pytest.fixture(scope="module")
def sequence():
    return simulate_sequence(0, n_images=3, size=256)


@pytest.fixture(scope="module")
def current(sequence):
    """The models the ties are matched through: the truth plus N(0, MODEL_SIGMA) in every unknown."""
    rng = np.random.default_rng(11)
    models = [with_scan_unknowns(im.model, scan_unknowns(im.model) + rng.normal(0, MODEL_SIGMA))
              for im in sequence.images]
    return models, [np.diag(MODEL_SIGMA**2)] * len(models)


@pytest.fixture(scope="module")
def ties(sequence, current):
    models, covariances = current
    return find_ties([im.data for im in sequence.images], models, static_surface(sequence.scene), covariances)


def true_errors(ties, sequence):
    """Per matched observation: its (pixel, scan) minus the true correspondent of its tie's reference
    observation (true models), and the σ of the difference."""
    truth = [im.model for im in sequence.images]
    matched = np.nonzero(~ties.reference)[0]
    reference = reference_rows(ties, matched)
    errors = np.zeros((matched.size, 2))
    for a, b in {(int(ties.image[r]), int(ties.image[k])) for k, r in zip(matched, reference, strict=True)}:
        on = (ties.image[reference] == a) & (ties.image[matched] == b)  # one call per pair of images
        p, s = transfer(truth[a], truth[b], ties.pixel[reference[on]], ties.scan[reference[on]])
        errors[on] = np.stack([ties.pixel[matched[on]] - p, ties.scan[matched[on]] - s], axis=1)
    sigmas = np.stack([np.hypot(ties.sigma_pixel[matched], ties.sigma_pixel[reference]),
                       np.hypot(ties.sigma_scan[matched], ties.sigma_scan[reference])], axis=1)
    return errors, sigmas


def reference_rows(ties, rows):
    """The row of the reference observation of each row's tie."""
    reference = np.full(ties.n_ties, -1)
    reference[ties.tie[ties.reference]] = np.nonzero(ties.reference)[0]
    return reference[ties.tie[rows]]


def test_hundreds_of_ties_on_every_overlapping_pair(ties):
    counts = ties.pair_counts()
    assert set(counts) == {(0, 1), (0, 2), (1, 2)}
    assert min(counts.values()) >= 100, counts
    assert all(2 <= s <= 10 for s in ties.search.values()), ties.search  # ~4 σ of ~1 px, not the maximum 30


def test_tie_ids_are_shared_across_images(ties):
    per_tie = np.bincount(ties.tie, minlength=ties.n_ties)
    assert per_tie.min() >= 2 and per_tie.max() <= 3 and np.any(per_tie == 3)
    assert np.all(np.bincount(ties.tie[ties.reference], minlength=ties.n_ties) == 1)
    for t in np.nonzero(per_tie == 3)[0][:20]:
        assert set(ties.image[ties.tie == t]) == {0, 1, 2}
    assert np.all(np.isnan(ties.correlation[ties.reference])) and np.all(ties.correlation[~ties.reference] >= 0.7)
    assert ties.latitude.size == ties.n_ties and ties.n_observations == ties.image.size


def test_ties_agree_with_the_true_models_to_a_fraction_of_a_pixel(ties, sequence):
    """The matched position is the true correspondent whatever the errors of the models matched through
    (about a pixel here): RMS error < 0.15 pixel per coordinate, no blunder above half a pixel, and the stated σ
    is the error's (normalised RMS 0.7-1.2: the former 0.2 pixel floor made it 0.25)."""
    errors, sigmas = true_errors(ties, sequence)
    rms = np.sqrt(np.mean(errors**2, axis=0))
    assert np.all(rms < 0.15), rms
    assert np.abs(errors).max() < 0.5, np.abs(errors).max(axis=0)
    normalised = np.sqrt(np.mean((errors / sigmas) ** 2, axis=0))
    assert np.all((normalised >= 0.7) & (normalised <= 1.2)), normalised


def test_the_models_errors_are_what_the_matching_absorbs(ties, sequence, current):
    """Sanity of the scoring: the current models alone put the correspondents pixels away from the truth."""
    models, _ = current
    truth = [im.model for im in sequence.images]
    k = np.nonzero(~ties.reference)[0][:50]
    r = reference_rows(ties, k)
    shifts = []
    for a, b in {(int(ties.image[i]), int(ties.image[j])) for j, i in zip(k, r, strict=True)}:
        on = (ties.image[r] == a) & (ties.image[k] == b)  # one call per pair of images
        predicted = transfer(models[a], models[b], ties.pixel[r[on]], ties.scan[r[on]])
        true = transfer(truth[a], truth[b], ties.pixel[r[on]], ties.scan[r[on]])
        shifts.append(np.hypot(predicted[0] - true[0], predicted[1] - true[1]))
    assert np.sqrt(np.mean(np.square(np.concatenate(shifts)))) > 0.5


@pytest.mark.slow
def test_an_unrelated_image_gives_no_ties(sequence, current):
    """Image 1 replaced by unrelated texture: its matches fail the correlation (or later) tests, images 0 and 2
    still tie."""
    models, covariances = current
    images = [im.data for im in sequence.images]
    images[1] = np.random.default_rng(3).uniform(0.0, 1.0, images[1].shape)
    ties = find_ties(images, models, static_surface(sequence.scene), covariances)
    counts = ties.pair_counts()
    assert counts.get((0, 1), 0) + counts.get((1, 2), 0) <= 2, counts
    assert counts[(0, 2)] >= 100
    tried = np.sum([counts for pair, counts in ties.candidates.items() if 1 in pair], axis=0)
    assert tried.sum() - tried[NO_DATA] >= 100 and tried[GOOD] <= 2, tried
    assert tried[LOW_CORRELATION] + tried[AT_EDGE] >= 0.9 * (tried.sum() - tried[NO_DATA]), tried


@pytest.mark.slow
def test_search_window_follows_the_models_uncertainty(ties, sequence, current):
    models, covariances = current
    static = static_surface(sequence.scene)
    images = [im.data for im in sequence.images]
    narrow = ties  # matched through the same models and covariances
    wide = find_ties(images, models, static, [4 * c for c in covariances])  # σ × 2
    for pair, search in narrow.search.items():
        assert 2 * (search - 1) - 1 <= wide.search[pair] - 1 <= 2 * (search - 1) + 1
    fixed = find_ties(images, models, static, options=TieOptions(search=7))
    assert set(fixed.search.values()) == {7}


def test_grid_mask_follows_the_raster():
    scene = ice_scene(np.random.default_rng(2))
    grid = MapGrid.centred(scene.projection, np.radians(74.0), np.radians(-85.0), 5000.0, 5000.0, 160, 160)
    mask = land_mask(scene, grid)
    static = grid_mask(grid, mask)
    rng = np.random.default_rng(4)
    row, column = rng.uniform(0, 159, (2, 400))
    x, y = grid.to_xy(row, column)
    latitude, longitude = scene.projection.inverse(x, y)
    expected = mask[np.rint(row).astype(int), np.rint(column).astype(int)]
    np.testing.assert_array_equal(static(latitude, longitude), expected)
    assert 0.1 < expected.mean() < 0.9
    assert not static(np.radians(60.0), np.radians(-85.0))  # off the grid
    with pytest.raises(SeaiceError, match="mask shape"):
        grid_mask(grid, mask[1:])


def test_land_relief_is_static_and_deterministic():
    """The same seed gives the same land; land does not change with time; pack ice does."""
    first, second = ice_scene(np.random.default_rng(9)), ice_scene(np.random.default_rng(9))
    xy = jnp.stack(jnp.meshgrid(jnp.linspace(-50e3, 50e3, 40), jnp.linspace(-50e3, 50e3, 40)), axis=-1)
    inland = jnp.stack(first.projection.forward(np.radians(71.0), np.radians(-82.0)))  # Baffin Island (GSHHG)
    offshore = jnp.stack(first.projection.forward(np.radians(74.0), np.radians(-72.0)))  # Baffin Bay
    land, pack = inland[None, None, :] + 0.4 * xy, offshore[None, None, :] + xy  # land: > 50 km from the sea
    assert np.all(np.asarray(first.coast_offset(land)) > 0) and np.all(np.asarray(first.is_pack(pack)))
    np.testing.assert_array_equal(np.asarray(first.brightness(land, 0.0)), np.asarray(second.brightness(land, 0.0)))
    np.testing.assert_array_equal(np.asarray(first.brightness(land, 0.0)), np.asarray(first.brightness(land, 86400.0)))
    assert np.abs(np.asarray(first.brightness(pack, 0.0) - first.brightness(pack, 86400.0))).max() > 0.1
    assert float(np.std(np.asarray(first.brightness(land, 0.0)))) > 0.05  # relief texture, not a flat plateau


@pytest.mark.parametrize("count", [2, 5, 6, 7, 12, 200])
def test_image_runs_are_bounded_consecutive_and_chained(count):
    """A point seen by ``count`` images (not in order, with gaps): runs of at most 6 of them, consecutive in
    sequence order, each sharing its last image with the next run's first, covering every image once more per
    join, of near-equal length; at most 6 images: one run."""
    rng = np.random.default_rng(count)
    images = rng.permutation(rng.choice(3 * count, count, replace=False))
    runs = image_runs(images, 6)
    ordered = np.sort(images)
    assert all(2 <= run.size <= 6 for run in runs)
    assert all(run[-1] == following[0] for run, following in zip(runs[:-1], runs[1:], strict=True))
    np.testing.assert_array_equal(np.concatenate([runs[0]] + [run[1:] for run in runs[1:]]), ordered)
    assert len(runs) == (1 if count <= 6 else -(-(count - 1) // 5))
    assert max(run.size for run in runs) - min(run.size for run in runs) <= 1


@pytest.mark.slow
def test_a_point_seen_by_more_images_than_the_cap_gives_chained_ties(sequence, current):
    """The three images with at most two per tie: every tie joins two images; the ties of one ground point
    (grouped by their positions, 8 pixels apart between points) are consecutive runs of the images that see it,
    sharing one image (a point seen by all three: images 0-1 and 1-2, never 0-2), so the images stay connected;
    the default cap leaves these points one tie of three observations."""
    models, covariances = current
    images = [im.data for im in sequence.images]
    static = static_surface(sequence.scene)
    split = find_ties(images, models, static, covariances, TieOptions(max_images=2, spacing=8.0))
    whole = find_ties(images, models, static, covariances, TieOptions(spacing=8.0))
    assert np.all(np.bincount(split.tie) == 2)
    per_tie = [frozenset(split.image[split.tie == t].tolist()) for t in range(split.n_ties)]
    north = 6_371_000.0 * split.latitude
    east = 6_371_000.0 * split.longitude * np.cos(split.latitude)
    distance = np.hypot(north[:, None] - north[None, :], east[:, None] - east[None, :])
    same = distance < 8_000.0  # the lattice is ~20 km (8 pixels of ~2.4 km), a tie's position within a pixel
    chained = 0
    for t in range(split.n_ties):
        group = [per_tie[u] for u in np.nonzero(same[t])[0]]
        assert len(group) <= 2, group
        if len(group) == 2:
            assert sorted(map(sorted, group)) == [[0, 1], [1, 2]], group
            chained += 1
    three = int(np.sum(np.bincount(whole.tie) == 3))
    assert chained // 2 >= 0.8 * three >= 40, (chained, three)
    counts = split.pair_counts()
    assert counts[(0, 1)] >= 40 and counts[(1, 2)] >= 40, counts
    assert counts.get((0, 2), 0) < 0.5 * min(counts[(0, 1)], counts[(1, 2)]), counts  # points image 1 misses
    with pytest.raises(SeaiceError, match="max_images"):
        TieOptions(max_images=1)

