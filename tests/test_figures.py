"""Every figure the package draws, on small synthetic inputs, passes one publication check
(:func:`tests.figure_checks.check_figure`: text inside the canvas and apart, a named coordinate system on maps,
vectors inside the frame, thinned and off the land, each scale stated once in the key); and the figure style's
particulars: ellipses and arrows drawn at the scales their key states, colour bars with units, legends beside the
data, the map decorations where they belong, extra formats written when asked."""

import inspect
import re
from types import SimpleNamespace

import matplotlib.pyplot as plt
import numpy as np
import pyproj
import pytest
from matplotlib.colors import to_rgb
from matplotlib.patches import Ellipse, FancyArrow, Rectangle
from matplotlib.quiver import Quiver
from matplotlib.text import Text
from scipy.spatial import KDTree

from seaice_jax.drift.kinematics import BoxAverages, box_averages
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.crs import CrsProjection
from seaice_jax.geometry.projections import (
    Equirectangular,
    LambertConformalConic,
    MapGrid,
    PolarStereographic,
    TangentPlane,
    nsidc_polar_stereographic,
)
from seaice_jax.imagery.movie import render_frames
from seaice_jax.io.coastline import coastline, land_mask_of_grid
from seaice_jax.io.sentinel1 import read_annotation
from seaice_jax.report.figures import (
    ARROWS_ACROSS,
    BOX_SIGMA_GID,
    ELLIPSE_GID,
    KEY_GID,
    MapLayer,
    MapPanel,
    box_averages_figure,
    coastline_overlay_figure,
    crs_name,
    image_field_figure,
    maps_figure,
    navigation_errors_figure,
    plot_vectors,
    remapped_figure,
    remapped_sar_figure,
    sar_geolocation_figure,
    tie_discrepancies_figure,
    trajectories_figure,
    vectors_figure,
    velocity_series_figure,
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
    overlay_figure,
)
from seaice_jax.simulate.satellite import noaa_image
from tests.figure_checks import assert_no_text_overprints, by_gid, check_figure, drawn_texts, map_axes

__all__ = ["assert_no_text_overprints"]  # tests/test_sar_cli.py uses it from here

CHI2_95_2D = np.sqrt(-2 * np.log(0.05))  # 95 % radius of a 2-D unit normal: sqrt of chi-square(2) quantile
LANCASTER = (np.radians(74.0), np.radians(-85.0))
AIDJEX = (np.radians(75.0), np.radians(-150.0))
EW = "tests/data/sentinel1/s1a-ew1-slc-hh-20210403t122536-20210403t122628-037286-046484-001.xml"


# ------------------------------------------------------------------------------------------------ cases


def lancaster_vectors(spacing=25e3, rows=12, columns=14):
    """A lattice over Lancaster Sound (half of it on land) with a smooth drift field."""
    projection = nsidc_polar_stereographic("north")
    grid = MapGrid.centred(projection, *LANCASTER, spacing, spacing, rows, columns)
    x, y = (np.asarray(a).ravel() for a in grid.xy())
    positions = np.stack([x, y], 1)
    vectors = np.stack([np.full(x.size, 4000.0), np.linspace(-2000.0, 2000.0, x.size)], 1)
    return projection, positions, vectors


def drift_case(sigma):
    projection = nsidc_polar_stereographic("north")
    grid = MapGrid.centred(projection, np.radians(75.0), np.radians(-80.0), 20e3, 20e3, 10, 10)
    x, y = (np.asarray(a).ravel() for a in grid.xy())
    positions = np.stack([x, y], 1)
    vectors = np.stack([np.full(x.size, 4000.0), np.linspace(-2000.0, 2000.0, x.size)], 1)
    covariances = np.broadcast_to(np.eye(2) * sigma**2, (x.size, 2, 2))
    return projection, positions, vectors, covariances


def radar_block_case(count=200):
    """A radar block's features in the tangent plane of its strips (160 x 40 km, far from land), drifting 35 km with
    100-300 m σ: the demo's drift figure."""
    rng = np.random.default_rng(3)
    positions = np.column_stack([rng.uniform(-80e3, 80e3, count), rng.uniform(-20e3, 20e3, count)])
    vectors = np.column_stack([rng.normal(-35e3, 2e3, count), rng.normal(0.0, 1e3, count)])
    sigma = rng.uniform(100.0, 300.0, count)
    covariances = np.einsum("n,ij->nij", sigma**2, np.eye(2))
    return TangentPlane(*AIDJEX), positions, vectors, covariances


def annotation_check():
    """A radar product's geolocation check (:func:`~seaice_jax.workflows.sar.check_geolocation`'s fields) on the
    real Smith Sound EW grid, with made-up millimetre differences (the model itself is tested elsewhere)."""
    annotation = read_annotation(EW)
    rng = np.random.default_rng(0)
    size = annotation.grid.line.size
    east, north = rng.normal(0, 2e-3, size), rng.normal(0, 2e-3, size)
    return SimpleNamespace(annotation=annotation, east=east, north=north, horizontal=np.hypot(east, north))


def remapped_sar_case():
    projection = nsidc_polar_stereographic("north")
    grid = MapGrid.centred(projection, np.radians(78.2), np.radians(-70.0), 2000.0, 2000.0, 60, 80)
    rng = np.random.default_rng(1)
    image = rng.uniform(0, 1, (60, 80))
    image[:, :10] = np.nan
    return image, grid, np.full((60, 80), 7.5), "S1A EW GRD HH, remapped"


def velocity_series():
    days = np.arange(3) * 86400.0 + 43200.0
    return {(k, 1): {"time": days, "u": np.full(3, 0.03 + 0.01 * k), "v": np.full(3, -0.02),
                     "sigma_u": np.full(3, 0.005), "sigma_v": np.full(3, 0.004), "count": np.full(3, 5)}
            for k in range(6)}


def navigation_curves(count=15):
    times = np.linspace(0, 3600, 50)
    return [(f"strip {k:02d}", times, np.stack([np.sin(times / 600 + k), np.cos(times / 900 + k)], 1) * 100,
             np.full((50, 2), 20.0)) for k in range(count)]


def all_figures():
    """Builders of every figure the package draws, each on a small synthetic case (the workflows' cases: a tracked
    drift field half on land, a dense lattice, a radar block's drift and its control discrepancies, box averages,
    trajectories, the demo's two-panel map, remapped images, the image-space figures, the line plots, the radar
    product's figures and a film's overlay)."""
    projection, positions, vectors = lancaster_vectors()
    x, y = positions.T
    sigma = np.broadcast_to(np.diag([300.0**2, 500.0**2]), (len(x), 2, 2))
    plane, block, drift, block_covariances = radar_block_case()
    dense_projection, dense, dense_vectors = lancaster_vectors(4e3, 60, 70)
    boxes = box_averages(x, y, vectors[:, 0] / 86400, (vectors[:, 1] + 300 * np.sin(x / 9e3)) / 86400, 75e3,
                         (x.min(), y.min()))
    strip_x, strip_y = np.meshgrid(np.linspace(-50e3, 50e3, 21), np.linspace(-20e3, 20e3, 10))
    stations = np.array([[-1100e3, -1260e3], [-1090e3, -1275e3], [-1180e3, -1330e3]])
    rng = np.random.default_rng(0)
    extent = [x.min() / 1000, x.max() / 1000, y.min() / 1000, y.max() / 1000]
    pixel, scan = np.meshgrid(np.linspace(1, 512, 33), np.linspace(1, 512, 33))
    model = noaa_image("south")
    return {
        "tracked drift": lambda: vectors_figure(positions, vectors, "Tracked drift", "0.85 days", covariances=sigma,
                                                background=positions[::7] + 3e3, projection=projection,
                                                background_label="points without a good vector"),
        "dense drift": lambda: vectors_figure(dense, dense_vectors, "Dense drift", "thinned",
                                              projection=dense_projection),
        "radar drift": lambda: vectors_figure(block, drift, "Drift day 0 -> day 16", "source 000, Fig. 7",
                                              covariances=block_covariances, projection=plane),
        "control discrepancies": lambda: vectors_figure(block[:3], drift[:3] / 20, "Radar minus known position",
                                                        "before the external adjustment", background=block,
                                                        projection=plane),
        "drift, nothing tracked": lambda: vectors_figure(positions[:0], vectors[:0], "Tracked drift", "none good",
                                                         background=positions, projection=projection),
        "drift, most vectors on land": lambda: vectors_figure(positions[100:103], vectors[100:103], "Drift", "on land",
                                                              covariances=sigma[:3], projection=projection),
        "drift, some vectors missing": lambda: vectors_figure(
            positions, np.where(np.arange(len(x))[:, None] % 3, vectors, np.nan), "Drift", "NaN rows",
            covariances=sigma, projection=projection),
        "box averages, none": lambda: box_averages_figure(BoxAverages(*[np.zeros(0)] * 6, np.zeros(0, int)), "Boxes",
                                                          background=positions, projection=projection),
        "box averages": lambda: box_averages_figure(boxes, "Box-averaged velocity (75 km boxes)",
                                                    background=positions, projection=projection),
        "trajectories": lambda: trajectories_figure(np.repeat(np.arange(x.size), 3), np.repeat(x, 3) + np.tile(
            [0.0, 2e3, 4e3], x.size), np.repeat(y, 3) - np.tile([0.0, 1e3, 2e3], x.size), "Floe trajectories",
            projection=projection),
        "maps": lambda: maps_figure([
            MapPanel(plane, [MapLayer("radar strip: lines every 20 s", strip_x, strip_y, "grid")],
                     "Simulated radar strip\ntangent plane at the strip centre"),
            MapPanel(projection, [MapLayer("image (every 32nd pixel/line)", *np.meshgrid(
                np.linspace(-1250e3, -950e3, 12), np.linspace(-1450e3, -1150e3, 12)), "grid"),
                MapLayer("reference stations", stations[:, 0], stations[:, 1], "labelled",
                         ["N DEV PT", "COB IS ICE", "E DEV"])], "Satellite image")], "Geolocation"),
        "remapped, 2 images": lambda: remapped_figure([rng.uniform(0, 1, (12, 14)) for _ in range(2)],
                                                      ["IMG01\n1983-03-08T01:12", "IMG02\n1983-03-08T21:42"],
                                                      extent, projection=projection),
        "remapped, 6 images": lambda: remapped_figure([rng.uniform(0, 1, (12, 14)) for _ in range(6)],
                                                      [f"IMG{k:02d} ({k + 1} of 30)\n1983-03-08T01:12"
                                                       for k in range(6)], extent, projection=projection),
        "image field": lambda: image_field_figure(pixel, scan, np.hypot(pixel - 200, scan - 250) / 200,
                                                  "Position uncertainty of the fitted image\nfrom the covariance",
                                                  "σ of ground position (km)",
                                                  ([165, 114, 200], [122, 173, 204], ["COB IS ICE", "N DEV PT",
                                                                                      "E DEV"])),
        "navigation errors": lambda: navigation_errors_figure(navigation_curves(), "Navigation errors"),
        "tie discrepancies": lambda: tie_discrepancies_figure(rng.normal(0, 900, (30, 2)),
                                                              rng.normal(0, 120, (30, 2))),
        "tie discrepancies, after only": lambda: tie_discrepancies_figure(None, rng.normal(0, 120, (30, 2))),
        "velocity series": lambda: velocity_series_figure(velocity_series(), "Daily box-averaged velocity",
                                                          "1983-03-08"),
        "coastline overlay": lambda: coastline_overlay_figure(
            rng.uniform(0, 1, (model.n_scans, model.n_pixels)), model, coastline(-100.0, 66.0, -55.0, 80.0),
            control=(np.array([100.0, 300.0]), np.array([50.0, 400.0]), ["2001", "2002"]), title="NOAA-7 overlay"),
        "sar geolocation": lambda: sar_geolocation_figure(annotation_check()),
        "remapped sar": lambda: remapped_sar_figure(*remapped_sar_case()),
        "film overlay": lambda: overlay_figure(MapGrid.centred(projection, *LANCASTER, 2500.0, 2500.0, 90, 110)),
    }


FIGURES = all_figures()


@pytest.mark.parametrize("kind", list(FIGURES))
def test_every_figure_can_be_published(kind):
    fig = FIGURES[kind]()
    try:
        fig.set_dpi(150)  # as written
        check_figure(fig)
    finally:
        plt.close(fig)


def test_the_check_covers_every_figure_function():
    """A figure function added to the package without a case above fails here."""
    import seaice_jax.report.figures as figures
    import seaice_jax.report.maps as maps

    source = inspect.getsource(all_figures)
    functions = [name for module in (figures, maps) for name, value in vars(module).items()
                 if name.endswith("_figure") and not name.startswith("_") and inspect.isfunction(value)
                 and value.__module__ == module.__name__]
    assert len(functions) >= 13
    assert [name for name in functions if f"{name}(" not in source] == []


# ------------------------------------------------------------------------------------------------ scales and keys


def key_of(fig):
    (key,) = [artist for ax in fig.axes for artist in by_gid(ax, KEY_GID)]
    return key


def legend_of(fig):
    (legend,) = [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]
    return legend


def key_rows(fig) -> list[tuple[object, str]]:
    """The key's rows: (the drawn patch, its text)."""
    key = key_of(fig)
    patches = [p for p in key.findobj() if isinstance(p, FancyArrow | Ellipse | Rectangle) and p.get_gid() is None
               and p is not getattr(key, "patch", None)]
    texts = [t.get_text() for t in key.findobj(Text) if t.get_text()]
    return list(zip(patches, texts, strict=False))


def stated(text: str) -> float:
    """The length a key's text states, in metres (or km/day as a number of km)."""
    number, unit = re.search(r"(\d+(?:\.\d+)?)\s*(km|m)\b", text).groups()
    return float(number) * (1000.0 if unit == "km" else 1.0)


@pytest.mark.parametrize("sigma, magnified", [(5.0, True), (600.0, False), (40e3, True)])
def test_ellipses_and_arrows_are_drawn_at_the_scales_their_key_states(sigma, magnified):
    projection, positions, vectors, covariances = drift_case(sigma)
    fig = vectors_figure(positions, vectors, "Drift", "test", background=positions[:3] + 5e3,
                         covariances=covariances, projection=projection)
    ax = fig.axes[0]
    (quiver,) = [c for c in ax.collections if isinstance(c, Quiver)]
    ellipses = by_gid(ax, ELLIPSE_GID)
    assert len(ellipses) == len(quiver.get_offsets())
    (arrow, arrow_text), (ellipse, ellipse_text) = key_rows(fig)
    # the key's arrow is as long on the map as a vector of the length it states
    length = np.ptp(arrow.get_path().vertices[:, 0])
    assert length == pytest.approx(stated(arrow_text) / quiver.scale, rel=1e-9)
    # every ellipse is drawn at the one scale of the key's ellipse: its 95 % semi-axis times (key radius / stated)
    ellipse_scale = ellipse.width / 2 / stated(ellipse_text)
    for drawn in ellipses:
        assert drawn.width / 2 == pytest.approx(CHI2_95_2D * sigma * ellipse_scale, rel=1e-9)
    assert ellipse_scale == pytest.approx(1 / quiver.scale, rel=1e-9) if not magnified else \
        ellipse_scale != pytest.approx(1 / quiver.scale, rel=1e-3)
    assert ("× the arrows' scale" in ellipse_text) == magnified
    # and visible beside the reference arrow without hiding it (a tenth to the whole arrow)
    reference = np.percentile(np.hypot(*vectors.T), 90) / quiver.scale
    assert 0.1 * reference <= ellipses[0].width / 2 <= reference
    assert "EPSG:3413" in ax.get_xlabel() and "km" in ax.get_xlabel()
    legend = legend_of(fig)
    assert {"vector", "points without a vector", "95 % error ellipse"} <= {t.get_text() for t in legend.get_texts()}
    check_figure(fig)
    plt.close(fig)


def test_box_rectangles_are_drawn_at_the_scale_their_key_states():
    projection, positions, vectors = lancaster_vectors()
    x, y = positions.T
    boxes = box_averages(x, y, vectors[:, 0] / 86400, (vectors[:, 1] + 300 * np.sin(x / 9e3)) / 86400, 75e3,
                         (x.min(), y.min()))
    fig = box_averages_figure(boxes, "Boxes", projection=projection)
    ax = fig.axes[0]
    (quiver,) = [c for c in ax.collections if isinstance(c, Quiver)]
    (arrow, arrow_text), (square, square_text) = key_rows(fig)
    km_per_day = stated(arrow_text) / 1000
    assert np.ptp(arrow.get_path().vertices[:, 0]) == pytest.approx(km_per_day / 86.4 / quiver.scale, rel=1e-9)
    scale = square.get_width() / 2 / (stated(square_text) / 1000 / 86.4)  # map metres per m/s
    shown = {tuple(p) for p in np.round(quiver.get_offsets(), 3)}
    for rectangle in by_gid(ax, BOX_SIGMA_GID):
        centre = np.array(rectangle.get_xy()) + [rectangle.get_width() / 2, rectangle.get_height() / 2]
        k = np.argmin(np.hypot(boxes.x + boxes.u / quiver.scale - centre[0], boxes.y + boxes.v / quiver.scale
                               - centre[1]))
        assert (round(boxes.x[k], 3), round(boxes.y[k], 3)) in shown
        assert rectangle.get_width() / 2 == pytest.approx(boxes.sigma_u[k] * scale, rel=1e-9)
        assert rectangle.get_height() / 2 == pytest.approx(boxes.sigma_v[k] * scale, rel=1e-9)
    plt.close(fig)


def test_dense_vectors_are_thinned_and_land_left_out_as_the_key_says():
    projection, positions, vectors = lancaster_vectors(4e3, 60, 70)
    fig = vectors_figure(positions, vectors, "Dense", "test", projection=projection)
    ax = fig.axes[0]
    (quiver,) = [c for c in ax.collections if isinstance(c, Quiver)]
    drawn = len(quiver.get_offsets())
    key = key_of(fig)
    note = [t.get_text() for t in key.findobj(Text) if "drawn" in t.get_text()][0]
    total, land, thinned = (int(v) for v in re.search(r"of (\d+) vectors drawn\n(\d+) on land left out\n(\d+) "
                                                      "thinned", note).groups())
    assert total == len(positions) and drawn + land + thinned == total
    assert f"{drawn} of {total}" in note
    assert 0.2 * total < land < 0.8 * total  # Lancaster Sound: about half of the lattice is on land
    assert drawn <= ARROWS_ACROSS * ARROWS_ACROSS * 2
    check_figure(fig)
    plt.close(fig)


@pytest.mark.parametrize("projection, name", [
    (nsidc_polar_stereographic("north"), "Polar stereographic north (EPSG:3413)"),
    (nsidc_polar_stereographic("south"), "Polar stereographic south (EPSG:3976)"),
    (PolarStereographic(np.radians(60.0), np.radians(10.0)), "Polar stereographic north (true scale 60.00°N, "
                                                             "central meridian 10.00°E)"),
    (TangentPlane(np.radians(70.3), np.radians(-148.4)), "Tangent plane at 70.30°N 148.40°W (orthographic)"),
    (Equirectangular(np.radians(74.0), np.radians(-85.0)), "Equirectangular at 74.00°N 85.00°W"),
    (LambertConformalConic(*np.radians([33.0, 45.0, 23.0, -96.0])), "Lambert conformal conic (parallels 33.00°N, "
                                                                     "45.00°N)"),
    (CrsProjection("EPSG:3031"), "WGS 84 / Antarctic Polar Stereographic (EPSG:3031)"),
])
def test_maps_name_their_coordinate_system_in_words(projection, name):
    assert crs_name(projection) == name
    assert "+" not in crs_name(projection)


# ------------------------------------------------------------------------------------------------ particulars


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
    assert "Polar stereographic north (EPSG:3413)" in fig.get_suptitle()
    renderer = fig.canvas.get_renderer()
    drawn_texts(fig)
    images_axes = [ax for ax in fig.axes if ax not in colour_bars]
    assert len(images_axes) == 6
    for k, a in enumerate(images_axes + colour_bars):
        for b in (images_axes + colour_bars)[k + 1:]:
            assert not a.get_window_extent(renderer).overlaps(b.get_window_extent(renderer))
    assert_no_text_overprints(fig)
    plt.close(fig)


def test_navigation_errors_keep_a_legend_and_distinct_colours_with_many_strips():
    fig = navigation_errors_figure(navigation_curves(), "Navigation errors")
    top = fig.axes[0]
    colours = {tuple(line.get_color()) for line in top.get_lines() if str(line.get_label()).startswith("strip")}
    assert len(colours) == 15
    legend = top.get_legend()
    assert legend is not None and {t.get_text() for t in legend.get_texts()} >= {f"strip {k:02d}" for k in range(15)}
    drawn_texts(fig)
    renderer = fig.canvas.get_renderer()
    assert not legend.get_window_extent(renderer).overlaps(top.get_window_extent(renderer))
    plt.close(fig)


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
    plt.close(both)
    plt.close(only)


def test_image_field_colour_bar_carries_the_label():
    pixel, scan = np.meshgrid(np.arange(20.0), np.arange(15.0))
    fig = image_field_figure(pixel, scan, np.hypot(pixel, scan), "Position σ", "σ (m)",
                             points=(np.array([3.0, 10.0]), np.array([4.0, 9.0]), ["A", "B"]))
    (colour_bar,) = [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]
    assert colour_bar.get_ylabel() == "σ (m)"
    drawn_texts(fig)
    renderer = fig.canvas.get_renderer()
    legend = fig.axes[0].get_legend()
    assert legend is not None
    assert not legend.get_window_extent(renderer).overlaps(fig.axes[0].get_window_extent(renderer))
    plt.close(fig)


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
    built = map_figures()
    yield built
    for fig in built.values():
        plt.close(fig)


@pytest.mark.parametrize("kind", ["vectors", "box averages", "trajectories", "maps", "remapped"])
def test_every_map_shows_coast_graticule_labels_and_scale(figures, kind):
    fig = figures[kind]
    maps = map_axes(fig)
    assert maps
    for ax in maps:
        (coast,) = by_gid(ax, COASTLINE_GID)
        x, y = coast.get_data()
        (x0, x1), (y0, y1) = sorted(ax.get_xlim()), sorted(ax.get_ylim())
        inside = (x > x0) & (x < x1) & (y > y0) & (y < y1)
        if ax.get_title() != "Prudhoe Bay":  # the radar strip's frame lies off the coast
            assert inside.sum() > 50, "the coast crosses every one of these frames"
        assert len(by_gid(ax, LAND_GID)) == (0 if kind == "remapped" else 1)  # images keep their pixels
        assert len(by_gid(ax, GRATICULE_GID)) == 1
        labels = [t.get_text() for t in by_gid(ax, GRATICULE_LABEL_GID)]
        assert any(t.endswith("°W") for t in labels) and any(t.endswith("°N") for t in labels), labels
        (bar,) = by_gid(ax, SCALE_BAR_GID)
        assert bar.txt_label.get_text().split()[1] == "km"
    fig.set_dpi(150)  # as written
    check_figure(fig)


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
