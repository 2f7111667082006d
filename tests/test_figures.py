"""The shared figure style, checked on the figure objects: nothing overprints, legends and vector keys lie outside
the data axes, colour bars carry units, maps name their coordinate system, error ellipses are drawn at a stated
scale (their true size when visible), and extra formats are written when asked."""

import itertools

import matplotlib.pyplot as plt
import numpy as np
import pyproj
import pytest
from matplotlib.colors import to_rgb
from matplotlib.patches import Ellipse
from matplotlib.quiver import Quiver, QuiverKey
from matplotlib.text import Text
from scipy.spatial import KDTree

from seaice_jax.drift.kinematics import box_averages
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.projections import MapGrid, TangentPlane, nsidc_polar_stereographic
from seaice_jax.imagery.movie import render_frames
from seaice_jax.io.coastline import coastline, land_mask_of_grid
from seaice_jax.report.figures import (
    MapLayer,
    MapPanel,
    box_averages_figure,
    coastline_overlay_figure,
    image_field_figure,
    maps_figure,
    navigation_errors_figure,
    plot_vectors,
    remapped_figure,
    tie_discrepancies_figure,
    trajectories_figure,
    vectors_figure,
)
from seaice_jax.report.maps import (
    COASTLINE_GID,
    CONTROL_GID,
    GRATICULE_GID,
    GRATICULE_LABEL_GID,
    LAND_COLOUR,
    LAND_GID,
    SCALE_BAR_GID,
    draw_coastline,
    map_overlay,
)
from seaice_jax.simulate.satellite import noaa_image

CHI2_95_2D = np.sqrt(-2 * np.log(0.05))  # 95 % radius of a 2-D unit normal: sqrt of chi-square(2) quantile


def boxes(fig):
    """Window extents of the visible, non-empty texts, the data axes and the legends after drawing."""
    renderer = fig.canvas.get_renderer()
    fig.canvas.draw()
    keys = [a.text for ax in fig.axes for a in ax.get_children() if isinstance(a, QuiverKey)]
    ticks = [label for ax in fig.axes for axis in (ax.xaxis, ax.yaxis) for label in drawn_tick_labels(axis)]
    tick_labels = all_tick_labels(fig)
    other = [t for t in fig.findobj(Text) if id(t) not in tick_labels]
    texts = [(t, t.get_window_extent(renderer)) for t in [*other, *keys, *ticks]
             if t.get_visible() and t.get_text().strip()]
    return renderer, texts


def all_tick_labels(fig) -> set:
    return {id(label) for ax in fig.axes for axis in (ax.xaxis, ax.yaxis)
            for label in axis.get_majorticklabels() + axis.get_minorticklabels()}


def drawn_tick_labels(axis) -> list:
    """The major tick labels matplotlib draws: those whose tick lies within the axis' view interval."""
    low, high = sorted(axis.get_view_interval())
    tolerance = 1e-9 * max(abs(low), abs(high), 1.0)
    locations = axis.get_majorticklocs()
    return [label for tick, location in zip(axis.get_major_ticks(len(locations)), locations, strict=True)
            if low - tolerance <= location <= high + tolerance for label in (tick.label1, tick.label2)]


def assert_no_text_overprints(fig):
    _, texts = boxes(fig)
    for (a, box_a), (b, box_b) in itertools.combinations(texts, 2):
        assert not box_a.overlaps(box_b), (a.get_text(), b.get_text())
    figure_box = fig.bbox
    for text, box in texts:
        assert box.x0 >= figure_box.x0 - 1 and box.x1 <= figure_box.x1 + 1, text.get_text()
        assert box.y0 >= figure_box.y0 - 1 and box.y1 <= figure_box.y1 + 1, text.get_text()


def drift_case(sigma):
    projection = nsidc_polar_stereographic("north")
    grid = MapGrid.centred(projection, np.radians(75.0), np.radians(-80.0), 20e3, 20e3, 10, 10)
    x, y = (np.asarray(a).ravel() for a in grid.xy())
    positions = np.stack([x, y], 1)
    vectors = np.stack([np.full(x.size, 4000.0), np.linspace(-2000.0, 2000.0, x.size)], 1)
    covariances = np.broadcast_to(np.eye(2) * sigma**2, (x.size, 2, 2))
    return projection, positions, vectors, covariances


@pytest.mark.parametrize("sigma, magnified", [(5.0, True), (600.0, False), (40e3, True)])
def test_vector_figure_draws_ellipses_at_a_stated_scale(sigma, magnified):
    projection, positions, vectors, covariances = drift_case(sigma)
    fig = vectors_figure(positions, vectors, "Drift", "test", background=positions[:3] + 5e3,
                         covariances=covariances, projection=projection)
    ax = fig.axes[0]
    (quiver,) = [c for c in ax.collections if isinstance(c, Quiver)]
    ellipses = [p for p in ax.patches if isinstance(p, Ellipse)]
    assert len(ellipses) == len(positions)
    legend = ax.get_legend()
    assert legend is not None
    labels = legend.get_texts()
    (ellipse_label,) = [t.get_text() for t in labels if "ellipse" in t.get_text()]
    if magnified:
        factor = float(ellipse_label.split("×")[1].split()[0])
        assert factor != 1.0
    else:
        assert "true size" in ellipse_label and "×" not in ellipse_label
        factor = 1.0
    # the drawn width is the 95 % diameter at the arrows' scale times the stated factor
    np.testing.assert_allclose(ellipses[0].width, 2 * factor * CHI2_95_2D * sigma / quiver.scale, rtol=1e-9)
    # and it is visible beside the reference arrow without hiding it (a tenth to the whole arrow)
    arrow = np.percentile(np.hypot(*vectors.T), 90) / quiver.scale
    assert 0.1 * arrow <= ellipses[0].width / 2 <= arrow
    assert "EPSG:3413" in ax.get_xlabel() and "km" in ax.get_xlabel()
    assert {"vector", "points without a vector"} <= {t.get_text() for t in labels}
    renderer, _ = boxes(fig)
    axes_box = ax.get_window_extent(renderer)
    assert not legend.get_window_extent(renderer).overlaps(axes_box)
    key_texts = [a.text for a in ax.get_children() if isinstance(a, QuiverKey)]
    assert key_texts[0].get_text().endswith(" km")
    assert not any(t.get_window_extent(renderer).overlaps(axes_box) for t in key_texts)
    assert not any(t.get_window_extent(renderer).overlaps(ax.title.get_window_extent(renderer)) for t in key_texts)
    assert_no_text_overprints(fig)


def test_remapped_figure_has_a_colour_bar_with_units_and_names_the_grid():
    projection = nsidc_polar_stereographic("north")
    rng = np.random.default_rng(0)
    images = [rng.uniform(0, 255, (40, 50)) for _ in range(6)]
    images[2][:10] = np.nan
    fig = remapped_figure(images, [f"IMG{k}\nsensor" for k in range(6)], [0, 50, 0, 40], projection=projection,
                          units="brightness (digital number)")
    colour_bars = [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]
    assert len(colour_bars) == 1
    assert "digital number" in colour_bars[0].get_ylabel() + colour_bars[0].get_xlabel()
    assert "EPSG:3413" in fig.get_suptitle()
    renderer, _ = boxes(fig)
    images_axes = [ax for ax in fig.axes if ax not in colour_bars]
    assert len(images_axes) == 6
    for a, b in itertools.combinations(images_axes + colour_bars, 2):
        assert not a.get_window_extent(renderer).overlaps(b.get_window_extent(renderer))
    assert_no_text_overprints(fig)


def test_navigation_errors_keep_a_legend_and_distinct_colours_with_many_strips():
    times = np.linspace(0, 3600, 50)
    curves = [(f"strip {k:02d}", times, np.stack([np.sin(times / 600 + k), np.cos(times / 900 + k)], 1) * 100,
               np.full((50, 2), 20.0)) for k in range(15)]
    fig = navigation_errors_figure(curves, "Navigation errors")
    top = fig.axes[0]
    colours = {tuple(line.get_color()) for line in top.get_lines() if str(line.get_label()).startswith("strip")}
    assert len(colours) == 15
    legend = top.get_legend()
    assert legend is not None and {t.get_text() for t in legend.get_texts()} >= {f"strip {k:02d}" for k in range(15)}
    renderer, _ = boxes(fig)
    assert not legend.get_window_extent(renderer).overlaps(top.get_window_extent(renderer))
    assert_no_text_overprints(fig)


def test_tie_discrepancies_show_one_panel_when_there_is_no_before():
    rng = np.random.default_rng(1)
    before, after = rng.normal(0, 900, (30, 2)), rng.normal(0, 120, (30, 2))
    both = tie_discrepancies_figure(before, after)
    assert [ax.get_title().split("\n")[0] for ax in both.axes] == ["before internal adjustment",
                                                                   "after internal adjustment"]
    rms = np.sqrt(np.mean((after / 1000) ** 2, axis=0))
    assert f"rms {rms[0]:.2f} km across, {rms[1]:.2f} km along" in both.axes[1].get_title()
    only = tie_discrepancies_figure(None, after)
    assert len(only.axes) == 1 and "simultaneous" in only.axes[0].get_title()
    assert_no_text_overprints(both)


def test_image_field_colour_bar_carries_the_label():
    pixel, scan = np.meshgrid(np.arange(20.0), np.arange(15.0))
    fig = image_field_figure(pixel, scan, np.hypot(pixel, scan), "Position σ", "σ (m)",
                             points=(np.array([3.0, 10.0]), np.array([4.0, 9.0]), ["A", "B"]))
    (colour_bar,) = [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]
    assert colour_bar.get_ylabel() == "σ (m)"
    renderer, _ = boxes(fig)
    legend = fig.axes[0].get_legend()
    assert legend is not None
    assert not legend.get_window_extent(renderer).overlaps(fig.axes[0].get_window_extent(renderer))


def test_extra_formats_are_written_beside_the_png(tmp_path, monkeypatch):
    _, positions, vectors, covariances = drift_case(300.0)
    monkeypatch.setenv("SEAICE_FIGURE_FORMATS", "pdf, svg")
    path = plot_vectors(tmp_path / "drift.png", positions, vectors, "Drift", "test", covariances=covariances)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (tmp_path / "drift.pdf").read_bytes()[:5] == b"%PDF-"
    assert b"<svg" in (tmp_path / "drift.svg").read_bytes()[:2000]
    monkeypatch.setenv("SEAICE_FIGURE_FORMATS", "tiff")
    with pytest.raises(SeaiceError, match="SEAICE_FIGURE_FORMATS: unknown figure format\\(s\\) tiff"):
        plot_vectors(tmp_path / "other.png", positions, vectors, "Drift", "test")
    assert not (tmp_path / "other.png").exists()


# ------------------------------------------------------------------------------------------------ maps


LANCASTER = (np.radians(74.0), np.radians(-85.0))


def by_gid(ax, gid: str) -> list:
    return [artist for artist in ax.findobj() if artist.get_gid() == gid]


def lancaster_vectors():
    projection = nsidc_polar_stereographic("north")
    grid = MapGrid.centred(projection, *LANCASTER, 25e3, 25e3, 12, 14)
    x, y = (np.asarray(a).ravel() for a in grid.xy())
    positions = np.stack([x, y], 1)
    vectors = np.stack([np.full(x.size, 4000.0), np.linspace(-2000.0, 2000.0, x.size)], 1)
    return projection, positions, vectors


def map_figures():
    """Every kind of map figure on the same Lancaster Sound area (and a radar panel in a tangent plane)."""
    projection, positions, vectors = lancaster_vectors()
    x, y = positions.T
    boxes = box_averages(x, y, vectors[:, 0] / 86400, vectors[:, 1] / 86400, 100e3, (x.min(), y.min()))
    plane = TangentPlane(np.radians(70.3), np.radians(-148.4))
    strip_x, strip_y = np.meshgrid(np.linspace(-30e3, 30e3, 7), np.linspace(-20e3, 25e3, 10))
    extent = [x.min() / 1000, x.max() / 1000, y.min() / 1000, y.max() / 1000]
    return {
        "vectors": vectors_figure(positions, vectors, "Drift", "test", projection=projection),
        "box averages": box_averages_figure(boxes, "Boxes", background=positions, projection=projection),
        "trajectories": trajectories_figure(np.arange(x.size) % 7, x, y, "Trajectories", projection=projection),
        "maps": maps_figure([MapPanel(plane, [MapLayer("radar strip", strip_x, strip_y, "grid")], "Prudhoe Bay"),
                             MapPanel(projection, [MapLayer("floes", x, y)], "Lancaster Sound")], "Maps"),
        "remapped": remapped_figure([np.random.default_rng(k).uniform(0, 1, (12, 14)) for k in range(2)], ["A", "B"],
                                    extent, projection=projection),
    }


@pytest.fixture(scope="module")
def figures():
    return map_figures()


@pytest.mark.parametrize("kind", ["vectors", "box averages", "trajectories", "maps", "remapped"])
def test_every_map_shows_coast_graticule_labels_and_scale(figures, kind):
    fig = figures[kind]
    maps = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    assert maps
    for ax in maps:
        (coast,) = by_gid(ax, COASTLINE_GID)
        x, y = coast.get_data()
        (x0, x1), (y0, y1) = sorted(ax.get_xlim()), sorted(ax.get_ylim())
        inside = (x > x0) & (x < x1) & (y > y0) & (y < y1)
        assert inside.sum() > 50, "the coast crosses every one of these frames"
        assert len(by_gid(ax, LAND_GID)) == (0 if kind == "remapped" else 1)  # images keep their pixels
        assert len(by_gid(ax, GRATICULE_GID)) == 1
        labels = [t.get_text() for t in by_gid(ax, GRATICULE_LABEL_GID)]
        assert any(t.endswith("°W") for t in labels) and any(t.endswith("°N") for t in labels), labels
        (bar,) = by_gid(ax, SCALE_BAR_GID)
        assert bar.txt_label.get_text().split()[1] == "km"
    fig.set_dpi(150)  # as written
    renderer, _ = boxes(fig)
    for ax in maps:  # labels and legends well inside the figure (glyphs reach a little past their boxes)
        assert ax.yaxis.label.get_window_extent(renderer).x0 > 2
        legend = ax.get_legend()
        assert legend is None or legend.get_window_extent(renderer).x1 < fig.bbox.x1 - 2
    assert_no_text_overprints(fig)


def test_graticule_labels_sit_where_their_lines_cross_the_frame(figures):
    to_geographic = pyproj.Transformer.from_crs("EPSG:3413", "EPSG:4326", always_xy=True)
    ax = figures["vectors"].axes[0]
    (x0, x1), (y0, y1) = sorted(ax.get_xlim()), sorted(ax.get_ylim())
    checked = 0
    for label in by_gid(ax, GRATICULE_LABEL_GID):
        fx, fy = label.get_position()
        value = float(label.get_text()[:-2]) * (-1 if label.get_text()[-1] in "WS" else 1)
        if label.get_text().endswith("W"):  # meridians on the top or bottom edge
            edge = y1 if fy > 0.5 else y0
            longitude, _ = to_geographic.transform(x0 + fx * (x1 - x0), edge)
            assert longitude == pytest.approx(value, abs=0.02)
        else:  # parallels on the left or right edge
            edge = x0 if fx < 0.5 else x1
            _, latitude = to_geographic.transform(edge, y0 + fy * (y1 - y0))
            assert latitude == pytest.approx(value, abs=0.01)
        checked += 1
    assert checked >= 4


def test_scale_bar_states_the_ground_distance_it_spans(figures):
    ax = figures["vectors"].axes[0]
    (bar,) = by_gid(ax, SCALE_BAR_GID)
    (rectangle,) = bar.size_bar.get_children()
    (x0, x1), (y0, y1) = sorted(ax.get_xlim()), sorted(ax.get_ylim())
    centre_x, centre_y = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    to_geographic = pyproj.Transformer.from_crs("EPSG:3413", "EPSG:4326", always_xy=True)
    lon, lat = to_geographic.transform([centre_x - rectangle.get_width() / 2, centre_x + rectangle.get_width() / 2],
                                       [centre_y, centre_y])
    _, _, ground = pyproj.Geod(ellps="WGS84").inv(lon[0], lat[0], lon[1], lat[1])
    stated = float(bar.txt_label.get_text().split()[0]) * 1000
    assert ground == pytest.approx(stated, rel=1e-3)


def test_drawn_coast_is_pyprojs_projection_of_the_gshhg_vertices():
    projection = nsidc_polar_stereographic("north")
    x, y = (float(v) for v in projection.forward(*LANCASTER))
    half = 150e3
    coast = coastline(-95.0, 71.0, -75.0, 77.0)
    lonlat = np.concatenate(coast.shorelines())
    px, py = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:3413", always_xy=True).transform(*lonlat.T)
    reference = np.column_stack([px, py])
    for tolerance in (0.0, None):  # every vertex, and simplified to the figure's resolution
        fig, ax = plt.subplots()
        ax.set_xlim(x - half, x + half)
        ax.set_ylim(y - half, y + half)
        draw_coastline(ax, coast, projection, tolerance=tolerance)
        (line,) = by_gid(ax, COASTLINE_GID)
        drawn = np.column_stack(line.get_data())
        drawn = drawn[np.isfinite(drawn).all(axis=1)]
        inner = (np.abs(drawn - [x, y]) < 0.97 * half).all(axis=1)  # not the points the frame's clip adds
        distance, _ = KDTree(reference).query(drawn[inner])
        assert inner.sum() > 200 and distance.max() < 1e-3
        if tolerance == 0.0:  # and nothing is missing
            wanted = reference[(np.abs(reference - [x, y]) < 0.97 * half).all(axis=1)]
            distance, _ = KDTree(drawn).query(wanted)
            assert distance.max() < 1e-3
        plt.close(fig)


def test_coastline_overlay_projects_the_coast_through_the_scan_model():
    model = noaa_image("south")
    coast = coastline(-100.0, 66.0, -55.0, 80.0)
    image = np.random.default_rng(0).uniform(0, 1, (model.n_scans, model.n_pixels))
    control = (np.array([100.0, 300.0]), np.array([50.0, 400.0]), ["2001", "2002"])
    fig = coastline_overlay_figure(image, model, coast, control=control, title="NOAA-7 overlay")
    ax = fig.axes[0]
    (line,) = by_gid(ax, COASTLINE_GID)
    pixel, scan = line.get_data()
    inside = np.isfinite(pixel) & (pixel >= 1) & (pixel <= model.n_pixels) & (scan >= 1) & (scan <= model.n_scans)
    assert inside.sum() > 1000
    latitude, longitude = (np.degrees(np.asarray(a)) for a in model.forward(pixel[inside], scan[inside]))
    vertices = np.concatenate(coast.shorelines())
    scale = np.cos(np.radians(74.0))
    distance, _ = KDTree(vertices * [scale, 1.0]).query(np.column_stack([longitude * scale, latitude]))
    assert distance.max() < 1e-6  # degrees: the drawn vertices are the GSHHG vertices, through the model
    (markers,) = by_gid(ax, CONTROL_GID)
    np.testing.assert_allclose(markers.get_offsets(), np.column_stack(control[:2]))
    assert ax.get_ylim()[0] > ax.get_ylim()[1]  # scan lines downward
    assert_no_text_overprints(fig)


def test_film_overlay_fills_the_gshhg_land_and_composites_over_the_frames():
    grid = MapGrid.centred(nsidc_polar_stereographic("north"), *LANCASTER, 2500.0, 2500.0, 90, 110)
    scale = 2
    overlay = map_overlay(grid, scale)
    assert overlay.shape == (90 * scale, 110 * scale, 4)
    land = np.repeat(np.repeat(land_mask_of_grid(grid), scale, axis=0), scale, axis=1)
    land_colour = (np.array(to_rgb(LAND_COLOUR)) * 255).round()
    opaque_land = (overlay[..., 3] == 255) & (np.abs(overlay[..., :3] - land_colour).max(axis=-1) <= 1)
    clear = overlay[..., 3] == 0
    judged = opaque_land | clear  # not under a line or a label
    assert judged.mean() > 0.8 and 0.2 < land.mean() < 0.8
    assert (opaque_land == land)[judged].mean() > 0.98
    images = np.random.default_rng(1).uniform(0, 1, (2, 90, 110))
    plain = render_frames(images, ["a", "b"], scale=scale)
    overlaid = render_frames(images, ["a", "b"], scale=scale, overlay=overlay)
    below_banner = np.zeros(clear.shape, bool)
    below_banner[40:] = True
    np.testing.assert_array_equal(overlaid[:, clear & below_banner], plain[:, clear & below_banner])
    opaque = (overlay[..., 3] == 255) & below_banner
    np.testing.assert_array_equal(overlaid[:, opaque], np.broadcast_to(overlay[opaque][:, :3],
                                                                       overlaid[:, opaque].shape))
