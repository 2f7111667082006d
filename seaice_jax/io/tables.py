"""CSV tables with a header row, validated: every error names the file, line and column."""

import csv
import math
from pathlib import Path

from seaice_jax.errors import SeaiceError
from seaice_jax.files import bare_column

MAX_TABLE_BYTES = 512 * 2**20
"""Largest CSV file read (bytes): a bigger one (or a device such as ``/dev/zero``) is refused before reading."""


def project_file(base: Path, value, where: str, key: str, allow_outside: bool = False) -> Path:
    """A file named in a project file: a string, resolved relative to the project's folder ``base`` and kept inside
    it unless ``allow_outside``.

    Raises:
        SeaiceError: naming ``where`` and ``key``.
    """
    if not isinstance(value, str) or not value.strip():
        raise SeaiceError(f"{where}: {key} must be a file name (a string), got {value!r}")
    path = (base / value).resolve()
    if not allow_outside and not path.is_relative_to(base.resolve()):
        raise SeaiceError(f"{where}: {key} = {value!r} is outside the project's folder {base} (allow_outside=True "
                          "allows it)")
    return path


def check_input_file(path: Path, max_bytes: int = MAX_TABLE_BYTES) -> None:
    """Refuse a missing input, one that is not a regular file, or one larger than ``max_bytes``.

    Raises:
        SeaiceError: naming the file.
    """
    if not path.exists():
        raise SeaiceError(f"{path}: file not found")
    if not path.is_file():
        raise SeaiceError(f"{path}: not a regular file")
    size = path.stat().st_size
    if size > max_bytes:
        raise SeaiceError(f"{path}: {size / 2**20:.0f} MiB, larger than the {max_bytes / 2**20:.0f} MiB a table may "
                          "have")


def read_table(path: Path, columns, numeric=None) -> list[tuple[int, dict]]:
    """The rows of a CSV (UTF-8, with or without a byte-order mark) as ``(line number, row dict)``, checking that
    the header has ``columns`` and that the ``numeric`` columns are finite numbers (converted to float). A degree
    column may carry its unit (``lat_deg`` for ``lat``: :func:`~seaice_jax.files.bare_column`).

    Raises:
        SeaiceError: naming the file and line (and column) at fault.
    """
    path = Path(path)
    check_input_file(path)
    try:
        with open(path, newline="", encoding="utf-8-sig") as stream:
            return _rows(path, csv.DictReader(stream), columns, numeric)
    except UnicodeDecodeError as error:
        raise SeaiceError(f"{path}: not UTF-8 text (byte {error.start}: {error.reason}); save it as UTF-8") from None
    except csv.Error as error:
        raise SeaiceError(f"{path}: not a readable CSV table ({error})") from None


def finite_number(text: str, column: str, where: str) -> float:
    """``text`` as a finite float, else a :class:`SeaiceError` naming ``where`` (file and line) and the column."""
    try:
        value = float(text)
    except ValueError:
        raise SeaiceError(f"{where}: column {column!r} value {text!r} is not a number") from None
    if not math.isfinite(value):
        raise SeaiceError(f"{where}: column {column!r} value {text!r} is not finite")
    return value


def _rows(path: Path, reader: csv.DictReader, columns, numeric) -> list[tuple[int, dict]]:
    header = [bare_column(c) for c in reader.fieldnames or []]
    missing = [c for c in columns if c not in header]
    if missing:
        raise SeaiceError(f"{path}, line 1: missing column(s) {', '.join(missing)}")
    rows = []
    for line, raw in enumerate(reader, start=2):
        if any(v.strip() for v in raw.get(None) or ()):
            raise SeaiceError(f"{path}, line {line}: more values than the header's {len(header)} columns")
        row = {bare_column(k): (v or "").strip() for k, v in raw.items() if k is not None}
        for column in numeric or ():
            row[column] = finite_number(row[column], column, f"{path}, line {line}")
        rows.append((line, row))
    return rows
