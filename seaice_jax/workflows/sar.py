"""``seaice sar geolocate``: a Sentinel-1 annotation's geolocation grid, recomputed by the zero-Doppler model on
the WGS84 ellipsoid and compared with ESA's, point by point.

For every grid point: forward (the grid's azimuth time, slant range and height -> latitude, longitude; the
difference from ESA's east and north, m), inverse (ESA's latitude, longitude, height -> azimuth time and slant range;
the differences, µs and m) and the image coordinates (line, pixel -> azimuth time and slant range through the bursts
or GRD polynomials and the bistatic shift; the difference in azimuth time, µs). Written: ``geolocation.csv`` (one row
per grid point), ``geolocation.png`` (the grid on a polar stereographic map with the coast, and the differences),
``report.txt``.
"""

import csv
import logging
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from seaice_jax._shapes import padded_to_bucket
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.earth import geodetic_to_ecef, north_east
from seaice_jax.geometry.state_vectors import StateVectorOrbit
from seaice_jax.geometry.zero_doppler import ellipsoid_ground_point, ellipsoid_imaging_time_and_range
from seaice_jax.io.sentinel1 import Sentinel1Annotation, read_annotation
from seaice_jax.outputs import output_folder

_log = logging.getLogger(__name__)
"""Where the SAR workflows report their stages when no ``say`` is given (INFO)."""

if TYPE_CHECKING:
    from seaice_jax.geometry.projections import MapGrid

FilePath = str | os.PathLike


@dataclass(frozen=True)
class GeolocationCheck:
    """Our geolocation of an annotation's grid beside ESA's: ``(k,)`` arrays in grid order.

    Attributes:
        annotation: the annotation read.
        latitude, longitude: our forward geolocation, degrees.
        east, north: ours minus ESA's, m. time_error: our inverse's azimuth time minus the grid's, s.
        range_error: our inverse's slant range minus the grid's, m. image_time_error: line/pixel -> azimuth time
            minus the grid's, s.
    """

    annotation: Sentinel1Annotation
    latitude: np.ndarray
    longitude: np.ndarray
    east: np.ndarray
    north: np.ndarray
    time_error: np.ndarray
    range_error: np.ndarray
    image_time_error: np.ndarray

    @property
    def horizontal(self) -> np.ndarray:
        """Horizontal distance of our point from ESA's, m."""
        return np.hypot(self.east, self.north)

    def report(self) -> str:
        """A few lines for the terminal."""
        a = self.annotation
        return "\n".join([
            f"{a.path.name}: {a.mission} {a.mode} {a.swath} {a.polarisation} {a.product_type}, {a.pass_direction}, "
            f"{a.lines} lines x {a.samples} samples, {a.grid.line.size} grid points",
            f"  latitude {a.grid.latitude.min():.3f}..{a.grid.latitude.max():.3f} deg, longitude "
            f"{a.grid.longitude.min():.3f}..{a.grid.longitude.max():.3f} deg",
            f"  forward (time, range, height -> lat/lon): horizontal difference from ESA max "
            f"{self.horizontal.max():.4f} m, RMS {np.sqrt(np.mean(self.horizontal**2)):.4f} m",
            f"  inverse (lat/lon/height -> time, range): max |dt| {np.abs(self.time_error).max() * 1e6:.2f} us, "
            f"max |dr| {np.abs(self.range_error).max() * 1000:.3f} mm",
            f"  image (line, pixel -> time): max |dt| {np.abs(self.image_time_error).max() * 1e6:.2f} us (bistatic "
            f"reference {a.bistatic_reference_time * 1e3:.6f} ms from the {a.bistatic_reference_source})",
        ])


def check_geolocation(annotation: Sentinel1Annotation) -> GeolocationCheck:
    """Recompute ``annotation``'s geolocation grid (see the module docstring). Points are padded to a bucket and the
    orbit to :data:`~seaice_jax.geometry.state_vectors.ORBIT_BUCKET` vectors: one compilation for every product."""
    grid = annotation.grid
    orbit = annotation.orbit()
    padded = orbit.bucketed()
    n = grid.line.size

    def cut(values):
        return np.asarray(values)[:n]

    latitude, longitude = (cut(v) for v in ellipsoid_ground_point(
        padded, padded_to_bucket(grid.azimuth_time), padded_to_bucket(grid.slant_range),
        padded_to_bucket(grid.height)))
    time, slant = (cut(v) for v in ellipsoid_imaging_time_and_range(
        padded, padded_to_bucket(np.radians(grid.latitude)), padded_to_bucket(np.radians(grid.longitude)),
        padded_to_bucket(grid.height), *orbit.time_span))
    ours = np.asarray(geodetic_to_ecef(latitude, longitude, grid.height))
    esa = np.asarray(geodetic_to_ecef(np.radians(grid.latitude), np.radians(grid.longitude), grid.height))
    north_axis, east_axis = (np.asarray(v) for v in north_east(esa))
    image_time, _ = annotation.radar_coordinates(grid.line, grid.pixel)
    return GeolocationCheck(annotation, np.degrees(latitude), np.degrees(longitude),
                            np.sum((ours - esa) * east_axis, -1), np.sum((ours - esa) * north_axis, -1),
                            time - grid.azimuth_time, slant - grid.slant_range, image_time - grid.azimuth_time)


@dataclass(frozen=True)
class GeolocateResult:
    """What ``seaice sar geolocate`` did: the check and the files written."""

    check: GeolocationCheck
    files: tuple[Path, ...]


def _utc(annotation: Sentinel1Annotation, seconds: np.ndarray) -> list[str]:
    moments = annotation.epoch + np.round(np.asarray(seconds) * 1e9).astype("timedelta64[ns]")
    return [f"{np.datetime_as_string(m, unit='us')}Z" for m in moments]


def write_geolocation_csv(path: Path, check: GeolocationCheck) -> Path:
    """One row per grid point: image coordinates, radar coordinates, ESA's and our positions, the differences."""
    grid = check.annotation.grid
    columns = ["line", "pixel", "azimuth_time_utc", "slant_range_time_s", "height_m", "esa_latitude_deg",
               "esa_longitude_deg", "latitude_deg", "longitude_deg", "east_difference_m", "north_difference_m",
               "horizontal_difference_m", "inverse_time_difference_us", "inverse_range_difference_m",
               "image_time_difference_us"]
    times = _utc(check.annotation, grid.azimuth_time)
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(columns)
        for k in range(grid.line.size):
            writer.writerow([int(grid.line[k]), int(grid.pixel[k]), times[k], f"{grid.slant_range_time[k]:.15e}",
                             f"{grid.height[k]:.3f}", f"{grid.latitude[k]:.12f}", f"{grid.longitude[k]:.12f}",
                             f"{check.latitude[k]:.12f}", f"{check.longitude[k]:.12f}", f"{check.east[k]:.5f}",
                             f"{check.north[k]:.5f}", f"{check.horizontal[k]:.5f}",
                             f"{check.time_error[k] * 1e6:.4f}", f"{check.range_error[k]:.6f}",
                             f"{check.image_time_error[k] * 1e6:.4f}"])
    return path


def run_geolocate(annotation_path: FilePath, out_dir: FilePath, reference: FilePath | None = None,
                  overwrite: bool = False, say: Callable[[str], None] | None = None) -> GeolocateResult:
    """``seaice sar geolocate``: read, check every grid point, write CSV, figure and report into ``out_dir``;
    ``say`` receives a message as each stage starts (default: this module's logger at INFO)."""
    from seaice_jax.report.figures import plot_sar_geolocation

    say = say or _log.info
    annotation = read_annotation(annotation_path, reference)
    inputs = [annotation_path] + ([reference] if reference is not None else [])
    with output_folder(out_dir, overwrite, inputs=inputs) as folder:
        say(f"geolocating {annotation.grid.line.size} grid points of {annotation.path.name}")
        check = check_geolocation(annotation)
        written = [write_geolocation_csv(folder.path / "geolocation.csv", check)]
        say("drawing the figure")
        written.append(plot_sar_geolocation(folder.path / "geolocation.png", check))
        report = folder.path / "report.txt"
        report.write_text(check.report() + "\n")
        written.append(report)
        files = folder.final(written)
    return GeolocateResult(check, files)


REMAP_CHUNK = 65_536
"""Grid cells geolocated per compiled call of the remap (one compilation for any grid size)."""
MAX_REMAP_CELLS = 64_000_000
"""Largest output grid of ``seaice sar remap`` (cells): about 2.5 GB of float32 image, maps and σ."""


def footprint_grid(annotation: Sentinel1Annotation, spacing: float) -> "MapGrid":
    """The NSIDC polar stereographic grid (EPSG:3413 north, 3976 south) of ``spacing`` metres that covers the
    annotation's geolocation grid, with a margin of one cell.

    Raises:
        SeaiceError: a grid above :data:`MAX_REMAP_CELLS` (names ``--spacing``).
    """
    from seaice_jax.geometry.projections import MapGrid, nsidc_polar_stereographic

    grid = annotation.grid
    projection = nsidc_polar_stereographic("north" if np.mean(grid.latitude) >= 0 else "south")
    x, y = (np.asarray(v) for v in projection.forward(np.radians(grid.latitude), np.radians(grid.longitude)))
    columns = int(np.ceil((x.max() - x.min()) / spacing)) + 3
    rows = int(np.ceil((y.max() - y.min()) / spacing)) + 3
    if rows * columns > MAX_REMAP_CELLS:
        raise SeaiceError(f"--spacing {spacing:g} m: the grid over {annotation.path.name} would have {rows} x "
                          f"{columns} cells, more than {MAX_REMAP_CELLS:,}; use a coarser spacing")
    return MapGrid(projection, x.min() - spacing, y.max() + spacing, spacing, spacing, rows, columns)


def source_maps(annotation: Sentinel1Annotation, grid: "MapGrid", height) -> tuple[np.ndarray, np.ndarray]:
    """Fractional image ``(line, pixel)`` of every cell centre of ``grid`` at ellipsoidal ``height`` (m, a number or
    ``(n_rows, n_columns)``): the inverse zero-Doppler model
    (:func:`~seaice_jax.geometry.zero_doppler.ellipsoid_imaging_time_and_range`) in chunks of :data:`REMAP_CHUNK`
    cells, then :meth:`~seaice_jax.io.sentinel1.Sentinel1Annotation.image_coordinates`. Each
    ``(n_rows, n_columns)``."""
    latitude, longitude = (np.asarray(v).reshape(-1) for v in grid.latitude_longitude())
    heights = np.broadcast_to(np.asarray(height, float), grid.shape).reshape(-1)
    orbit = annotation.orbit()
    padded = orbit.bucketed()
    time, slant = np.empty_like(latitude), np.empty_like(latitude)
    for start in range(0, latitude.size, REMAP_CHUNK):
        part = slice(start, start + REMAP_CHUNK)
        n = latitude[part].size
        chunk = [np.pad(v[part], (0, REMAP_CHUNK - n), mode="edge") for v in (latitude, longitude, heights)]
        t, r = ellipsoid_imaging_time_and_range(padded, chunk[0], chunk[1], chunk[2], *orbit.time_span)
        time[part], slant[part] = np.asarray(t)[:n], np.asarray(r)[:n]
    line, pixel = annotation.image_coordinates(time, slant)
    return line.reshape(grid.shape), pixel.reshape(grid.shape)


GRID_HEIGHT_PASSES = 3
"""Passes of :func:`terrain_source_maps`: image coordinates at the median height, then at the grid's heights there,
twice more (a cell's height error shrinks by the terrain's slope times the layover, each pass)."""


def terrain_source_maps(annotation: Sentinel1Annotation, grid: "MapGrid") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`source_maps` on the surface of the annotation's geolocation-grid heights (the processor's terrain: the
    geoid over the sea), bilinear in image line and pixel between the grid's points: ``(line, pixel, height)``.
    A cell's height depends on where it falls in the image, so the maps are iterated (:data:`GRID_HEIGHT_PASSES`)
    from the median height; outside the grid's span the nearest grid height is used."""
    height = np.full(grid.shape, float(np.median(annotation.grid.height)))
    for _ in range(GRID_HEIGHT_PASSES):
        line, pixel = source_maps(annotation, grid, height)
        near = _grid_field(annotation, annotation.grid.height, line, pixel)
        height = np.where(np.isfinite(near), near, height)
    return line, pixel, height


def orbit_position_sigma(annotation: Sentinel1Annotation, orbit_sigma: float, height=None) -> np.ndarray:
    """Horizontal σ (m, root sum of the east and north variances) of the ground point at every geolocation grid
    point caused by an orbit position error of σ = ``orbit_sigma`` metres on each axis (uncorrelated): σ² · J Jᵀ
    with J the Jacobian of the ground point's east and north with respect to an offset of every state vector's
    position, by autodiff through the forward model, at ``height`` (m; default the grid's own heights). ``(k,)`` in
    grid order."""
    import jax
    import jax.numpy as jnp

    grid = annotation.grid
    heights = grid.height if height is None else np.broadcast_to(np.asarray(height, float), grid.height.shape)
    orbit = annotation.orbit()
    padded = orbit.bucketed()
    reference = np.asarray(geodetic_to_ecef(np.radians(grid.latitude), np.radians(grid.longitude), heights))
    north_axis, east_axis = (np.asarray(v) for v in north_east(reference))

    def ground(offset, time, slant, surface):
        shifted = StateVectorOrbit(padded.times, padded.positions + offset[None, :], padded.velocities, padded.order,
                                   padded.count)
        latitude, longitude = ellipsoid_ground_point(shifted, time, slant, surface, on_failure="nan")
        return geodetic_to_ecef(latitude, longitude, surface)

    jacobian = jax.jit(jax.vmap(jax.jacfwd(ground), in_axes=(None, 0, 0, 0)))(
        jnp.zeros(3), *(jnp.asarray(padded_to_bucket(v)) for v in (grid.azimuth_time, grid.slant_range, heights)))
    jacobian = np.asarray(jacobian)[: grid.line.size]
    horizontal = np.einsum("ki,kij->kj", east_axis, jacobian) ** 2 + np.einsum("ki,kij->kj", north_axis, jacobian) ** 2
    return orbit_sigma * np.sqrt(horizontal.sum(axis=-1))


def _grid_field(annotation: Sentinel1Annotation, values: np.ndarray, line, pixel) -> np.ndarray:
    """A field given at the geolocation grid points, bilinear in (line, pixel) at fractional image coordinates (the
    nearest edge value beyond the grid's span; NaN where a coordinate is)."""
    from seaice_jax.imagery.remap import resample

    lines, pixels, table = annotation.grid.table(values)
    row = np.interp(line, lines, np.arange(lines.size))
    column = np.interp(pixel, pixels, np.arange(pixels.size))
    field, _ = resample(table, row, column, np.isfinite(row) & np.isfinite(column))
    return field


@dataclass(frozen=True)
class SarRemapResult:
    """What ``seaice sar remap`` did: the grid, the remapped image and σ (NaN outside the image), the files."""

    grid: "MapGrid"
    image: np.ndarray
    position_sigma: np.ndarray
    report: str
    files: tuple[Path, ...]


def run_sar_remap(annotation_path: FilePath, image_path: FilePath, out_dir: FilePath, spacing: float = 200.0,
                  height: float | None = None, orbit_sigma: float = 5.0, decimation: int = 1,
                  overwrite: bool = False, say: Callable[[str], None] | None = None) -> SarRemapResult:
    """``seaice sar remap``: a GRD (or stripmap) image onto the NSIDC polar stereographic grid by the exact
    zero-Doppler model: every cell centre -> azimuth time and slant range -> image line and pixel -> bilinear
    sample. Writes ``remapped.tif`` (float32 GeoTIFF, NaN outside the image), ``position_sigma.tif`` (m: the
    horizontal σ from ``orbit_sigma``), both with the zero-Doppler time of the image's middle line as their
    acquisition time, ``remapped.png`` and ``report.txt``.

    Args:
        spacing: grid cell size, m. height: ellipsoidal height of the surface, m (default: the median of the
            geolocation grid's heights, the geoid there for a scene over the sea). orbit_sigma: the orbit's position
            σ per axis, m. decimation: the image keeps every ``decimation``-th line and sample of the product.
            say: receives a message as each stage starts (default: this module's logger at INFO).
    """
    from seaice_jax.imagery.remap import resample
    from seaice_jax.io.products import write_geotiff
    from seaice_jax.io.sequence import read_image_file
    from seaice_jax.report.figures import crs_name, plot_remapped_sar

    say = say or _log.info
    for name, value in (("--spacing", spacing), ("--orbit-sigma", orbit_sigma)):
        if not (np.isfinite(value) and value > 0):
            raise SeaiceError(f"{name} must be a positive number of metres, got {value}")
    annotation = read_annotation(annotation_path).decimated(decimation)
    image = read_image_file(Path(image_path))
    if image.shape != (annotation.lines, annotation.samples):
        raise SeaiceError(f"{image_path}: image of {image.shape[0]} x {image.shape[1]} pixels, but "
                          f"{annotation.path.name} (decimation {decimation}) describes {annotation.lines} lines x "
                          f"{annotation.samples} samples")
    grid = footprint_grid(annotation, spacing)
    with output_folder(out_dir, overwrite, inputs=[annotation_path, image_path]) as folder:
        say(f"geolocating {grid.n_rows} x {grid.n_columns} cells of {spacing:g} m")
        if height is None:
            line, pixel, surface = terrain_source_maps(annotation, grid)
        else:
            surface = np.full(grid.shape, float(height))
            line, pixel = source_maps(annotation, grid, surface)
        say("resampling")
        remapped, valid = resample(image, line, pixel, np.isfinite(line) & np.isfinite(pixel))
        sigma = _grid_field(annotation, orbit_position_sigma(annotation, orbit_sigma, height), line, pixel)
        sigma = np.where(valid, sigma, np.nan)
        middle = _utc(annotation, annotation.line_time([(annotation.lines - 1) / 2]))[0]  # the scene's mid-line time
        written = [write_geotiff(folder.path / "remapped.tif", remapped, grid,
                                 f"{annotation.path.name} remapped by the zero-Doppler model", time=middle),
                   write_geotiff(folder.path / "position_sigma.tif", sigma, grid,
                                 f"horizontal position sigma (m) from an orbit sigma of {orbit_sigma:g} m per axis",
                                 time=middle)]
        report = "\n".join([
            f"{annotation.path.name} (decimation {decimation}) -> {grid.n_rows} x {grid.n_columns} cells of "
            f"{spacing:g} m, {crs_name(grid.projection)}, surface height "
            f"{np.min(surface):.1f}..{np.max(surface):.1f} m "
            f"({'the geolocation grid' if height is None else '--height'})",
            f"  {int(valid.sum())} cells inside the image; position sigma from the orbit ({orbit_sigma:g} m per "
            f"axis): {np.nanmin(sigma):.2f}..{np.nanmax(sigma):.2f} m"])
        written.append(plot_remapped_sar(folder.path / "remapped.png", remapped, grid, sigma,
                                         f"{annotation.mission} {annotation.mode} {annotation.polarisation} "
                                         f"{annotation.product_type} {np.datetime_as_string(annotation.epoch, 'm')}"))
        (folder.path / "report.txt").write_text(report + "\n")
        written.append(folder.path / "report.txt")
        files = folder.final(written)
    return SarRemapResult(grid, remapped, sigma, report, files)

