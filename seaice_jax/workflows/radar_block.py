"""``seaice block``: a radar block project end to end — adjustment (simultaneous or the sequential method of 1979),
drift between coverages, and the files researchers use (CSV, GeoJSON, figures, a text report).

Three steps: :func:`adjust_block` computes a :class:`BlockAnalysis` (nothing written), :func:`block_report` turns it
into text and :func:`write_block` into files. A failing project therefore leaves the output folder untouched.
"""

import logging
import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from seaice_jax.adjust.engine import not_converged_error
from seaice_jax.adjust.engine.quality import global_test
from seaice_jax.adjust.radar.block import BlockOptions, BlockResult, simultaneous_block
from seaice_jax.adjust.radar.sequential import SequentialResult, sequential_block
from seaice_jax.drift.kinematics import DriftVectors, TransformFit, drift_vectors, error_ellipses, fit_transform
from seaice_jax.errors import SeaiceError
from seaice_jax.files import atomic_path, write_csv, write_geojson
from seaice_jax.io.project import Project, read_project
from seaice_jax.memory import block_peak, check_memory
from seaice_jax.outputs import output_folder
from seaice_jax.report.figures import plot_navigation_errors, plot_tie_discrepancies, plot_vectors
from seaice_jax.sensors.navigation import error_basis_size

METHODS = ("simultaneous", "sequential")


@dataclass(frozen=True)
class DriftPair:
    """The drift between two consecutive coverages, at the drift and control points measured in both.

    Attributes:
        first, second: coverage indices (``second = first + 1``). points: ``(k,)`` point indices.
        start: ``(k, 2)`` map positions (m) at the first coverage. displacement: ``(k, 2)`` m.
        covariance: ``(k, 2, 2)`` m² of the displacements (simultaneous method), else ``None``.
        vectors: displacements, speeds and directions. rigid, affine: the general drift fitted to the points.
    """

    first: int
    second: int
    points: np.ndarray
    start: np.ndarray
    displacement: np.ndarray
    covariance: np.ndarray | None
    vectors: DriftVectors
    rigid: TransformFit
    affine: TransformFit


@dataclass(frozen=True)
class BlockAnalysis:
    """Everything ``seaice block`` computed, before anything is written.

    Attributes:
        project: the project read. method: ``"simultaneous"`` or ``"sequential"``. options: of the simultaneous
        adjustment. positions: per coverage ``(points, 2)`` map metres (rows: ``project.point_ids``; NaN where not
        measured). covariances: per coverage ``(points, 2, 2)`` m² (simultaneous method; ``None`` for sequential).
        drift: the coverage pairs with drift. unmeasured: ``(first coverage, points measured in both)`` of the pairs
        with fewer than three common points. sequential: the 1979 method's result per coverage (sequential
        method). adjustment: the simultaneous adjustment (simultaneous method).
    """

    project: Project
    method: str
    options: BlockOptions
    positions: tuple[np.ndarray, ...]
    covariances: tuple[np.ndarray, ...] | None
    drift: tuple[DriftPair, ...]
    unmeasured: tuple[tuple[int, int], ...]
    sequential: tuple[SequentialResult, ...] = ()
    adjustment: BlockResult | None = None

    @property
    def point_ids(self) -> tuple[str, ...]:
        return self.project.point_ids


@dataclass(frozen=True)
class BlockRun:
    """What ``seaice block`` computed (``result``) and wrote (``files``, the text ``report``)."""

    files: tuple[Path, ...]
    report: str
    result: BlockAnalysis


# ------------------------------------------------------------------------------------------------ compute


def _sequential(project: Project):
    """The 1979 method per coverage: its results and the point positions ``(points, 2)`` of each coverage."""
    n = len(project.point_ids)
    results, positions = [], []
    for coverage in project.coverages:
        control = {p: np.array(v[:2]) for p, v in coverage.control.items()} or None
        result = sequential_block(coverage.strips, coverage.measurements, project.plane, control=control)
        unsolved = np.nonzero(~np.isfinite(result.rectified).all(axis=1))[0]
        if unsolved.size:
            k = unsolved[0]
            more = f" (and {unsolved.size - 1} more such measurements)" if unsolved.size > 1 else ""
            raise SeaiceError(f"coverage {coverage.name!r}: point {project.point_ids[coverage.measurements.point[k]]} "
                              f"is measured (strip {coverage.strips[coverage.measurements.strip[k]].name}) but has no "
                              "ground solution with the nadir-calibrated radar constants and the navigation: its "
                              f"slant range is shorter than the flying height, off the film's ground range{more}; "
                              "correct or remove its measurement")
        results.append(result)
        positions.append(result.point_positions(coverage.measurements, n))
    return tuple(results), tuple(positions)


def _drift_pair(project: Project, k: int, first, displacement, covariance) -> DriftPair | int:
    """The drift from coverage ``k`` to ``k + 1``, or the number of common points if fewer than three."""
    homologous = np.isin(np.array(project.point_kinds), ("drift", "control"))
    both = np.nonzero(homologous & np.isfinite(displacement).all(axis=1))[0]
    if both.size < 3:
        return int(both.size)
    interval = project.coverages[k + 1].epoch - project.coverages[k].epoch
    start, end = first[both], first[both] + displacement[both]
    return DriftPair(k, k + 1, both, start, displacement[both], None if covariance is None else covariance[both],
                     drift_vectors(start, end, interval if interval > 0 else 1.0),
                     fit_transform(start, end, "rigid", 100.0), fit_transform(start, end, "affine", 100.0))


def block_unknowns(coverages, options: BlockOptions) -> int:
    """The number of global unknowns (navigation-error coefficients of both components, radar constants) of the
    simultaneous adjustment of ``coverages``, counted from the strips' spans as the block's layout numbers them
    (:func:`~seaice_jax.adjust.radar.layout.layout_block`), without building it."""
    count, flight, components = 0, options.navigation_scope == "flight", 2
    for coverage in coverages:
        start = min(s.start_time for s in coverage.strips)
        if flight and options.take_off_time is not None:
            start = min(start, options.take_off_time)
        flown = (start, max(s.end_time for s in coverage.strips))
        for j, strip in enumerate(coverage.strips):
            span = flown if flight else (strip.start_time, strip.end_time)
            q = error_basis_size(options.navigation_model, *span, options.knot_spacing)
            count += components * (2 + (q if j == 0 else 0)) if flight else components * q
    strips = sum(len(coverage.strips) for coverage in coverages)
    return count + (2 * strips if options.radar_constants == "strip" else 2)


def adjust_block(project: Project, method: str = "simultaneous",
                 options: BlockOptions | None = None) -> BlockAnalysis:
    """Adjust the project's coverages with ``method`` and derive the drift between consecutive coverages (on
    land — ``surface = "land"`` — one set of positions serves every coverage and there is no drift).

    Raises:
        NotConvergedError: the simultaneous adjustment stopped unconverged (``seaice block`` exits 1), naming its
            iterations, σ̂0 and the unknown its last step moved most.
    """
    if method not in METHODS:
        raise SeaiceError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    options = options or BlockOptions()
    sequential, adjustment = (), None
    if method == "sequential":
        sequential, positions = _sequential(project)
        covariances = None
        drift = [(positions[k + 1] - positions[k], None) for k in range(len(positions) - 1)]
    else:
        unknowns = block_unknowns(project.coverages, options)
        check_memory(block_peak(unknowns), f"the simultaneous adjustment of {unknowns} unknowns (navigation model "
                                           f"{options.navigation_model}, --knot-spacing {options.knot_spacing:g} s)")
        adjustment = simultaneous_block(project.coverages, project.plane, len(project.point_ids),
                                        replace(options, static_points=project.surface == "land"),
                                        point_ids=project.point_ids)
        if not adjustment.converged:
            assert adjustment.adjustment is not None  # simultaneous_block always returns the engine's result
            raise not_converged_error(adjustment.adjustment, "the block adjustment",
                                      "check the project's radar constants, navigation and control points")
        positions, covariances = tuple(adjustment.positions), tuple(adjustment.covariances)
        drift = list(zip(adjustment.drift, adjustment.drift_covariance, strict=True))
    pairs, unmeasured = [], []
    for k, (displacement, covariance) in enumerate(drift):
        pair = _drift_pair(project, k, positions[k], displacement, covariance)
        if isinstance(pair, DriftPair):
            pairs.append(pair)
        else:
            unmeasured.append((k, pair))
    return BlockAnalysis(project, method, options, positions, covariances, tuple(pairs), tuple(unmeasured),
                       sequential, adjustment)


# ------------------------------------------------------------------------------------------------ report


def _rms_km(values):
    values = np.asarray(values, float).reshape(-1, 2)
    return np.sqrt(np.mean(values**2, axis=0)) / 1000 if values.size else np.array([np.nan, np.nan])


def _coverage_line(coverage) -> str:
    return (f"  {coverage.name}: {len(coverage.strips)} strips, {coverage.measurements.x.size} measurements, "
            f"{len(coverage.control)} control points")


def _sequential_lines(result: BlockAnalysis) -> list[str]:
    lines = []
    for coverage, sequential in zip(result.project.coverages, result.sequential, strict=True):
        before, after = _rms_km(sequential.tie_before), _rms_km(sequential.tie_after)
        calibrated = sum(c.scale_estimated for c in sequential.calibrations)
        lines += [_coverage_line(coverage),
                  f"    tie discrepancies across/along track: before ±{before[0]:.2f}/±{before[1]:.2f} km, after "
                  f"±{after[0]:.3f}/±{after[1]:.3f} km",
                  f"    nadir calibration: sweep delay and scale on {calibrated} strip(s), sweep delay alone on "
                  f"{len(sequential.calibrations) - calibrated}"]
    return lines


def _blunder_lines(result: BlockAnalysis) -> list[str]:
    adjustment, alpha = result.adjustment, result.options.alpha
    assert adjustment is not None
    if not adjustment.blunders:
        return [f"  no observation fails the w-test (α = {alpha})"]
    lines = [f"  {len(adjustment.blunders)} observation(s) fail the w-test (α = {alpha}); worst first:"]
    for b in adjustment.blunders[:10]:
        unit = {"control": " m", "prior": ""}.get(b.group, " mm")
        note = "" if b.separable else f" (cannot be told from an error in {b.confounded_with})"
        lines.append(f"    {b.description}: w = {b.w:+.1f}, estimated error {b.estimated_error:+.3f}{unit}{note}")
    return lines


_GROUP_NAMES = {"image[0]": "image x (along track)", "image[1]": "image y (slant range)", "nadir": "nadir returns",
                "control[0]": "control x", "control[1]": "control y"}


def _simultaneous_lines(result: BlockAnalysis) -> list[str]:
    adjustment, options = result.adjustment, result.options
    assert adjustment is not None and result.covariances is not None
    _, p_value, accepted = global_test(adjustment.sigma0**2, adjustment.degrees_of_freedom)
    lines = [f"  {adjustment.solver} solve: {len(adjustment.strips)} strips, navigation-error model "
             f"{options.navigation_model} per {options.navigation_scope}, {adjustment.iterations} Gauss-Newton "
             "iterations",
             f"  σ̂0 = {adjustment.sigma0:.3f} with {adjustment.degrees_of_freedom} degrees of freedom; global test "
             f"{'accepted' if accepted else 'REJECTED'} (p = {float(p_value):.3g})"
             + ("" if accepted else ": the observations disagree beyond their σ" if adjustment.sigma0 > 1 else
                ": the residuals are smaller than the σ say (the σ are pessimistic)")]
    for c, coverage in enumerate(result.project.coverages):
        ties = _rms_km(adjustment.tie_discrepancies(c))
        sigma = np.sqrt(np.nanmean(np.diagonal(result.covariances[c], axis1=1, axis2=2), axis=0)) / 1000
        lines.append(f"{_coverage_line(coverage)}; tie discrepancies after adjustment ±{ties[0]:.3f}/±{ties[1]:.3f} "
                     f"km (x/y); mean point σ {sigma[0]:.3f}/{sigma[1]:.3f} km")
    engine_result = adjustment.adjustment
    components = None if engine_result is None else engine_result.variance_components
    if components:
        lines.append("  variance components (σ̂g² of each group, 1 when its a priori σ are right; the σ above are "
                     "rescaled by them):")
        lines += [f"    {_GROUP_NAMES.get(g, g)}: {c.value:.3f} ±{c.sigma:.3f} (redundancy {c.redundancy:.0f}, "
                  f"p = {c.p_value:.3g})" for g, c in components.items()]
    if options.robust is not None:
        lines.append(f"  robust ({options.robust}) reweighting: the w-tests are those of the final weights")
    lines.append("  radar constants (sweep delay mm, range scale m/mm, ±σ):")
    strips = {(s.coverage, s.name): s for s in adjustment.strips}.values()
    lines += [f"    {s.coverage}/{s.name}: {s.sweep_delay:.3f} ±{s.sigma_sweep_delay:.3f}, {s.range_scale:.3f} "
              f"±{s.sigma_range_scale:.3f}" for s in strips]
    return lines + _blunder_lines(result)


def _drift_lines(result: BlockAnalysis) -> list[str]:
    coverages = result.project.coverages
    lines = [f"  drift {coverages[k].name} -> {coverages[k + 1].name}: only {count} drift or control points measured "
             "in both, no drift computed" for k, count in result.unmeasured]
    for pair in result.drift:
        shift_km = pair.rigid.parameters["shift"] / 1000
        lines += [f"  drift {coverages[pair.first].name} -> {coverages[pair.second].name} ({pair.points.size} points):"
                  f" general drift {shift_km[0]:+.2f}, {shift_km[1]:+.2f} km (x, y), rotation "
                  f"{np.degrees(float(pair.rigid.parameters['rotation'])):+.3f}°",
                  f"    relative motion after removing it: rms {pair.rigid.rms / 1000:.3f} km; affine matrix "
                  f"{np.round(pair.affine.parameters['matrix'], 4).tolist()}"]
        if pair.covariance is not None:
            sigma = np.sqrt(np.diagonal(pair.covariance, axis1=1, axis2=2))
            lines.append(f"    drift σ (x, y): median {np.median(sigma[:, 0]):.0f}, {np.median(sigma[:, 1]):.0f} m")
    return lines


def block_report(result: BlockAnalysis) -> str:
    """The text report of a block adjustment (``report.txt``)."""
    project = result.project
    lines = [f"seaice block {project.name}: method {result.method}, {len(project.coverages)} coverage(s), "
             f"{len(project.point_ids)} points"]
    lines += _sequential_lines(result) if result.method == "sequential" else _simultaneous_lines(result)
    return "\n".join(lines + _drift_lines(result))


# ------------------------------------------------------------------------------------------------ write


def _json_number(value):
    """A float for JSON, ``None`` for NaN (JSON has no NaN)."""
    return None if not np.isfinite(value) else float(value)


def _point_columns(result: BlockAnalysis) -> dict:
    """The columns of ``adjusted_points.csv``: every measured point of every coverage, with σ and 95 % error
    ellipses when the method gives covariances."""
    project = result.project
    seen = [np.nonzero(np.isfinite(p).all(axis=1))[0] for p in result.positions]
    xy = np.concatenate([p[s] for p, s in zip(result.positions, seen, strict=True)]).reshape(-1, 2)
    lat, lon = project.plane.inverse(xy[:, 0], xy[:, 1])
    columns = {"point": [project.point_ids[p] for s in seen for p in s],
               "coverage": [c.name for c, s in zip(project.coverages, seen, strict=True) for _ in s],
               "x_m": xy[:, 0], "y_m": xy[:, 1], "lat_deg": np.degrees(np.asarray(lat)),
               "lon_deg": np.degrees(np.asarray(lon))}
    if result.covariances is not None:
        cov = np.concatenate([c[s] for c, s in zip(result.covariances, seen, strict=True)]).reshape(-1, 2, 2)
        major, minor, angle = error_ellipses(cov)
        columns.update(sigma_x_m=np.sqrt(cov[:, 0, 0]), sigma_y_m=np.sqrt(cov[:, 1, 1]), covariance_xy_m2=cov[:, 0, 1],
                       ellipse_major_m=major, ellipse_minor_m=minor,
                       ellipse_azimuth_deg=90.0 - np.degrees(angle))  # clockwise from grid north
    return columns


def _drift_feature(result: BlockAnalysis, pair: DriftPair, i: int, sigma) -> dict:
    """The GeoJSON LineString of drift vector ``i`` of ``pair`` (RFC 7946: [longitude, latitude] degrees)."""
    plane = result.project.plane
    ends = [plane.inverse(*xy) for xy in (pair.start[i], pair.start[i] + pair.displacement[i])]
    return {"type": "Feature", "geometry": {"type": "LineString", "coordinates": [
        [float(np.degrees(lon)), float(np.degrees(lat))] for lat, lon in ends]}, "properties": {
        "point": result.point_ids[pair.points[i]], "dx_m": float(pair.vectors.displacement[i, 0]),
        "dy_m": float(pair.vectors.displacement[i, 1]), "sigma_dx_m": _json_number(sigma[i, 0]),
        "sigma_dy_m": _json_number(sigma[i, 1]), "speed_m_s": float(pair.vectors.speed[i]),
        "direction_deg": float(pair.vectors.direction[i]), "relative_dx_m": float(pair.rigid.residuals[i, 0]),
        "relative_dy_m": float(pair.rigid.residuals[i, 1])}}


def _write_drift(result: BlockAnalysis, out: Path) -> list[Path]:
    """``drift.csv`` and ``drift.geojson`` (nothing if no pair has drift)."""
    if not result.drift:
        return []
    names = [c.name for c in result.project.coverages]
    columns = {k: [] for k in ("point", "from", "to", "dx_m", "dy_m", "sigma_dx_m", "sigma_dy_m", "speed_m_s",
                               "direction_deg", "relative_dx_m", "relative_dy_m")}
    features = []
    for pair in result.drift:
        k = pair.points.size
        sigma = (np.full((k, 2), np.nan) if pair.covariance is None
                 else np.sqrt(np.diagonal(pair.covariance, axis1=1, axis2=2)))
        values = {"point": [result.point_ids[p] for p in pair.points], "from": [names[pair.first]] * k,
                  "to": [names[pair.second]] * k, "dx_m": pair.vectors.displacement[:, 0],
                  "dy_m": pair.vectors.displacement[:, 1], "sigma_dx_m": sigma[:, 0], "sigma_dy_m": sigma[:, 1],
                  "speed_m_s": pair.vectors.speed, "direction_deg": pair.vectors.direction,
                  "relative_dx_m": pair.rigid.residuals[:, 0], "relative_dy_m": pair.rigid.residuals[:, 1]}
        for name, value in values.items():
            columns[name] += list(value)
        features += [_drift_feature(result, pair, i, sigma) for i in range(k)]
    return [write_csv(out / "drift.csv", columns), write_geojson(out / "drift.geojson", features)]


def _navigation_curves(result: BlockAnalysis):
    """``(label, times, error (k, 2), sigma (k, 2))`` of every strip's estimated navigation error (m)."""
    assert result.adjustment is not None
    strips = [s for c in result.project.coverages for s in c.strips]
    curves = []
    for estimate, strip in zip(result.adjustment.strips, strips, strict=True):
        times = strip.record_times[(strip.record_times >= strip.start_time) & (strip.record_times <= strip.end_time)]
        curves.append((f"{estimate.coverage}/{estimate.name}", times, *estimate.navigation_error(times)))
    return curves


def _write_simultaneous_tables(result: BlockAnalysis, out: Path) -> list[Path]:
    """``strips.csv``, ``navigation_errors.csv`` and ``observations.csv`` of the simultaneous adjustment."""
    adjustment, coverages = result.adjustment, result.project.coverages
    assert adjustment is not None
    strips, curves = adjustment.strips, _navigation_curves(result)
    return [
        write_csv(out / "strips.csv", {"coverage": [s.coverage for s in strips], "strip": [s.name for s in strips],
                                       "sweep_delay_mm": [s.sweep_delay for s in strips],
                                       "sigma_sweep_delay_mm": [s.sigma_sweep_delay for s in strips],
                                       "range_scale_m_per_mm": [s.range_scale for s in strips],
                                       "sigma_range_scale_m_per_mm": [s.sigma_range_scale for s in strips]}),
        write_csv(out / "navigation_errors.csv", {
            "strip": [label for label, t, *_ in curves for _ in t],
            "time_s": np.concatenate([t for _, t, *_ in curves]),
            "north_m": np.concatenate([e[:, 0] for *_, e, _ in curves]),
            "east_m": np.concatenate([e[:, 1] for *_, e, _ in curves]),
            "sigma_north_m": np.concatenate([s[:, 0] for *_, s in curves]),
            "sigma_east_m": np.concatenate([s[:, 1] for *_, s in curves])}),
        write_csv(out / "observations.csv", {
            "point": [result.point_ids[p] for p in adjustment.point_of],
            "coverage": [coverages[c].name for c in adjustment.coverage_of],
            "strip": [coverages[c].strips[s].name for c, s in zip(adjustment.coverage_of, adjustment.strip_of,
                                                                  strict=True)],
            "residual_x_mm": adjustment.residuals[:, 0], "residual_y_mm": adjustment.residuals[:, 1],
            "redundancy_x": adjustment.redundancy[:, 0], "redundancy_y": adjustment.redundancy[:, 1],
            "w_x": adjustment.w[:, 0], "w_y": adjustment.w[:, 1]}),
        plot_navigation_errors(out / "navigation_errors.png", curves, "Estimated navigation errors with ±1σ bands"),
    ]


def _sequential_figures(result: BlockAnalysis, out: Path) -> list[Path]:
    """Per coverage: radar minus known position at the control points (before the external adjustment) and the
    tie discrepancies before and after."""
    files = []
    n = len(result.point_ids)
    for k, (coverage, sequential) in enumerate(zip(result.project.coverages, result.sequential, strict=True), 1):
        internal = sequential.point_positions(coverage.measurements, n, "internal")
        known = [p for p in coverage.control if np.isfinite(internal[p]).all()]
        if known:
            where = np.array([coverage.control[p][:2] for p in known])
            files.append(plot_vectors(out / f"control_discrepancies_c{k}.png", where, internal[known] - where,
                                      f"Radar minus known position at the control points, {coverage.name}",
                                      "before the external adjustment (source 000, Figs 5 and 6)",
                                      background=internal[np.isfinite(internal).all(axis=1)],
                                      projection=result.project.plane))
        if sequential.tie_before.size:
            files.append(plot_tie_discrepancies(out / f"tie_discrepancies_c{k}.png", sequential.tie_before,
                                                sequential.tie_after))
    return files


def _simultaneous_figures(result: BlockAnalysis, out: Path) -> list[Path]:
    """Per coverage: the tie discrepancies after the adjustment."""
    assert result.adjustment is not None
    files = []
    for k in range(1, len(result.project.coverages) + 1):
        ties = result.adjustment.tie_discrepancies(k - 1)
        if ties.size:
            files.append(plot_tie_discrepancies(out / f"tie_discrepancies_c{k}.png", None, ties))
    return files


def _drift_figures(result: BlockAnalysis, out: Path) -> list[Path]:
    """Per coverage pair: the drift (source 000, Fig. 7) and the relative motion (Fig. 8), with 95 % ellipses."""
    names = [c.name for c in result.project.coverages]
    files = []
    for pair in result.drift:
        files.append(plot_vectors(out / f"drift_c{pair.second}.png", pair.start, pair.vectors.displacement,
                                  f"Drift {names[pair.first]} -> {names[pair.second]}", "source 000, Fig. 7",
                                  covariances=pair.covariance, projection=result.project.plane))
        files.append(plot_vectors(out / f"relative_motion_c{pair.second}.png", pair.start, pair.rigid.residuals,
                                  "Relative motion after removing the general (rigid) drift", "source 000, Fig. 8",
                                  covariances=pair.covariance, projection=result.project.plane))
    return files


_log = logging.getLogger(__name__)
"""Where :func:`run_block` reports its stages when no ``say`` is given (INFO)."""


def write_block(result: BlockAnalysis, out_dir: str | os.PathLike, report: str | None = None) -> tuple[Path, ...]:
    """Write ``adjusted_points.csv`` (with σ and 95 % error ellipses for the simultaneous method), ``drift.csv``,
    ``drift.geojson``, figures and ``report.txt`` (``report``, default :func:`block_report`); the simultaneous method
    adds ``strips.csv``, ``navigation_errors.csv`` and ``observations.csv`` (residuals, redundancy numbers,
    w-tests). Returns the paths written."""
    out = Path(out_dir)
    files = [write_csv(out / "adjusted_points.csv", _point_columns(result)), *_write_drift(result, out)]
    if result.method == "sequential":
        files += _sequential_figures(result, out)
    else:
        files += _write_simultaneous_tables(result, out) + _simultaneous_figures(result, out)
    files += _drift_figures(result, out)
    with atomic_path(out / "report.txt") as temporary:
        temporary.write_text((block_report(result) if report is None else report) + "\n")
    return (*files, out / "report.txt")


def run_block(project_path: str | os.PathLike, out_dir: str | os.PathLike, method: str = "simultaneous",
              options: BlockOptions | None = None, overwrite: bool = False,
              say: Callable[[str], None] | None = None) -> BlockRun:
    """Read the project, :func:`adjust_block` it, and :func:`write_block` its files into ``out_dir`` (one run, one
    folder: :func:`~seaice_jax.outputs.output_folder`; ``overwrite`` replaces an existing one whole); ``say``
    receives a message as each stage starts (the command line prints them; default: this module's logger,
    ``seaice_jax.workflows.radar_block``, at INFO)."""
    say = say or _log.info
    with output_folder(out_dir, overwrite, inputs=(project_path,)) as folder:
        say(f"reading {project_path}")
        project = read_project(project_path)
        say(f"adjusting the block ({method}; the first run compiles for a minute or more)")
        result = adjust_block(project, method, options)
        report = block_report(result)
        say("writing tables and figures")
        files = folder.final(write_block(result, folder.path, report))
    return BlockRun(files, report, result)
