"""Floe position records (source 001, the ICE module and its buffer files), in CSV.

One record per floe per image: ``floe_id, time, image, pixel, scan, latitude_deg, longitude_deg`` (time ISO 8601
UTC, pixel and scan 1-based fractional image coordinates, latitude and longitude in degrees; ``latitude`` and
``longitude`` without the unit are read too: :func:`~seaice_jax.files.bare_column`); records of automatic tracking
also carry ``tracking_sigma_x_m, tracking_sigma_y_m, correlation`` (:data:`TRACKING_COLUMNS`: the σ along the
grid's x and y axes and the peak correlation of the tracked step that reached the fix, ``nan`` at a floe's first
fix). Reading validates what the 1985 buffer check did, and names the file and line of the first record at fault:

* every column present, numbers finite, latitude within ±90°, longitude within ±180°;
* a valid date and time;
* the image known (when the caller lists the images of the sequence);
* no floe twice in one image (duplicate ids);
* each floe's records in increasing time.
"""

import csv
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seaice_jax.errors import SeaiceError
from seaice_jax.files import bare_column, write_csv
from seaice_jax.timefmt import format_time, parse_time, seconds_since, time_after

COLUMNS = ("floe_id", "time", "image", "pixel", "scan", "latitude", "longitude")
TRACKING_COLUMNS = ("tracking_sigma_x_m", "tracking_sigma_y_m", "correlation")
"""Optional columns of tracked records, read when all are present."""


@dataclass(frozen=True)
class FloeRecords:
    """Floe positions, one row per floe per image (angles in radians, times in s since ``epoch``).

    Attributes:
        floe, image: ``(n,)`` str ids. time: ``(n,)`` s. pixel, scan: ``(n,)``. latitude, longitude: ``(n,)`` rad.
        epoch: ISO 8601 UTC of time 0. lines: ``(n,)`` the file line of each record (0 if not from a file).
        tracking_sigma: ``(n, 2)`` m along the tracking grid's x and y, σ of the tracked step that reached each fix;
            correlation: ``(n,)`` its peak normalised cross-correlation (both NaN at a floe's first fix; ``None``:
            records not from automatic tracking).
    """

    floe: np.ndarray
    time: np.ndarray
    image: np.ndarray
    pixel: np.ndarray
    scan: np.ndarray
    latitude: np.ndarray
    longitude: np.ndarray
    epoch: str = "1970-01-01T00:00:00Z"
    lines: np.ndarray | None = None
    tracking_sigma: np.ndarray | None = None
    correlation: np.ndarray | None = None

    def __len__(self):
        return self.floe.size


def _parse_record(row: dict, where: str, known):
    """One record's ``(floe, time, image, [pixel, scan, latitude, longitude])``, checked: a floe id, a valid date,
    finite numbers, latitude within ±90° and longitude within [-180°, 360°), a known image (``known``: ``None``
    for any)."""
    floe, image = (row["floe_id"] or "").strip(), (row["image"] or "").strip()
    if not floe:
        raise SeaiceError(f"{where}: empty floe_id")
    try:
        moment = parse_time(row["time"])
    except ValueError:
        raise SeaiceError(f"{where}: floe {floe}: invalid date {row['time']!r} (ISO 8601 expected, e.g. "
                          "1983-03-08T14:05:00Z)") from None
    numbers = []
    for name in ("pixel", "scan", "latitude", "longitude"):
        try:
            value = float(row[name])
        except (TypeError, ValueError):
            raise SeaiceError(f"{where}: floe {floe}: {name} {row[name]!r} is not a number") from None
        if not np.isfinite(value):
            raise SeaiceError(f"{where}: floe {floe}: {name} is not finite")
        numbers.append(value)
    if abs(numbers[2]) > 90 or not -180 <= numbers[3] < 360:
        raise SeaiceError(f"{where}: floe {floe}: position ({numbers[2]}, {numbers[3]}) outside latitude [-90°, 90°] "
                          "/ longitude [-180°, 360°)")
    if known is not None and image not in known:
        raise SeaiceError(f"{where}: floe {floe}: unknown image {image!r} (known: {', '.join(sorted(known))})")
    return floe, moment, image, numbers


def read_records(path: str | os.PathLike, images=None, epoch: str | None = None) -> FloeRecords:
    """Read and validate a floe record CSV.

    Args:
        images: the known image ids (``None``: any).
        epoch: ISO 8601 time 0 of the returned times (default: the earliest record).

    Raises:
        SeaiceError: naming the file and line (and floe) of the first bad record.
    """
    path = Path(path)
    if not path.is_file():
        raise SeaiceError(f"{path}: {'not a regular file' if path.exists() else 'file not found'}")
    try:
        with open(path, newline="", encoding="utf-8-sig") as stream:
            reader = csv.DictReader(stream)
            reader.fieldnames = [bare_column(c) for c in reader.fieldnames or []]
            missing = [c for c in COLUMNS if c not in reader.fieldnames]
            if missing:
                raise SeaiceError(f"{path}: missing column(s) {', '.join(missing)} (need {', '.join(COLUMNS)})")
            rows = list(reader)
    except UnicodeDecodeError as error:
        raise SeaiceError(f"{path}: not UTF-8 text (byte {error.start}: {error.reason}); save it as UTF-8") from None
    except csv.Error as error:
        raise SeaiceError(f"{path}: not a readable CSV table ({error})") from None
    if not rows:
        raise SeaiceError(f"{path}: no records")
    known = None if images is None else set(images)
    tracked = all(c in reader.fieldnames for c in TRACKING_COLUMNS)
    parsed, seen, last, tracking = [], {}, {}, []
    for k, row in enumerate(rows):
        line = k + 2  # the header is line 1
        where = f"{path}, line {line}"
        floe, moment, image, numbers = _parse_record(row, where, known)
        if (floe, image) in seen:
            raise SeaiceError(f"{where}: floe {floe} appears twice in image {image} (first at line "
                              f"{seen[(floe, image)]}): duplicate id")
        seen[(floe, image)] = line
        if floe in last and moment <= last[floe][0]:
            raise SeaiceError(f"{where}: floe {floe}: time {format_time(moment)} is not after its previous record "
                              f"(line {last[floe][1]}, {format_time(last[floe][0])}): dates must increase")
        last[floe] = (moment, line)
        parsed.append((floe, moment, image, *numbers, line))
        if tracked:
            tracking.append([_optional_number(row, name, where, floe) for name in TRACKING_COLUMNS])
    epoch = epoch or format_time(min(p[1] for p in parsed))
    columns = list(zip(*parsed, strict=True))
    tracking_values = np.array(tracking, float).reshape(-1, 3) if tracked else None
    return FloeRecords(np.array(columns[0]), seconds_since(epoch, columns[1]), np.array(columns[2]),
                       np.array(columns[3]), np.array(columns[4]), np.radians(columns[5]), np.radians(columns[6]),
                       epoch, np.array(columns[7]),
                       None if tracking_values is None else tracking_values[:, :2],
                       None if tracking_values is None else tracking_values[:, 2])


def _optional_number(row: dict, name: str, where: str, floe: str) -> float:
    """A number of an optional column: empty or ``nan`` is NaN; anything else not a number is an error."""
    text = (row[name] or "").strip()
    try:
        return float(text) if text else np.nan
    except ValueError:
        raise SeaiceError(f"{where}: floe {floe}: {name} {row[name]!r} is not a number") from None


def write_records(path: str | os.PathLike, records: FloeRecords) -> Path:
    """Write floe records as CSV (atomically), in the format :func:`read_records` reads."""
    times = [time_after(records.epoch, t) for t in records.time]
    tracking = {}
    if records.tracking_sigma is not None and records.correlation is not None:
        tracking = dict(zip(TRACKING_COLUMNS, (records.tracking_sigma[:, 0], records.tracking_sigma[:, 1],
                                               records.correlation), strict=True))
    return write_csv(path, {"floe_id": records.floe, "time": np.array(times), "image": records.image,
                            "pixel": records.pixel, "scan": records.scan,
                            "latitude_deg": np.degrees(records.latitude),
                            "longitude_deg": np.degrees(records.longitude), **tracking},
                     float_format="%.10g")
