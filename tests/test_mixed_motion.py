"""The mixed-motion flag of the tracker (issue 29): a vector whose patch straddles two motions (pack ice beside fast
ice or land) is flagged MIXED_MOTION — by the land in its patch, or by its satellite patches disagreeing beyond their
σ — and a vector of one motion is not; the flag is OSI SAF's close_to_coast_or_edge in the OSI SAF layout."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter, shift

from seaice_jax.errors import SeaiceError
from seaice_jax.imagery.tracking import (
    DISAGREEMENT_REFERENCE,
    DISAGREEMENT_SCALE,
    GOOD,
    MIXED_MOTION,
    MIXED_MOTION_THRESHOLD,
    ON_LAND,
    STATUS,
    TrackingOptions,
    disagreement_reference,
    disagreement_variance_scale,
    neighbour_disagreement,
    patch_touches_land,
    track,
)
from seaice_jax.io.products import OSISAF_STATUS, TO_OSISAF_STATUS

SIZE = 120
MOTION = (2.0, 1.5)  # pixels (row, column): the pack ice's displacement
EDGE = 60  # the first column of pack ice in the two-motion pair


def texture(seed: int) -> np.ndarray:
    """``(SIZE, SIZE)`` a smooth random texture of brightness σ about 0.15 (floes of a few pixels)."""
    field = gaussian_filter(np.random.default_rng(seed).normal(size=(SIZE, SIZE)), 1.5)
    return 0.5 + 0.15 * field / field.std()


def noisy(image: np.ndarray, seed: int) -> np.ndarray:
    return image + np.random.default_rng(seed).normal(0.0, 0.01, image.shape)


@pytest.fixture(scope="module")
def one_motion_pair():
    """The texture and the texture moved by ``MOTION`` everywhere, each with white noise of 0.01."""
    first = texture(1)
    return noisy(first, 2), noisy(shift(first, MOTION, order=3, mode="nearest"), 3)


@pytest.fixture(scope="module")
def two_motion_pair():
    """As ``one_motion_pair``, but only the columns from ``EDGE`` on move (pack ice); the rest stays (fast ice)."""
    first = texture(1)
    moved = shift(first, MOTION, order=3, mode="nearest")
    second = np.where(np.arange(SIZE)[None, :] >= EDGE, moved, first)
    return noisy(first, 2), noisy(second, 3)


def test_a_patch_across_two_motions_is_flagged_and_one_motion_is_not(two_motion_pair):
    on_edge = np.arange(30.0, 91.0, 10.0)  # rows of points on the first column of pack ice
    rows = np.concatenate([on_edge, on_edge])
    columns = np.concatenate([np.full(7, EDGE), np.full(7, 30.0)])  # on the edge; 30 pixels into the fast ice
    no_median_test = TrackingOptions(median_threshold=1e9)  # 14 points in two groups: not its case
    first, second = two_motion_pair
    across = track(first, second, no_median_test, points=(rows, columns))
    assert (across.status[:7] == MIXED_MOTION).all()  # the patch sees both: flagged
    assert (across.status[7:] == GOOD).all()  # its satellites all on fast ice: one motion
    np.testing.assert_allclose(across.d_row[7:], 0.0, atol=0.1)
    statistic = neighbour_disagreement(first, second, rows, columns)
    assert (statistic[:7] > 5 * MIXED_MOTION_THRESHOLD).all() and (statistic[7:] < MIXED_MOTION_THRESHOLD).all()
    # without the test, the vectors on the edge are good, and they err by far more than their peak's σ
    unflagged = track(first, second, replace(no_median_test, mixed_motion_threshold=None, disagreement_scale=None),
                      points=(rows, columns))
    assert (unflagged.status == GOOD).all()
    normalised = np.concatenate([(unflagged.d_row[:7] - MOTION[0]) / unflagged.sigma_row[:7],
                                 (unflagged.d_column[:7] - MOTION[1]) / unflagged.sigma_column[:7]])
    assert np.sqrt(np.mean(normalised**2)) > 3.0


def test_one_motion_is_not_flagged(one_motion_pair):
    first, second = one_motion_pair
    tracked = track(first, second)
    assert tracked.status.size > 100
    assert not (tracked.status == MIXED_MOTION).any()
    good = tracked.good
    assert good.mean() > 0.9
    np.testing.assert_allclose(tracked.d_row[good], MOTION[0], atol=0.2)
    statistic = neighbour_disagreement(first, second, tracked.row[good], tracked.column[good])
    assert np.isfinite(statistic).mean() > 0.9 and np.nanmax(statistic) < MIXED_MOTION_THRESHOLD


def test_land_in_the_patch_is_mixed_motion_and_land_itself_on_land(one_motion_pair):
    land = np.zeros((SIZE, SIZE), bool)
    land[:, :20] = True
    first, second = one_motion_pair
    rows, columns = np.array([60.0, 60.0, 60.0]), np.array([10.0, 25.0, 60.0])  # on land, 5 px off, far off
    for options in (TrackingOptions(), TrackingOptions(mixed_motion_threshold=None)):  # the land rule is not optional
        status = track(first, second, options, points=(rows, columns), land=land).status
        assert status.tolist() == [ON_LAND, MIXED_MOTION, GOOD]


def test_patch_touches_land_counts_the_square_and_nothing_off_the_grid():
    land = np.zeros((10, 10), bool)
    land[5, 5] = True
    rows = np.array([5.0, 2.0, 3.0, 5.4, np.nan, -3.0, 12.0])
    columns = np.array([8.0, 2.0, 3.0, 7.4, 5.0, 5.0, 5.0])
    touches = patch_touches_land(land, rows, columns, 2)
    assert touches.tolist() == [False, False, True, True, False, False, False]
    assert patch_touches_land(land, np.array([12.0]), np.array([5.0]), 7).tolist() == [True]  # the square reaches


def test_the_flag_is_osisaf_close_to_coast_or_edge_and_the_threshold_must_be_positive():
    assert OSISAF_STATUS[TO_OSISAF_STATUS[MIXED_MOTION]] == "close_to_coast_or_edge"
    assert MIXED_MOTION == max(STATUS)  # appended: the earlier codes keep their numbers
    with pytest.raises(SeaiceError, match="mixed_motion_threshold"):
        TrackingOptions(mixed_motion_threshold=0.0)


def test_the_sigma_is_scaled_by_the_neighbour_statistic(two_motion_pair):
    """σ² from the peak times a + b χ²_ν / m where the neighbour statistic is measured (m: its median over the call's
    vectors the flag leaves), the peak's alone where not (issue 29: the vectors across the fast-ice edge the flag
    misses erred by 1.11 times the peak's σ; their χ²_ν is larger than the pair's typical one)."""
    first, second = two_motion_pair
    # fast ice far from the edge, patches that straddle it (the patch's half is 7 pixels), pack ice far from it
    across = np.arange(EDGE - 7.0, EDGE + 8.0)
    rows = np.repeat(np.arange(30.0, 91.0, 10.0), across.size + 2)
    columns = np.tile([30.0, *across, 90.0], 7)
    options = TrackingOptions(median_threshold=1e9)
    scaled = track(first, second, options, points=(rows, columns))
    peak = track(first, second, replace(options, disagreement_scale=None), points=(rows, columns))
    assert scaled.disagreement is not None and peak.disagreement is not None
    np.testing.assert_array_equal(scaled.status, peak.status)  # the scale moves no vector and flags nothing
    np.testing.assert_array_equal(scaled.disagreement, peak.disagreement)
    tested = np.isfinite(scaled.disagreement)
    assert tested.sum() >= 40 and not tested[~(scaled.good | (scaled.status == MIXED_MOTION))].any()
    np.testing.assert_allclose(scaled.disagreement[tested], neighbour_disagreement(
        first, second, rows[tested], columns[tested]), rtol=1e-12)
    a, b = DISAGREEMENT_SCALE
    kept = scaled.disagreement[tested & (scaled.status == GOOD)]  # measured and not flagged
    assert kept.size >= 20 and disagreement_reference(scaled.disagreement) == np.median(kept)
    factor = np.where(tested, a + b * np.nan_to_num(scaled.disagreement) / np.median(kept), 1.0)
    for axis in ("sigma_row", "sigma_column"):
        np.testing.assert_allclose(getattr(scaled, axis), getattr(peak, axis) * np.sqrt(factor), rtol=1e-12)
    # the good vectors across the edge (the flag misses some) get a larger σ than those far from it
    straddling = scaled.good & (np.abs(columns - EDGE) <= 7)
    far = scaled.good & ((columns == 30.0) | (columns == 90.0))
    assert straddling.sum() >= 5 and far.sum() == 14
    assert np.median(factor[straddling]) > 1.0 > 2 * np.median(factor[far])
    unscaled = track(first, second, replace(options, mixed_motion_threshold=None, disagreement_scale=None),
                     points=(rows, columns))
    assert unscaled.disagreement is None  # no neighbour test at all: σ from the peak
    np.testing.assert_array_equal(unscaled.sigma_row, peak.sigma_row)
    with pytest.raises(SeaiceError, match="disagreement_scale"):
        TrackingOptions(disagreement_scale=(-0.1, 0.5))


def test_the_reference_of_the_scale_is_the_calls_median_or_the_tuned_one_for_few_vectors():
    statistic = np.array([0.5, 1.0, 2.0, 9.0, np.nan] * 5)  # 20 measured, 15 of them at most the threshold 4
    assert disagreement_reference(statistic) == DISAGREEMENT_REFERENCE  # too few for the call's own median
    many = np.concatenate([statistic, [1.0] * 5])  # now 20 kept, median 1.0 (9.0 is flagged: not counted)
    assert disagreement_reference(many) == 1.0
    assert disagreement_reference(many, TrackingOptions(mixed_motion_threshold=None)) == 1.0  # 25 measured, all kept
    a, b = DISAGREEMENT_SCALE
    np.testing.assert_allclose(disagreement_variance_scale(many)[:5], [a + b * 0.5, a + b, a + 2 * b, a + 9 * b, 1.0])
    np.testing.assert_array_equal(disagreement_variance_scale(many, TrackingOptions(disagreement_scale=None)), 1.0)
