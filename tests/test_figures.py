"""The shared figure style, checked on the figure objects: nothing overprints, legends and vector keys lie outside
the data axes, colour bars carry units, maps name their coordinate system, error ellipses are drawn at a stated
scale (their true size when visible), and extra formats are written when asked."""

import itertools

import numpy as np
import pytest
from matplotlib.patches import Ellipse
from matplotlib.quiver import Quiver, QuiverKey
from matplotlib.text import Text

from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.projections import MapGrid, nsidc_polar_stereographic
from seaice_jax.report.figures import (
    image_field_figure,
    navigation_errors_figure,
    plot_vectors,
    remapped_figure,
    tie_discrepancies_figure,
    vectors_figure,
)

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
    labels = ax.get_legend().get_texts()
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
    assert not ax.get_legend().get_window_extent(renderer).overlaps(axes_box)
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
    colours = {tuple(line.get_color()) for line in top.get_lines() if line.get_label().startswith("strip")}
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
    assert not fig.axes[0].get_legend().get_window_extent(renderer).overlaps(fig.axes[0].get_window_extent(renderer))


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
