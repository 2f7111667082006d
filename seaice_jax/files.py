"""Atomic file output: every file is written under a temporary name and renamed, so an interrupted run never
leaves a partial file that looks complete."""

import contextlib
import csv
import json
import os
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike


def current_umask() -> int:
    """The process's file-creation mask (read without changing it for longer than one call)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` only if the block succeeds."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    os.close(handle)
    os.chmod(temporary, 0o666 & ~current_umask())
    try:
        yield Path(temporary)
        os.replace(temporary, path)
    finally:
        if os.path.exists(temporary):
            os.unlink(temporary)


DEGREE_COLUMNS = ("lat", "lon", "latitude", "longitude")
"""CSV columns in degrees. Every CSV the package writes names each number's unit in its column (``x_m``,
``time_s``, ``speed_m_s``, ``divergence_per_s``, ``lat_deg``; pixel, scan line and count columns are their own unit,
w-tests and redundancy numbers have none); the readers take these columns with or without ``_deg``
(:func:`bare_column`), so that files written before the unit was added, and hand-made ones, still read."""


def bare_column(name: str) -> str:
    """The name a reader uses for CSV column ``name``: ``lat_deg`` -> ``lat`` for the :data:`DEGREE_COLUMNS`, any
    other name as it is (stripped of blanks)."""
    name = name.strip()
    bare = name.removesuffix("_deg")
    return bare if bare in DEGREE_COLUMNS else name


def write_csv(path: str | os.PathLike, columns: Mapping[str, ArrayLike], float_format: str = "%.9g") -> Path:
    """Write equal-length ``columns`` (name -> values) to a CSV with a header row, atomically (column names carry
    their units: :data:`DEGREE_COLUMNS`).

    Raises:
        ValueError: naming the column whose length differs.
    """
    names = list(columns)
    values = [np.asarray(columns[name]).reshape(-1) for name in names]
    lengths = {name: v.size for name, v in zip(names, values, strict=True)}
    if len(set(lengths.values())) > 1:
        raise ValueError(f"{path}: columns differ in length: {lengths}")

    def cell(x):
        return float_format % x if isinstance(x, float | np.floating) else str(x)

    with atomic_path(path) as temporary, open(temporary, "w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(names)
        for row in zip(*values, strict=True):
            writer.writerow([cell(x) for x in row])
    return Path(path)


def write_json(path: str | os.PathLike, data) -> Path:
    """Write ``data`` as indented JSON, atomically."""
    with atomic_path(path) as temporary:
        temporary.write_text(json.dumps(data, indent=2) + "\n")
    return Path(path)


def write_geojson(path: str | os.PathLike, features) -> Path:
    """Write a GeoJSON FeatureCollection (RFC 7946: coordinates are [longitude, latitude] degrees), atomically."""
    return write_json(path, {"type": "FeatureCollection", "features": list(features)})
