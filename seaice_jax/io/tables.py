"""CSV tables with a header row, validated: every error names the file, line and column."""

import csv
from pathlib import Path

from seaice_jax.errors import SeaiceError


def read_table(path: Path, columns, numeric=None) -> list[tuple[int, dict]]:
    """The rows of a CSV as ``(line number, row dict)``, checking that the header has ``columns`` and that the
    ``numeric`` columns are numbers (converted to float).

    Raises:
        SeaiceError: naming the file and line (and column) at fault.
    """
    if not path.exists():
        raise SeaiceError(f"{path}: file not found")
    with open(path, newline="") as stream:
        reader = csv.DictReader(stream)
        header = [c.strip() for c in reader.fieldnames or []]
        missing = [c for c in columns if c not in header]
        if missing:
            raise SeaiceError(f"{path}, line 1: missing column(s) {', '.join(missing)}")
        rows = []
        for line, raw in enumerate(reader, start=2):
            row = {k.strip(): (v or "").strip() for k, v in raw.items() if k is not None}
            for column in numeric or ():
                try:
                    row[column] = float(row[column])
                except ValueError:
                    raise SeaiceError(f"{path}, line {line}: column {column!r} value {row[column]!r} is not a "
                                      "number") from None
            rows.append((line, row))
    return rows
