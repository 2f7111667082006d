"""Station catalogues and control-point measurements (source 001, Appendix A, VHR2 function 3).

* The AGRID station catalogue (``IM3:AGRID.STN``): one station per line, fixed columns — number 1-5, blanks 6-10,
  name 11-40, latitude degree 41-45, minute 46-50, longitude degree 51-55, minute 56-60; numbers right-justified,
  the name left-justified. The sign of a coordinate is carried by its degree field ("-0" for a negative
  coordinate under one degree).
* Control-point measurements as CSV, one dialect for every reader and writer of the package (``seaice rectify``,
  a sequence project's ``control`` files, the files ``seaice simulate lancaster`` writes):
  ``id,pixel,scan,latitude_deg,longitude_deg,sigma_m`` (:data:`MEASUREMENT_COLUMNS`), see
  :func:`read_measurements`.

Every error names the file and line.
"""

import csv
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seaice_jax.errors import SeaiceError
from seaice_jax.files import atomic_path, bare_column
from seaice_jax.io.tables import check_input_file, finite_number
from seaice_jax.sensors.control import ControlPoints


@dataclass(frozen=True)
class Station:
    """A catalogue station: number, name and position in decimal degrees."""

    number: int
    name: str
    latitude_deg: float
    longitude_deg: float


@dataclass(frozen=True)
class Measurement:
    """A control point measured on an image: id, name, pixel, scan (1-based), known position (degrees), ground σ
    (m, ``None``: not given) and the file's line it was read from (0: not read from a file)."""

    id: str
    name: str
    pixel: float
    scan: float
    latitude_deg: float
    longitude_deg: float
    sigma_m: float | None = None
    line: int = 0


MEASUREMENT_COLUMNS = ("id", "pixel", "scan", "latitude_deg", "longitude_deg", "sigma_m")
"""The control-point CSV dialect, in the order the package writes it (``name`` may follow): see
:func:`read_measurements`."""

_ALIASES = {"lat": "latitude", "lon": "longitude", "sigma_km": "sigma_m"}
"""Older column names (after :func:`~seaice_jax.files.bare_column`) -> the dialect's: older files' ``lat``/``lon``
and ``seaice rectify``'s former ``sigma_km``."""


def _field(line: str, start: int, end: int) -> str:
    return line[start - 1:end].strip()


def _degrees_minutes(degrees: str, minutes: str, where: str, what: str) -> float:
    try:
        d, m = float(degrees), float(minutes or 0.0)
    except ValueError:
        raise SeaiceError(f"{where}: {what} degree {degrees!r} / minute {minutes!r} is not a number") from None
    if not 0.0 <= m < 60.0:
        raise SeaiceError(f"{where}: {what} minute {m} is outside [0, 60)")
    sign = -1.0 if degrees.startswith("-") else 1.0
    return sign * (abs(d) + m / 60.0)


def read_agrid(path: str | os.PathLike) -> list[Station]:
    """Read an AGRID station catalogue. Blank lines are skipped."""
    stations, seen = [], {}
    for number, line in enumerate(Path(path).read_text().splitlines(), start=1):
        if not line.strip():
            continue
        where = f"{path}, line {number}"
        if len(line.rstrip()) < 51:
            raise SeaiceError(f"{where}: too short for the AGRID layout (columns 1-60), got {len(line.rstrip())}")
        try:
            station_number = int(_field(line, 1, 5))
        except ValueError:
            raise SeaiceError(f"{where}: station number {_field(line, 1, 5)!r} (columns 1-5) is not an integer") \
                from None
        if station_number <= 0:
            raise SeaiceError(f"{where}: station number must be > 0, got {station_number}")
        if station_number in seen:
            raise SeaiceError(f"{where}: station {station_number} already defined on line {seen[station_number]}")
        seen[station_number] = number
        latitude = _degrees_minutes(_field(line, 41, 45), _field(line, 46, 50), where, "latitude")
        longitude = _degrees_minutes(_field(line, 51, 55), _field(line, 56, 60), where, "longitude")
        if abs(latitude) > 90.0:
            raise SeaiceError(f"{where}: latitude {latitude:.4f}° is outside [-90°, 90°]")
        if abs(longitude) > 360.0:
            raise SeaiceError(f"{where}: longitude {longitude:.4f}° is outside [-360°, 360°]")
        stations.append(Station(station_number, _field(line, 11, 40), latitude, longitude))
    return stations


def _format_degrees_minutes(value: float) -> tuple[str, str]:
    total_minutes = round(abs(value) * 60.0, 2)
    degrees, minutes = divmod(total_minutes, 60.0)
    sign = "-" if value < 0 else ""
    return f"{sign}{int(degrees)}", f"{minutes:.2f}".rstrip("0").rstrip(".")


def write_agrid(path: str | os.PathLike, stations) -> Path:
    """Write stations in the AGRID layout (minutes to 0.01'), atomically."""
    lines = []
    for station in stations:
        if not 0 < station.number <= 99999:
            raise SeaiceError(f"station {station.number}: number must be 1-99999 to fit columns 1-5")
        lat_d, lat_m = _format_degrees_minutes(station.latitude_deg)
        lon_d, lon_m = _format_degrees_minutes(station.longitude_deg)
        lines.append(f"{station.number:>5}{'':5}{station.name[:30]:<30}{lat_d:>5}{lat_m:>5}{lon_d:>5}{lon_m:>5}")
    with atomic_path(path) as temporary:
        temporary.write_text("\n".join(lines) + "\n")
    return Path(path)


def read_measurements(path: str | os.PathLike, catalogue: list[Station] | None = None) -> list[Measurement]:
    """Read control-point measurements from a CSV file in the package's one control-point dialect.

    Columns (a header row; UTF-8, with or without a byte-order mark; any order; other columns are ignored):

    * ``id``: the point's identifier (unique in the file);
    * ``pixel``, ``scan``: where the point was measured on the image, 1-based pixel (along a scan line) and scan
      line, fractional allowed;
    * ``latitude_deg``, ``longitude_deg``: its known position, decimal degrees (latitude within ±90°, longitude
      within [-180°, 360°)); left out (or blank on a row) when ``catalogue`` gives the station of that number;
    * ``sigma_m`` (optional): the ground standard deviation of the known position, metres (blank: not given;
      ``seaice rectify`` then uses ``--sigma``);
    * ``name`` (optional): the station's name, for the reports.

    This is what ``seaice simulate lancaster`` writes beside each image
    (:func:`~seaice_jax.io.sequence.write_sequence`) and what a sequence project's ``control`` file is, so a
    simulated image's control points go straight to ``seaice rectify``. Older files still read: ``lat``/``lon``,
    ``latitude``/``longitude``, ``lat_deg``/``lon_deg`` for the position, and ``sigma_km`` (kilometres) for the σ.
    The AGRID catalogue is a different file (:func:`read_agrid`).

    Raises:
        SeaiceError: naming the file and line (and column) at fault, before anything is fitted or written.
    """
    by_number = {str(s.number): s for s in catalogue or []}
    check_input_file(Path(path))
    try:
        return _read_measurements(path, by_number, catalogue)
    except UnicodeDecodeError as error:
        raise SeaiceError(f"{path}: not UTF-8 text (byte {error.start}: {error.reason}); save it as UTF-8") from None
    except csv.Error as error:
        raise SeaiceError(f"{path}: not a readable CSV table ({error})") from None


def _dialect_columns(path, fieldnames) -> dict:
    """``{the dialect's bare column name: the file's column}``, refusing a column given under two names."""
    columns: dict = {}
    for field in fieldnames or []:
        if field is None:
            continue
        bare = bare_column(field)
        name = _ALIASES.get(bare, bare)
        if name in columns and columns[name] != field:
            raise SeaiceError(f"{path}, line 1: columns {columns[name]!r} and {field!r} both give {name}; keep one")
        columns[name] = field
    return columns


def _read_measurements(path, by_number: dict, catalogue) -> list[Measurement]:
    with open(path, newline="", encoding="utf-8-sig") as stream:
        reader = csv.DictReader(stream)
        columns = _dialect_columns(path, reader.fieldnames)
        required = ["id", "pixel", "scan"] + ([] if catalogue else ["latitude", "longitude"])
        missing = [f"{c}_deg" if c in ("latitude", "longitude") else c for c in required if c not in columns]
        if missing:
            raise SeaiceError(f"{path}, line 1: missing column(s) {', '.join(missing)} "
                              f"(have {', '.join(sorted(columns.values())) or 'none'})")
        measurements, seen = [], {}
        for line_number, raw in enumerate(reader, start=2):
            where = f"{path}, line {line_number}"
            if any((v or "").strip() for v in raw.get(None) or ()):
                raise SeaiceError(f"{where}: more values than the header's {len(reader.fieldnames or [])} columns")
            row = {name: raw.get(field) or "" for name, field in columns.items()}
            point = row["id"].strip()
            if not point:
                raise SeaiceError(f"{where}: empty id")
            if point in seen:
                raise SeaiceError(f"{where}: point {point} already measured on line {seen[point]}")
            seen[point] = line_number
            measurements.append(_measurement(row, columns, point, where, by_number, line_number))
    return measurements


def _measurement(row: dict, columns: dict, point: str, where: str, by_number: dict, line: int) -> Measurement:
    """One measurement row: its own position (and name) or the catalogue station's; latitude within ±90°; σ > 0."""
    def number(name):
        return finite_number(row[name].strip(), columns[name].strip(), where)

    if row.get("latitude", "").strip() != "":
        latitude, longitude = number("latitude"), number("longitude")
        name = row.get("name", "").strip()
    elif point in by_number:
        station = by_number[point]
        latitude, longitude, name = station.latitude_deg, station.longitude_deg, station.name
    else:
        raise SeaiceError(f"{where}: point {point} has no lat/lon and is not in the station catalogue")
    if abs(latitude) > 90.0:
        raise SeaiceError(f"{where}: point {point} latitude {latitude}° is outside [-90°, 90°]")
    if not -180.0 <= longitude < 360.0:
        raise SeaiceError(f"{where}: point {point} longitude {longitude}° is outside [-180°, 360°)")
    sigma = None
    if row.get("sigma_m", "").strip():
        sigma = number("sigma_m") * (1000.0 if bare_column(columns["sigma_m"]) == "sigma_km" else 1.0)
        if sigma <= 0:
            raise SeaiceError(f"{where}: point {point} {columns['sigma_m']} must be > 0")
    return Measurement(point, name, number("pixel"), number("scan"), latitude, longitude, sigma, line)


def control_points(measurements: list[Measurement], default_sigma_km: float = 1.0) -> ControlPoints:
    """Measurements as :class:`ControlPoints` (σ from each measurement, else ``default_sigma_km``, km)."""
    if not measurements:
        raise SeaiceError("no control-point measurements")
    if not (np.isfinite(default_sigma_km) and default_sigma_km > 0):
        raise SeaiceError(f"--sigma (default_sigma_km) must be > 0, got {default_sigma_km}")
    return ControlPoints.from_degrees(
        [m.pixel for m in measurements], [m.scan for m in measurements],
        [m.latitude_deg for m in measurements], [m.longitude_deg for m in measurements],
        [default_sigma_km if m.sigma_m is None else m.sigma_m / 1000.0 for m in measurements],
        [m.id for m in measurements])


def check_in_image(measurements: list[Measurement], n_pixels: int, n_scans: int, path,
                   options: str = " (--pixels, --scans)") -> None:
    """Refuse measurements outside the image of ``n_pixels`` pixels by ``n_scans`` scan lines (1-based, as the
    1985 images are counted: from 0.5 to ``n + 0.5`` covers every pixel's area).

    Args:
        options: appended to the message: what sets the image's size.

    Raises:
        SeaiceError: naming the file, the line, the point and its pixel/scan.
    """
    for m in measurements:
        if not (0.5 <= m.pixel <= n_pixels + 0.5 and 0.5 <= m.scan <= n_scans + 0.5):
            where = f"{path}, line {m.line}" if m.line else f"{path}"
            raise SeaiceError(f"{where}: point {m.id} at pixel {m.pixel}, scan {m.scan} is outside the image of "
                              f"{n_pixels} pixels x {n_scans} scan lines{options}")
