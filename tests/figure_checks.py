"""One check of whether a figure can be published, for every figure the package draws (:func:`check_figure`).

Each check works on the drawn figure (``fig.canvas.draw()``, then the artists' window extents and data):

- :func:`check_text_inside`: every visible text (titles, axis and tick labels, legends, keys, colour-bar labels,
  graticule labels, scale bars, annotations) lies inside the canvas.
- :func:`check_no_overlaps`: no two of those texts' boxes overlap.
- :func:`check_named_crs`: no text is a raw PROJ string, and every map (axes with land or a graticule drawn)
  names its coordinate system in words (or by EPSG code) in its axis labels, its title or the figure's title, with
  kilometres on its axes.
- :func:`check_in_frame`: every arrow, from its base to its tip, and every ellipse or rectangle drawn on a map lies
  within the axes' limits (nothing leaves the frame).
- :func:`check_scales_stated_once`: a map with arrows has exactly one key (``gid`` :data:`KEY_GID`) and it states
  the arrows' length once; with error ellipses (or σ rectangles) the key states their scale once, and no legend
  states another (no "true size", no "×" magnification beside the ellipse symbol).
- :func:`check_thinned`: the arrows' bases are at least the axes' width / :data:`ARROWS_ACROSS` apart.
- :func:`check_nothing_on_land`: no arrow base, background point, trajectory vertex or first-fix marker lies on the
  land drawn on the map (beyond the drawing's simplification of the coast).
"""

import itertools
import re

import numpy as np
import shapely
from matplotlib.collections import PolyCollection
from matplotlib.legend import Legend
from matplotlib.patches import Ellipse, Rectangle
from matplotlib.quiver import Quiver, QuiverKey
from matplotlib.text import Text

from seaice_jax.report.figures import (
    ARROWS_ACROSS,
    BACKGROUND_GID,
    BOX_SIGMA_GID,
    ELLIPSE_GID,
    FIRST_FIX_GID,
    KEY_GID,
    TRAJECTORY_GID,
)
from seaice_jax.report.maps import GRATICULE_GID, LAND_GID

RAW_PROJ = re.compile(r"\+(proj|lat_0|lon_0|R|a|rf|ellps|units|x_0|y_0|lat_ts|no_defs)\b=?")
"""Pieces of a PROJ string: none may appear in a figure's text."""

NAMED_CRS = re.compile(r"stereographic|tangent plane|orthographic|equirectangular|lambert|mercator|albers|\bUTM\b|"
                       r"EPSG:\d+", re.IGNORECASE)
"""A coordinate system named in words (or by EPSG code)."""

LENGTH = re.compile(r"\d(\.\d+)?\s*(m|km|km/day|m/s|cm/s)\b")
"""A stated length or speed."""


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


def drawn_texts(fig) -> list:
    """``(text, window extent)`` of every visible, non-empty text the figure draws, after drawing it."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    keys = [a.text for ax in fig.axes for a in ax.get_children() if isinstance(a, QuiverKey)]
    ticks = [label for ax in fig.axes if ax.axison for axis in (ax.xaxis, ax.yaxis)
             for label in drawn_tick_labels(axis)]
    tick_labels = all_tick_labels(fig)
    hidden = {id(t) for ax in fig.axes if not ax.axison for t in (ax.xaxis.label, ax.yaxis.label)}
    other = [t for t in fig.findobj(Text) if id(t) not in tick_labels | hidden]
    unique = list({id(t): t for t in [*other, *keys, *ticks]}.values())
    return [(t, t.get_window_extent(renderer)) for t in unique
            if t.get_visible() and t.get_text().strip() and _shown(t)]


def _shown(text) -> bool:
    """Whether the axes holding ``text`` (if any) is visible: a hidden axes draws none of its texts."""
    parent = getattr(text, "axes", None)
    return parent is None or parent.get_visible()


def check_text_inside(fig, texts=None):
    """Every drawn text inside the canvas (a pixel of slack for antialiasing)."""
    box = fig.bbox
    for text, extent in texts if texts is not None else drawn_texts(fig):
        assert extent.x0 >= box.x0 - 1 and extent.x1 <= box.x1 + 1, f"text leaves the figure: {text.get_text()!r}"
        assert extent.y0 >= box.y0 - 1 and extent.y1 <= box.y1 + 1, f"text leaves the figure: {text.get_text()!r}"


def check_no_overlaps(fig, texts=None):
    """No two drawn texts' boxes overlap."""
    for (a, box_a), (b, box_b) in itertools.combinations(texts if texts is not None else drawn_texts(fig), 2):
        assert not box_a.overlaps(box_b), f"texts overprint: {a.get_text()!r} and {b.get_text()!r}"


def by_gid(ax, gid: str) -> list:
    return [artist for artist in ax.findobj() if artist.get_gid() == gid]


def map_axes(fig) -> list:
    """The axes that are maps in a projection: those with land or a graticule drawn (a coastline alone may be drawn
    in image space)."""
    return [ax for ax in fig.axes if any(by_gid(ax, gid) for gid in (LAND_GID, GRATICULE_GID))]


def check_named_crs(fig, texts=None):
    """No raw PROJ string anywhere; each map names its coordinate system and says its axes are in km."""
    for text, _ in texts if texts is not None else drawn_texts(fig):
        assert not RAW_PROJ.search(text.get_text()), f"a PROJ string in the figure: {text.get_text()!r}"
    suptitle = fig.get_suptitle() if hasattr(fig, "get_suptitle") else ""
    for ax in map_axes(fig):
        if not ax.axison:
            continue  # a frameless overlay (a film's): no axes to label
        words = " ".join([ax.get_xlabel(), ax.get_ylabel(), ax.get_title(), suptitle])
        assert NAMED_CRS.search(words), f"a map without a named coordinate system: {words!r}"
        assert "km" in ax.get_xlabel() and "km" in ax.get_ylabel(), (ax.get_xlabel(), ax.get_ylabel())


def _quiver_tips(quiver) -> tuple[np.ndarray, np.ndarray]:
    """Bases and tips (data units) of a quiver drawn with ``scale_units="xy"`` and ``angles="xy"``."""
    assert quiver.scale_units == "xy" and quiver.angles == "xy", "vector maps draw arrows in data units"
    bases = np.asarray(quiver.get_offsets(), float)
    vectors = np.column_stack([np.ravel(quiver.U), np.ravel(quiver.V)])
    return bases, bases + vectors / quiver.scale


def check_in_frame(fig):
    """Arrows (base to tip), ellipses and rectangles of every axes inside its limits."""
    for ax in fig.axes:
        (x0, x1), (y0, y1) = sorted(ax.get_xlim()), sorted(ax.get_ylim())
        slack = 1e-9 * max(x1 - x0, y1 - y0)
        points = []
        for quiver in [c for c in ax.collections if isinstance(c, Quiver)]:
            points += list(_quiver_tips(quiver))
        for patch in ax.patches:
            if isinstance(patch, Ellipse | Rectangle) and patch.get_transform() is not None:
                corners = patch.get_patch_transform().transform(patch.get_path().vertices)
                points.append(corners)
        for block in points:
            assert ((block[:, 0] >= x0 - slack) & (block[:, 0] <= x1 + slack) & (block[:, 1] >= y0 - slack)
                    & (block[:, 1] <= y1 + slack)).all(), "a vector, ellipse or rectangle leaves the map's frame"


def check_scales_stated_once(fig, texts=None):
    """One key per map with arrows, stating the arrows' length once and, with ellipses or σ rectangles, their scale
    once; no legend entry states a scale of its own."""
    texts = texts if texts is not None else drawn_texts(fig)
    vector_maps = [ax for ax in fig.axes if any(isinstance(c, Quiver) for c in ax.collections)]
    keys = [artist for ax in fig.axes for artist in by_gid(ax, KEY_GID)]
    assert len(keys) == len(vector_maps), f"{len(vector_maps)} vector maps with {len(keys)} keys"
    shapes = [s for ax in vector_maps for s in by_gid(ax, ELLIPSE_GID) + by_gid(ax, BOX_SIGMA_GID)]
    for key in keys:
        key_texts = [t.get_text() for t in key.findobj(Text)]
        stated = [t for t in key_texts if LENGTH.search(t)]
        assert len(stated) == 1 + bool(shapes), f"the key states {len(stated)} lengths: {key_texts}"
    for legend in fig.findobj(Legend):
        for entry in legend.get_texts():
            words = entry.get_text()
            assert not (vector_maps and LENGTH.search(words)) and "×" not in words and "true size" not in words, \
                f"a scale in the legend, not the key: {words!r}"
    ellipse_statements = [t.get_text() for t, _ in texts if "ellipse" in t.get_text() and LENGTH.search(t.get_text())]
    if any(by_gid(ax, ELLIPSE_GID) for ax in fig.axes):
        assert len(ellipse_statements) == 1, f"the ellipses' scale is stated {len(ellipse_statements)} times"


def check_thinned(fig, across: int = ARROWS_ACROSS):
    """Arrow bases at least the axes' width / ``across`` apart."""
    for ax in fig.axes:
        for quiver in [c for c in ax.collections if isinstance(c, Quiver)]:
            bases = np.asarray(quiver.get_offsets(), float)
            if len(bases) < 2:
                continue
            spacing = abs(np.diff(ax.get_xlim())[0]) / across
            distance = np.hypot(*(bases[:, None, :] - bases[None, :, :]).transpose(2, 0, 1))
            np.fill_diagonal(distance, np.inf)
            assert distance.min() >= spacing * (1 - 1e-9), \
                f"arrows {distance.min():.4g} apart, more than {across} across the map"


def _land(ax):
    """The land drawn on a map as one shapely geometry (``None``: no land drawn)."""
    collections = [c for c in by_gid(ax, LAND_GID) if isinstance(c, PolyCollection)]
    rings = [path.vertices for c in collections for path in c.get_paths() if len(path.vertices) >= 4]
    return shapely.union_all([shapely.Polygon(r).buffer(0) for r in rings]) if rings else None


def _data_points(ax) -> np.ndarray:
    """Where the data artists sit: arrow bases, background points, trajectory vertices, first fixes."""
    blocks = [np.asarray(q.get_offsets(), float) for q in ax.collections if isinstance(q, Quiver)]
    for artist in by_gid(ax, BACKGROUND_GID):
        blocks.append(np.asarray(artist.get_offsets(), float))
    for gid in (TRAJECTORY_GID, FIRST_FIX_GID):
        for line in by_gid(ax, gid):
            blocks.append(np.column_stack(line.get_data()).astype(float))
    points = np.concatenate(blocks) if blocks else np.zeros((0, 2))
    return points[np.isfinite(points).all(axis=1)]


def check_nothing_on_land(fig):
    """No data point inside the land drawn on a map by more than the drawing's simplification (a 700th of the
    frame's larger side)."""
    for ax in fig.axes:
        land = _land(ax)
        points = _data_points(ax)
        if land is None or not len(points):
            continue
        (x0, x1), (y0, y1) = sorted(ax.get_xlim()), sorted(ax.get_ylim())
        inside = shapely.contains_xy(land, points[:, 0], points[:, 1])
        if inside.any():
            depth = shapely.distance(shapely.points(points[inside]), land.boundary)
            assert depth.max() <= max(x1 - x0, y1 - y0) / 700, \
                f"{int((depth > max(x1 - x0, y1 - y0) / 700).sum())} data points drawn on land"


def check_figure(fig):
    """Every check above on one figure."""
    texts = drawn_texts(fig)
    check_text_inside(fig, texts)
    check_no_overlaps(fig, texts)
    check_named_crs(fig, texts)
    check_in_frame(fig)
    check_scales_stated_once(fig, texts)
    check_thinned(fig)
    check_nothing_on_land(fig)


def assert_no_text_overprints(fig):
    """Texts inside the canvas and apart (the text checks alone, for figures checked elsewhere)."""
    texts = drawn_texts(fig)
    check_no_overlaps(fig, texts)
    check_text_inside(fig, texts)
