"""``seaice block``: a radar block project end to end — adjustment per coverage, drift between coverages, and
the files researchers use (CSV, GeoJSON, figures, a text report). Everything is computed before anything is
written, so a failing project leaves the output folder untouched."""

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seaice_jax.adjust.sequential import sequential_block
from seaice_jax.drift.kinematics import drift_vectors, fit_transform
from seaice_jax.errors import SeaiceError
from seaice_jax.io.files import atomic_path, write_csv, write_geojson
from seaice_jax.io.project import read_project
from seaice_jax.plots import plot_tie_discrepancies, plot_vectors

METHODS = ("sequential",)


@dataclass(frozen=True)
class BlockRun:
    """What ``seaice block`` computed and wrote."""

    files: tuple[Path, ...]
    report: str
    positions: tuple[np.ndarray, ...]  # (points, 2) map metres per coverage, NaN where not measured


def run_block(project_path: str | os.PathLike, out_dir: str | os.PathLike, method: str = "sequential") -> BlockRun:
    """Adjust every coverage of the project with ``method`` and derive the drift between consecutive coverages."""
    if method not in METHODS:
        raise SeaiceError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    project = read_project(project_path)
    n = len(project.point_ids)
    results, positions = [], []
    for coverage in project.coverages:
        control = {p: np.array(v[:2]) for p, v in coverage.control.items()} or None
        result = sequential_block(coverage.strips, coverage.measurements, project.plane, control=control)
        results.append(result)
        positions.append(result.point_positions(coverage.measurements, n))
    lines = [f"seaice block {project.name}: method {method}, {len(project.coverages)} coverage(s), {n} points"]
    for coverage, result in zip(project.coverages, results, strict=True):
        before = np.sqrt(np.mean(result.tie_before**2, axis=0)) / 1000 if result.tie_before.size else [np.nan] * 2
        after = np.sqrt(np.mean(result.tie_after**2, axis=0)) / 1000 if result.tie_after.size else [np.nan] * 2
        calibrated = sum(c.scale_estimated for c in result.calibrations)
        lines += [f"  {coverage.name}: {len(coverage.strips)} strips, {coverage.measurements.x.size} measurements, "
                  f"{len(coverage.control)} control points",
                  f"    tie discrepancies across/along track: before ±{before[0]:.2f}/±{before[1]:.2f} km, after "
                  f"±{after[0]:.3f}/±{after[1]:.3f} km",
                  f"    nadir calibration: sweep delay and scale on {calibrated} strip(s), sweep delay alone on "
                  f"{len(result.calibrations) - calibrated}"]
    drift_rows, drift_features, drift_plots = [], [], []
    for k in range(1, len(project.coverages)):
        first, second = positions[k - 1], positions[k]
        homologous = np.isin(np.array(project.point_kinds), ("drift", "control"))
        both = np.nonzero(homologous & np.isfinite(first).all(axis=1) & np.isfinite(second).all(axis=1))[0]
        if both.size < 3:
            lines.append(f"  drift {project.coverages[k - 1].name} -> {project.coverages[k].name}: only {both.size} "
                         "drift or control points measured in both, no drift computed")
            continue
        interval = project.coverages[k].epoch - project.coverages[k - 1].epoch
        drift = drift_vectors(first[both], second[both], interval if interval > 0 else 1.0)
        rigid = fit_transform(first[both], second[both], "rigid", 100.0)
        affine = fit_transform(first[both], second[both], "affine", 100.0)
        shift_km = rigid.parameters["shift"] / 1000
        lines += [f"  drift {project.coverages[k - 1].name} -> {project.coverages[k].name} ({both.size} points): "
                  f"general drift {shift_km[0]:+.2f}, {shift_km[1]:+.2f} km (x, y), rotation "
                  f"{np.degrees(float(rigid.parameters['rotation'])):+.3f}°",
                  f"    relative motion after removing it: rms {rigid.rms / 1000:.3f} km; affine matrix "
                  f"{np.round(affine.parameters['matrix'], 4).tolist()}"]
        lat0, lon0 = (np.degrees(np.asarray(a)) for a in project.plane.inverse(first[both, 0], first[both, 1]))
        lat1, lon1 = (np.degrees(np.asarray(a)) for a in project.plane.inverse(second[both, 0], second[both, 1]))
        for i, p in enumerate(both):
            drift_rows.append((project.point_ids[p], project.coverages[k - 1].name, project.coverages[k].name,
                               *drift.displacement[i], drift.speed[i], drift.direction[i], *rigid.residuals[i]))
            drift_features.append({"type": "Feature", "geometry": {"type": "LineString", "coordinates": [
                [float(lon0[i]), float(lat0[i])], [float(lon1[i]), float(lat1[i])]]}, "properties": {
                "point": project.point_ids[p], "dx_m": float(drift.displacement[i, 0]),
                "dy_m": float(drift.displacement[i, 1]), "speed_m_s": float(drift.speed[i]),
                "direction_deg": float(drift.direction[i]), "relative_dx_m": float(rigid.residuals[i, 0]),
                "relative_dy_m": float(rigid.residuals[i, 1])}})
        drift_plots.append((k, first[both], drift.displacement, rigid.residuals))

    out = Path(out_dir)
    files = []
    rows = [(project.point_ids[p], c.name, *positions[k][p]) for k, c in enumerate(project.coverages)
            for p in range(n) if np.isfinite(positions[k][p]).all()]
    lat, lon = project.plane.inverse(np.array([r[2] for r in rows]), np.array([r[3] for r in rows]))
    files.append(write_csv(out / "adjusted_points.csv", {
        "point": [r[0] for r in rows], "coverage": [r[1] for r in rows], "x_m": [r[2] for r in rows],
        "y_m": [r[3] for r in rows], "lat": np.degrees(np.asarray(lat)), "lon": np.degrees(np.asarray(lon))}))
    if drift_rows:
        names = ("point", "from", "to", "dx_m", "dy_m", "speed_m_s", "direction_deg", "relative_dx_m",
                 "relative_dy_m")
        files.append(write_csv(out / "drift.csv", {name: [r[i] for r in drift_rows] for i, name in
                                                   enumerate(names)}))
        files.append(write_geojson(out / "drift.geojson", drift_features))
    for k, (coverage, result) in enumerate(zip(project.coverages, results, strict=True), start=1):
        internal = result.point_positions(coverage.measurements, n, "internal")
        known = [p for p in coverage.control if np.isfinite(internal[p]).all()]
        if known:
            where = np.array([coverage.control[p][:2] for p in known])
            files.append(plot_vectors(out / f"control_discrepancies_c{k}.png", where, internal[known] - where,
                                      f"Radar minus known position at the control points, {coverage.name}",
                                      "before the external adjustment (source 000, Figs 5 and 6)",
                                      background=internal[np.isfinite(internal).all(axis=1)]))
        if result.tie_before.size:
            files.append(plot_tie_discrepancies(out / f"tie_discrepancies_c{k}.png", result.tie_before,
                                                result.tie_after))
    for k, where, displacement, relative in drift_plots:
        files.append(plot_vectors(out / f"drift_c{k}.png", where, displacement,
                                  f"Drift {project.coverages[k - 1].name} -> {project.coverages[k].name}",
                                  "source 000, Fig. 7"))
        files.append(plot_vectors(out / f"relative_motion_c{k}.png", where, relative,
                                  "Relative motion after removing the general (rigid) drift", "source 000, Fig. 8"))
    report = "\n".join(lines)
    with atomic_path(out / "report.txt") as temporary:
        temporary.write_text(report + "\n")
    files.append(out / "report.txt")
    return BlockRun(tuple(files), report, tuple(positions))
