"""The figures people look at, in one style. Each ``<name>_figure`` builds a matplotlib figure; ``plot_<name>``
writes it as a PNG atomically and returns its path.

The style every figure shares (checked on every figure by ``tests/figure_checks.py``): constrained layout, so
titles, legends, keys and colour bars get their own room and no text overprints another or leaves the canvas; colour
bars with units; every symbol in a legend; map axes in kilometres of a coordinate system named in words
(:func:`crs_name`, e.g. "Polar stereographic north (EPSG:3413)", never a PROJ string). Vector maps (drift, box
averages) hold every arrow tip and ellipse inside the frame, draw at most :data:`ARROWS_ACROSS` arrows across the
map's width, leave out what starts on land, and state their scales once, in a key beside the map: a reference arrow
and a reference 95 % ellipse (or ±1σ rectangle), each drawn exactly as large as on the map with the length it stands
for (the ellipses at the arrows' scale, or at a stated multiple of it where that would leave them invisible or
hiding the arrows); the key also counts the vectors left out. PDF and/or SVG copies are written beside the PNG when
the environment variable ``SEAICE_FIGURE_FORMATS`` lists them (e.g. ``pdf,svg``).
"""

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from seaice_jax.drift.kinematics import error_ellipses  # noqa: E402
from seaice_jax.errors import SeaiceError  # noqa: E402
from seaice_jax.files import atomic_path  # noqa: E402
from seaice_jax.report.maps import (  # noqa: E402
    COASTLINE_GID,
    CONTROL_GID,
    coast_in_image,
    decorate_map,
    frame_coastline,
    on_land,
)

FIGURE_FORMATS_VARIABLE = "SEAICE_FIGURE_FORMATS"
"""Environment variable listing extra formats (``pdf``, ``svg``, comma-separated) written beside each PNG."""

_EXTRA_FORMATS = ("pdf", "svg")

ARROWS_ACROSS = 20
"""The density rule of every vector map: arrows (and box averages) whose bases lie closer than the map frame's width
divided by this to an arrow already drawn (taken in the order given) are left out, and the reference arrow is 0.8 of
that spacing long, so arrows do not run into one another. The key says how many were left out."""

VECTOR_GID = "vectors"
ELLIPSE_GID = "error ellipse"
BOX_SIGMA_GID = "box sigma"
BOX_COUNT_GID = "box count"
BACKGROUND_GID = "background points"
TRAJECTORY_GID = "trajectory"
FIRST_FIX_GID = "first fix"
KEY_GID = "key"
"""``gid`` s of the data artists (tests find them, and check that none is drawn on land) and of the key beside a
vector map (the arrow's length and the ellipses' or rectangles' scale, each stated once)."""


@dataclass(frozen=True)
class MapLayer:
    """Points or grid lines to draw on a map, in projected metres.

    Attributes:
        label: legend text.
        x, y: ``(n_lines, n_samples)`` for a ``"grid"`` (drawn as lines along both axes), or ``(n,)`` points.
        kind: ``"grid"``, ``"points"`` or ``"labelled"`` (points with ``names``).
        names: labels for ``"labelled"`` points.
    """

    label: str
    x: np.ndarray
    y: np.ndarray
    kind: str = "points"
    names: Sequence[str] = ()


@dataclass(frozen=True)
class MapPanel:
    """One map: a projection (``forward(lat, lon) -> (x, y)`` in metres), its layers and a title."""

    projection: object
    layers: Sequence[MapLayer]
    title: str


def _degrees_text(radians, positive: str, negative: str) -> str:
    value = float(np.degrees(float(radians)))
    return f"{abs(value):.2f}°{positive if value >= 0 else negative}"


def crs_name(projection) -> str:
    """How a figure names a map's coordinate system, in words, with its EPSG code where it has one (never a raw PROJ
    string): ``"Polar stereographic north (EPSG:3413)"``, ``"Tangent plane at 74.92°N 148.16°W (orthographic)"``;
    a CRS computed by PROJ by its own name."""
    from seaice_jax.geometry.crs import CrsProjection
    from seaice_jax.geometry.projections import (
        Equirectangular,
        LambertConformalConic,
        PolarStereographic,
        TangentPlane,
    )

    if projection is None:
        return "map grid"
    code = projection.epsg_code() if hasattr(projection, "epsg_code") else None
    epsg = f" (EPSG:{code})" if code is not None else ""
    if isinstance(projection, PolarStereographic):
        hemisphere = "north" if float(projection.standard_parallel) >= 0 else "south"
        if code is not None:
            return f"Polar stereographic {hemisphere}{epsg}"
        return (f"Polar stereographic {hemisphere} (true scale "
                f"{_degrees_text(projection.standard_parallel, 'N', 'S')}, central meridian "
                f"{_degrees_text(projection.central_meridian, 'E', 'W')})")
    if isinstance(projection, TangentPlane):
        return (f"Tangent plane at {_degrees_text(projection.latitude, 'N', 'S')} "
                f"{_degrees_text(projection.longitude, 'E', 'W')} (orthographic)")
    if isinstance(projection, Equirectangular):
        return (f"Equirectangular at {_degrees_text(projection.reference_latitude, 'N', 'S')} "
                f"{_degrees_text(projection.reference_longitude, 'E', 'W')}")
    if isinstance(projection, LambertConformalConic):
        return (f"Lambert conformal conic (parallels {_degrees_text(projection.standard_parallel_1, 'N', 'S')}, "
                f"{_degrees_text(projection.standard_parallel_2, 'N', 'S')}){epsg}")
    if isinstance(projection, CrsProjection):
        crs = projection.crs
        name = crs.name if crs.name and crs.name.lower() != "unknown" else (
            crs.coordinate_operation.method_name if crs.coordinate_operation is not None else "projected CRS")
        return f"{name}{epsg}"
    return f"{type(projection).__name__}{epsg}"


def _figure(width: float, height: float, rows: int = 1, columns: int = 1, **options) -> tuple[Figure, Any]:
    """A figure with constrained layout (the layout engine that keeps every label, key and colour bar apart)."""
    return plt.subplots(rows, columns, figsize=(width, height), layout="constrained", **options)


def _extra_formats() -> list[str]:
    requested = [f.strip().lower() for f in os.environ.get(FIGURE_FORMATS_VARIABLE, "").split(",") if f.strip()]
    unknown = sorted(set(requested) - set(_EXTRA_FORMATS))
    if unknown:
        raise SeaiceError(f"{FIGURE_FORMATS_VARIABLE}: unknown figure format(s) {', '.join(unknown)} (use "
                          f"{', '.join(_EXTRA_FORMATS)})")
    return requested


def _save(fig, path) -> Path:
    """Write as PNG (and the :data:`FIGURE_FORMATS_VARIABLE` formats beside it) atomically, close."""
    path = Path(path)
    try:
        for extension in ["png", *_extra_formats()]:
            target = path if extension == "png" else path.with_suffix(f".{extension}")
            with atomic_path(target) as temporary:
                fig.savefig(temporary, format=extension, dpi=150)
    finally:
        plt.close(fig)
    return path


def _legend_outside(ax, **options):
    """The axes' legend to the right of the axes (never over the data); nothing when there is nothing to explain."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, fontsize=7, frameon=False,
                  **options)


def _decorate(ax, projection, **options):
    """The map decorations (:func:`~seaice_jax.report.maps.decorate_map`) where the map's projection is known."""
    if projection is not None:
        decorate_map(ax, projection, **options)


def _kilometre_axes(ax, crs: str):
    """Axes in km of ``crs`` (named once, on the x axis); the equal-aspect map box sits at the top left of its layout
    cell (centred, a box shrunk to its aspect moves away from where the constrained layout measured its axis labels,
    which then leave the figure; at the top, it lines up with the legend beside it)."""
    ax.set_anchor("NW")
    kilometres = matplotlib.ticker.FuncFormatter(lambda v, _: f"{v / 1000:.0f}")
    ax.xaxis.set_major_formatter(kilometres)
    ax.yaxis.set_major_formatter(kilometres)
    ax.set_xlabel(f"x (km), {crs}", fontsize=8)
    ax.set_ylabel("y (km)", fontsize=8)


def _nice(value: float) -> float:
    """The 1-2-5 number nearest ``value`` (> 0) on a log scale."""
    exponent = np.floor(np.log10(value))
    mantissa = value / 10**exponent
    return float(min((1.0, 2.0, 5.0, 10.0), key=lambda m: abs(np.log(mantissa / m))) * 10**exponent)


def ellipse_magnification(semi_major, arrow_length) -> float:
    """The factor 95 % ellipses are drawn at, relative to the arrows' scale, beside vectors whose reference arrow is
    ``arrow_length`` long (both in map units): 1 when the median semi-major axis is between a tenth and the whole of
    the arrow (visible, not hiding the vectors), else the 1-2-5 factor that brings it to about a third of the
    arrow. The key states the scale the ellipses are drawn at."""
    semi_major = np.asarray(semi_major, float)
    semi_major = semi_major[np.isfinite(semi_major) & (semi_major > 0)]
    if not semi_major.size:
        return 1.0
    typical = float(np.median(semi_major))
    if 0.1 * arrow_length <= typical <= arrow_length:
        return 1.0
    return _nice(arrow_length / 3.0 / typical)


def _colours(count: int):
    """``count`` distinct colours: the 10- or 20-colour qualitative maps, then samples of a continuous one."""
    if count <= 10:
        return [plt.get_cmap("tab10")(k) for k in range(count)]
    if count <= 20:
        return [plt.get_cmap("tab20")(k) for k in range(count)]
    return [plt.get_cmap("viridis")(v) for v in np.linspace(0.0, 0.95, count)]


def thin_points(x, y, spacing: float) -> np.ndarray:
    """Indices of the points kept when each point closer than ``spacing`` to one kept before it (in the order given)
    is left out: every two kept points are at least ``spacing`` apart (greedy, over a grid of ``spacing`` cells)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    if spacing <= 0 or x.size < 2:
        return np.arange(x.size)
    cells: dict[tuple[int, int], list[int]] = {}
    column, row = np.floor(x / spacing).astype(int), np.floor(y / spacing).astype(int)
    kept = []
    for k in range(x.size):
        near = (m for i in (-1, 0, 1) for j in (-1, 0, 1) for m in cells.get((column[k] + i, row[k] + j), ()))
        if all((x[k] - x[m]) ** 2 + (y[k] - y[m]) ** 2 >= spacing**2 for m in near):
            kept.append(k)
            cells.setdefault((column[k], row[k]), []).append(k)
    return np.asarray(kept, int)


def _thin(points, ax) -> np.ndarray:
    """:func:`thin_points` of ``(n, 2)`` points at the :data:`ARROWS_ACROSS` spacing of the axes' width."""
    return thin_points(points[:, 0], points[:, 1], float(np.ptp(ax.get_xlim())) / ARROWS_ACROSS)


def _points(values) -> np.ndarray:
    """``(n, 2)`` finite rows of ``values`` (``None``: none)."""
    if values is None:
        return np.zeros((0, 2))
    values = np.asarray(values, float).reshape(-1, 2)
    return values[np.isfinite(values).all(axis=1)]


def _frame(*point_sets, margin: float = 0.04, shape: float = 0.25) -> tuple[float, float, float, float]:
    """``(x0, x1, y0, y1)``: the box of all finite points, widened by ``margin`` of its larger side, and its smaller
    side to at least ``shape`` of the larger (points along a line still make a map)."""
    points = np.concatenate([_points(p) for p in point_sets])
    if not points.size:
        return -1.0, 1.0, -1.0, 1.0
    low, high = points.min(axis=0), points.max(axis=0)
    pad = max(margin * float(np.max(high - low)), 1.0)
    low, high = low - pad, high + pad
    centre, half = (low + high) / 2, np.maximum((high - low) / 2, shape * float(np.max(high - low)) / 2)
    return centre[0] - half[0], centre[0] + half[0], centre[1] - half[1], centre[1] + half[1]


def _map_figure(frame, width: float = 8.5, side: float = 2.4) -> tuple[Figure, Any, Any]:
    """One map axes (equal aspect, limits ``frame``) in a figure whose height follows the frame's shape, and beside
    it a panel ``side`` inches wide (no axes of its own) for the legend and the key: ``(figure, map, panel)``. The
    panel is an axes of the layout, so what it holds is measured and kept inside the figure whatever the map's
    shape (an equal-aspect map shrinks within its cell, where the layout does not see it)."""
    x0, x1, y0, y1 = frame
    aspect = (y1 - y0) / max(x1 - x0, 1e-9)
    fig, (ax, panel) = _figure(width, float(np.clip((width - side - 0.9) * aspect + 1.3, 2.6, 8.0)), 1, 2,
                               gridspec_kw={"width_ratios": [width - side, side]})
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    panel.set_axis_off()
    return fig, ax, panel


def _panel_legend(ax, panel):
    """The map's legend at the top of the side panel (nothing when there is nothing to explain)."""
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        panel.legend(handles, labels, loc="upper left", bbox_to_anchor=(0.0, 1.0), borderaxespad=0.0, fontsize=7,
                     frameon=False)


def _sea(ax, projection, *point_sets) -> tuple[Any, list[np.ndarray]]:
    """The coastline of the axes' frame (``None`` without a projection) and, per ``(n, 2)`` point set, where the
    points are at sea (not on its land, :func:`~seaice_jax.report.maps.on_land`)."""
    if projection is None:
        return None, [np.ones(len(p), bool) for p in point_sets]
    coast = frame_coastline(ax, projection)
    return coast, [~on_land(projection, p[:, 0], p[:, 1], coast) if len(p) else np.ones(0, bool)
                   for p in point_sets]


def _length_text(value: float, unit: str) -> str:
    """A key's length: metres as ``"5 km"`` or ``"200 m"``; other units as given."""
    if unit == "m":
        return f"{value / 1000:g} km" if value >= 1000 else f"{value:g} m"
    return f"{value:g} {unit}"


def _key(ax, panel, rows, note: str = ""):
    """The key at the bottom of the side panel: each row a patch drawn in the map's data scale (an arrow, an
    ellipse, a rectangle: exactly as large as on the map ``ax``) beside its text, then ``note``."""
    from matplotlib.offsetbox import AnchoredOffsetbox, AuxTransformBox, HPacker, TextArea, VPacker

    children = []
    for patch, text in rows:
        drawing = AuxTransformBox(ax.transData)
        drawing.add_artist(patch)
        children.append(HPacker(children=[drawing, TextArea(text, textprops={"fontsize": 7})], align="center",
                                pad=0, sep=6))
    if note:
        children.append(TextArea(note, textprops={"fontsize": 6.5, "color": "0.3"}))
    key = AnchoredOffsetbox("lower left", child=VPacker(children=children, align="left", pad=0, sep=6),
                            bbox_to_anchor=(0.0, 0.0), bbox_transform=panel.transAxes, borderpad=0.0, frameon=False)
    key.set_gid(KEY_GID)
    panel.add_artist(key)


def _arrow_patch(ax, length: float, colour: str = "C0"):
    """A horizontal arrow ``length`` data units long, shaped as :func:`_quiver` draws them."""
    from matplotlib.patches import FancyArrow

    width = _SHAFT * float(np.ptp(ax.get_xlim()))
    return FancyArrow(0.0, 0.0, length, 0.0, width=width, head_width=3 * width, head_length=5 * width,
                      length_includes_head=True, color=colour, lw=0)


_SHAFT = 0.003
"""Arrow shaft width, a fraction of the map's width (matplotlib's quiver ``width``)."""


def _quiver(ax, positions, vectors, scale: float, label: str):
    """Arrows from ``positions`` along ``vectors`` at ``scale`` vector units per map unit (``gid``
    :data:`VECTOR_GID`)."""
    return ax.quiver(positions[:, 0], positions[:, 1], vectors[:, 0], vectors[:, 1], angles="xy", scale_units="xy",
                     scale=scale, width=_SHAFT, color="C0", label=label, gid=VECTOR_GID, zorder=3)


def _median_nearest(points, sample: int = 400, chunk: int = 20_000) -> float:
    """The median distance from a point to its nearest neighbour among ``(n, 2)`` points (n > 1), over an evenly
    spaced sample of at most ``sample`` of them (each against all, in chunks: memory stays small)."""
    points = np.asarray(points, float)
    chosen = np.unique(np.linspace(0, len(points) - 1, min(sample, len(points))).astype(int))
    nearest = np.full(chosen.size, np.inf)
    for start in range(0, len(points), chunk):
        block = points[start:start + chunk]
        distance = np.hypot(*(points[chosen, None, :] - block[None, :, :]).transpose(2, 0, 1))
        distance[chosen[:, None] == np.arange(start, start + len(block))[None, :]] = np.inf
        nearest = np.minimum(nearest, distance.min(axis=1))
    return float(np.median(nearest))


def _arrow_scale(vectors, positions, frame) -> tuple[float, float]:
    """``(scale, reference)``: vector units per map unit that draw the 90th-percentile vector (``reference``) 0.8 of
    the arrows' spacing long: the median distance from a base to its nearest neighbour, at least the
    :data:`ARROWS_ACROSS` spacing of the frame ``(x0, x1, y0, y1)`` (what thinning leaves) and at most a sixth of
    its width (a few scattered vectors)."""
    lengths = np.hypot(*np.asarray(vectors, float).reshape(-1, 2).T)
    lengths = lengths[np.isfinite(lengths)]
    reference = float(np.percentile(lengths, 90)) if lengths.size else 0.0
    reference = reference if reference > 0 else 1.0
    width = frame[1] - frame[0]
    nearest = _median_nearest(positions) if len(positions) > 1 else width
    return reference / (0.8 * float(np.clip(nearest, width / ARROWS_ACROSS, width / 6))), reference


def _thinned_note(total: int, land: int, thinned: int, noun: str) -> str:
    """The key's account of what a vector map leaves out."""
    lines = [f"{total - land - thinned} of {total} {noun} drawn"]
    if land:
        lines.append(f"{land} on land left out")
    if thinned:
        lines.append(f"{thinned} thinned (1 per 1/{ARROWS_ACROSS} of the width)")
    return "\n".join(lines)


def _panel_frame(panel: MapPanel) -> tuple[float, float, float, float]:
    """The frame of a map panel: its layers' points, widened by a tenth of the larger side."""
    return _frame(*[np.column_stack([np.ravel(layer.x), np.ravel(layer.y)]) for layer in panel.layers], margin=0.1)


def _draw_panel(ax, panel: MapPanel, frame, colours):
    for colour, layer in zip(colours, panel.layers, strict=True):
        if layer.kind == "grid":
            ax.plot(layer.x, layer.y, color=colour, lw=0.5)
            ax.plot(layer.x.T, layer.y.T, color=colour, lw=0.5)
            ax.plot([], [], color=colour, label=layer.label)
        else:
            ax.scatter(layer.x, layer.y, s=14, color=colour, label=layer.label, zorder=3)
            for name, x, y in zip(layer.names, layer.x, layer.y, strict=False):
                ax.annotate(name, (x, y), textcoords="offset points", xytext=(4, 4), fontsize=7)
    ax.set_xlim(*frame[:2])
    ax.set_ylim(*frame[2:])
    ax.set_aspect("equal")
    decorate_map(ax, panel.projection)
    _kilometre_axes(ax, crs_name(panel.projection))
    ax.set_title(panel.title, fontsize=9)


def maps_figure(panels: Sequence[MapPanel], title: str) -> Figure:
    """Maps side by side, each as wide as its frame's shape asks, with the coastline and land, a labelled graticule
    and a scale bar (:func:`~seaice_jax.report.maps.decorate_map`), axes in projected kilometres of the panel's
    projection (named under it), one legend below them all."""
    frames = [_panel_frame(panel) for panel in panels]
    ratios = [float(np.clip((x1 - x0) / max(y1 - y0, 1e-9), 0.5, 2.5)) for x0, x1, y0, y1 in frames]
    fig, axes = _figure(max(4.2 * sum(ratios) + 1.5 * len(panels), 7.0), 6.0, 1, len(panels), squeeze=False,
                        gridspec_kw={"width_ratios": ratios})
    colours = _colours(sum(len(panel.layers) for panel in panels))  # one legend: a colour per layer of any panel
    for ax, panel, frame in zip(axes[0], panels, frames, strict=True):
        _draw_panel(ax, panel, frame, colours[:len(panel.layers)])
        colours = colours[len(panel.layers):]
    handles = [entry for ax in axes[0] for entry in zip(*ax.get_legend_handles_labels(), strict=True)]
    if handles:
        fig.legend(*zip(*handles, strict=True), loc="outside lower center", ncol=min(len(handles), 3), fontsize=7,
                   frameon=False)
    fig.suptitle(title, fontsize=11)
    return fig


def plot_maps(path: str | os.PathLike, *args, **options) -> Path:
    """Write :func:`maps_figure` as the PNG ``path`` (and the requested extra formats beside it)."""
    return _save(maps_figure(*args, **options), path)


def image_field_figure(pixel, scan, values, title: str, label: str, points=None) -> Figure:
    """A field over an image's pixel/scan grid (e.g. position σ) as a filled contour map, scan lines downward.

    Args:
        pixel, scan, values: ``(n_scan, n_pixel)`` grids. label: the colour bar's label, with units.
        points: optional ``(pixel, scan, names)`` to mark (control points).
    """
    fig, ax = _figure(7.0, 5.5)
    filled = ax.contourf(pixel, scan, values, levels=15, cmap="viridis")
    fig.colorbar(filled, ax=ax, label=label)
    if points is not None:
        px, sc, names = points
        ax.scatter(px, sc, color="white", edgecolor="black", s=30, zorder=3, label="control points")
        for name, x, y in zip(names, px, sc, strict=False):
            ax.annotate(name, (x, y), textcoords="offset points", xytext=(4, 4), fontsize=7, color="white")
        ax.legend(loc="upper left", bbox_to_anchor=(0.0, -0.12), fontsize=7, frameon=False)
    ax.set_xlabel("pixel")
    ax.set_ylabel("scan line")
    ax.invert_yaxis()
    ax.set_title(title, fontsize=9)
    return fig


def plot_image_field(path: str | os.PathLike, *args, **options) -> Path:
    """Write :func:`image_field_figure` as the PNG ``path`` (and the requested extra formats beside it)."""
    return _save(image_field_figure(*args, **options), path)


def vectors_figure(positions, vectors, title: str, label: str, background=None,
                   covariances=None, projection=None, background_label: str = "points without a vector") -> Figure:
    """Vectors (e.g. drift, error or discrepancy vectors, metres) at map positions (metres), as arrows.

    The map's frame holds every point, arrow and ellipse; the arrows are thinned to :data:`ARROWS_ACROSS` across
    its width and those starting on land left out (with a ``projection``), the key beside the map saying how many.
    The key shows the reference arrow and, with ``covariances``, a reference 95 % ellipse, each drawn at its scale
    on the map with the length it stands for. ``background``: optional ``(n, 2)`` positions drawn as grey dots
    (``background_label`` in the legend; those on land left out); ``covariances``: optional ``(n, 2, 2)`` (m²) of
    the vectors, drawn as 95 % error ellipses at the arrow tips at the arrows' scale, or at a 1-2-5 multiple of it
    where that would leave them invisible or hiding the arrows (:func:`ellipse_magnification`); ``projection``: the
    positions' map projection, named on the axes and used to draw the coastline and land, a labelled graticule and
    a scale bar (:func:`~seaice_jax.report.maps.decorate_map`).
    """
    from matplotlib.patches import Ellipse

    positions, vectors = np.asarray(positions, float).reshape(-1, 2), np.asarray(vectors, float).reshape(-1, 2)
    finite = np.isfinite(positions).all(axis=1) & np.isfinite(vectors).all(axis=1)
    positions, vectors = positions[finite], vectors[finite]
    background = _points(background)
    scale, reference = _arrow_scale(vectors, positions, _frame(positions, background))
    tips = positions + vectors / scale
    major = minor = angle = np.zeros(len(positions))
    factor = 1.0
    if covariances is not None:
        major, minor, angle = (np.asarray(a, float)[finite] for a in error_ellipses(covariances))
        factor = ellipse_magnification(major / scale, 0.8 * reference / scale)
    reach = np.nan_to_num(factor * major / scale)[:, None]
    fig, ax, panel = _map_figure(_frame(positions, background, tips, tips - reach, tips + reach, margin=0.03))
    coast, (sea, background_sea) = _sea(ax, projection, positions, background)
    shown = np.flatnonzero(sea)[_thin(positions[sea], ax)]
    if len(background):
        ax.scatter(*background[background_sea].T, s=3, color="0.7", zorder=1, label=background_label,
                   gid=BACKGROUND_GID)
    _quiver(ax, positions[shown], vectors[shown], scale, "vector")
    rows: list[tuple[Any, str]] = [(_arrow_patch(ax, _nice(reference) / scale), _length_text(_nice(reference), "m"))]
    drawn = shown[np.isfinite(major[shown])] if covariances is not None else shown[:0]
    if drawn.size:
        for k in drawn:
            ax.add_patch(Ellipse(tuple(tips[k]), 2 * factor * float(major[k]) / scale,
                                 2 * factor * float(minor[k]) / scale, angle=float(np.degrees(angle[k])),
                                 fill=False, color="C3", lw=0.6, gid=ELLIPSE_GID, zorder=2.9))
        ax.plot([], [], color="C3", lw=0.6, label="95 % error ellipse")
    if drawn.size and np.median(major[drawn]) > 0:
        typical = _nice(float(np.median(major[drawn])))
        radius = factor * typical / scale
        rows.append((Ellipse((0.0, 0.0), 2 * radius, 2 * radius, fill=False, color="C3", lw=0.6),
                     f"95 % ellipse, semi-axis {_length_text(typical, 'm')}"
                     + ("" if factor == 1.0 else f"\n(ellipses {factor:g}× the arrows' scale)")))
    _key(ax, panel, rows, _thinned_note(len(positions), int((~sea).sum()), len(np.flatnonzero(sea)) - len(shown),
                                 "vectors"))
    _decorate(ax, projection, coast=coast)
    _kilometre_axes(ax, crs_name(projection))
    fig.suptitle(f"{title}\n{label}", fontsize=9)
    _panel_legend(ax, panel)
    return fig


def plot_vectors(path: str | os.PathLike, *args, **options) -> Path:
    """Write :func:`vectors_figure` as the PNG ``path`` (and the requested extra formats beside it)."""
    return _save(vectors_figure(*args, **options), path)


def navigation_errors_figure(curves, title: str) -> Figure:
    """Estimated navigation-error curves with their ±1σ bands, one distinct colour per curve, the legend beside.

    Args:
        curves: sequence of ``(label, times (n,) s, errors (n, 2) m north/east, sigma (n, 2) m)``.
    """
    columns = 1 + len(curves) // 24
    fig, axes = _figure(8.0 + 1.6 * columns, 6.0, 2, 1, sharex=True)
    for colour, (label, times, errors, sigma) in zip(_colours(len(curves)), curves, strict=True):
        minutes = np.asarray(times) / 60.0
        for component, ax in enumerate(axes):
            ax.plot(minutes, errors[:, component] / 1000.0, color=colour, lw=1, label=label)
            ax.fill_between(minutes, (errors[:, component] - sigma[:, component]) / 1000.0,
                            (errors[:, component] + sigma[:, component]) / 1000.0, color=colour, alpha=0.2)
    axes[0].fill_between([], [], [], color="0.5", alpha=0.2, label="±1σ band")
    axes[0].set_ylabel("north error (km)")
    axes[1].set_ylabel("east error (km)")
    axes[1].set_xlabel("time (min)")
    axes[0].set_title(title, fontsize=9)
    _legend_outside(axes[0], ncol=columns)
    for ax in axes:
        ax.grid(alpha=0.3)
    return fig


def plot_navigation_errors(path: str | os.PathLike, *args, **options) -> Path:
    """Write :func:`navigation_errors_figure` as the PNG ``path`` (and the requested extra formats beside it)."""
    return _save(navigation_errors_figure(*args, **options), path)


def tie_discrepancies_figure(before, after) -> Figure:
    """Tie-point discrepancies (across, along track; metres) before and after the internal adjustment (source 000,
    Fig. 4); ``before`` ``None``: one panel, after a (simultaneous) adjustment only."""
    panels = [(before, "before internal adjustment"), (after, "after internal adjustment")] if before is not None \
        else [(after, "after the simultaneous adjustment")]
    fig, axes = _figure(5.0 * len(panels) + 0.5, 4.8, 1, len(panels), squeeze=False)
    finite = np.concatenate([np.ravel(np.asarray(v, float)) for v, _ in panels]) / 1000.0
    finite = finite[np.isfinite(finite)]
    limit = 1.1 * float(np.max(np.abs(finite))) if finite.size and np.max(np.abs(finite)) > 0 else 1.0
    for ax, (values, title) in zip(axes[0], panels, strict=True):
        values = np.asarray(values, float) / 1000.0
        ax.scatter(values[:, 0], values[:, 1], s=8, label="tie point")
        rms = np.sqrt(np.mean(values**2, axis=0)) if values.size else (np.nan, np.nan)
        ax.set_title(f"{title}\nrms {rms[0]:.2f} km across, {rms[1]:.2f} km along", fontsize=9)
        ax.set_xlabel("across-track discrepancy (km)")
        ax.set_ylabel("along-track discrepancy (km)")
        ax.axhline(0, color="0.8", lw=0.5)
        ax.axvline(0, color="0.8", lw=0.5)
        ax.set_xlim(-limit, limit)
        ax.set_ylim(-limit, limit)
        ax.set_aspect("equal")
        ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(5, prune="lower"))  # no clash at the corner
    return fig


def plot_tie_discrepancies(path: str | os.PathLike, *args, **options) -> Path:
    """Write :func:`tie_discrepancies_figure` as the PNG ``path`` (and the requested extra formats beside it)."""
    return _save(tie_discrepancies_figure(*args, **options), path)


def box_averages_figure(boxes, title: str, background=None, projection=None) -> Figure:
    """Box-averaged velocity vectors with their standard-deviation rectangles at the arrow tips (source 001,
    Figure 4-7): ``boxes`` a :class:`~seaice_jax.drift.kinematics.BoxAverages` (m, m/s); the number under each
    arrow is the count of velocities averaged. The rectangles are ±1 standard deviation at the arrows' scale (or a
    1-2-5 multiple of it, :func:`ellipse_magnification`); the key shows a reference arrow and rectangle with the
    velocities they stand for. Boxes whose centre is on land are left out, and thinned as arrows are
    (:data:`ARROWS_ACROSS`); ``background``: floe positions (grey, those on land left out); ``projection``: the
    map's, for the coastline, graticule and scale bar (:func:`~seaice_jax.report.maps.decorate_map`)."""
    from matplotlib.patches import Rectangle

    positions = np.column_stack([np.asarray(boxes.x, float), np.asarray(boxes.y, float)])
    velocity = np.column_stack([np.asarray(boxes.u, float), np.asarray(boxes.v, float)])
    sigma = np.nan_to_num(np.column_stack([np.asarray(boxes.sigma_u, float), np.asarray(boxes.sigma_v, float)]))
    count = np.asarray(boxes.count)
    finite = np.isfinite(positions).all(axis=1) & np.isfinite(velocity).all(axis=1)
    positions, velocity, sigma, count = positions[finite], velocity[finite], sigma[finite], count[finite]
    background = _points(background)
    scale, reference = _arrow_scale(velocity, positions, _frame(positions, background))
    factor = ellipse_magnification(np.max(sigma, axis=1) / scale, 0.8 * reference / scale)
    tips = positions + velocity / scale
    fig, ax, panel = _map_figure(_frame(positions, background, tips - factor * sigma / scale,
                                        tips + factor * sigma / scale, margin=0.03))
    coast, (sea, background_sea) = _sea(ax, projection, positions, background)
    shown = np.flatnonzero(sea)[_thin(positions[sea], ax)]
    if len(background):
        ax.scatter(*background[background_sea].T, s=2, color="0.75", zorder=1, label="floe positions",
                   gid=BACKGROUND_GID)
    _quiver(ax, positions[shown], velocity[shown], scale, "box-average velocity")
    for k in shown:
        w, h = 2 * factor * sigma[k] / scale
        ax.add_patch(Rectangle((tips[k, 0] - w / 2, tips[k, 1] - h / 2), w, h, fill=False, color="C3", lw=0.8,
                               gid=BOX_SIGMA_GID, zorder=2.9))
        ax.annotate(str(count[k]), tuple(positions[k]), fontsize=6, color="0.3", xytext=(0, -3), ha="center",
                    va="top", textcoords="offset points", gid=BOX_COUNT_GID)
    ax.plot([], [], color="C3", lw=0.8, label="±1 standard deviation")
    ax.plot([], [], " ", label="numbers: velocities per box")
    per_day = 86.4  # km/day per m/s: the key states round numbers of km/day
    typical = _nice(float(np.median(sigma[shown])) * per_day) if shown.size and np.median(sigma[shown]) > 0 \
        else _nice(reference * per_day)
    half = factor * typical / per_day / scale
    rows: list[tuple[Any, str]] = [(_arrow_patch(ax, _nice(reference * per_day) / per_day / scale),
                                    _length_text(_nice(reference * per_day), "km/day"))]
    if shown.size:
        rows.append((Rectangle((-half, -half), 2 * half, 2 * half, fill=False, color="C3", lw=0.8),
                     f"±1σ of {_length_text(typical, 'km/day')}"
                     + ("" if factor == 1.0 else f"\n(rectangles {factor:g}× the arrows' scale)")))
    _key(ax, panel, rows, _thinned_note(len(positions), int((~sea).sum()), len(np.flatnonzero(sea)) - len(shown),
                                 "boxes"))
    _decorate(ax, projection, coast=coast)
    _kilometre_axes(ax, crs_name(projection))
    fig.suptitle(title, fontsize=9)
    _panel_legend(ax, panel)
    return fig


def plot_box_averages(path: str | os.PathLike, *args, **options) -> Path:
    """Write :func:`box_averages_figure` as the PNG ``path`` (and the requested extra formats beside it)."""
    return _save(box_averages_figure(*args, **options), path)


def velocity_series_figure(series, title: str, epoch_label: str) -> Figure:
    """Box-averaged velocity per day (source 001, Figure 4-5): u and v (km/day) against days, one line per box,
    error bars ±1 standard deviation."""
    columns = 1 + len(series) // 24
    fig, axes = _figure(8.0 + 1.6 * columns, 5.5, 2, 1, sharex=True)
    for colour, (key, entry) in zip(_colours(len(series)), series.items(), strict=True):
        days = entry["time"] / 86400.0
        for ax, component in zip(axes, ("u", "v"), strict=True):
            ax.errorbar(days, entry[component] * 86.4, yerr=np.nan_to_num(entry[f"sigma_{component}"]) * 86.4,
                        marker="o", ms=3, capsize=2, color=colour, label=f"box {key}")
    for ax, component in zip(axes, ("grid x", "grid y"), strict=True):
        ax.axhline(0, color="0.6", lw=0.6)
        ax.set_ylabel(f"{component} (km/day)")
    axes[1].set_xlabel(f"days since {epoch_label}")
    axes[0].set_title(f"{title} (bars: ±1 standard deviation)", fontsize=9)
    _legend_outside(axes[0], ncol=columns)
    return fig


def plot_velocity_series(path: str | os.PathLike, *args, **options) -> Path:
    """Write :func:`velocity_series_figure` as the PNG ``path`` (and the requested extra formats beside it)."""
    return _save(velocity_series_figure(*args, **options), path)


def remapped_figure(images, titles, extent_km, projection=None,
                    units: str = "image value (as digitized)") -> Figure:
    """Remapped images side by side (NaN white) on one grey scale with its colour bar (``units``), axes in km of
    ``projection`` (named in the title; given: with the coastline as a line over the image, a labelled graticule and
    a scale bar, :func:`~seaice_jax.report.maps.decorate_map`)."""
    count = len(images)
    columns = min(count, 4)
    rows = -(-count // columns)
    fig, axes = _figure(3.0 * columns + 1.2, 3.0 * rows + 0.6, rows, columns, squeeze=False)
    finite = [np.asarray(image, float)[np.isfinite(image)] for image in images]
    values = np.concatenate(finite) if any(v.size for v in finite) else np.zeros(1)
    low, high = np.percentile(values, [1, 99])
    for ax in axes.ravel()[count:]:
        ax.remove()
    shown = []
    for k, ax in enumerate(axes.ravel()[:count]):
        shown.append(ax.imshow(np.ma.masked_invalid(images[k]), cmap="gray", extent=extent_km, origin="upper",
                               vmin=low, vmax=high))
        ax.set_title(titles[k], fontsize=8)
        ax.tick_params(labelsize=6)
        ax.set_xlabel("x (km)", fontsize=7)
        ax.set_ylabel("y (km)", fontsize=7)
        _decorate(ax, projection, unit=1000.0, land=False, coast_colour="orange", fontsize=5.0)
    fig.colorbar(shown[0], ax=list(axes.ravel()[:count]), label=units, shrink=0.8)
    fig.suptitle(f"Remapped images on one grid, {crs_name(projection)}; white: no data", fontsize=9)
    return fig


def plot_remapped(path: str | os.PathLike, *args, **options) -> Path:
    """Write :func:`remapped_figure` as the PNG ``path`` (and the requested extra formats beside it)."""
    return _save(remapped_figure(*args, **options), path)


def trajectories_figure(floe, x, y, title: str, limit: int = 400, projection=None) -> Figure:
    """Floe trajectories (source 001, Figure 4-3): one line per floe through its fixes (m, in time order of the
    rows), a dot at its first fix; at most ``limit`` floes drawn; fixes on land are left out (the line breaks
    there); ``projection``: the map's, for the coastline, graticule and scale bar
    (:func:`~seaice_jax.report.maps.decorate_map`)."""
    floe, x, y = np.asarray(floe), np.asarray(x, float), np.asarray(y, float)
    fixes = np.column_stack([x, y])
    fig, ax, panel = _map_figure(_frame(fixes))
    coast, (sea,) = _sea(ax, projection, fixes)
    floes = list(dict.fromkeys(floe.tolist()))
    lines, firsts = [], []
    for f in floes[:limit]:
        at = np.flatnonzero(floe == f)
        line = np.where(sea[at, None], fixes[at], np.nan)
        lines.append(np.vstack([line, [np.nan, np.nan]]))
        if sea[at[0]]:
            firsts.append(fixes[at[0]])
    joined = np.concatenate(lines) if lines else np.zeros((0, 2))
    ax.plot(joined[:, 0], joined[:, 1], lw=0.7, color="C0", gid=TRAJECTORY_GID, label="trajectory")
    first = _points(firsts)
    ax.plot(first[:, 0], first[:, 1], ".", ms=3, color="C3", gid=FIRST_FIX_GID, label="first fix")
    left_out = [f"{len(floes) - limit} of {len(floes)} floes not drawn"] if len(floes) > limit else []
    if (~sea).any():
        left_out.append(f"{int((~sea).sum())} fixes on land left out")
    if left_out:
        ax.plot([], [], " ", label="\n".join(left_out))
    _decorate(ax, projection, coast=coast)
    _kilometre_axes(ax, crs_name(projection))
    fig.suptitle(title, fontsize=9)
    _panel_legend(ax, panel)
    return fig


def plot_trajectories(path: str | os.PathLike, *args, **options) -> Path:
    """Write :func:`trajectories_figure` as the PNG ``path`` (and the requested extra formats beside it)."""
    return _save(trajectories_figure(*args, **options), path)


def coastline_overlay_figure(image, model, coastline, control=None, title: str = "") -> Figure:
    """The coastline-overlay check of a rectification (source 001, Appendix A, VHR2: "good rectifications, as judged
    both from control point errors and coastal map overlays"): the image in image space, scan lines downward, with
    the coastline projected into it through the fitted scan model, so a misfit shows as a shifted or twisted coast.

    Args:
        image: ``(n_scans, n_pixels)`` image values (NaN: no data); scan line 1 is the top row, pixel 1 the left
            column (1-based centres, as the model counts).
        model: a :class:`~seaice_jax.geometry.scan.ScanModel`; the coast's latitudes/longitudes (degrees) enter
            :meth:`~seaice_jax.geometry.scan.ScanModel.inverse` as the model's sphere latitudes, the convention
            control stations follow.
        coastline: a :class:`~seaice_jax.io.coastline.Coastline` covering the image.
        control: optional measured control points ``(pixel, scan)`` or ``(pixel, scan, names)`` (1-based), drawn
            as markers.
        title: the figure's title.
    """
    image = np.asarray(image, float)
    if image.ndim != 2:
        raise SeaiceError(f"coastline overlay: the image must be 2-D (scan lines x pixels), got shape {image.shape}")
    fig, ax = _figure(8.0, float(np.clip(6.0 * image.shape[0] / max(image.shape[1], 1) + 1.0, 4.0, 12.0)))
    ax.set_anchor("W")
    finite = image[np.isfinite(image)]
    low, high = np.percentile(finite, [1, 99]) if finite.size else (0.0, 1.0)
    ax.imshow(np.ma.masked_invalid(image), cmap="gray", vmin=low, vmax=high, interpolation="nearest",
              extent=(0.5, image.shape[1] + 0.5, image.shape[0] + 0.5, 0.5))
    pixel, scan = coast_in_image(model, coastline, image.shape)
    ax.plot(pixel, scan, color="yellow", lw=0.7, gid=COASTLINE_GID, label="coastline (GSHHG) through the model")
    if control is not None:
        px, sc = (np.asarray(v, float) for v in control[:2])
        ax.scatter(px, sc, marker="+", s=60, color="C3", lw=1.2, zorder=3, gid=CONTROL_GID,
                   label="control points (measured)")
        for name, x, y in zip(control[2] if len(control) > 2 else (), px, sc, strict=False):
            ax.annotate(str(name), (x, y), textcoords="offset points", xytext=(4, 4), fontsize=7, color="C3")
    ax.set_xlim(0.5, image.shape[1] + 0.5)
    ax.set_ylim(image.shape[0] + 0.5, 0.5)
    ax.set_xlabel("pixel")
    ax.set_ylabel("scan line")
    ax.set_title(title or "Coastline overlay of the rectification", fontsize=9)
    _legend_outside(ax)
    return fig


def plot_coastline_overlay(path: str | os.PathLike, image, model, coastline, control=None, title: str = "") -> Path:
    """Write :func:`coastline_overlay_figure` as the PNG ``path`` (and the requested extra formats beside it)."""
    return _save(coastline_overlay_figure(image, model, coastline, control, title), path)


def sar_geolocation_figure(check) -> Figure:
    """A radar product's geolocation grid recomputed by the zero-Doppler model beside the processor's (a
    :class:`~seaice_jax.workflows.sar.GeolocationCheck`): left, the grid on the NSIDC polar stereographic map
    (EPSG:3413 north, 3976 south) with the coast, coloured by the horizontal difference; right, each point's east
    and north difference, coloured by pixel (range)."""
    from seaice_jax.geometry.projections import nsidc_polar_stereographic

    annotation, grid = check.annotation, check.annotation.grid
    projection = nsidc_polar_stereographic("north" if np.mean(grid.latitude) >= 0 else "south")
    x, y = (np.asarray(v) for v in projection.forward(np.radians(grid.latitude), np.radians(grid.longitude)))
    difference = check.horizontal * 1000.0
    fig, (ax_map, ax_diff) = _figure(11.0, 5.0, 1, 2, gridspec_kw={"width_ratios": [1.25, 1.0]})
    gx, gy = grid.table(x)[2], grid.table(y)[2]
    edge_x = np.concatenate([gx[0], gx[:, -1], gx[-1, ::-1], gx[::-1, 0]])
    edge_y = np.concatenate([gy[0], gy[:, -1], gy[-1, ::-1], gy[::-1, 0]])
    ax_map.plot(edge_x, edge_y, color="0.3", lw=0.8, label="image footprint")
    dots = ax_map.scatter(x, y, c=difference, s=9, cmap="viridis", zorder=3, label="geolocation grid points")
    margin = 0.15 * max(np.ptp(x), np.ptp(y))
    ax_map.set_xlim(x.min() - margin, x.max() + margin)
    ax_map.set_ylim(y.min() - margin, y.max() + margin)
    ax_map.set_aspect("equal")
    crs = crs_name(projection)
    _kilometre_axes(ax_map, crs)
    _decorate(ax_map, projection)
    fig.colorbar(dots, ax=ax_map, label="horizontal difference from ESA (mm)", shrink=0.8)
    legend = ax_map.legend(loc="upper left", bbox_to_anchor=(0.0, -0.12), fontsize=7, frameon=False, ncol=2)
    legend.legend_handles[1].set_color("0.4")  # type: ignore[union-attr]  # the points' colour is the bar's
    ax_map.set_title(f"{annotation.mission} {annotation.mode} {annotation.swath} {annotation.polarisation} "
                     f"{annotation.product_type}, {np.datetime_as_string(annotation.epoch, unit='D')}", fontsize=9)
    points = ax_diff.scatter(check.east * 1000.0, check.north * 1000.0, c=grid.pixel, s=9, cmap="plasma")
    fig.colorbar(points, ax=ax_diff, label="pixel (slant range increases)", shrink=0.8)
    ax_diff.axhline(0.0, color="0.6", lw=0.6)
    ax_diff.axvline(0.0, color="0.6", lw=0.6)
    limit = max(5.0, 1.15 * float(np.max(np.abs(np.concatenate([check.east, check.north])))) * 1000.0)
    ax_diff.set_xlim(-limit, limit)
    ax_diff.set_ylim(-limit, limit)
    ax_diff.set_aspect("equal")
    ax_diff.set_xlabel("east difference (mm)", fontsize=8)
    ax_diff.set_ylabel("north difference (mm)", fontsize=8)
    ax_diff.set_title(f"zero-Doppler model minus ESA: max {difference.max():.1f} mm ({grid.line.size} points)",
                      fontsize=9)
    return fig


def plot_sar_geolocation(path: str | os.PathLike, check) -> Path:
    """Write :func:`sar_geolocation_figure` as the PNG ``path`` (and the requested extra formats beside it)."""
    return _save(sar_geolocation_figure(check), path)


def remapped_sar_figure(image, grid, position_sigma, title: str) -> Figure:
    """A radar image remapped onto a map grid (left, grey, 1-99 % stretch, the coast as a line) beside the
    horizontal position σ of its cells (right, m), both in km of the grid's projection with graticule and scale."""
    aspect = grid.n_rows * float(grid.pixel_height) / (grid.n_columns * float(grid.pixel_width))
    fig, (ax_image, ax_sigma) = _figure(11.0, float(np.clip(3.9 * aspect + 1.3, 3.5, 9.0)), 1, 2)
    left = float(grid.x_first) - 0.5 * float(grid.pixel_width)
    top = float(grid.y_first) + 0.5 * float(grid.pixel_height)
    extent = (left, left + grid.n_columns * float(grid.pixel_width), top - grid.n_rows * float(grid.pixel_height),
              top)
    finite = np.asarray(image)[np.isfinite(image)]
    low, high = np.percentile(finite, [1, 99]) if finite.size else (0.0, 1.0)
    crs = crs_name(grid.projection)
    shown = ax_image.imshow(np.ma.masked_invalid(image), cmap="gray", extent=extent, vmin=low, vmax=high,
                            interpolation="nearest")
    fig.colorbar(shown, ax=ax_image, label="image value (as in the product)", shrink=0.8)
    sigma = ax_sigma.imshow(np.ma.masked_invalid(position_sigma), cmap="viridis", extent=extent,
                            interpolation="nearest")
    fig.colorbar(sigma, ax=ax_sigma, label="horizontal position σ from the orbit (m)", shrink=0.8)
    for ax, name in ((ax_image, title), (ax_sigma, "position σ")):
        _kilometre_axes(ax, crs)
        _decorate(ax, grid.projection, land=False, coast_colour="orange")
        ax.set_title(name, fontsize=9)
    return fig


def plot_remapped_sar(path: str | os.PathLike, *args, **options) -> Path:
    """Write :func:`remapped_sar_figure` as the PNG ``path`` (and the requested extra formats beside it)."""
    return _save(remapped_sar_figure(*args, **options), path)
