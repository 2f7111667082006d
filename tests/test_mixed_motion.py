"""The mixed-motion flag of the tracker (issue 29): a vector whose patch straddles two motions (pack ice beside fast
ice or land) is flagged MIXED_MOTION — by the land in its patch, or by its satellite patches disagreeing beyond their
σ — and a vector of one motion is not; the flag is OSI SAF's close_to_coast_or_edge in the OSI SAF layout."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter, shift

from seaice_jax.errors import SeaiceError
from seaice_jax.imagery.tracking import (
    GOOD,
    MIXED_MOTION,
    MIXED_MOTION_THRESHOLD,
    ON_LAND,
    STATUS,
    TrackingOptions,
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
    # without the test, the vectors on the edge are good, and they err by far more than their σ
    unflagged = track(first, second, replace(no_median_test, mixed_motion_threshold=None), points=(rows, columns))
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
