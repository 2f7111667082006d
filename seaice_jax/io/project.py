"""Radar block projects: a TOML file naming coverages and strips, with CSV files beside it.

```toml
[project]
name = "aidjex"
map_centre_deg = [74.8, -147.5]      # tangent-plane map centre (latitude, longitude)

[[coverage]]
name = "day 0"
epoch_s = 0.0
measurements = "c1_measurements.csv"  # point,strip,x_mm,y_mm
control = "c1_control.csv"            # point,lat,lon,sigma_m   (optional)

[[coverage.strip]]
name = "S01"
navigation = "c1_S01_navigation.csv"  # time_s,x_m,y_m,z_m,vx_m_s,vy_m_s,vz_m_s,altitude_m (ECEF)
time_marks = "c1_S01_marks.csv"       # x_mm,time_s
nadir = "c1_S01_nadir.csv"            # x_mm,y_mm
sweep_delay_mm = 10.0
range_scale_m_per_mm = 250.0
look_side = "right"
```

Every error names the file and line; reading never writes anything.
"""

import csv
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.projections import TangentPlane
from seaice_jax.io.files import atomic_path, write_csv
from seaice_jax.sensors.slar import check_time_marks
from seaice_jax.sensors.strips import Measurements, StripRecord

NAVIGATION_COLUMNS = ("time_s", "x_m", "y_m", "z_m", "vx_m_s", "vy_m_s", "vz_m_s", "altitude_m")


@dataclass(frozen=True)
class ProjectCoverage:
    """One coverage of a project: strips, measurements (point indices into ``Project.point_ids``), control."""

    name: str
    epoch: float
    strips: list
    measurements: Measurements
    control: dict  # point index -> (x, y, sigma) map metres


@dataclass(frozen=True)
class Project:
    """A radar block project read from TOML + CSV."""

    name: str
    plane: TangentPlane
    point_ids: tuple[str, ...]
    coverages: tuple[ProjectCoverage, ...]


def _read_table(path: Path, columns, numeric=None):
    """Rows of a CSV as dicts, checking the header; yields (line number, row)."""
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


def _numbers(path, columns):
    rows = _read_table(path, columns, columns)
    return np.array([[row[c] for c in columns] for _, row in rows], float).reshape(-1, len(columns)), rows


def read_project(path: str | os.PathLike) -> Project:
    """Read and validate a project (see the module docstring)."""
    path = Path(path)
    try:
        config = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise SeaiceError(f"{path}: file not found") from None
    except tomllib.TOMLDecodeError as error:
        raise SeaiceError(f"{path}: {error}") from None
    base = path.parent
    project = config.get("project", {})
    centre = project.get("map_centre_deg")
    if not (isinstance(centre, list) and len(centre) == 2):
        raise SeaiceError(f"{path}: [project] map_centre_deg must be [latitude, longitude]")
    plane = TangentPlane(np.radians(centre[0]), np.radians(centre[1]))
    ids: dict[str, int] = {}
    coverages = []
    for c, cov in enumerate(config.get("coverage", [])):
        label = f"{path}: coverage {cov.get('name', c + 1)!r}"
        strips, strip_index = [], {}
        for s, strip in enumerate(cov.get("strip", [])):
            name = strip.get("name", f"strip {s + 1}")
            for key in ("navigation", "time_marks", "nadir", "sweep_delay_mm", "range_scale_m_per_mm"):
                if key not in strip:
                    raise SeaiceError(f"{label} strip {name!r}: missing {key}")
            navigation, _ = _numbers(base / strip["navigation"], NAVIGATION_COLUMNS)
            marks, mark_rows = _numbers(base / strip["time_marks"], ("x_mm", "time_s"))
            for k in range(1, marks.shape[0]):
                if marks[k, 0] <= marks[k - 1, 0] or marks[k, 1] <= marks[k - 1, 1]:
                    raise SeaiceError(f"{base / strip['time_marks']}, line {mark_rows[k][0]}: time mark does not "
                                      f"increase (x {marks[k, 0]} mm, t {marks[k, 1]} s after x "
                                      f"{marks[k - 1, 0]} mm, t {marks[k - 1, 1]} s)")
            check_time_marks(marks[:, 0], marks[:, 1], str(base / strip["time_marks"]))
            nadir, _ = _numbers(base / strip["nadir"], ("x_mm", "y_mm"))
            look_side = strip.get("look_side", "right")
            if look_side not in ("right", "left"):
                raise SeaiceError(f"{label} strip {name!r}: look_side must be 'right' or 'left'")
            strip_index[name] = s
            strips.append(StripRecord(name, float(marks[0, 1]), float(marks[-1, 1]), navigation[:, 0],
                                      navigation[:, 1:4], navigation[:, 4:7], navigation[:, 7], marks[:, 0],
                                      marks[:, 1], nadir[:, 0], nadir[:, 1], float(strip["sweep_delay_mm"]),
                                      float(strip["range_scale_m_per_mm"]), look_side))
        if "measurements" not in cov:
            raise SeaiceError(f"{label}: missing measurements")
        measurement_path = base / cov["measurements"]
        point, strip_of, x, y, seen = [], [], [], [], {}
        for line, row in _read_table(measurement_path, ("point", "strip", "x_mm", "y_mm"), ("x_mm", "y_mm")):
            if row["strip"] not in strip_index:
                raise SeaiceError(f"{measurement_path}, line {line}: unknown strip {row['strip']!r} (coverage has "
                                  f"{', '.join(strip_index) or 'no strips'})")
            key = (row["point"], row["strip"])
            if key in seen:
                raise SeaiceError(f"{measurement_path}, line {line}: point {row['point']} already measured on strip "
                                  f"{row['strip']} (line {seen[key]})")
            seen[key] = line
            point.append(ids.setdefault(row["point"], len(ids)))
            strip_of.append(strip_index[row["strip"]])
            x.append(row["x_mm"])
            y.append(row["y_mm"])
        control = {}
        if cov.get("control"):
            control_path = base / cov["control"]
            for line, row in _read_table(control_path, ("point", "lat", "lon", "sigma_m"), ("lat", "lon", "sigma_m")):
                if abs(row["lat"]) > 90 or not row["sigma_m"] > 0:
                    raise SeaiceError(f"{control_path}, line {line}: point {row['point']}: latitude within ±90° and "
                                      "sigma_m > 0 required")
                cx, cy = plane.forward(np.radians(row["lat"]), np.radians(row["lon"]))
                control[ids.setdefault(row["point"], len(ids))] = (float(cx), float(cy), row["sigma_m"])
        coverages.append(ProjectCoverage(cov.get("name", f"coverage {c + 1}"), float(cov.get("epoch_s", 0.0)), strips,
                                         Measurements(np.array(point, int), np.array(strip_of, int), np.array(x),
                                                      np.array(y)), control))
    if not coverages:
        raise SeaiceError(f"{path}: no [[coverage]] tables")
    return Project(project.get("name", path.stem), plane, tuple(ids), tuple(coverages))


def write_project(scenario, out_dir: str | os.PathLike) -> Path:
    """Write a simulated :class:`~seaice_jax.simulate.aircraft.Scenario` as a project (plus ``truth.csv``)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ids = [f"P{i + 1:04d}" for i in range(len(scenario.kinds))]
    centre = [float(np.degrees(scenario.plane.latitude)), float(np.degrees(scenario.plane.longitude))]
    lines = ["[project]", f'name = "{scenario.name}"', f"map_centre_deg = [{centre[0]!r}, {centre[1]!r}]", ""]
    truth_rows = {"point": [], "coverage": [], "kind": [], "lat": [], "lon": [], "x_m": [], "y_m": []}
    for c, coverage in enumerate(scenario.coverages, start=1):
        m = coverage.measurements
        write_csv(out / f"c{c}_measurements.csv", {"point": [ids[p] for p in m.point],
                                                    "strip": [coverage.strips[s].name for s in m.strip],
                                                    "x_mm": m.x, "y_mm": m.y})
        lat_c, lon_c = [], []
        for point in coverage.control:
            lat, lon = scenario.plane.inverse(coverage.control[point][0], coverage.control[point][1])
            lat_c.append(float(np.degrees(lat)))
            lon_c.append(float(np.degrees(lon)))
        write_csv(out / f"c{c}_control.csv", {"point": [ids[p] for p in coverage.control], "lat": lat_c,
                                               "lon": lon_c, "sigma_m": [v[2] for v in coverage.control.values()]})
        lines += ["[[coverage]]", f'name = "{coverage.name}"', f"epoch_s = {coverage.epoch!r}",
                  f'measurements = "c{c}_measurements.csv"', f'control = "c{c}_control.csv"', ""]
        for strip in coverage.strips:
            stem = f"c{c}_{strip.name}"
            write_csv(out / f"{stem}_navigation.csv", dict(zip(NAVIGATION_COLUMNS, (
                strip.record_times, *strip.record_positions.T, *strip.record_velocities.T, strip.record_altitudes),
                strict=True)), float_format="%.12g")
            write_csv(out / f"{stem}_marks.csv", {"x_mm": strip.mark_x, "time_s": strip.mark_times},
                      float_format="%.12g")
            write_csv(out / f"{stem}_nadir.csv", {"x_mm": strip.nadir_x, "y_mm": strip.nadir_y},
                      float_format="%.12g")
            lines += ["[[coverage.strip]]", f'name = "{strip.name}"', f'navigation = "{stem}_navigation.csv"',
                      f'time_marks = "{stem}_marks.csv"', f'nadir = "{stem}_nadir.csv"',
                      f"sweep_delay_mm = {strip.sweep_delay!r}", f"range_scale_m_per_mm = {strip.range_scale!r}",
                      f'look_side = "{strip.look_side}"', ""]
        lat, lon = scenario.plane.inverse(coverage.truth[:, 0], coverage.truth[:, 1])
        truth_rows["point"] += ids
        truth_rows["coverage"] += [coverage.name] * len(ids)
        truth_rows["kind"] += list(scenario.kinds)
        truth_rows["lat"] += list(np.degrees(np.asarray(lat)))
        truth_rows["lon"] += list(np.degrees(np.asarray(lon)))
        truth_rows["x_m"] += list(coverage.truth[:, 0])
        truth_rows["y_m"] += list(coverage.truth[:, 1])
    write_csv(out / "truth.csv", truth_rows, float_format="%.12g")
    with atomic_path(out / "project.toml") as temporary:
        temporary.write_text("\n".join(lines))
    return out / "project.toml"
