"""Radar block projects: a TOML file naming coverages and strips, with CSV files beside it.

```toml
[project]
name = "aidjex"
map_centre_deg = [74.8, -147.5]      # tangent-plane map centre (latitude, longitude)
surface = "ice"                      # or "land": points do not move between coverages

[[coverage]]
name = "day 0"
epoch_s = 0.0
measurements = "c1_measurements.csv"  # point,strip,kind,x_mm,y_mm   (comparator x', y')
control = "c1_control.csv"            # point,lat_deg,lon_deg,sigma_m   (optional; lat, lon also read)

[[coverage.strip]]
name = "S01"
navigation = "c1_S01_navigation.csv"  # time_s,x_m,y_m,z_m,vx_m_s,vy_m_s,vz_m_s,altitude_m (ECEF)
time_marks = "c1_S01_marks.csv"       # x_mm,y_mm,time_s   (comparator x', y' of each time mark)
range_reference_mm = [[20.0, 35.0], [470.0, 38.9]]  # two comparator points on the range reference line
far_range_mm = [19.6, 85.0]           # any comparator point at larger range than the reference line
sweep_delay_mm = 10.0
range_scale_m_per_mm = 250.0
look_side = "right"
```

Measurements are comparator coordinates x', y' on the film; each strip's time-mark line and range reference line
define its image frame (:class:`~seaice_jax.sensors.slar.ImageFrame`): x along the marks in the direction of
increasing time, y from the range reference line toward far range. ``kind`` is the point's role: ``tie`` (ties
strips of one coverage), ``drift`` (a feature measured in more than one coverage; it may tie strips too),
``control`` (known position, listed in the control file) or ``nadir`` (a nadir return, for the calibration of
sweep delay and range scale against the altimeter; one strip only).

Every error names the file and line; reading never writes anything.
"""

import itertools
import os
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from seaice_jax.errors import SeaiceError
from seaice_jax.files import atomic_path, write_csv
from seaice_jax.geometry.projections import TangentPlane
from seaice_jax.io.tables import check_input_file, project_file, read_table
from seaice_jax.outputs import output_folder
from seaice_jax.sensors.slar import ImageFrame, check_time_marks
from seaice_jax.sensors.strips import Coverage, Measurements, StripRecord

NAVIGATION_COLUMNS = ("time_s", "x_m", "y_m", "z_m", "vx_m_s", "vy_m_s", "vz_m_s", "altitude_m")
KINDS = ("tie", "drift", "control", "nadir")
_MARK_OFFSET = -3.0  # mm: where the simulated films carry their time marks, beside the range reference line


@dataclass(frozen=True)
class Project:
    """A radar block project read from TOML + CSV."""

    name: str
    plane: TangentPlane
    point_ids: tuple[str, ...]
    point_kinds: tuple[str, ...]
    coverages: tuple[Coverage, ...]
    surface: str = "ice"


def _number(table: dict, key: str, where: str, positive: bool = False, non_negative: bool = False) -> float:
    """A finite number of a TOML table (``positive``: > 0; ``non_negative``: >= 0), or an error naming the key."""
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
        raise SeaiceError(f"{where}: {key} must be a finite number, got {value!r}")
    if positive and not value > 0:
        raise SeaiceError(f"{where}: {key} must be > 0, got {value!r}")
    if non_negative and not value >= 0:
        raise SeaiceError(f"{where}: {key} must be >= 0, got {value!r}")
    return float(value)


def _numbers(path, columns):
    rows = read_table(path, columns, columns)
    return np.array([[row[c] for c in columns] for _, row in rows], float).reshape(-1, len(columns)), rows


def _comparator_point(value, label, key, count=1):
    """A TOML list of ``count`` comparator points [x', y'] as an ``(count, 2)`` array, or an error naming it."""
    points = np.asarray(value if count > 1 else [value], dtype=object)
    if points.shape != (count, 2) or not all(isinstance(v, int | float) for v in points.ravel()):
        shape = "[[x', y'], [x', y']]" if count > 1 else "[x', y']"
        raise SeaiceError(f"{label}: {key} must be {shape} in mm, got {value!r}")
    return points.astype(float)


def _read_strip(strip, s, base, label, allow_outside=False):
    """One ``[[coverage.strip]]`` table -> (name, frame, StripRecord without nadir returns)."""
    if not isinstance(strip, dict):
        raise SeaiceError(f"{label}: strip {s + 1} must be a [[coverage.strip]] table")
    name = str(strip.get("name", f"strip {s + 1}"))
    where = f"{label} strip {name!r}"
    for key in ("navigation", "time_marks", "range_reference_mm", "far_range_mm", "sweep_delay_mm",
                "range_scale_m_per_mm"):
        if key not in strip:
            raise SeaiceError(f"{where}: missing {key}")
    sweep_delay = _number(strip, "sweep_delay_mm", where, non_negative=True)
    range_scale = _number(strip, "range_scale_m_per_mm", where, positive=True)
    navigation_path = project_file(base, strip["navigation"], where, "navigation", allow_outside)
    navigation, navigation_rows = _numbers(navigation_path, NAVIGATION_COLUMNS)
    if navigation.shape[0] < 2:
        raise SeaiceError(f"{navigation_path}: need at least two navigation records")
    for k in range(1, navigation.shape[0]):
        if navigation[k, 0] <= navigation[k - 1, 0]:
            raise SeaiceError(f"{navigation_path}, line {navigation_rows[k][0]}: time_s {navigation[k, 0]} does not "
                              f"increase (previous record {navigation[k - 1, 0]})")
    marks_path = project_file(base, strip["time_marks"], where, "time_marks", allow_outside)
    marks, mark_rows = _numbers(marks_path, ("x_mm", "y_mm", "time_s"))
    if marks.shape[0] < 2:
        raise SeaiceError(f"{marks_path}: need at least two time marks")
    reference = _comparator_point(strip["range_reference_mm"], where, "range_reference_mm", 2)
    far = _comparator_point(strip["far_range_mm"], where, "far_range_mm")[0]
    frame = ImageFrame.from_lines(marks[:, :2], reference, far)
    mark_x = np.asarray(frame.to_image(marks[:, 0], marks[:, 1])[0])
    for k in range(1, marks.shape[0]):
        if mark_x[k] <= mark_x[k - 1] or marks[k, 2] <= marks[k - 1, 2]:
            raise SeaiceError(f"{marks_path}, line {mark_rows[k][0]}: time mark does not increase (x {mark_x[k]:.3f} "
                              f"mm, t {marks[k, 2]} s after x {mark_x[k - 1]:.3f} mm, t {marks[k - 1, 2]} s along "
                              "the time-mark line)")
    check_time_marks(mark_x, marks[:, 2], str(marks_path))
    if marks[0, 2] < navigation[0, 0] or marks[-1, 2] > navigation[-1, 0]:
        raise SeaiceError(f"{marks_path}: time marks {marks[0, 2]}..{marks[-1, 2]} s reach outside the navigation "
                          f"records' span {navigation[0, 0]}..{navigation[-1, 0]} s ({navigation_path})")
    look_side = strip.get("look_side", "right")
    if look_side not in ("right", "left"):
        raise SeaiceError(f"{where}: look_side must be 'right' or 'left'")
    record = StripRecord(name, float(marks[0, 2]), float(marks[-1, 2]), navigation[:, 0], navigation[:, 1:4],
                         navigation[:, 4:7], navigation[:, 7], mark_x, marks[:, 2], np.zeros(0), np.zeros(0),
                         sweep_delay, range_scale, look_side)
    return name, frame, record


def _map_plane_and_surface(path: Path, project: dict) -> tuple[TangentPlane, str]:
    """The ``[project]`` table's map plane and surface (``"ice"`` or ``"land"``)."""
    centre = project.get("map_centre_deg")
    if not (isinstance(centre, list) and len(centre) == 2 and all(
            isinstance(v, int | float) and not isinstance(v, bool) and np.isfinite(v) for v in centre)):
        raise SeaiceError(f"{path}: [project] map_centre_deg must be [latitude, longitude] in degrees, got {centre!r}")
    if not (-90 < centre[0] < 90 and -180 <= centre[1] < 360):
        raise SeaiceError(f"{path}: [project] map_centre_deg {centre!r}: latitude must be within (-90°, 90°) and "
                          "longitude within [-180°, 360°)")
    surface = project.get("surface", "ice")
    if surface not in ("ice", "land"):
        raise SeaiceError(f"{path}: [project] surface must be 'ice' or 'land', got {surface!r}")
    return TangentPlane(np.radians(centre[0]), np.radians(centre[1])), surface


def _check_measurement(row: dict, where: str, strip_index: dict, kinds: dict, seen: dict, nadir_lines: dict,
                       line: int) -> None:
    """One measurement row: a known strip and kind, the same kind as elsewhere, measured once per strip, and a
    nadir return on one strip only (records what it has seen in ``kinds``, ``seen`` and ``nadir_lines``)."""
    if row["strip"] not in strip_index:
        raise SeaiceError(f"{where}: unknown strip {row['strip']!r} (coverage has "
                          f"{', '.join(strip_index) or 'no strips'})")
    if row["kind"] not in KINDS:
        raise SeaiceError(f"{where}: point {row['point']}: kind {row['kind']!r} is not one of {', '.join(KINDS)}")
    first = kinds.setdefault(row["point"], (row["kind"], where))
    if first[0] != row["kind"]:
        raise SeaiceError(f"{where}: point {row['point']} is {row['kind']!r} here but {first[0]!r} at {first[1]}")
    key = (row["point"], row["strip"])
    if key in seen:
        raise SeaiceError(f"{where}: point {row['point']} already measured on strip {row['strip']} "
                          f"(line {seen[key]})")
    if row["kind"] == "nadir":
        if row["point"] in nadir_lines:
            raise SeaiceError(f"{where}: nadir return {row['point']} already measured (line "
                              f"{nadir_lines[row['point']]}); a nadir return belongs to one strip")
        nadir_lines[row["point"]] = line
    seen[key] = line


def _read_measurements(path: Path, strip_index: dict, frames: list, ids: dict, kinds: dict):
    """The measurement CSV of a coverage: its :class:`Measurements` (comparator -> image coordinates), each
    strip's nadir returns ``[(x, y), ...]`` and the line of each control point's first measurement."""
    point, strip_of, x, y, seen, nadir_lines, control_lines = [], [], [], [], {}, {}, {}
    nadir = [[] for _ in frames]
    for line, row in read_table(path, ("point", "strip", "kind", "x_mm", "y_mm"), ("x_mm", "y_mm")):
        _check_measurement(row, f"{path}, line {line}", strip_index, kinds, seen, nadir_lines, line)
        if row["kind"] == "control":
            control_lines.setdefault(row["point"], line)
        j = strip_index[row["strip"]]
        image_x, image_y = (float(v) for v in frames[j].to_image(row["x_mm"], row["y_mm"]))
        if row["kind"] == "nadir":
            nadir[j].append((image_x, image_y))
            continue
        point.append(ids.setdefault(row["point"], len(ids)))
        strip_of.append(j)
        x.append(image_x)
        y.append(image_y)
    return (Measurements(np.array(point, int), np.array(strip_of, int), np.array(x), np.array(y)), nadir,
            control_lines)


def _read_control(path: Path, plane: TangentPlane, ids: dict, kinds: dict) -> dict:
    """The control CSV of a coverage: ``{point index: (x, y, σ)}`` map metres."""
    control, lines = {}, {}
    for line, row in read_table(path, ("point", "lat", "lon", "sigma_m"), ("lat", "lon", "sigma_m")):
        if abs(row["lat"]) > 90 or not -180 <= row["lon"] < 360 or not row["sigma_m"] > 0:
            raise SeaiceError(f"{path}, line {line}: point {row['point']}: latitude within [-90°, 90°], longitude "
                              f"within [-180°, 360°) and sigma_m > 0 required, got lat {row['lat']}, lon "
                              f"{row['lon']}, sigma_m {row['sigma_m']}")
        if row["point"] in lines:
            raise SeaiceError(f"{path}, line {line}: control point {row['point']} already defined on line "
                              f"{lines[row['point']]}")
        lines[row["point"]] = line
        if kinds.get(row["point"], ("control",))[0] != "control":
            raise SeaiceError(f"{path}, line {line}: point {row['point']} is a control point here but "
                              f"{kinds[row['point']][0]!r} at {kinds[row['point']][1]}")
        cx, cy = plane.forward(np.radians(row["lat"]), np.radians(row["lon"]))
        control[ids.setdefault(row["point"], len(ids))] = (float(cx), float(cy), row["sigma_m"])
    return control


def _read_coverage(cov: dict, c: int, path: Path, plane: TangentPlane, ids: dict, kinds: dict,
                   allow_outside: bool = False) -> Coverage:
    """One ``[[coverage]]`` table with its strips, measurements and control points."""
    base, label = path.parent, f"{path}: coverage {cov.get('name', c + 1)!r}"
    strips, frames, strip_index = [], [], {}
    if not isinstance(cov.get("strip", []), list):
        raise SeaiceError(f"{label}: strips must be [[coverage.strip]] tables")
    for s, strip in enumerate(cov.get("strip", [])):
        name, frame, record = _read_strip(strip, s, base, label, allow_outside)
        if name in strip_index:
            raise SeaiceError(f"{label}: strip {name!r} defined twice")
        strip_index[name] = s
        strips.append(record)
        frames.append(frame)
    if "measurements" not in cov:
        raise SeaiceError(f"{label}: missing measurements")
    measurements_path = project_file(base, cov["measurements"], label, "measurements", allow_outside)
    measurements, nadir, control_lines = _read_measurements(measurements_path, strip_index, frames, ids, kinds)
    strips = [replace(strip, nadir_x=np.array([v[0] for v in nadir[j]]), nadir_y=np.array([v[1] for v in nadir[j]]))
              for j, strip in enumerate(strips)]
    control_path = project_file(base, cov["control"], label, "control", allow_outside) if cov.get("control") else None
    control = _read_control(control_path, plane, ids, kinds) if control_path is not None else {}
    for name, line in control_lines.items():  # a control point without a known position would become a tie
        if ids[name] not in control:
            where = (f"the coverage's control file {control_path}" if control_path is not None
                     else f"a control file ({label} gives none)")
            raise SeaiceError(f"{measurements_path}, line {line}: control point {name} is not in {where}: give its "
                              "position there, or measure it as a 'tie' or 'drift' point")
    epoch = _number(cov, "epoch_s", label) if "epoch_s" in cov else 0.0
    return Coverage(str(cov.get("name", f"coverage {c + 1}")), epoch, tuple(strips), measurements, control)


def read_project(path: str | os.PathLike, allow_outside: bool = False) -> Project:
    """Read and validate a project (see the module docstring). The files it names are resolved relative to the
    project file's folder and must lie inside it unless ``allow_outside``.

    Raises:
        SeaiceError: naming the file, line, table or key at fault.
    """
    path = Path(path)
    check_input_file(path)
    try:
        config = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except UnicodeDecodeError as error:
        raise SeaiceError(f"{path}: not UTF-8 text (byte {error.start}: {error.reason}); save it as UTF-8") from None
    except tomllib.TOMLDecodeError as error:
        raise SeaiceError(f"{path}: {error}") from None
    project = config.get("project", {})
    if not isinstance(project, dict) or not isinstance(config.get("coverage", []), list):
        raise SeaiceError(f"{path}: [project] must be a table and coverages [[coverage]] tables")
    plane, surface = _map_plane_and_surface(path, project)
    ids: dict[str, int] = {}
    kinds: dict[str, tuple[str, str]] = {}  # point -> (kind, where it was first given)
    coverages = [_read_coverage(cov, c, path, plane, ids, kinds, allow_outside)
                 for c, cov in enumerate(config.get("coverage", []))]
    if not coverages:
        raise SeaiceError(f"{path}: no [[coverage]] tables")
    for before, after in itertools.pairwise(coverages):
        if after.epoch < before.epoch or (after.epoch == before.epoch and surface == "ice"):
            raise SeaiceError(f"{path}: coverage {after.name!r} epoch_s {after.epoch} is not after coverage "
                              f"{before.name!r} epoch_s {before.epoch} (coverages of drifting ice are listed in "
                              "time order)")
    point_kinds = tuple(kinds.get(p, ("control",))[0] for p in ids)
    return Project(project.get("name", path.stem), plane, tuple(ids), point_kinds, tuple(coverages), surface)


def _point_kinds(scenario):
    """The project kind of every simulated feature: control, drift (seen in more than one coverage) or tie."""
    control = set().union(*(c.control for c in scenario.coverages))
    seen = np.zeros(len(scenario.kinds), int)
    for coverage in scenario.coverages:
        seen[np.unique(coverage.measurements.point)] += 1
    return ["control" if p in control else "drift" if seen[p] > 1 else "tie" for p in range(len(scenario.kinds))]


def write_project(scenario, out_dir: str | os.PathLike, overwrite: bool = False) -> Path:
    """Write a simulated :class:`~seaice_jax.simulate.aircraft.Scenario` as a project (plus ``truth.csv``), as one
    run (:func:`~seaice_jax.outputs.output_folder`; ``overwrite`` replaces an existing folder whole).

    Each film is laid on the comparator turned by a small angle and shifted, as an operator would place it, so
    the comparator coordinates x', y' differ from the image coordinates; the time marks are printed 3 mm beside
    the range reference line.
    """
    with output_folder(out_dir, overwrite) as folder:
        _write_project_files(scenario, folder.path)
    return folder.target / "project.toml"


def _write_project_files(scenario, out: Path) -> None:
    ids = [f"P{i + 1:04d}" for i in range(len(scenario.kinds))]
    kinds = _point_kinds(scenario)
    centre = [float(np.degrees(scenario.plane.latitude)), float(np.degrees(scenario.plane.longitude))]
    surface = "land" if np.all(np.asarray(scenario.kinds) == "land") else "ice"
    lines = ["[project]", f'name = "{scenario.name}"', f"map_centre_deg = [{centre[0]!r}, {centre[1]!r}]",
             f'surface = "{surface}"', ""]
    truth_rows = {"point": [], "coverage": [], "kind": [], "lat_deg": [], "lon_deg": [], "x_m": [], "y_m": []}
    for c, (coverage, truth) in enumerate(zip(scenario.coverages, scenario.truth, strict=True), start=1):
        m = coverage.measurements
        frames = [ImageFrame.placed(np.radians(0.4 + 0.15 * j), (20.0 + j, 35.0 - 0.5 * j))
                  for j in range(len(coverage.strips))]
        columns = {"point": [], "strip": [], "kind": [], "x_mm": [], "y_mm": []}
        for j, strip in enumerate(coverage.strips):
            rows = np.nonzero(m.strip == j)[0]
            nadir_ids = [f"N{c}-{strip.name}-{k + 1:03d}" for k in range(strip.nadir_x.size)]
            columns["point"] += [ids[p] for p in m.point[rows]] + nadir_ids
            columns["strip"] += [strip.name] * (rows.size + len(nadir_ids))
            columns["kind"] += [kinds[p] for p in m.point[rows]] + ["nadir"] * len(nadir_ids)
            xc, yc = frames[j].to_comparator(np.concatenate([m.x[rows], strip.nadir_x]),
                                             np.concatenate([m.y[rows], strip.nadir_y]))
            columns["x_mm"] += list(np.asarray(xc))
            columns["y_mm"] += list(np.asarray(yc))
        write_csv(out / f"c{c}_measurements.csv", columns, float_format="%.12g")
        lat_c, lon_c = [], []
        for point in coverage.control:
            lat, lon = scenario.plane.inverse(coverage.control[point][0], coverage.control[point][1])
            lat_c.append(float(np.degrees(lat)))
            lon_c.append(float(np.degrees(lon)))
        write_csv(out / f"c{c}_control.csv", {"point": [ids[p] for p in coverage.control], "lat_deg": lat_c,
                                               "lon_deg": lon_c, "sigma_m": [v[2] for v in coverage.control.values()]})
        lines += ["[[coverage]]", f'name = "{coverage.name}"', f"epoch_s = {coverage.epoch!r}",
                  f'measurements = "c{c}_measurements.csv"', f'control = "c{c}_control.csv"', ""]
        for j, strip in enumerate(coverage.strips):
            stem = f"c{c}_{strip.name}"
            write_csv(out / f"{stem}_navigation.csv", dict(zip(NAVIGATION_COLUMNS, (
                strip.record_times, *strip.record_positions.T, *strip.record_velocities.T, strip.record_altitudes),
                strict=True)), float_format="%.12g")
            mark_xc, mark_yc = frames[j].to_comparator(strip.mark_x, np.full(strip.mark_x.shape, _MARK_OFFSET))
            write_csv(out / f"{stem}_marks.csv", {"x_mm": np.asarray(mark_xc), "y_mm": np.asarray(mark_yc),
                                                  "time_s": strip.mark_times}, float_format="%.12g")
            reference = np.asarray(frames[j].to_comparator([0.0, float(strip.mark_x[-1])], [0.0, 0.0])).T
            far = np.asarray(frames[j].to_comparator(0.0, 50.0))
            lines += ["[[coverage.strip]]", f'name = "{strip.name}"', f'navigation = "{stem}_navigation.csv"',
                      f'time_marks = "{stem}_marks.csv"',
                      f"range_reference_mm = {[[float(v) for v in point] for point in reference]!r}",
                      f"far_range_mm = {[float(v) for v in far]!r}",
                      f"sweep_delay_mm = {strip.sweep_delay!r}", f"range_scale_m_per_mm = {strip.range_scale!r}",
                      f'look_side = "{strip.look_side}"', ""]
        lat, lon = scenario.plane.inverse(truth.positions[:, 0], truth.positions[:, 1])
        truth_rows["point"] += ids
        truth_rows["coverage"] += [coverage.name] * len(ids)
        truth_rows["kind"] += list(scenario.kinds)
        truth_rows["lat_deg"] += list(np.degrees(np.asarray(lat)))
        truth_rows["lon_deg"] += list(np.degrees(np.asarray(lon)))
        truth_rows["x_m"] += list(truth.positions[:, 0])
        truth_rows["y_m"] += list(truth.positions[:, 1])
    write_csv(out / "truth.csv", truth_rows, float_format="%.12g")
    with atomic_path(out / "project.toml") as temporary:
        temporary.write_text("\n".join(lines))
