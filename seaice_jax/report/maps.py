"""Map decorations in the project's own projections, drawn with matplotlib: the coastline and land (GSHHG, from
:mod:`seaice_jax.io.coastline`), a latitude/longitude graticule labelled at the frame, and a scale bar.

A map's axes are a projection's plane coordinates (metres, or kilometres with ``unit=1000``), so every decoration is
a set of lines in those coordinates: coast, meridians and parallels are projected with the map's own ``forward`` /
``inverse`` (:mod:`seaice_jax.geometry.projections`, tested against PROJ) and matplotlib clips them to the frame.
Cartopy is not used: it is not a dependency, it downloads Natural Earth at first use (the project works offline),
and its coordinate systems have neither the project's :class:`~seaice_jax.geometry.projections.TangentPlane` (on the
project's sphere) nor source 001's image grid, so each figure would need a second definition of its projection that
could disagree with the first.

Artists carry ``gid`` s (:data:`COASTLINE_GID`, :data:`LAND_GID`, :data:`GRATICULE_GID`,
:data:`GRATICULE_LABEL_GID`, :data:`SCALE_BAR_GID`) so tests and users find them on a figure; they stay out of the
legends (map furniture, and the legends beside fixed-aspect maps must stay narrow for the layout to fit).
"""

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure
from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

from seaice_jax.geometry.projections import MapGrid
from seaice_jax.io.coastline import Coastline, bounds_of_grid, bucketed, coastline_of_grid

COASTLINE_GID = "coastline"
LAND_GID = "land"
GRATICULE_GID = "graticule"
GRATICULE_LABEL_GID = "graticule label"
SCALE_BAR_GID = "scale bar"
CONTROL_GID = "control points"

LAND_COLOUR = "#e6dcc6"
COAST_COLOUR = "#5a4a32"
GRATICULE_COLOUR = "0.6"

_STEPS = (0.05, 0.1, 0.2, 0.25, 0.5, 1.0, 2.0, 5.0, 10.0, 15.0, 20.0, 30.0, 45.0, 60.0, 90.0)
"""Graticule spacings (degrees) to choose from."""


def frame_grid(projection, x_limits, y_limits, unit: float = 1.0, samples: int = 33) -> MapGrid:
    """The map frame ``x_limits`` x ``y_limits`` (axes units; ``unit`` metres each) as a ``samples`` x ``samples``
    :class:`~seaice_jax.geometry.projections.MapGrid` whose outer pixel centres lie on the frame."""
    (x0, x1), (y0, y1) = sorted(x_limits), sorted(y_limits)
    return MapGrid(projection, x0 * unit, y1 * unit, (x1 - x0) * unit / (samples - 1),
                   (y1 - y0) * unit / (samples - 1), samples, samples)


def frame_coastline(ax, projection, unit: float = 1.0) -> Coastline:
    """The coastline covering the axes' current frame (:func:`~seaice_jax.io.coastline.coastline_of_grid`)."""
    return coastline_of_grid(frame_grid(projection, ax.get_xlim(), ax.get_ylim(), unit))


def _frame(ax, unit: float) -> tuple[float, float, float, float]:
    """``(x0, y0, x1, y1)`` of the axes' frame in metres."""
    (x0, x1), (y0, y1) = sorted(ax.get_xlim()), sorted(ax.get_ylim())
    return x0 * unit, y0 * unit, x1 * unit, y1 * unit


def _nan_joined(lines) -> tuple[np.ndarray, np.ndarray]:
    """``(x, y)`` of the ``(n, 2)`` lines joined with NaN between them (one artist draws them all)."""
    if not lines:
        return np.zeros(0), np.zeros(0)
    joined = np.concatenate([np.vstack([line, [np.nan, np.nan]]) for line in lines])
    return joined[:, 0], joined[:, 1]


def draw_coastline(ax, coast: Coastline, projection, unit: float = 1.0, land: bool = True,
                   colour: str = COAST_COLOUR, tolerance: float | None = None):
    """The coast as one line (``gid`` :data:`COASTLINE_GID`) and, with ``land``, the land filled beneath the data
    (``gid`` :data:`LAND_GID`), on axes in ``projection``'s plane (``unit`` metres per axes unit), within the axes'
    current frame (call it after the limits are set; it does not change them).

    ``tolerance``: metres the lines may be simplified by; default 1/1500 of the frame's larger side (under a pixel
    of a 150 dpi figure), which keeps a whole-Arctic map fast.
    """
    import shapely

    x0, y0, x1, y1 = _frame(ax, unit)
    tolerance = max(x1 - x0, y1 - y0) / 1500.0 if tolerance is None else tolerance
    margin = 0.02 * max(x1 - x0, y1 - y0)
    box = (x0 - margin, y0 - margin, x1 + margin, y1 + margin)
    lines = coast.projected(projection, tolerance)
    if lines:
        clipped = shapely.get_parts(shapely.clip_by_rect(shapely.linestrings(np.concatenate(lines), indices=np.repeat(
            np.arange(len(lines)), [len(line) for line in lines])), *box))
        coordinates, index = shapely.get_coordinates(clipped, return_index=True)
        lines = np.split(coordinates, np.flatnonzero(np.diff(index)) + 1) if len(coordinates) else []
    x, y = _nan_joined(lines)
    ax.plot(x / unit, y / unit, color=colour, lw=0.6, zorder=2.2, gid=COASTLINE_GID, label="_coastline (GSHHG)",
            scalex=False, scaley=False)
    if land:
        polygons = shapely.get_parts(shapely.clip_by_rect(coast.projected_polygons(projection, tolerance), *box))
        rings = [np.asarray(polygon.exterior.coords) / unit for polygon in polygons
                 if polygon.geom_type == "Polygon" and not polygon.is_empty]
        ax.add_collection(PolyCollection(rings, facecolors=LAND_COLOUR, edgecolors="none", zorder=0.2, gid=LAND_GID,
                                         label="_land"), autolim=False)


def _step(span: float, lines: int = 5) -> float:
    """The graticule spacing (degrees) giving about ``lines`` lines across ``span`` degrees."""
    return min(_STEPS, key=lambda step: abs(np.log(max(span, 1e-9) / step / lines)))


def _longitude_text(longitude: float) -> str:
    longitude = (longitude + 180.0) % 360.0 - 180.0
    if np.isclose(abs(longitude), 180.0) or np.isclose(longitude, 0.0):
        return f"{abs(longitude):g}°"
    return f"{abs(longitude):g}°{'E' if longitude > 0 else 'W'}"


def _latitude_text(latitude: float) -> str:
    return "0°" if np.isclose(latitude, 0.0) else f"{abs(latitude):g}°{'N' if latitude > 0 else 'S'}"


def _crossings(x, y, frame) -> dict[str, list[float]]:
    """Where the polyline ``x``, ``y`` crosses each edge of ``frame`` ``(x0, y0, x1, y1)``, as fractions along that
    edge (left to right, bottom to top)."""
    x0, y0, x1, y1 = frame
    found: dict[str, list[float]] = {}
    for edge, along, across, level, low, high in (("top", x, y, y1, x0, x1), ("bottom", x, y, y0, x0, x1),
                                                  ("left", y, x, x0, y0, y1), ("right", y, x, x1, y0, y1)):
        side = across - level
        with np.errstate(invalid="ignore"):
            change = np.flatnonzero(np.sign(side[:-1]) * np.sign(side[1:]) < 0)
        t = side[change] / (side[change] - side[change + 1])
        where = along[change] + t * (along[change + 1] - along[change])
        found[edge] = [float((w - low) / (high - low)) for w in where if low <= w <= high]
    return found


def draw_graticule(ax, projection, unit: float = 1.0, fontsize: float = 6.0):
    """Meridians and parallels (``gid`` :data:`GRATICULE_GID`) at a 1-2-5 spacing that gives a few lines across the
    frame, each labelled once just inside the frame where it crosses it (``gid`` :data:`GRATICULE_LABEL_GID`):
    meridians on the top edge (else the bottom), parallels on the left (else the right); labels that would crowd
    one another or a corner are left out. Call it after the limits are set; it does not change them."""
    frame = _frame(ax, unit)
    grid = frame_grid(projection, ax.get_xlim(), ax.get_ylim(), unit)
    latitude, longitude = (np.degrees(a) for a in bucketed(projection.inverse, *grid.xy()))
    finite = np.isfinite(latitude) & np.isfinite(longitude)
    latitude, longitude = latitude[finite], longitude[finite]
    south, north = float(latitude.min()), float(latitude.max())
    west, _, east, _ = bounds_of_grid(grid, margin=0.0)
    span = (east - west) % 360.0 or 360.0
    latitude_step, longitude_step = _step(north - south), _step(span)
    parallels = np.arange(np.ceil(south / latitude_step), np.floor(north / latitude_step) + 1) * latitude_step
    meridians = np.arange(np.ceil(west / longitude_step), np.floor((west + span) / longitude_step) + 1) * \
        longitude_step
    meridians = meridians[meridians < west + 360.0 - 1e-9] if span >= 360.0 else meridians
    curves = []
    pad = max(latitude_step, 1.0)
    along_meridian = np.radians(np.linspace(max(south - pad, -90.0), min(north + pad, 90.0), 400))
    for meridian in meridians:
        x, y = bucketed(projection.forward, along_meridian, np.full_like(along_meridian, np.radians(meridian)))
        curves.append(("meridian", _longitude_text(meridian), x, y))
    along_parallel = np.radians(np.linspace(west - 1.0, west + span + 1.0, 721))
    for parallel in parallels:
        x, y = bucketed(projection.forward, np.full_like(along_parallel, np.radians(parallel)), along_parallel)
        curves.append(("parallel", _latitude_text(parallel), x, y))
    lines = [np.column_stack([x, y]) / unit for _, _, x, y in curves]
    gx, gy = _nan_joined(lines)
    ax.plot(gx, gy, color=GRATICULE_COLOUR, lw=0.5, ls=(0, (4, 3)), zorder=1.5, gid=GRATICULE_GID,
            label="_graticule", scalex=False, scaley=False)
    _label_graticule(ax, curves, frame, fontsize)


def _label_graticule(ax, curves, frame, fontsize: float):
    """Place one label per graticule line inside the frame where it crosses it, keeping labels apart."""
    width_inches, height_inches = ax.get_position().width * ax.figure.get_figwidth(), \
        ax.get_position().height * ax.figure.get_figheight()
    character = 0.6 * fontsize / 72.0  # inches per character, roughly
    line = 1.6 * fontsize / 72.0
    placed: dict[str, list[tuple[float, float]]] = {"top": [], "bottom": [], "left": [], "right": []}
    for kind, text, x, y in curves:
        crossings = _crossings(x, y, frame)
        edges = ("top", "bottom") if kind == "meridian" else ("left", "right")
        for edge in edges:
            half = (0.5 * len(text) * character + 0.05) / width_inches if edge in ("top", "bottom") else \
                (0.5 * line + 0.02) / height_inches
            corner = (len(text) * character + 0.1) / width_inches if edge in ("top", "bottom") else \
                (1.5 * line) / height_inches
            low, high = corner, 1.0 - corner
            if edge == "bottom":  # the scale bar's corner, lower right
                high = min(high, 0.7 - corner)  # the bar spans at most a fifth of the frame, plus its padding
            elif edge == "right":
                low = max(low, 0.5 / height_inches)
            spots = [s for s in crossings[edge] if low <= s <= high
                     and all(abs(s - other) > half + other_half for other, other_half in placed[edge])]
            if spots:
                spot = spots[0]
                placed[edge].append((spot, half))
                position = {"top": (spot, 0.99), "bottom": (spot, 0.01), "left": (0.01, spot),
                            "right": (0.99, spot)}[edge]
                alignment = {"top": ("center", "top"), "bottom": ("center", "bottom"), "left": ("left", "center"),
                             "right": ("right", "center")}[edge]
                ax.text(*position, text, transform=ax.transAxes, ha=alignment[0], va=alignment[1], fontsize=fontsize,
                        color="0.25", gid=GRATICULE_LABEL_GID, zorder=4, clip_on=True,
                        bbox={"boxstyle": "square,pad=0.1", "facecolor": "white", "edgecolor": "none", "alpha": 0.7})
                break


def _nice(value: float) -> float:
    """The largest 1-2-5 number not above ``value`` (> 0)."""
    exponent = np.floor(np.log10(value))
    return float(max(m for m in (1.0, 2.0, 5.0, 10.0) if m * 10**exponent <= value * (1 + 1e-12)) * 10**exponent)


def map_scale(projection, x: float, y: float) -> float:
    """The projection's scale at map point ``(x, y)`` metres along x: map metres per metre on the WGS84 ellipsoid
    (pyproj's geodesic), from a 1 km step either side."""
    import pyproj

    step = 1000.0
    latitude, longitude = (np.degrees(a) for a in bucketed(projection.inverse, np.array([x - step, x + step]),
                                                           np.array([y, y])))
    _, _, ground = pyproj.Geod(ellps="WGS84").inv(longitude[0], latitude[0], longitude[1], latitude[1])
    return 2 * step / ground


def draw_scale_bar(ax, projection, unit: float = 1.0, fontsize: float = 6.0):
    """A scale bar in the lower right corner (``gid`` :data:`SCALE_BAR_GID`): a 1-2-5 length in km near a fifth of
    the frame's width, drawn at the projection's scale at the frame's centre (:func:`map_scale`; say so in the
    label where the scale varies over the frame by more than 1 %)."""
    x0, y0, x1, y1 = _frame(ax, unit)
    centre = map_scale(projection, 0.5 * (x0 + x1), 0.5 * (y0 + y1))
    corners = [map_scale(projection, x, y) for x in (x0, x1) for y in (y0, y1)]
    ground = _nice(0.2 * (x1 - x0) / centre)
    label = f"{ground / 1000:g} km" + (" (at centre)" if max(abs(c / centre - 1) for c in corners) > 0.01 else "")
    bar = AnchoredSizeBar(ax.transData, ground * centre / unit, label, "lower right", pad=0.3, borderpad=0.4,
                          sep=2, frameon=True, size_vertical=0.008 * (y1 - y0) / unit,  # type: ignore[arg-type]
                          color="black", fontproperties={"size": fontsize})
    bar.patch.set_alpha(0.7)
    bar.set_gid(SCALE_BAR_GID)
    bar.set_zorder(4)
    ax.add_artist(bar)


def decorate_map(ax, projection, unit: float = 1.0, coast: Coastline | None = None, land: bool = True,
                 coast_colour: str = COAST_COLOUR, fontsize: float = 6.0):
    """Coastline (and land), labelled graticule and scale bar on map axes in ``projection``'s plane (``unit``
    metres per axes unit), for the axes' current frame, which is kept (autoscaling is turned off).

    ``coast``: the coastline to draw; default :func:`frame_coastline`. Images drawn on the map keep their pixels:
    pass ``land=False`` to draw the coast as a line only."""
    ax.set_xlim(ax.get_xlim())
    ax.set_ylim(ax.get_ylim())
    ax.set_autoscale_on(False)
    draw_coastline(ax, frame_coastline(ax, projection, unit) if coast is None else coast, projection, unit, land,
                   coast_colour)
    draw_graticule(ax, projection, unit, fontsize)
    draw_scale_bar(ax, projection, unit, fontsize)


def overlay_figure(grid: MapGrid, scale: int = 2, land: bool = True, coast: Coastline | None = None,
                   fontsize: float = 6.0) -> Figure:
    """The figure :func:`map_overlay` renders: one frameless axes filling a ``(n_columns·scale, n_rows·scale)``
    pixel canvas at 100 dots per inch, transparent, with the grid's extent as its limits and
    :func:`decorate_map`'s coast (``land`` filled), labelled graticule and scale bar."""
    height, width = grid.n_rows * scale, grid.n_columns * scale
    fig = Figure(figsize=(width / 100.0, height / 100.0), dpi=100)
    FigureCanvasAgg(fig)
    fig.patch.set_alpha(0.0)
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.set_axis_off()
    left = float(grid.x_first) - 0.5 * float(grid.pixel_width)
    top = float(grid.y_first) + 0.5 * float(grid.pixel_height)
    ax.set_xlim(left, left + grid.n_columns * float(grid.pixel_width))
    ax.set_ylim(top - grid.n_rows * float(grid.pixel_height), top)
    decorate_map(ax, grid.projection, coast=coast, land=land, fontsize=fontsize)
    return fig


def map_overlay(grid: MapGrid, scale: int = 2, land: bool = True, coast: Coastline | None = None,
                fontsize: float = 6.0) -> np.ndarray:
    """The map decorations of a grid's raster (a film's frames) as an RGBA image to lay over it:
    ``(n_rows·scale, n_columns·scale, 4)`` uint8, transparent where nothing is drawn; pixel ``(i, j)`` covers grid
    cell ``(i // scale, j // scale)``. Drawn by :func:`decorate_map` (coast, ``land`` filled, labelled graticule,
    scale bar) at 100 dots per inch (:func:`overlay_figure`), so a film and the figures show the same map."""
    fig = overlay_figure(grid, scale, land, coast, fontsize)
    canvas = fig.canvas
    canvas.draw()
    return np.array(canvas.buffer_rgba(), dtype=np.uint8)  # type: ignore[attr-defined]


def on_land(projection, x, y, coast: Coastline) -> np.ndarray:
    """``True`` where map points ``(x, y)`` (metres in ``projection``'s plane, any shape) lie on the coast's GSHHG
    land (:meth:`~seaice_jax.io.coastline.Coastline.contains` of their latitude and longitude); NaN points are not on
    land. Figures leave such vectors, boxes and floe fixes out."""
    x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
    if not x.size:
        return np.zeros(x.shape, bool)
    latitude, longitude = bucketed(projection.inverse, x.ravel(), y.ravel())
    return coast.contains(np.degrees(latitude), np.degrees(longitude)).reshape(x.shape)


def coast_in_image(model, coast: Coastline, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The coast in an image's space through a scan model: ``(pixel, scan)`` 1-based, lines joined with NaN gaps.

    ``model``: a :class:`~seaice_jax.geometry.scan.ScanModel` (its ``inverse(latitude, longitude)``, radians; the
    coast's degrees are taken as the model's latitudes, as control stations are). ``shape``: ``(n_scans, n_pixels)``;
    vertices farther than the image's size outside it are dropped, and lines are broken where they jump by more than
    half the image (the other branch of the inverse).
    """
    lines = coast.shorelines()
    if not lines:
        return np.zeros(0), np.zeros(0)
    longitude, latitude = _nan_joined(lines)
    pixel, scan = bucketed(model.inverse, np.radians(latitude), np.radians(longitude))
    n_scans, n_pixels = shape
    outside = (pixel < 1 - n_pixels) | (pixel > 2 * n_pixels) | (scan < 1 - n_scans) | (scan > 2 * n_scans)
    jump = np.hypot(np.diff(pixel), np.diff(scan)) > 0.5 * max(shape)
    drop = outside | np.concatenate([[False], jump])
    return np.where(drop, np.nan, pixel), np.where(drop, np.nan, scan)
