"""The figures people look at. Every function writes a PNG atomically and returns its path."""

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker  # noqa: E402
import numpy as np  # noqa: E402

from seaice_jax.drift.kinematics import error_ellipses  # noqa: E402
from seaice_jax.files import atomic_path  # noqa: E402


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


def _save(fig, path) -> Path:
    """Lay out, write as PNG atomically, close."""
    fig.tight_layout()
    with atomic_path(path) as temporary:
        fig.savefig(temporary, format="png", dpi=110)
    plt.close(fig)
    return Path(path)


def _graticule(ax, projection, x_limits, y_limits):
    """Meridians and parallels (1°/5° apart on small maps, 5°/20° on large ones) on projected axes."""
    span_km = max(np.ptp(x_limits), np.ptp(y_limits)) / 1000.0
    lat_step, lon_step = (1.0, 5.0) if span_km < 1500 else (5.0, 20.0)
    latitude_grid = np.radians(np.linspace(40.0, 89.9, 400))
    for lon in np.arange(-180.0, 180.0, lon_step):
        x, y = projection.forward(latitude_grid, np.full_like(latitude_grid, np.radians(lon)))
        ax.plot(np.asarray(x), np.asarray(y), color="0.85", lw=0.6, zorder=0)
    longitude_grid = np.radians(np.linspace(-180.0, 180.0, 1441))
    for lat in np.arange(40.0, 90.0, lat_step):
        x, y = projection.forward(np.full_like(longitude_grid, np.radians(lat)), longitude_grid)
        ax.plot(np.asarray(x), np.asarray(y), color="0.85", lw=0.6, zorder=0)


def _draw_panel(ax, panel: MapPanel):
    xs = np.concatenate([np.ravel(layer.x) for layer in panel.layers])
    ys = np.concatenate([np.ravel(layer.y) for layer in panel.layers])
    margin = 0.1 * max(np.nanmax(xs) - np.nanmin(xs), np.nanmax(ys) - np.nanmin(ys))
    x_limits = (np.nanmin(xs) - margin, np.nanmax(xs) + margin)
    y_limits = (np.nanmin(ys) - margin, np.nanmax(ys) + margin)
    _graticule(ax, panel.projection, x_limits, y_limits)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for colour, layer in zip(colours * 3, panel.layers, strict=False):
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
    kilometres = matplotlib.ticker.FuncFormatter(lambda v, _: f"{v / 1000:.0f}")
    ax.xaxis.set_major_formatter(kilometres)
    ax.yaxis.set_major_formatter(kilometres)
    ax.set_xlabel("x (km)")
    ax.set_ylabel("y (km)")
    ax.set_title(panel.title, fontsize=9)
    ax.legend(loc="best", fontsize=7)


def plot_maps(path: str | os.PathLike, panels: Sequence[MapPanel], title: str) -> Path:
    """Maps side by side, each with a graticule, axes in projected kilometres; written atomically as PNG."""
    fig, axes = plt.subplots(1, len(panels), figsize=(6.5 * len(panels), 6.5), squeeze=False)
    for ax, panel in zip(axes[0], panels, strict=True):
        _draw_panel(ax, panel)
    fig.suptitle(title, fontsize=11)
    return _save(fig, path)


def plot_image_field(path: str | os.PathLike, pixel, scan, values, title: str, label: str, points=None) -> Path:
    """A field over an image's pixel/scan grid (e.g. position σ) as a filled contour map, scan lines downward.

    Args:
        pixel, scan, values: ``(n_scan, n_pixel)`` grids.
        points: optional ``(pixel, scan, names)`` to mark (control points).
    """
    fig, ax = plt.subplots(figsize=(6.5, 5.5))
    filled = ax.contourf(pixel, scan, values, levels=15, cmap="viridis")
    fig.colorbar(filled, ax=ax, label=label)
    if points is not None:
        px, sc, names = points
        ax.scatter(px, sc, color="white", edgecolor="black", s=30, zorder=3, label="control points")
        for name, x, y in zip(names, px, sc, strict=False):
            ax.annotate(name, (x, y), textcoords="offset points", xytext=(4, 4), fontsize=7, color="white")
        ax.legend(loc="lower right", fontsize=7)
    ax.set_xlabel("pixel")
    ax.set_ylabel("scan line")
    ax.invert_yaxis()
    ax.set_title(title, fontsize=9)
    return _save(fig, path)


def plot_vectors(path: str | os.PathLike, positions, vectors, title: str, label: str, background=None,
                 covariances=None) -> Path:
    """Vectors (e.g. drift, error or discrepancy vectors, metres) at map positions (metres), as arrows.

    The arrow scale is printed in the key; ``background``: optional ``(n, 2)`` positions drawn as dots;
    ``covariances``: optional ``(n, 2, 2)`` (m²) of the vectors, drawn as 95 % error ellipses at the arrow tips, at
    the arrows' scale.
    """
    from matplotlib.patches import Ellipse

    positions, vectors = np.asarray(positions, float), np.asarray(vectors, float)
    fig, ax = plt.subplots(figsize=(7.5, 6.5))
    if background is not None:
        ax.scatter(*np.asarray(background).T / 1000.0, s=3, color="0.7", zorder=0)
    length = float(np.nanpercentile(np.hypot(*vectors.T), 90)) if vectors.size else 1.0
    scale = max(length, 1e-9) / 8.0  # metres of vector per km of map
    arrows = ax.quiver(positions[:, 0] / 1000.0, positions[:, 1] / 1000.0, vectors[:, 0], vectors[:, 1],
                       angles="xy", scale_units="xy", scale=scale, width=0.003, color="C0")
    ax.quiverkey(arrows, 0.85, 1.02, length, f"{length / 1000:.2f} km", labelpos="E", coordinates="axes")
    if covariances is not None:
        major, minor, angle = error_ellipses(covariances)
        tips = positions / 1000.0 + vectors / scale
        for k in np.nonzero(np.isfinite(major) & np.isfinite(tips).all(axis=1))[0]:
            ax.add_patch(Ellipse(tips[k], 2 * major[k] / scale, 2 * minor[k] / scale, angle=np.degrees(angle[k]),
                                 fill=False, color="C3", lw=0.6))
        ax.plot([], [], color="C3", lw=0.6, label="95 % error ellipse")
        ax.legend(loc="lower right", fontsize=8)
    ax.set_aspect("equal")
    ax.set_xlabel("x (km)")
    ax.set_ylabel("y (km)")
    ax.set_title(f"{title}\n{label}", fontsize=9)
    return _save(fig, path)


def plot_navigation_errors(path: str | os.PathLike, curves, title: str) -> Path:
    """Estimated navigation-error curves with their ±1σ bands.

    Args:
        curves: sequence of ``(label, times (n,) s, errors (n, 2) m north/east, sigma (n, 2) m)``.
    """
    fig, axes = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for k, (label, times, errors, sigma) in enumerate(curves):
        minutes = np.asarray(times) / 60.0
        for component, ax in enumerate(axes):
            ax.plot(minutes, errors[:, component] / 1000.0, color=f"C{k % 10}", lw=1, label=label)
            ax.fill_between(minutes, (errors[:, component] - sigma[:, component]) / 1000.0,
                            (errors[:, component] + sigma[:, component]) / 1000.0, color=f"C{k % 10}", alpha=0.2)
    axes[0].set_ylabel("north error (km)")
    axes[1].set_ylabel("east error (km)")
    axes[1].set_xlabel("time (min)")
    axes[0].set_title(title, fontsize=9)
    if len(curves) <= 12:
        axes[0].legend(fontsize=7, ncol=4)
    for ax in axes:
        ax.grid(alpha=0.3)
    return _save(fig, path)


def plot_tie_discrepancies(path: str | os.PathLike, before, after) -> Path:
    """Tie-point discrepancies (across, along track; metres) before and after the internal adjustment (source 000,
    Fig. 4)."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.8))
    for ax, values, title in zip(axes, (before, after), ("before internal adjustment", "after"), strict=True):
        values = np.asarray(values, float) / 1000.0
        ax.scatter(values[:, 0], values[:, 1], s=8)
        rms = np.sqrt(np.mean(values**2, axis=0)) if values.size else (np.nan, np.nan)
        ax.set_title(f"{title}: rms ±{rms[0]:.2f} km across, ±{rms[1]:.2f} km along", fontsize=9)
        ax.set_xlabel("across-track discrepancy (km)")
        ax.set_ylabel("along-track discrepancy (km)")
        ax.axhline(0, color="0.8", lw=0.5)
        ax.axvline(0, color="0.8", lw=0.5)
    return _save(fig, path)


def plot_box_averages(path: str | os.PathLike, boxes, title: str, background=None) -> Path:
    """Box-averaged velocity vectors with their standard-deviation rectangles at the arrow tips (source 001,
    Figure 4-7): ``boxes`` a :class:`~seaice_jax.drift.kinematics.BoxAverages` (m, m/s)."""
    from matplotlib.patches import Rectangle

    fig, ax = plt.subplots(figsize=(7.5, 6.5))
    if background is not None:
        ax.scatter(*np.asarray(background).T / 1000.0, s=2, color="0.75", zorder=0)
    speed = np.hypot(boxes.u, boxes.v)
    reference = float(np.nanmax(speed)) if speed.size else 0.1
    columns = np.unique(np.asarray(boxes.x, float))
    spacing_km = float(np.nanmin(np.diff(columns))) / 1000.0 if columns.size > 1 else 125.0
    scale = max(reference, 1e-9) / (0.4 * spacing_km)  # m/s per km of map
    x, y = boxes.x / 1000.0, boxes.y / 1000.0
    arrows = ax.quiver(x, y, boxes.u, boxes.v, angles="xy", scale_units="xy", scale=scale, width=0.004, color="C0")
    for k in range(x.size):
        tip = (x[k] + boxes.u[k] / scale, y[k] + boxes.v[k] / scale)
        w, h = 2 * boxes.sigma_u[k] / scale, 2 * boxes.sigma_v[k] / scale
        ax.add_patch(Rectangle((tip[0] - w / 2, tip[1] - h / 2), w, h, fill=False, color="C3", lw=0.8))
        ax.annotate(str(boxes.count[k]), (x[k], y[k]), fontsize=6, color="0.3", xytext=(2, -8),
                    textcoords="offset points")
    ax.quiverkey(arrows, 0.82, 1.02, reference, f"{reference * 86.4:.1f} km/day", labelpos="E", coordinates="axes")
    ax.plot([], [], color="C3", lw=0.8, label="±1 standard deviation")
    ax.legend(loc="lower right", fontsize=8)
    ax.set_aspect("equal")
    ax.set_xlabel("grid x (km)")
    ax.set_ylabel("grid y (km)")
    ax.set_title(title, fontsize=9)
    return _save(fig, path)


def plot_velocity_series(path: str | os.PathLike, series, title: str, epoch_label: str) -> Path:
    """Box-averaged velocity per day (source 001, Figure 4-5): u and v (km/day) against days, one line per box."""
    fig, axes = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True)
    for key, entry in series.items():
        days = entry["time"] / 86400.0
        for ax, component in zip(axes, ("u", "v"), strict=True):
            ax.errorbar(days, entry[component] * 86.4, yerr=np.nan_to_num(entry[f"sigma_{component}"]) * 86.4,
                        marker="o", ms=3, capsize=2, label=f"box {key}")
    for ax, component in zip(axes, ("grid x", "grid y"), strict=True):
        ax.axhline(0, color="0.6", lw=0.6)
        ax.set_ylabel(f"{component} (km/day)")
    axes[1].set_xlabel(f"days since {epoch_label}")
    axes[0].legend(fontsize=7, ncol=4)
    axes[0].set_title(title, fontsize=9)
    return _save(fig, path)


def plot_remapped(path: str | os.PathLike, images, titles, extent_km, vectors=None) -> Path:
    """Remapped images side by side (NaN white); ``vectors``: optional ``(x, y, dx, dy)`` km on the first."""
    count = len(images)
    fig, axes = plt.subplots(1, count, figsize=(3.2 * count, 3.4), squeeze=False)
    for k, ax in enumerate(axes[0]):
        ax.imshow(np.ma.masked_invalid(images[k]), cmap="gray", extent=extent_km, origin="upper")
        ax.set_title(titles[k], fontsize=8)
        ax.set_xlabel("x (km)", fontsize=7)
        ax.tick_params(labelsize=6)
        if k == 0 and vectors is not None:
            ax.quiver(*vectors, angles="xy", scale_units="xy", scale=0.2, color="C1", width=0.006)
    return _save(fig, path)


def plot_trajectories(path: str | os.PathLike, floe, x, y, title: str, limit: int = 400) -> Path:
    """Floe trajectories (source 001, Figure 4-3): one line per floe through its fixes (m, in time order of the
    rows), a dot at its first fix; at most ``limit`` floes drawn."""
    floe, x, y = np.asarray(floe), np.asarray(x, float), np.asarray(y, float)
    fig, ax = plt.subplots(figsize=(7.5, 6.5))
    for f in list(dict.fromkeys(floe.tolist()))[:limit]:
        at = floe == f
        ax.plot(x[at] / 1000.0, y[at] / 1000.0, lw=0.7, color="C0")
        ax.plot(x[at][:1] / 1000.0, y[at][:1] / 1000.0, ".", ms=3, color="C3")
    ax.set_aspect("equal")
    ax.set_xlabel("grid x (km)")
    ax.set_ylabel("grid y (km)")
    ax.set_title(title, fontsize=9)
    return _save(fig, path)
