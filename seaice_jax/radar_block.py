"""``seaice block``: a radar block project end to end — adjustment (simultaneous or the sequential method of 1979),
drift between coverages, and the files researchers use (CSV, GeoJSON, figures, a text report). Everything is
computed before anything is written, so a failing project leaves the output folder untouched."""

import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from seaice_jax.adjust.block import BlockOptions, simultaneous_block
from seaice_jax.adjust.quality import global_test
from seaice_jax.adjust.sequential import sequential_block
from seaice_jax.drift.kinematics import drift_vectors, fit_transform
from seaice_jax.errors import SeaiceError
from seaice_jax.io.files import atomic_path, write_csv, write_geojson
from seaice_jax.io.project import read_project
from seaice_jax.plots import error_ellipses, plot_navigation_errors, plot_tie_discrepancies, plot_vectors

METHODS = ("simultaneous", "sequential")


@dataclass(frozen=True)
class BlockRun:
    """What ``seaice block`` computed and wrote.

    Attributes:
        files: written. report: the text report. point_ids: the project's point ids, in the order of the rows of
        ``positions``: per coverage ``(points, 2)`` map metres (NaN where not measured). covariances: per coverage
        ``(points, 2, 2)`` m² (simultaneous method; ``None`` for sequential).
    """

    files: tuple[Path, ...]
    report: str
    point_ids: tuple[str, ...]
    positions: tuple[np.ndarray, ...]
    covariances: tuple[np.ndarray, ...] | None


def _rms_km(values):
    values = np.asarray(values, float).reshape(-1, 2)
    return np.sqrt(np.mean(values**2, axis=0)) / 1000 if values.size else np.array([np.nan, np.nan])


def _sequential(project, n, lines):
    positions, plots = [], []
    for k, coverage in enumerate(project.coverages, start=1):
        control = {p: np.array(v[:2]) for p, v in coverage.control.items()} or None
        result = sequential_block(coverage.strips, coverage.measurements, project.plane, control=control)
        positions.append(result.point_positions(coverage.measurements, n))
        before, after = _rms_km(result.tie_before), _rms_km(result.tie_after)
        calibrated = sum(c.scale_estimated for c in result.calibrations)
        lines += [f"  {coverage.name}: {len(coverage.strips)} strips, {coverage.measurements.x.size} measurements, "
                  f"{len(coverage.control)} control points",
                  f"    tie discrepancies across/along track: before ±{before[0]:.2f}/±{before[1]:.2f} km, after "
                  f"±{after[0]:.3f}/±{after[1]:.3f} km",
                  f"    nadir calibration: sweep delay and scale on {calibrated} strip(s), sweep delay alone on "
                  f"{len(result.calibrations) - calibrated}"]
        internal = result.point_positions(coverage.measurements, n, "internal")
        known = [p for p in coverage.control if np.isfinite(internal[p]).all()]
        if known:
            where = np.array([coverage.control[p][:2] for p in known])
            plots.append(lambda out, k=k, c=coverage, w=where, v=internal[known] - where, b=internal: plot_vectors(
                out / f"control_discrepancies_c{k}.png", w, v, f"Radar minus known position at the control points, "
                f"{c.name}", "before the external adjustment (source 000, Figs 5 and 6)",
                background=b[np.isfinite(b).all(axis=1)]))
        if result.tie_before.size:
            plots.append(lambda out, k=k, r=result: plot_tie_discrepancies(out / f"tie_discrepancies_c{k}.png",
                                                                           r.tie_before, r.tie_after))
    drift = [(positions[k] - positions[k - 1], None) for k in range(1, len(positions))]
    return positions, None, drift, plots, []


def _simultaneous(project, n, lines, options):
    result = simultaneous_block(project.coverages, project.plane, n,
                                replace(options, static_points=project.surface == "land"),
                                point_ids=project.point_ids)
    _, p_value, accepted = global_test(result.sigma0**2, result.degrees_of_freedom)
    lines += [f"  {result.solver} solve: {len(result.strips)} strips, navigation-error model "
              f"{options.navigation_model} per {options.navigation_scope}, {result.iterations} Gauss-Newton "
              "iterations"
              f"{'' if result.converged else ' (NOT CONVERGED)'}",
              f"  σ̂0 = {result.sigma0:.3f} with {result.degrees_of_freedom} degrees of freedom; global test "
              f"{'accepted' if accepted else 'REJECTED'} (p = {float(p_value):.3g})"]
    for c, coverage in enumerate(project.coverages):
        ties = _rms_km(result.tie_discrepancies(c))
        sigma = np.sqrt(np.nanmean(np.diagonal(result.covariances[c], axis1=1, axis2=2), axis=0)) / 1000
        lines.append(f"  {coverage.name}: {len(coverage.strips)} strips, {coverage.measurements.x.size} measurements, "
                     f"{len(coverage.control)} control points; tie discrepancies after adjustment "
                     f"±{ties[0]:.3f}/±{ties[1]:.3f} km (x/y); mean point σ {sigma[0]:.3f}/{sigma[1]:.3f} km")
    names = {(s.coverage, s.name): s for s in result.strips}
    lines.append("  radar constants (sweep delay mm, range scale m/mm, ±σ):")
    lines += [f"    {s.coverage}/{s.name}: {s.sweep_delay:.3f} ±{s.sigma_sweep_delay:.3f}, {s.range_scale:.3f} "
              f"±{s.sigma_range_scale:.3f}" for s in names.values()]
    if result.blunders:
        lines.append(f"  {len(result.blunders)} observation(s) fail the w-test (α = {options.alpha}); worst first:")
        for b in result.blunders[:10]:
            coverage = project.coverages[b.coverage]
            lines.append(f"    point {project.point_ids[b.point]} on {coverage.name}/{coverage.strips[b.strip].name}:"
                         f" image {b.component}, w = {b.w:+.1f}, estimated error {b.estimated_error:+.3f} mm")
    else:
        lines.append(f"  no observation fails the w-test (α = {options.alpha})")
    curves = []
    for estimate, strip in zip(result.strips, [s for c in project.coverages for s in c.strips], strict=True):
        times = strip.record_times[(strip.record_times >= strip.start_time) & (strip.record_times <= strip.end_time)]
        curves.append((f"{estimate.coverage}/{estimate.name}", times, *estimate.navigation_error(times)))
    plots = [lambda out: plot_navigation_errors(out / "navigation_errors.png", curves,
                                                "Estimated navigation errors with ±1σ bands")]
    for k in range(1, len(project.coverages) + 1):
        ties = result.tie_discrepancies(k - 1)
        if ties.size:
            plots.append(lambda out, k=k, t=ties: plot_tie_discrepancies(out / f"tie_discrepancies_c{k}.png", t, t))
    extra = [("strips.csv", {"coverage": [s.coverage for s in result.strips], "strip": [s.name for s in result.strips],
                             "sweep_delay_mm": [s.sweep_delay for s in result.strips],
                             "sigma_sweep_delay_mm": [s.sigma_sweep_delay for s in result.strips],
                             "range_scale_m_per_mm": [s.range_scale for s in result.strips],
                             "sigma_range_scale_m_per_mm": [s.sigma_range_scale for s in result.strips]}),
             ("navigation_errors.csv", {
                 "strip": [label for label, t, *_ in curves for _ in t],
                 "time_s": np.concatenate([t for _, t, *_ in curves]),
                 "north_m": np.concatenate([e[:, 0] for *_, e, _ in curves]),
                 "east_m": np.concatenate([e[:, 1] for *_, e, _ in curves]),
                 "sigma_north_m": np.concatenate([s[:, 0] for *_, s in curves]),
                 "sigma_east_m": np.concatenate([s[:, 1] for *_, s in curves])}),
             ("observations.csv", {
                 "point": [project.point_ids[p] for p in result.point_of],
                 "coverage": [project.coverages[c].name for c in result.coverage_of],
                 "strip": [project.coverages[c].strips[s].name for c, s in zip(result.coverage_of, result.strip_of,
                                                                             strict=True)],
                 "residual_x_mm": result.residuals[:, 0], "residual_y_mm": result.residuals[:, 1],
                 "redundancy_x": result.redundancy[:, 0], "redundancy_y": result.redundancy[:, 1],
                 "w_x": result.w[:, 0], "w_y": result.w[:, 1]})]
    drift = list(zip(result.drift, result.drift_covariance, strict=True))
    return list(result.positions), list(result.covariances), drift, plots, extra


def run_block(project_path: str | os.PathLike, out_dir: str | os.PathLike, method: str = "simultaneous",
              options: BlockOptions | None = None) -> BlockRun:
    """Adjust the project's coverages with ``method`` and derive the drift between consecutive coverages.

    Writes ``adjusted_points.csv`` (with σ and 95 % error ellipses for the simultaneous method), ``drift.csv``,
    ``drift.geojson``, figures and ``report.txt``; the simultaneous method adds ``strips.csv``,
    ``navigation_errors.csv`` and ``observations.csv`` (residuals, redundancy numbers, w-tests).
    """
    if method not in METHODS:
        raise SeaiceError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    project = read_project(project_path)
    n = len(project.point_ids)
    lines = [f"seaice block {project.name}: method {method}, {len(project.coverages)} coverage(s), {n} points"]
    if method == "sequential":
        positions, covariances, drift, plots, extra = _sequential(project, n, lines)
    else:
        positions, covariances, drift, plots, extra = _simultaneous(project, n, lines, options or BlockOptions())

    drift_rows, drift_features, drift_plots = [], [], []
    homologous = np.isin(np.array(project.point_kinds), ("drift", "control"))
    for k in range(1, len(project.coverages)):
        if k - 1 >= len(drift):  # land: one set of positions for all coverages, no drift
            break
        displacement, covariance = drift[k - 1]
        first = positions[k - 1]
        both = np.nonzero(homologous & np.isfinite(displacement).all(axis=1))[0]
        names = f"{project.coverages[k - 1].name} -> {project.coverages[k].name}"
        if both.size < 3:
            lines.append(f"  drift {names}: only {both.size} drift or control points measured in both, no drift "
                         "computed")
            continue
        interval = project.coverages[k].epoch - project.coverages[k - 1].epoch
        vectors = drift_vectors(first[both], first[both] + displacement[both], interval if interval > 0 else 1.0)
        rigid = fit_transform(first[both], first[both] + displacement[both], "rigid", 100.0)
        affine = fit_transform(first[both], first[both] + displacement[both], "affine", 100.0)
        shift_km = rigid.parameters["shift"] / 1000
        lines += [f"  drift {names} ({both.size} points): general drift {shift_km[0]:+.2f}, {shift_km[1]:+.2f} km "
                  f"(x, y), rotation {np.degrees(float(rigid.parameters['rotation'])):+.3f}°",
                  f"    relative motion after removing it: rms {rigid.rms / 1000:.3f} km; affine matrix "
                  f"{np.round(affine.parameters['matrix'], 4).tolist()}"]
        sigma = (np.sqrt(np.diagonal(covariance[both], axis1=1, axis2=2)) if covariance is not None
                 else np.full((both.size, 2), np.nan))
        if covariance is not None:
            lines.append(f"    drift σ (x, y): median {np.median(sigma[:, 0]):.0f}, {np.median(sigma[:, 1]):.0f} m")
        second = first[both] + displacement[both]
        lat0, lon0 = (np.degrees(np.asarray(a)) for a in project.plane.inverse(first[both, 0], first[both, 1]))
        lat1, lon1 = (np.degrees(np.asarray(a)) for a in project.plane.inverse(second[:, 0], second[:, 1]))
        for i, p in enumerate(both):
            drift_rows.append((project.point_ids[p], project.coverages[k - 1].name, project.coverages[k].name,
                               *vectors.displacement[i], *sigma[i], vectors.speed[i], vectors.direction[i],
                               *rigid.residuals[i]))
            drift_features.append({"type": "Feature", "geometry": {"type": "LineString", "coordinates": [
                [float(lon0[i]), float(lat0[i])], [float(lon1[i]), float(lat1[i])]]}, "properties": {
                "point": project.point_ids[p], "dx_m": float(vectors.displacement[i, 0]),
                "dy_m": float(vectors.displacement[i, 1]), "sigma_dx_m": _json_number(sigma[i, 0]),
                "sigma_dy_m": _json_number(sigma[i, 1]), "speed_m_s": float(vectors.speed[i]),
                "direction_deg": float(vectors.direction[i]), "relative_dx_m": float(rigid.residuals[i, 0]),
                "relative_dy_m": float(rigid.residuals[i, 1])}})
        drift_plots.append((k, first[both], vectors.displacement, rigid.residuals,
                            None if covariance is None else covariance[both]))

    out = Path(out_dir)
    files = []
    columns = {"point": [], "coverage": [], "x_m": [], "y_m": []}
    sigma_columns = {"sigma_x_m": [], "sigma_y_m": [], "covariance_xy_m2": [], "ellipse_major_m": [],
                     "ellipse_minor_m": [], "ellipse_azimuth_deg": []}
    for k, coverage in enumerate(project.coverages):
        seen = np.nonzero(np.isfinite(positions[k]).all(axis=1))[0]
        columns["point"] += [project.point_ids[p] for p in seen]
        columns["coverage"] += [coverage.name] * seen.size
        columns["x_m"] += list(positions[k][seen, 0])
        columns["y_m"] += list(positions[k][seen, 1])
        if covariances is not None:
            cov = covariances[k][seen]
            major, minor, angle = error_ellipses(cov)
            sigma_columns["sigma_x_m"] += list(np.sqrt(cov[:, 0, 0]))
            sigma_columns["sigma_y_m"] += list(np.sqrt(cov[:, 1, 1]))
            sigma_columns["covariance_xy_m2"] += list(cov[:, 0, 1])
            sigma_columns["ellipse_major_m"] += list(major)
            sigma_columns["ellipse_minor_m"] += list(minor)
            sigma_columns["ellipse_azimuth_deg"] += list(90.0 - np.degrees(angle))  # clockwise from grid north
    lat, lon = project.plane.inverse(np.array(columns["x_m"]), np.array(columns["y_m"]))
    columns.update(lat=np.degrees(np.asarray(lat)), lon=np.degrees(np.asarray(lon)))
    if covariances is not None:
        columns.update(sigma_columns)
    files.append(write_csv(out / "adjusted_points.csv", columns))
    if drift_rows:
        names = ("point", "from", "to", "dx_m", "dy_m", "sigma_dx_m", "sigma_dy_m", "speed_m_s", "direction_deg",
                 "relative_dx_m", "relative_dy_m")
        files.append(write_csv(out / "drift.csv", {name: [r[i] for r in drift_rows] for i, name in
                                                   enumerate(names)}))
        files.append(write_geojson(out / "drift.geojson", drift_features))
    for name, table in extra:
        files.append(write_csv(out / name, table))
    files += [plot(out) for plot in plots]
    for k, where, displacement, relative, covariance in drift_plots:
        files.append(plot_vectors(out / f"drift_c{k}.png", where, displacement,
                                  f"Drift {project.coverages[k - 1].name} -> {project.coverages[k].name}",
                                  "source 000, Fig. 7", covariances=covariance))
        files.append(plot_vectors(out / f"relative_motion_c{k}.png", where, relative,
                                  "Relative motion after removing the general (rigid) drift", "source 000, Fig. 8",
                                  covariances=covariance))
    report = "\n".join(lines)
    with atomic_path(out / "report.txt") as temporary:
        temporary.write_text(report + "\n")
    files.append(out / "report.txt")
    return BlockRun(tuple(files), report, project.point_ids, tuple(positions),
                    None if covariances is None else tuple(covariances))


def _json_number(value):
    """A float for JSON, ``None`` for NaN (JSON has no NaN)."""
    return None if not np.isfinite(value) else float(value)
