"""The figures people look at, in one style. Each ``<name>_figure`` builds a matplotlib figure; ``plot_<name>``
writes it as a PNG atomically and returns its path.

The style every figure shares: constrained layout (titles, vector keys, legends and colour bars get their own room:
nothing overprints), legends and vector keys outside the data axes, colour bars with units, map axes in kilometres
of a named coordinate system (EPSG code or PROJ string), every symbol in a legend, and 95 % error ellipses drawn at
a stated magnification when their true size would be invisible or would hide the vectors. PDF and/or SVG copies are
written beside the PNG when the environment variable ``SEAICE_FIGURE_FORMATS`` lists them (e.g. ``pdf,svg``).
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
from seaice_jax.report.maps import COASTLINE_GID, CONTROL_GID, coast_in_image, decorate_map  # noqa: E402

FIGURE_FORMATS_VARIABLE = "SEAICE_FIGURE_FORMATS"
"""Environment variable listing extra formats (``pdf``, ``svg``, comma-separated) written beside each PNG."""

_EXTRA_FORMATS = ("pdf", "svg")


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


def crs_name(projection) -> str:
    """How a figure names a map's coordinate system: ``EPSG:<code>`` where there is one, else the PROJ string."""
    if projection is None:
        return "map grid"
    code = projection.epsg_code() if hasattr(projection, "epsg_code") else None
    if code is not None:
        return f"EPSG:{code}"
    return projection.proj_string() if hasattr(projection, "proj_string") else type(projection).__name__


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


def _vector_key(ax, arrows, length: float, label: str):
    """The vector key to the right of the axes, below the legend (never over the title)."""
    ax.quiverkey(arrows, 1.04, 0.02, length, label, labelpos="E", coordinates="axes", fontproperties={"size": 7})


def _decorate(ax, projection, **options):
    """The map decorations (:func:`~seaice_jax.report.maps.decorate_map`) where the map's projection is known."""
    if projection is not None:
        decorate_map(ax, projection, **options)


def _kilometre_axes(ax, crs: str):
    """Axes in km of ``crs``; the equal-aspect map box sits at the left of its layout cell (centred, a box shrunk to
    its aspect moves away from where the constrained layout measured its axis labels, which then leave the
    figure)."""
    ax.set_anchor("W")
    kilometres = matplotlib.ticker.FuncFormatter(lambda v, _: f"{v / 1000:.0f}")
    ax.xaxis.set_major_formatter(kilometres)
    ax.yaxis.set_major_formatter(kilometres)
    ax.set_xlabel(f"x (km, {crs})", fontsize=8)
    ax.set_ylabel(f"y (km, {crs})", fontsize=8)


def _nice(value: float) -> float:
    """The 1-2-5 number nearest ``value`` (> 0) on a log scale."""
    exponent = np.floor(np.log10(value))
    mantissa = value / 10**exponent
    return float(min((1.0, 2.0, 5.0, 10.0), key=lambda m: abs(np.log(mantissa / m))) * 10**exponent)


def ellipse_magnification(semi_major, arrow_length) -> float:
    """The factor 95 % ellipses are drawn at beside vectors whose reference arrow is ``arrow_length`` long (both in
    map units): 1 when the median semi-major axis is between a tenth and the whole of the arrow (visible, not hiding
    the vectors), else the 1-2-5 factor that brings it to about a third of the arrow."""
    semi_major = np.asarray(semi_major, float)
    semi_major = semi_major[np.isfinite(semi_major) & (semi_major > 0)]
    if not semi_major.size:
        return 1.0
    typical = float(np.median(semi_major))
    if 0.1 * arrow_length <= typical <= arrow_length:
        return 1.0
    return _nice(arrow_length / 3.0 / typical)


def _magnification_text(factor: float) -> str:
    return "true size" if factor == 1.0 else f"drawn ×{factor:g} true size"


def _colours(count: int):
    """``count`` distinct colours: the 10- or 20-colour qualitative maps, then samples of a continuous one."""
    if count <= 10:
        return [plt.get_cmap("tab10")(k) for k in range(count)]
    if count <= 20:
        return [plt.get_cmap("tab20")(k) for k in range(count)]
    return [plt.get_cmap("viridis")(v) for v in np.linspace(0.0, 0.95, count)]


def _draw_panel(ax, panel: MapPanel):
    xs = np.concatenate([np.ravel(layer.x) for layer in panel.layers])
    ys = np.concatenate([np.ravel(layer.y) for layer in panel.layers])
    margin = 0.1 * max(np.nanmax(xs) - np.nanmin(xs), np.nanmax(ys) - np.nanmin(ys))
    x_limits = (np.nanmin(xs) - margin, np.nanmax(xs) + margin)
    y_limits = (np.nanmin(ys) - margin, np.nanmax(ys) + margin)
    for colour, layer in zip(_colours(len(panel.layers)), panel.layers, strict=True):
        if layer.kind == "grid":
            ax.plot(layer.x, layer.y, color=colour, lw=0.5)
            ax.plot(layer.x.T, layer.y.T, color=colour, lw=0.5)
            ax.plot([], [], color=colour, label=layer.label)
        else:
            ax.scatter(layer.x, layer.y, s=14, color=colour, label=layer.label, zorder=3)
            for name, x, y in zip(layer.names, layer.x, layer.y, strict=False):
                ax.annotate(name, (x, y), textcoords="offset points", xytext=(4, 4), fontsize=7)
    ax.set_xlim(*x_limits)
    ax.set_ylim(*y_limits)
    ax.set_aspect("equal")
    decorate_map(ax, panel.projection)
    _kilometre_axes(ax, crs_name(panel.projection))
    ax.set_title(panel.title, fontsize=9)
    _legend_outside(ax)


def maps_figure(panels: Sequence[MapPanel], title: str) -> Figure:
    """Maps side by side, each with the coastline and land, a labelled graticule and a scale bar
    (:func:`~seaice_jax.report.maps.decorate_map`), axes in projected kilometres of the panel's projection."""
    fig, axes = _figure(6.0 * len(panels) + 1.5, 5.5, 1, len(panels), squeeze=False)
    for ax, panel in zip(axes[0], panels, strict=True):
        _draw_panel(ax, panel)
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

    The arrow scale is in the vector key; ``background``: optional ``(n, 2)`` positions drawn as grey dots
    (``background_label`` in the legend); ``covariances``: optional ``(n, 2, 2)`` (m²) of the vectors, drawn as
    95 % error ellipses at the arrow tips at the arrows' scale times :func:`ellipse_magnification` (stated in the
    legend); ``projection``: the positions' map projection, named on the axes and used to draw the coastline
    and land, a labelled graticule and a scale bar (:func:`~seaice_jax.report.maps.decorate_map`).
    """
    from matplotlib.patches import Ellipse

    positions, vectors = np.asarray(positions, float), np.asarray(vectors, float)
    fig, ax = _figure(8.5, 6.0)
    if background is not None:
        ax.scatter(*np.asarray(background).T, s=3, color="0.7", zorder=0, label=background_label)
    length = float(np.nanpercentile(np.hypot(*vectors.T), 90)) if vectors.size else 1.0
    length = max(length, 1e-9)
    extent = np.concatenate([positions, np.asarray(background, float).reshape(-1, 2)]) if background is not None \
        else positions
    span = float(np.nanmax(np.ptp(extent, axis=0))) if extent.size else 1.0
    arrow = max(0.06 * span, 1.0)  # map metres of the reference (90th percentile) arrow
    scale = length / arrow  # metres of vector per metre of map
    arrows = ax.quiver(positions[:, 0], positions[:, 1], vectors[:, 0], vectors[:, 1], angles="xy",
                       scale_units="xy", scale=scale, width=0.003, color="C0", label="vector")
    _vector_key(ax, arrows, length, f"{length / 1000:.3g} km")
    if covariances is not None:
        major, minor, angle = error_ellipses(covariances)
        factor = ellipse_magnification(np.asarray(major) / scale, arrow)
        tips = positions + vectors / scale
        for k in np.nonzero(np.isfinite(major) & np.isfinite(tips).all(axis=1))[0]:
            ax.add_patch(Ellipse(tips[k], 2 * factor * major[k] / scale, 2 * factor * minor[k] / scale,
                                 angle=np.degrees(angle[k]), fill=False, color="C3", lw=0.6))
        ax.plot([], [], color="C3", lw=0.6, label=f"95 % error ellipse\n({_magnification_text(factor)})")
    ax.set_aspect("equal")
    _decorate(ax, projection)
    _kilometre_axes(ax, crs_name(projection))
    ax.set_title(f"{title}\n{label}", fontsize=9)
    _legend_outside(ax)
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
    arrow is the count of velocities averaged; ``projection``: the map's, for the coastline, graticule and scale bar
    (:func:`~seaice_jax.report.maps.decorate_map`)."""
    from matplotlib.patches import Rectangle

    fig, ax = _figure(8.5, 6.0)
    if background is not None:
        ax.scatter(*np.asarray(background).T, s=2, color="0.75", zorder=0, label="floe positions")
    speed = np.hypot(boxes.u, boxes.v)
    reference = float(np.nanmax(speed)) if speed.size else 0.1
    columns = np.unique(np.asarray(boxes.x, float))
    spacing = float(np.nanmin(np.diff(columns))) if columns.size > 1 else 125e3
    scale = max(reference, 1e-9) / (0.4 * spacing)  # m/s per metre of map
    x, y = np.asarray(boxes.x, float), np.asarray(boxes.y, float)
    arrows = ax.quiver(x, y, boxes.u, boxes.v, angles="xy", scale_units="xy", scale=scale, width=0.004, color="C0",
                       label="box-average velocity")
    for k in range(x.size):
        tip = (x[k] + boxes.u[k] / scale, y[k] + boxes.v[k] / scale)
        w, h = 2 * boxes.sigma_u[k] / scale, 2 * boxes.sigma_v[k] / scale
        ax.add_patch(Rectangle((tip[0] - w / 2, tip[1] - h / 2), w, h, fill=False, color="C3", lw=0.8))
        ax.annotate(str(boxes.count[k]), (x[k], y[k]), fontsize=6, color="0.3", xytext=(2, -8),
                    textcoords="offset points")
    _vector_key(ax, arrows, reference, f"{reference * 86.4:.3g} km/day")
    ax.plot([], [], color="C3", lw=0.8, label="±1 standard deviation")
    ax.plot([], [], " ", label="numbers: velocities per box")
    ax.set_aspect("equal")
    _decorate(ax, projection)
    _kilometre_axes(ax, crs_name(projection))
    ax.set_title(title, fontsize=9)
    _legend_outside(ax)
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


def remapped_figure(images, titles, extent_km, vectors=None, projection=None,
                  units: str = "image value (as digitized)") -> Figure:
    """Remapped images side by side (NaN white) on one grey scale with its colour bar (``units``), axes in km of
    ``projection`` (given: with the coastline as a line over the image, a labelled graticule and a scale bar,
    :func:`~seaice_jax.report.maps.decorate_map`); ``vectors``: optional ``(x, y, dx, dy)`` km on the first."""
    count = len(images)
    columns = min(count, 4)
    rows = -(-count // columns)
    fig, axes = _figure(3.0 * columns + 1.2, 3.0 * rows + 0.6, rows, columns, squeeze=False)
    finite = [np.asarray(image, float)[np.isfinite(image)] for image in images]
    values = np.concatenate(finite) if any(v.size for v in finite) else np.zeros(1)
    low, high = np.percentile(values, [1, 99])
    crs = crs_name(projection)
    for ax in axes.ravel()[count:]:
        ax.remove()
    shown = []
    for k, ax in enumerate(axes.ravel()[:count]):
        shown.append(ax.imshow(np.ma.masked_invalid(images[k]), cmap="gray", extent=extent_km, origin="upper",
                                vmin=low, vmax=high))
        ax.set_title(titles[k], fontsize=8)
        ax.tick_params(labelsize=6)
        if k == 0 and vectors is not None:
            ax.quiver(*vectors, angles="xy", scale_units="xy", scale=0.2, color="C1", width=0.006)
        ax.set_xlabel("x (km)", fontsize=7)
        ax.set_ylabel("y (km)", fontsize=7)
        _decorate(ax, projection, unit=1000.0, land=False, coast_colour="orange", fontsize=5.0)
    fig.colorbar(shown[0], ax=list(axes.ravel()[:count]), label=units, shrink=0.8)
    fig.suptitle(f"Remapped images on one grid ({crs}); white: no data", fontsize=9)
    return fig


def plot_remapped(path: str | os.PathLike, *args, **options) -> Path:
    """Write :func:`remapped_figure` as the PNG ``path`` (and the requested extra formats beside it)."""
    return _save(remapped_figure(*args, **options), path)


def trajectories_figure(floe, x, y, title: str, limit: int = 400, projection=None) -> Figure:
    """Floe trajectories (source 001, Figure 4-3): one line per floe through its fixes (m, in time order of the
    rows), a dot at its first fix; at most ``limit`` floes drawn; ``projection``: the map's, for the coastline,
    graticule and scale bar (:func:`~seaice_jax.report.maps.decorate_map`)."""
    floe, x, y = np.asarray(floe), np.asarray(x, float), np.asarray(y, float)
    fig, ax = _figure(8.5, 6.0)
    for f in list(dict.fromkeys(floe.tolist()))[:limit]:
        at = floe == f
        ax.plot(x[at], y[at], lw=0.7, color="C0")
        ax.plot(x[at][:1], y[at][:1], ".", ms=3, color="C3")
    ax.plot([], [], lw=0.7, color="C0", label="trajectory")
    ax.plot([], [], ".", ms=3, color="C3", label="first fix")
    ax.set_aspect("equal")
    _decorate(ax, projection)
    _kilometre_axes(ax, crs_name(projection))
    ax.set_title(title, fontsize=9)
    _legend_outside(ax)
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
    ax_map.legend(loc="upper left", bbox_to_anchor=(0.0, -0.12), fontsize=7, frameon=False, ncol=2)
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
    fig, (ax_image, ax_sigma) = _figure(11.0, 5.2, 1, 2)
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
