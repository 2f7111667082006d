"""The GSHHG coastline: clipped, projected and as a land mask, checked against independent truth — pyproj's
projection of the same vertices, places whose land or water is known, and roaring-landmask's own point-in-land test
(its raster mask plus its own polygon test, a second implementation over the same shoreline)."""

import importlib

import numpy as np
import pyproj
import pytest
import shapely
from scipy.spatial import KDTree

from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.crs import CrsProjection
from seaice_jax.geometry.projections import MapGrid, TangentPlane, nsidc_polar_stereographic
from seaice_jax.io.coastline import bounds_of_grid, bucketed, coastline, coastline_of_grid, land_mask_of_grid

KNOWN = [  # (name, latitude, longitude degrees, on land)
    ("Devon Island, centre", 75.3, -87.5, True),
    ("Bylot Island, centre", 73.25, -78.6, True),
    ("Baffin Island, Borden Peninsula", 72.8, -84.0, True),
    ("Lancaster Sound", 74.2, -84.0, False),
    ("Baffin Bay", 73.5, -68.0, False),
    ("Deadhorse, by Prudhoe Bay", 70.2, -148.45, True),
    ("Beaufort Sea off Prudhoe Bay", 70.9, -148.4, False),
]


@pytest.fixture(scope="module")
def lancaster():
    return coastline(-95.0, 71.0, -70.0, 77.0)


def test_coastline_in_epsg3413_agrees_with_pyproj(lancaster):
    projection = nsidc_polar_stereographic("north")
    lines = lancaster.projected(projection)
    lonlat = np.concatenate(lancaster.shorelines())
    x, y = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:3413", always_xy=True).transform(lonlat[:, 0], lonlat[:, 1])
    ours = np.concatenate(lines)
    assert ours.shape == (len(x), 2) and len(x) > 10_000
    np.testing.assert_allclose(ours, np.column_stack([x, y]), rtol=0, atol=1e-3)  # millimetres


def test_shorelines_leave_out_the_clipping_box(lancaster):
    west, south, east, north = lancaster.bounds
    rings = np.concatenate(lancaster.rings())
    on_edge = np.isclose(rings[:, 0], west) | np.isclose(rings[:, 0], east) | np.isclose(rings[:, 1], south)
    assert on_edge.sum() > 10  # land runs out of the box: the rings follow its edges
    for line in lancaster.shorelines():
        edge = (np.isclose(line[:, 0], west) | np.isclose(line[:, 0], east) | np.isclose(line[:, 1], south)
                | np.isclose(line[:, 1], north))
        assert not (edge[:-1] & edge[1:]).any()


@pytest.mark.parametrize("name, latitude, longitude, land", KNOWN)
def test_known_places_land_where_the_land_mask_says(name, latitude, longitude, land):
    projection = nsidc_polar_stereographic("north")
    grid = MapGrid.centred(projection, np.radians(latitude), np.radians(longitude), 2500.0, 2500.0, 41, 41)
    mask = land_mask_of_grid(grid)
    x, y = projection.forward(np.radians(latitude), np.radians(longitude))
    row, column = (int(round(float(v))) for v in grid.to_pixel(x, y))
    assert (row, column) == (20, 20)
    assert mask[row, column] == land, name
    box = coastline_of_grid(grid)
    assert box.contains(latitude, longitude) == land, name


@pytest.mark.slow
def test_land_mask_agrees_with_roaring_landmask():
    roaring_landmask = importlib.import_module("roaring_landmask")  # a compiled module without type stubs

    grid = MapGrid.centred(nsidc_polar_stereographic("north"), np.radians(74.0), np.radians(-85.0), 5000.0,
                           5000.0, 80, 90)
    latitude, longitude = (np.degrees(a) for a in bucketed(grid.projection.inverse, *grid.xy()))
    reference = roaring_landmask.RoaringLandmask.new_with_provider(roaring_landmask.LandmaskProvider.Gshhg)
    theirs = np.asarray(reference.contains_many(longitude.ravel(), latitude.ravel())).reshape(grid.shape)
    ours = land_mask_of_grid(grid)
    assert 0.2 < ours.mean() < 0.8
    np.testing.assert_array_equal(ours, theirs)


def test_a_box_across_the_antimeridian():
    chukchi = coastline(170.0, 64.0, -165.0, 72.0)
    assert chukchi.contains(71.25, -179.5)  # Wrangel Island
    assert chukchi.contains(65.5, 178.0)  # Chukotka
    assert chukchi.contains(65.4, -166.0)  # Alaska, Seward Peninsula
    assert not chukchi.contains(68.0, -170.0)  # Chukchi Sea
    ends = np.concatenate([line[[0, -1]] for line in chukchi.shorelines()])
    assert np.abs(ends[:, 0]).max() <= 180.0
    for line in chukchi.shorelines():  # GSHHG's cut at the antimeridian is no coast
        at_cut = np.isclose(np.abs(line[:, 0]), 180.0)
        assert not (at_cut[:-1] & at_cut[1:]).any()


def test_a_grid_around_the_pole_takes_every_longitude():
    grid = MapGrid.centred(nsidc_polar_stereographic("north"), np.radians(90.0), 0.0, 50e3, 50e3, 40, 40)
    west, south, east, north = bounds_of_grid(grid, margin=0.0)
    assert (west, east, north) == (-180.0, 180.0, 90.0)
    latitude, _ = (np.degrees(a) for a in bucketed(grid.projection.inverse, *grid.xy()))
    assert south == pytest.approx(latitude.min())


def test_tangent_plane_lines_break_on_the_far_side():
    plane = TangentPlane(np.radians(74.0), np.radians(-85.0))
    coast = coastline(-180.0, 60.0, 180.0, 90.0)
    lines = coast.projected(plane, tolerance=5000.0)
    points = np.concatenate(lines)
    assert np.isfinite(points).all()
    assert np.hypot(*points.T).max() <= float(plane.radius) + 1.0


def test_simplified_lines_keep_their_vertices_and_stay_within_the_tolerance(lancaster):
    projection = nsidc_polar_stereographic("north")
    full = np.concatenate(lancaster.projected(projection))
    simplified = lancaster.projected(projection, tolerance=500.0)
    kept = np.concatenate(simplified)
    assert len(kept) < 0.5 * len(full)
    distance, _ = KDTree(full).query(kept)
    assert distance.max() < 1e-6  # Douglas-Peucker keeps a subset of the vertices
    lines = shapely.multilinestrings([shapely.linestrings(line) for line in simplified])
    assert shapely.distance(shapely.points(full), lines).max() <= 500.0 + 1e-6  # no vertex further than asked


def test_bucketed_equals_the_direct_evaluation():
    projection = nsidc_polar_stereographic("north")
    rng = np.random.default_rng(3)
    for size in (0, 1, 17, 300):
        latitude, longitude = np.radians(rng.uniform(60, 89, size)), np.radians(rng.uniform(-180, 180, size))
        x, y = bucketed(projection.forward, latitude, longitude)
        assert x.shape == (size,)
        if size:
            direct = projection.forward(latitude, longitude)
            np.testing.assert_allclose(x, np.asarray(direct[0]), rtol=0, atol=1e-6)
            np.testing.assert_allclose(y, np.asarray(direct[1]), rtol=0, atol=1e-6)
    # a PROJ-defined grid (evaluated by PROJ on the host) both ways, against the package's own EPSG:3413
    proj = CrsProjection("EPSG:3413")
    latitude, longitude = np.radians(rng.uniform(60, 89, 50)), np.radians(rng.uniform(-180, 180, 50))
    x, y = bucketed(proj.forward, latitude, longitude)
    native = projection.forward(latitude, longitude)
    np.testing.assert_allclose(x, np.asarray(native[0]), rtol=0, atol=1e-3)
    np.testing.assert_allclose(y, np.asarray(native[1]), rtol=0, atol=1e-3)
    back = bucketed(proj.inverse, x, y)
    np.testing.assert_allclose(back[0], latitude, rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.cos(back[1] - longitude), 1.0, rtol=0, atol=1e-12)


@pytest.mark.parametrize("box, message", [((-95.0, 77.0, -70.0, 71.0), "south \\(77.0\\) must be below north"),
                                          ((-195.0, 71.0, -70.0, 77.0), "west = -195.0 degrees is outside")])
def test_a_bad_box_is_named(box, message):
    with pytest.raises(SeaiceError, match=message):
        coastline(*box)


def test_tracking_starts_no_vector_and_no_floe_on_the_coastlines_land(tmp_path):
    from scipy.ndimage import gaussian_filter

    from seaice_jax.imagery.tracking import (
        GOOD,
        MIXED_MOTION,
        ON_LAND,
        TrackingOptions,
        grid_points,
        patch_touches_land,
    )
    from seaice_jax.io.remapped import RemappedStack
    from seaice_jax.workflows.track import land_of_grid, track_sequence

    grid = MapGrid.centred(nsidc_polar_stereographic("north"), np.radians(74.25), np.radians(-84.0), 2500.0, 2500.0,
                           80, 90)
    texture = gaussian_filter(np.random.default_rng(4).normal(size=grid.shape), 1.5)
    values = np.stack([texture, np.roll(texture, (1, 2), axis=(0, 1))])
    stack = RemappedStack(values, np.ones(values.shape, bool), np.array([0.0, 86400.0]), ("A", "B"),
                          "1980-03-01T00:00:00Z", grid, {}, (), np.zeros((0, 0)), np.full(values.shape, np.nan))
    np.save(tmp_path / "land.npy", land_mask_of_grid(grid))
    land = land_of_grid(tmp_path / "land.npy", grid)
    np.testing.assert_array_equal(land, land_of_grid("coastline", grid))
    options = TrackingOptions()
    everywhere = track_sequence(stack, options)
    at_sea = track_sequence(stack, options, land=land)
    rows, columns = (a.astype(int) for a in grid_points(grid.shape, options))
    on_land = land[rows, columns]
    assert 0.2 < on_land.mean() < 0.8
    assert everywhere.pairs[0].good[on_land].mean() > 0.9  # textured land tracks as well as ice without the mask
    assert (at_sea.pairs[0].status[on_land] == ON_LAND).all()  # with it, every vector from land is "on land"
    sea, unmasked = at_sea.pairs[0].status[~on_land], everywhere.pairs[0].status[~on_land]
    assert (sea == ON_LAND).sum() < 0.2 * sea.size  # at sea, only those that end on land join them
    assert not (everywhere.pairs[0].status == MIXED_MOTION).any()  # one motion everywhere: no patch across two
    # a good vector with land in its patch (start or end) is MIXED_MOTION: land does not drift; the rest as unmasked
    mixed = sea == MIXED_MOTION
    assert mixed.any() and (unmasked[mixed] == GOOD).all()
    assert patch_touches_land(land, rows, columns, options.patch // 2 + 3)[~on_land][mixed].all()
    kept = (sea != ON_LAND) & ~mixed
    np.testing.assert_array_equal(sea[kept], unmasked[kept])
    first = at_sea.records.time == 0.0
    x, y = grid.projection.forward(at_sea.records.latitude[first], at_sea.records.longitude[first])
    row, column = (np.round(np.asarray(a)).astype(int) for a in grid.to_pixel(x, y))
    assert first.sum() == (~on_land).sum() and not land[row, column].any()  # no floe starts on land
    with pytest.raises(SeaiceError, match="no such land mask"):
        land_of_grid(tmp_path / "missing.npy", grid)


@pytest.mark.slow
def test_sequence_ties_fall_back_to_the_coastlines_land(tmp_path):
    from seaice_jax.io.sequence import read_sequence
    from seaice_jax.simulate.satellite import simulate_sequence
    from seaice_jax.workflows.sequence_adjust import static_mask_path
    from seaice_jax.workflows.simulated_sequence import write_simulated_sequence

    project_path = write_simulated_sequence(tmp_path / "project", sequence=simulate_sequence(5, n_images=2, size=96))
    project = read_sequence(project_path)
    simulated_land = np.load(tmp_path / "project" / "land_mask.npy")
    assert static_mask_path(project, None) == tmp_path / "project" / "static_mask.npy"
    for name in ("static_mask.npy", "land_mask.npy"):
        (tmp_path / "project" / name).unlink()
    assert static_mask_path(project, None) is None  # run_adjust then takes land_mask_of_grid(project.grid)
    land = land_mask_of_grid(project.grid)
    assert land.shape == project.grid.shape and 0.1 < land.mean() < 0.9
    assert (land == simulated_land).mean() > 0.95  # the simulated scene stands on the same GSHHG land
    with pytest.raises(SeaiceError, match="no static-surface mask"):
        static_mask_path(project, tmp_path / "missing.npy")


def test_clipped_regions_are_kept_on_disk_and_read_back(tmp_path, monkeypatch):
    from seaice_jax.io.coastline import COASTLINE_CACHE_VARIABLE, coastline_cache_folder

    monkeypatch.setenv(COASTLINE_CACHE_VARIABLE, str(tmp_path))
    assert coastline_cache_folder() == tmp_path
    box = (-84.25, 74.0, -83.0, 74.75)  # Lancaster Sound's south shore, Baffin Island
    coastline.cache_clear()
    computed = coastline(*box)
    (kept,) = tmp_path.glob("gshhg-*.wkb")
    coastline.cache_clear()
    read = coastline(*box)
    assert len(read.polygons) == len(computed.polygons) > 0 and not computed.contains(74.3, -83.7)
    assert all(shapely.equals_exact(a, b, 0.0) for a, b in zip(read.polygons, computed.polygons, strict=True))
    kept.write_bytes(shapely.to_wkb(shapely.multipolygons([shapely.box(-84.0, 74.2, -83.5, 74.4)])))
    coastline.cache_clear()
    assert coastline(*box).contains(74.3, -83.7)  # what is on disk is what is used: a square "island" at sea
    kept.write_bytes(b"not WKB")
    coastline.cache_clear()
    assert len(coastline(*box).polygons) == len(computed.polygons)  # a damaged entry is computed again
    sea = (-68.5, 73.3, -68.0, 73.6)  # Baffin Bay: no land, kept as such
    assert coastline(*sea).polygons == ()
    coastline.cache_clear()
    assert coastline(*sea).polygons == () and len(list(tmp_path.glob("gshhg-*.wkb"))) == 2
    monkeypatch.setenv(COASTLINE_CACHE_VARIABLE, "")
    assert coastline_cache_folder() is None
    coastline.cache_clear()
