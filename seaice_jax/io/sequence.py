"""Image-sequence projects: a TOML file naming the images, their times, scan models or control points, and the
map grid to remap into, with the image and control files beside it.

```toml
epoch = "1983-03-08T00:00:00Z"        # time origin of the outputs (ISO 8601 UTC)

[grid]
projection = "nsidc-north"            # nsidc-north | nsidc-south | equirectangular (source 001's image grid),
                                      # or any projected CRS pyproj knows: "EPSG:3031", "+proj=laea ...", WKT
centre_deg = [74.0, -85.0]            # latitude, longitude of the grid's centre
pixel_m = [2500.0, 2500.0]            # width, height
shape = [150, 150]                    # rows, columns

[[image]]
name = "IMG01"
time = "1983-03-08T01:12:00Z"
file = "IMG01.npy"                    # .npy, .tif/.tiff or .png: rows = scan lines, columns = pixels
satellite = "NOAA-7"
altitude_m = 0.0                      # 0: curvature-corrected image
control = "IMG01_control.csv"         # id,pixel,scan,latitude_deg,longitude_deg,sigma_m: fit the scan model ...
# ... or give it: direction, scanner_angle_span_deg, subtrack_pixel, orbital_angle_first_deg,
#     orbital_angle_span_deg, ascending_node_deg
# ... or find control points on the coastline (GSHHG), starting from those six keys as a rough model:
# control = "coastline"
# ascending_node_deg = -83.1          # the node's longitude from the orbital bulletin
# orbital_angle_first_deg = 131.0     # 360° x (minutes from the node to the first scan line) / period
# control_search = 32                 # ± pixels searched around the rough model (default 32)
```

Every error names the file (and line, or image) at fault; reading never writes anything.
"""

import os
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seaice_jax.errors import SeaiceError
from seaice_jax.files import atomic_path, write_csv
from seaice_jax.geometry.crs import projection_from_definition
from seaice_jax.geometry.earth import MEAN_RADIUS
from seaice_jax.geometry.projections import Equirectangular, MapGrid, nsidc_polar_stereographic
from seaice_jax.geometry.scan import SCAN_UNKNOWNS, Orbit, ScanModel, satellite_orbit
from seaice_jax.io.stations import check_in_image, control_points, read_measurements
from seaice_jax.io.tables import check_input_file, project_file
from seaice_jax.memory import DEFAULT_BUDGET, check_memory, remap_peak
from seaice_jax.sensors.control import ControlPoints
from seaice_jax.timefmt import format_time, parse_time, time_after

MODEL_KEYS = tuple(name if name == "subtrack_pixel" else f"{name}_deg" for name in SCAN_UNKNOWNS)
"""The keys of a given scan model: its unknowns (:data:`~seaice_jax.geometry.scan.SCAN_UNKNOWNS`), angles in
degrees."""
PROJECTIONS = ("nsidc-north", "nsidc-south", "equirectangular")
"""The named grid projections; any other ``projection`` is a CRS definition pyproj knows (``"EPSG:3031"``, a PROJ
string, WKT: :func:`~seaice_jax.geometry.crs.projection_from_definition`)."""


@dataclass(frozen=True)
class SequenceImage:
    """One image of a sequence project: its pixels, time (s since the project's epoch), orbit, and either a
    scan model, control points to fit one, or (``control = "coastline"``) a ``rough`` model to start the search for
    control points on the coastline from, ± ``control_search`` pixels."""

    name: str
    time: float
    data: np.ndarray
    orbit: Orbit
    model: ScanModel | None
    control: ControlPoints | None
    direction: str
    rough: ScanModel | None = None
    control_search: int = 32


MEMORY_BUDGET = DEFAULT_BUDGET
"""Bytes one image file may take (a bigger one is refused); a project's remap is checked against its estimated peak
(:func:`~seaice_jax.memory.remap_peak`, :func:`~seaice_jax.memory.check_memory`)."""


@dataclass(frozen=True)
class SequenceProject:
    path: Path
    epoch: str
    grid: MapGrid
    grid_spec: dict
    images: tuple[SequenceImage, ...]


def named_projection(projection: str, centre_deg):
    """The metric projection of one of :data:`PROJECTIONS` (the equi-rectangular one true at ``centre_deg``) or of
    a CRS definition pyproj knows (``"EPSG:3031"``, a PROJ string, WKT)."""
    if projection == "equirectangular":
        return Equirectangular(np.radians(centre_deg[0]), np.radians(centre_deg[1]))
    if projection in PROJECTIONS:
        return nsidc_polar_stereographic(projection.split("-")[1])
    if not isinstance(projection, str):
        raise SeaiceError(f"grid projection must be text, got {projection!r}")
    try:
        return projection_from_definition(projection)
    except SeaiceError as error:
        raise SeaiceError(f"grid projection must be one of {', '.join(PROJECTIONS)} or a projected CRS pyproj "
                          f"knows (EPSG:code, PROJ string, WKT): {error}") from None


def make_grid(projection: str, centre_deg, pixel_m, shape) -> MapGrid:
    """The :class:`MapGrid` of a project's ``[grid]`` table."""
    metric = named_projection(projection, centre_deg)
    centre = metric.forward(np.radians(centre_deg[0]), np.radians(centre_deg[1]))
    if not np.all(np.isfinite(np.asarray(centre, float))):
        raise SeaiceError(f"centre_deg {list(centre_deg)!r} is outside the domain of projection {projection!r}")
    return MapGrid.centred(metric, np.radians(centre_deg[0]), np.radians(centre_deg[1]), float(pixel_m[0]),
                           float(pixel_m[1]), int(shape[0]), int(shape[1]))


def read_image_file(path: Path) -> np.ndarray:
    """A single-band image as float64 ``(scan lines, pixels)``."""
    if not path.exists():
        raise SeaiceError(f"{path}: file not found")
    suffix = path.suffix.lower()
    if suffix in (".npy", ".tif", ".tiff"):
        import tifffile

        try:
            data = np.load(path, allow_pickle=False) if suffix == ".npy" else tifffile.imread(path)
        except (ValueError, EOFError, OSError, tifffile.TiffFileError) as error:
            kind = "a .npy array" if suffix == ".npy" else "a TIFF image"
            raise SeaiceError(f"{path}: truncated or not {kind} ({error})") from None
    elif suffix == ".png":
        import cv2

        data = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_ANYDEPTH)
        if data is None:
            raise SeaiceError(f"{path}: not a readable PNG")
    else:
        raise SeaiceError(f"{path}: image files must be .npy, .tif or .png")
    data = np.asarray(data, float)
    if data.ndim != 2:
        raise SeaiceError(f"{path}: a single-band image (2-D) is needed, got shape {data.shape}")
    return data


def _read_control(path: Path, shape) -> ControlPoints:
    """An image's control points (:func:`~seaice_jax.io.stations.read_measurements`: the package's one
    control-point dialect), each with its σ, inside the image of ``shape`` (scan lines, pixels)."""
    points = read_measurements(path)
    if not points:
        raise SeaiceError(f"{path}: no control points")
    for point in points:
        if point.sigma_m is None:
            raise SeaiceError(f"{path}, line {point.line}: point {point.id} has no sigma_m (a sequence project's "
                              "control points need their ground σ, metres)")
    check_in_image(points, shape[1], shape[0], path, options=" (1-based)")
    return control_points(points)


def _given_model(entry: dict, label: str, orbit: Orbit, direction: str, shape) -> ScanModel:
    """The scan model an ``[[image]]`` gives (:data:`MODEL_KEYS`, angles in degrees) for an image of ``shape``."""
    if direction not in ("south", "north"):
        raise SeaiceError(f"{label}: a given scan model needs direction = 'south' or 'north'")
    for key in MODEL_KEYS:
        if isinstance(entry[key], bool) or not isinstance(entry[key], int | float) or not np.isfinite(entry[key]):
            raise SeaiceError(f"{label}: {key} must be a finite number, got {entry[key]!r}")
    unknowns = {unknown: float(entry[key]) if key == "subtrack_pixel" else np.radians(entry[key])
                for unknown, key in zip(SCAN_UNKNOWNS, MODEL_KEYS, strict=True)}
    return ScanModel(**unknowns, orbit=orbit, direction=direction, n_pixels=shape[1], n_scans=shape[0])


def _name_and_time(entry: dict, k: int, path: Path, epoch: str) -> tuple[str, float]:
    """The name and time (s since ``epoch``) of image ``k``'s ``[[image]]`` table."""
    if not isinstance(entry, dict):
        raise SeaiceError(f"{path}: image {k + 1} must be an [[image]] table")
    name = str(entry.get("name", f"image {k + 1}"))
    try:
        return name, (parse_time(entry["time"]) - parse_time(epoch)).total_seconds()
    except (KeyError, ValueError):
        raise SeaiceError(f"{path}: image {name!r}: time {entry.get('time')!r} is not an ISO 8601 date-time") from None


def _read_image(entry: dict, k: int, path: Path, epoch: str, allow_outside: bool = False) -> SequenceImage:
    """One ``[[image]]`` table: its time, pixels, orbit, and control points or a given scan model."""
    name, time = _name_and_time(entry, k, path, epoch)
    label = f"{path}: image {name!r}"
    if "file" not in entry:
        raise SeaiceError(f"{label}: no file")
    image_path = project_file(path.parent, entry["file"], label, "file", allow_outside)
    check_input_file(image_path, MEMORY_BUDGET)
    data = read_image_file(image_path)
    if not np.all(np.isfinite(data)):
        raise SeaiceError(f"{image_path}: {np.count_nonzero(~np.isfinite(data))} pixel values are not finite")
    try:
        orbit = satellite_orbit(entry.get("satellite", "NOAA-7"), altitude=float(entry.get("altitude_m", 0.0)))
    except ValueError as error:
        raise SeaiceError(f"{label}: {error}") from None
    direction = entry.get("direction", "auto")
    model = control = rough = None
    search = entry.get("control_search", 32)
    if entry.get("control") == "coastline":
        if not all(key in entry for key in MODEL_KEYS):
            missing = ", ".join(key for key in MODEL_KEYS if key not in entry)
            raise SeaiceError(f"{label}: control = 'coastline' needs the rough scan model to start from "
                              f"(direction and {', '.join(MODEL_KEYS)}); missing {missing}")
        if isinstance(search, bool) or not isinstance(search, int) or search < 1:
            raise SeaiceError(f"{label}: control_search must be a positive whole number of pixels, got {search!r}")
        rough = _given_model(entry, label, orbit, direction, data.shape)
    elif "control" in entry:
        control = _read_control(project_file(path.parent, entry["control"], label, "control", allow_outside),
                                data.shape)
    elif all(key in entry for key in MODEL_KEYS):
        model = _given_model(entry, label, orbit, direction, data.shape)
    else:
        raise SeaiceError(f"{label}: give either control = 'file.csv' or the scan model ({', '.join(MODEL_KEYS)}), "
                          "or control = 'coastline' with a rough scan model")
    return SequenceImage(name, time, data, orbit, model, control, direction, rough, search)


def _check_hemisphere(path: Path, projection, latitude: float, half_height: float) -> None:
    """A polar stereographic grid centred in its own hemisphere; an equi-rectangular grid (``half_height`` m north
    and south of its centre) not reaching beyond a pole, where its rows would stand for latitudes over 90°."""
    if (projection, latitude > 0) in (("nsidc-north", False), ("nsidc-south", True)):
        raise SeaiceError(f"{path}: [grid] centre_deg latitude {latitude} lies outside the {projection} grid's "
                          f"hemisphere; use nsidc-{'south' if projection == 'nsidc-north' else 'north'}")
    reach = abs(latitude) + np.degrees(half_height / MEAN_RADIUS)
    if projection == "equirectangular" and reach > 90:
        raise SeaiceError(f"{path}: [grid] an equirectangular grid centred at latitude {latitude} with "
                          f"{half_height:g} m north and south reaches latitude {reach:.3f}°, beyond the pole; use "
                          "nsidc-north or nsidc-south there")


def _checked_grid(path: Path, spec: dict) -> MapGrid:
    """The ``[grid]`` table as a :class:`MapGrid`: finite numbers, latitude within ±90°, longitude within
    [-180°, 360°), pixel sizes > 0, a shape of two positive integers on which one image's remap fits in the memory
    budget (:func:`~seaice_jax.memory.check_memory`)."""
    for key in ("centre_deg", "pixel_m", "shape"):
        value = spec.get(key)
        if not (isinstance(value, list) and len(value) == 2 and all(
                isinstance(v, int | float) and not isinstance(v, bool) and np.isfinite(v) for v in value)):
            raise SeaiceError(f"{path}: [grid] {key} must be two numbers, got {value!r}")
    (latitude, longitude), pixel_m, shape = spec["centre_deg"], spec["pixel_m"], spec["shape"]
    if not (-90 <= latitude <= 90 and -180 <= longitude < 360):
        raise SeaiceError(f"{path}: [grid] centre_deg {spec['centre_deg']!r}: latitude must be within [-90°, 90°] and "
                          "longitude within [-180°, 360°)")
    if not (pixel_m[0] > 0 and pixel_m[1] > 0):
        raise SeaiceError(f"{path}: [grid] pixel_m must be > 0, got {pixel_m!r}")
    if not all(isinstance(n, int) and n >= 1 for n in shape):
        raise SeaiceError(f"{path}: [grid] shape must be two positive integers (rows, columns), got {shape!r}")
    projection = spec.get("projection", "nsidc-north")
    _check_hemisphere(path, projection, latitude, pixel_m[1] * shape[0] / 2)
    check_memory(remap_peak(shape[0] * shape[1], 1), f"{path}: [grid] shape {shape!r}: remapping one image on it")
    try:
        return make_grid(projection, spec["centre_deg"], pixel_m, shape)
    except SeaiceError as error:
        raise SeaiceError(f"{path}: [grid] {error}") from None


def read_sequence(path: str | os.PathLike, allow_outside: bool = False) -> SequenceProject:
    """Read and check a sequence project (see the module docstring). The files it names are resolved relative to
    its folder and must lie inside it unless ``allow_outside``; the remap of all its images must fit in the memory
    budget (:func:`~seaice_jax.memory.remap_peak`, :func:`~seaice_jax.memory.check_memory`).

    Raises:
        SeaiceError: naming the file, table, key or line at fault.
    """
    path = Path(path)
    epoch, spec, grid, entries = _project_header(path)
    cells = grid.shape[0] * grid.shape[1]
    what = f"{path}: {len(entries)} images on a {grid.shape[0]} x {grid.shape[1]} grid"
    check_memory(remap_peak(cells, len(entries)), what)
    images, names = [], set()
    for k, entry in enumerate(entries):
        image = _read_image(entry, k, path, epoch, allow_outside)
        if image.name in names:
            raise SeaiceError(f"{path}: image {image.name!r}: duplicate image name")
        names.add(image.name)
        images.append(image)
    if not images:
        raise SeaiceError(f"{path}: no [[image]] entries")
    check_memory(remap_peak(cells, len(images), sum(im.data.size for im in images)), f"{what} (with their pixels)")
    times = [im.time for im in images]
    if any(b <= a for a, b in zip(times, times[1:], strict=False)):
        raise SeaiceError(f"{path}: image times must increase in the order listed")
    return SequenceProject(path, epoch, grid, dict(spec), tuple(images))


def read_sequence_outline(path: str | os.PathLike) -> tuple[SequenceProject, tuple[dict, ...]]:
    """A sequence project checked as :func:`read_sequence` checks it without reading its images' files, for an
    archive whose images are read one at a time (:func:`read_sequence_image`, e.g. by Dask workers): no memory
    budget for the stack.

    Returns:
        ``(project, entries)``: the project with no ``images`` and its ``[[image]]`` tables (names unique, times
        increasing).
    """
    path = Path(path)
    epoch, spec, grid, entries = _project_header(path)
    if not entries:
        raise SeaiceError(f"{path}: no [[image]] entries")
    names, times = set(), []
    for k, entry in enumerate(entries):
        name, time = _name_and_time(entry, k, path, epoch)
        if name in names:
            raise SeaiceError(f"{path}: image {name!r}: duplicate image name")
        names.add(name)
        times.append(time)
    if any(b <= a for a, b in zip(times, times[1:], strict=False)):
        raise SeaiceError(f"{path}: image times must increase in the order listed")
    return SequenceProject(path, epoch, grid, dict(spec), ()), tuple(entries)


def read_sequence_image(project: SequenceProject, entry: dict, k: int, allow_outside: bool = False) -> SequenceImage:
    """Image ``k`` of ``project`` (:func:`read_sequence_outline`) from its ``[[image]]`` table ``entry``, read and
    checked as :func:`read_sequence` reads each image."""
    return _read_image(entry, k, project.path, project.epoch, allow_outside)


def _project_header(path: Path) -> tuple[str, dict, MapGrid, list]:
    """``(epoch, grid spec, grid, [[image]] tables)`` of a project file, checked."""
    check_input_file(path)
    try:
        document = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except UnicodeDecodeError as error:
        raise SeaiceError(f"{path}: not UTF-8 text (byte {error.start}: {error.reason}); save it as UTF-8") from None
    except tomllib.TOMLDecodeError as error:
        raise SeaiceError(f"{path}: {error}") from None
    try:
        epoch = format_time(parse_time(document.get("epoch", "")))
    except ValueError:
        raise SeaiceError(f"{path}: epoch {document.get('epoch')!r} is not an ISO 8601 date-time") from None
    spec = document.get("grid")
    if not isinstance(spec, dict):
        raise SeaiceError(f"{path}: a [grid] table is needed")
    grid = _checked_grid(path, spec)
    entries = document.get("image", [])
    if not isinstance(entries, list):
        raise SeaiceError(f"{path}: images must be [[image]] tables")
    return epoch, spec, grid, entries


def write_sequence(sequence, out_dir: str | os.PathLike, grid_spec: dict, satellite: str = "NOAA-7") -> Path:
    """Write a simulated :class:`~seaice_jax.simulate.satellite.ImageSequence` as a project: the images
    (``.npy``), their control points (CSV) and ``sequence.toml`` (written last, so a complete project is one with
    its TOML file)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    epoch = parse_time(sequence.epoch)
    lines = [f'epoch = "{format_time(epoch)}"', "", "[grid]", f'projection = "{grid_spec["projection"]}"',
             f"centre_deg = {list(map(float, grid_spec['centre_deg']))}",
             f"pixel_m = {list(map(float, grid_spec['pixel_m']))}", f"shape = {list(map(int, grid_spec['shape']))}"]
    for image in sequence.images:
        with atomic_path(out / f"{image.name}.npy") as temporary, open(temporary, "wb") as stream:
            np.save(stream, image.data)
        c = image.control
        write_csv(out / f"{image.name}_control.csv", {
            "id": np.array(c.ids), "pixel": np.asarray(c.pixel), "scan": np.asarray(c.scan),
            "latitude_deg": np.degrees(np.asarray(c.latitude)), "longitude_deg": np.degrees(np.asarray(c.longitude)),
            "sigma_m": np.asarray(c.sigma)}, float_format="%.10g")
        moment = time_after(sequence.epoch, image.time)
        lines += ["", "[[image]]", f'name = "{image.name}"', f'time = "{moment}"', f'file = "{image.name}.npy"',
                  f'satellite = "{satellite}"', f"altitude_m = {float(image.model.orbit.altitude)!r}",
                  f'direction = "{image.model.direction}"', f'control = "{image.name}_control.csv"']
    path = out / "sequence.toml"
    with atomic_path(path) as temporary:
        temporary.write_text("\n".join(lines) + "\n")
    return path
