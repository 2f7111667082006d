"""The approximate transformer (seaice_jax.imagery.approximate) against closed-form transforms (its use by the
remapping paths is tested in tests/test_imagery.py against the exact inverse of every output pixel)."""

import numpy as np
import pytest

from seaice_jax.imagery.approximate import approximate_maps


def curved(image, row, column):
    """A closed-form transform with strong higher-order terms, defined left of a tilted line."""
    source_row = row + 1.5 * np.sin(row / 13.0) + 0.004 * column**2 / (1.0 + image)
    source_column = 0.8 * column + 1.0 * np.cos(column / 10.0 + row / 15.0)
    return source_row, source_column, row + 0.37 * column < 41.3


@pytest.mark.parametrize("max_error", [0.2, 0.05, 0.01])
def test_closed_form_transform_within_the_threshold_at_every_pixel(max_error):
    shape = (70, 90)  # not a multiple of the tile
    maps = approximate_maps(curved, 2, shape, max_error, step=16)
    index, row, column = np.meshgrid(np.arange(2), np.arange(70.0), np.arange(90.0), indexing="ij")
    truth_row, truth_column, truth_ok = curved(index, row, column)
    np.testing.assert_array_equal(maps.ok, truth_ok)  # the boundary of the defined region is exact
    error = np.hypot(maps.row - truth_row, maps.column - truth_column)[truth_ok]
    assert error.max() <= max_error
    assert 0.1 * max_error < error.max()  # interpolated, not exact everywhere
    assert np.isnan(maps.row[~truth_ok]).all()
    assert maps.exact_points < 0.6 * row.size
    exact = approximate_maps(curved, 2, shape, 0.0)
    np.testing.assert_array_equal(exact.row[truth_ok], truth_row[truth_ok])
    np.testing.assert_array_equal(exact.ok, truth_ok)


def test_pixels_near_an_edge_are_exact_and_bad_options_named():
    shape = (64, 64)
    maps = approximate_maps(curved, 1, shape, 0.2, step=16, row_edges=(20.5,), column_edges=(-0.5, 30.5))
    index, row, column = np.meshgrid(np.arange(1), np.arange(64.0), np.arange(64.0), indexing="ij")
    truth_row, truth_column, truth_ok = curved(index, row, column)
    near = truth_ok & ((np.abs(maps.row - 20.5) <= 0.2) | (np.abs(maps.column - 30.5) <= 0.2)
                       | (np.abs(maps.column + 0.5) <= 0.2))
    assert near.sum() > 20
    np.testing.assert_array_equal(maps.row[near], truth_row[near])
    np.testing.assert_array_equal(maps.column[near], truth_column[near])
    # so no pixel lands on the other side of an edge than its exact position
    for approximate, exact, edge in ((maps.row, truth_row, 20.5), (maps.column, truth_column, 30.5)):
        assert np.array_equal(approximate[truth_ok] <= edge, exact[truth_ok] <= edge)
    with pytest.raises(ValueError, match="step must be a power of two"):
        approximate_maps(curved, 1, shape, 0.05, step=12)
    with pytest.raises(ValueError, match="max_error must be >= 0"):
        approximate_maps(curved, 1, shape, -0.1)
