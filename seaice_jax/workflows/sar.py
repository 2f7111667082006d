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
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seaice_jax._shapes import padded_to_bucket
from seaice_jax.geometry.earth import geodetic_to_ecef, north_east
from seaice_jax.geometry.state_vectors import ORBIT_BUCKET
from seaice_jax.geometry.zero_doppler import ellipsoid_ground_point, ellipsoid_imaging_time_and_range
from seaice_jax.io.sentinel1 import Sentinel1Annotation, read_annotation
from seaice_jax.outputs import output_folder

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
    padded = orbit.padded(max(ORBIT_BUCKET, orbit.times.size))
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
                  overwrite: bool = False, say: Callable[[str], None] = lambda _: None) -> GeolocateResult:
    """``seaice sar geolocate``: read, check every grid point, write CSV, figure and report into ``out_dir``."""
    from seaice_jax.report.figures import plot_sar_geolocation

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
