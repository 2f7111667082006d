"""``seaice demo``: the main job on the built-in scenario (grows with the project).

Geolocates a simulated radar strip (range-Doppler, source 000 eq. A5) and the satellite image of source 001
Figure 3-3 (great-circle scan model), checks both by their inverses, compares the Figure 3-3 stations with the
printed deviations, fits the image's orbit and scan parameters to the five stations from no prior knowledge
(Gauss-Newton, with covariance), adjusts a small radar block by both methods, and runs a short simulated image
sequence through rectification, remapping, tracking, velocities and a film; writes CSV tables, reports, NetCDF,
GeoTIFF, GeoJSON and PNG maps.
"""

import os
from dataclasses import dataclass
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from seaice_jax.adjust.orbit_fit import ControlPoints, fit_scan_model, position_uncertainty
from seaice_jax.geometry.earth import latitude_longitude
from seaice_jax.geometry.projections import TangentPlane, nsidc_polar_stereographic
from seaice_jax.geometry.range_doppler import ground_point, imaging_time_and_range
from seaice_jax.image_sequence import run_movie, run_remap, run_track, run_velocities, write_simulated_sequence
from seaice_jax.imagery.remap import remap
from seaice_jax.imagery.tracking import track
from seaice_jax.io.files import atomic_path, write_csv, write_json
from seaice_jax.io.project import write_project
from seaice_jax.plots import MapLayer, MapPanel, plot_image_field, plot_maps
from seaice_jax.radar_block import run_block
from seaice_jax.reports import orbit_fit_json, orbit_fit_report
from seaice_jax.simulate.aircraft import FlightPlan, aidjex_scenario
from seaice_jax.simulate.satellite import simulate_sequence, true_displacement
from seaice_jax.simulate.scenarios import FIGURE_3_3_STATIONS, demo_radar_strip, figure_3_3_image

_DEG = np.pi / 180.0


@dataclass(frozen=True)
class DemoResult:
    """What the demo wrote and the numbers its summary reports."""

    files: tuple[Path, ...]
    radar_points: int
    radar_time_error_s: float
    radar_range_error_m: float
    image_points: int
    image_round_trip_pixels: float
    station_dlat_difference_arcmin: float
    station_dlon_difference_arcmin: float
    fit_rms_km: float
    fit_subtrack_pixel: float
    summary: str


def _compare_methods(scenario, runs) -> list[str]:
    """Lines comparing block adjustments with the simulation's truth: stations and drift of the ice features."""
    lines = []
    for name, run in runs.items():
        index = np.array([int(p[1:]) - 1 for p in run.point_ids])  # write_project names feature i "P{i + 1:04d}"
        truth = [c.truth[index] for c in scenario.coverages]
        kinds = scenario.kinds[index]
        stations = kinds == "station"
        station = np.concatenate([run.positions[c][stations] - truth[c][stations] for c in range(2)])
        drift = (run.positions[1] - run.positions[0]) - (truth[1] - truth[0])
        drift = drift[(kinds == "ice") & np.isfinite(drift).all(axis=1)]
        s, d = (np.sqrt(np.mean(v**2, axis=0)) / 1000 for v in (station, drift))
        lines.append(f"{name:<18} stations {s[0]:.3f} / {s[1]:.3f}, drift {d[0]:.3f} / {d[1]:.3f}")
    return lines


def _image_sequence(out_dir: Path):
    """Four simulated NOAA-7-like images of moving pack ice (one cloudy) through the whole workflow, and the
    tracked drift against the simulation's truth."""
    sequence = simulate_sequence(0, n_images=4, size=160, clouds=True)
    project = write_simulated_sequence(out_dir / "project", sequence=sequence)
    remapped = run_remap(project, out_dir / "remapped", progress=False)
    tracked = run_track(out_dir / "remapped", out_dir / "drift", progress=False)
    speeds = run_velocities(out_dir / "drift" / "floes.csv", out_dir / "velocities", box_size=75_000.0)
    film = run_movie(out_dir / "remapped", out_dir / "film.gif", land_mask=out_dir / "project" / "land_mask.npy",
                     records=out_dir / "drift" / "floes.csv")
    # tracked displacements of the first pair against the truth, with the fitted and with the true scan models
    grid = remapped.results["grid"]
    first, second = sequence.images[:2]
    errors = {}
    for label, models in (("fitted", remapped.results["models"]), ("true", [first.model, second.model])):
        values, valid = remap([first.data, second.data], models[:2], grid)
        d = track(values[0], values[1], valid_first=valid[0], valid_second=valid[1])
        vectors = d.in_map(grid)
        xy = np.stack([vectors["x"], vectors["y"]], 1)[d.good]
        truth = true_displacement(sequence.scene, xy, first.time, second.time)
        measured = np.stack([vectors["dx"], vectors["dy"]], 1)[d.good]
        length = np.hypot(*(measured - truth).T)
        errors[label] = (float(np.median(length)) / 1000, float(np.sqrt(np.mean(length**2))) / 1000, d.good.sum())
    lines = ["  satellite image sequence (4 simulated NOAA-7 passes over Lancaster-like pack ice, one day apart; "
             "sequence/):",
             *["    " + line for line in remapped.report.splitlines()],
             *["    " + line for line in tracked.report.splitlines()],
             *["    " + line for line in speeds.report.splitlines()],
             f"    {film.report}",
             f"    tracked drift of the first pair against the truth ({errors['fitted'][2]} vectors), error "
             f"length median / RMS: {errors['fitted'][0]:.2f} / {errors['fitted'][1]:.2f} km with the fitted scan "
             f"models, {errors['true'][0]:.2f} / {errors['true'][1]:.2f} km with the true ones: the rectification "
             "limits it; the RMS comes from vectors straddling the fast-ice edge and cloud edges"]
    return lines, [*remapped.files, *tracked.files, *speeds.files, *film.files]


def run_demo(out_dir: str | os.PathLike = "seaice-demo") -> DemoResult:
    """Run the demo and write its files into ``out_dir`` (created if missing)."""
    out_dir = Path(out_dir)
    files = []

    # Radar strip: every image line (time) x range sample -> ground point, and back.
    strip = demo_radar_strip()
    position, velocity = strip.trajectory(jnp.asarray(strip.times))
    shape = (strip.times.size, strip.slant_ranges.size)
    points = ground_point(jnp.broadcast_to(position[:, None, :], shape + (3,)),
                          jnp.broadcast_to(velocity[:, None, :], shape + (3,)),
                          jnp.broadcast_to(jnp.asarray(strip.slant_ranges)[None, :], shape),
                          look_side=strip.look_side)
    time_back, range_back = imaging_time_and_range(points, strip.trajectory, strip.times[0] - 60.0,
                                                   strip.times[-1] + 60.0)
    time_grid, range_grid = np.meshgrid(strip.times, strip.slant_ranges, indexing="ij")
    time_error = float(np.max(np.abs(np.asarray(time_back) - time_grid)))
    range_error = float(np.max(np.abs(np.asarray(range_back) - range_grid)))
    radar_lat, radar_lon = (np.asarray(a) for a in latitude_longitude(points))
    centre = TangentPlane(float(np.mean(radar_lat)), float(np.mean(radar_lon)))
    radar_x, radar_y = (np.asarray(a) for a in centre.forward(radar_lat, radar_lon))
    files.append(write_csv(out_dir / "radar_strip.csv", {
        "time_s": time_grid, "slant_range_m": range_grid,
        "latitude_deg": radar_lat / _DEG, "longitude_deg": radar_lon / _DEG,
        "tangent_plane_x_m": radar_x, "tangent_plane_y_m": radar_y,
    }))

    # Satellite image of Figure 3-3: a pixel/scan grid -> latitude/longitude, and back.
    model = figure_3_3_image()
    pixel, scan = np.meshgrid(np.linspace(1, 512, 17), np.linspace(1, 512, 17), indexing="ij")
    image_lat, image_lon = (np.asarray(a) for a in model.forward(pixel, scan))
    pixel_back, scan_back = model.inverse(image_lat, image_lon)
    round_trip = float(np.max(np.hypot(np.asarray(pixel_back) - pixel, np.asarray(scan_back) - scan)))
    polar = nsidc_polar_stereographic("north")
    image_x, image_y = (np.asarray(a) for a in polar.forward(image_lat, image_lon))
    files.append(write_csv(out_dir / "satellite_image.csv", {
        "pixel": pixel, "scan": scan, "latitude_deg": image_lat / _DEG, "longitude_deg": image_lon / _DEG,
        "epsg3413_x_m": image_x, "epsg3413_y_m": image_y,
    }))

    stations = FIGURE_3_3_STATIONS
    station_lat, station_lon = (np.asarray(a) / _DEG for a in model.forward(
        np.array([s.pixel for s in stations], float), np.array([s.scan for s in stations], float)))
    dlat = (station_lat - np.array([s.latitude_deg for s in stations])) * 60.0
    dlon = (station_lon - np.array([s.longitude_deg for s in stations])) * 60.0
    printed_dlat = np.array([s.printed_dlat_arcmin for s in stations])
    printed_dlon = np.array([s.printed_dlon_arcmin for s in stations])
    files.append(write_csv(out_dir / "figure_3_3_stations.csv", {
        "id": [s.number for s in stations], "name": [s.name for s in stations],
        "pixel": [s.pixel for s in stations], "scan": [s.scan for s in stations],
        "latitude_deg": [s.latitude_deg for s in stations], "longitude_deg": [s.longitude_deg for s in stations],
        "dlat_arcmin": dlat, "dlon_arcmin": dlon,
        "printed_dlat_arcmin": printed_dlat, "printed_dlon_arcmin": printed_dlon,
    }))
    known_x, known_y = (np.asarray(a) for a in polar.forward(
        np.array([s.latitude_deg for s in stations]) * _DEG, np.array([s.longitude_deg for s in stations]) * _DEG))

    files.append(plot_maps(out_dir / "map.png", [
        MapPanel(centre, [MapLayer("radar strip: lines every 20 s, ranges 10.5-30 km", radar_x, radar_y, "grid")],
                 "Simulated radar strip (range-Doppler, right-looking)\ntangent plane at the strip centre"),
        MapPanel(polar, [
            MapLayer("NOAA-7 image of source 001 Fig. 3-3 (every 32nd pixel/line)", image_x, image_y, "grid"),
            MapLayer("reference stations", known_x, known_y, "labelled", [s.name for s in stations]),
        ], "Satellite image (great-circle scan model)\nNSIDC polar stereographic EPSG:3413"),
    ], "seaice_jax demo: geolocation by the two geometric models"))

    # Orbit fit from the five stations alone (no starting values), with its report and uncertainty map.
    control = ControlPoints.from_degrees([s.pixel for s in stations], [s.scan for s in stations],
                                         [s.latitude_deg for s in stations], [s.longitude_deg for s in stations],
                                         1.0, [str(s.number) for s in stations])
    fit = fit_scan_model(control, model.orbit, direction="auto")
    names = {str(s.number): s.name for s in stations}
    report = orbit_fit_report(fit, names=names)
    report_path = out_dir / "orbit_fit_report.txt"
    with atomic_path(report_path) as temporary:
        temporary.write_text(report + "\n")
    files.append(report_path)
    files.append(write_json(out_dir / "orbit_fit.json", orbit_fit_json(fit)))
    grid_pixel, grid_scan = np.meshgrid(np.linspace(1, 512, 33), np.linspace(1, 512, 33))
    sigma_north, sigma_east = (np.asarray(a) for a in position_uncertainty(fit, grid_pixel, grid_scan,
                                                                            a_priori=True))
    files.append(plot_image_field(
        out_dir / "position_sigma.png", grid_pixel, grid_scan, np.hypot(sigma_north, sigma_east) / 1000.0,
        "Position uncertainty of the fitted image (5 stations, 1 km each)\n"
        "from the covariance of the five orbit/scan unknowns", "σ of ground position (km)",
        ([s.pixel for s in stations], [s.scan for s in stations], [s.name for s in stations])))

    # A small simulated AIDJEX-like block (3 strips, two coverages 16 days apart) by both methods.
    scenario = aidjex_scenario(0, plan=FlightPlan(strips=3), features=200)
    block_project = write_project(scenario, out_dir / "aidjex")
    block = run_block(block_project, out_dir / "aidjex" / "simultaneous")
    sequential = run_block(block_project, out_dir / "aidjex" / "sequential", method="sequential")
    files += [block_project, *block.files, *sequential.files]
    comparison = _compare_methods(scenario, {"sequential (1979)": sequential, "simultaneous": block})

    # A short satellite image sequence: rectify on land control, remap, track, velocities, film.
    sequence_lines, sequence_files = _image_sequence(out_dir / "sequence")
    files += sequence_files

    dlat_difference = float(np.max(np.abs(dlat - printed_dlat)))
    dlon_difference = float(np.max(np.abs(dlon - printed_dlon)))
    lines = [
        "seaice_jax demo",
        f"  radar strip: {radar_lat.size} points, {strip.times[-1] - strip.times[0]:.0f} s of flight at 10 km, "
        f"ground swath {np.ptp(radar_y) / 1000:.0f} x {np.ptp(radar_x) / 1000:.0f} km",
        f"    inverse(forward): time error {time_error:.1e} s, range error {range_error:.1e} m",
        f"  satellite image (source 001 Fig. 3-3, NOAA-7, southbound): {image_lat.size} grid points,",
        f"    latitude {np.min(image_lat) / _DEG:.2f}..{np.max(image_lat) / _DEG:.2f} deg, "
        f"longitude {np.min(image_lon) / _DEG:.2f}..{np.max(image_lon) / _DEG:.2f} deg",
        f"    inverse(forward): {round_trip:.1e} pixel",
        "    Figure 3-3 stations, computed minus known vs printed (arc minutes):",
        *[f"      {s.number} {s.name:<11} DLAT {a:+.2f} (printed {s.printed_dlat_arcmin:+.4f})  "
          f"DLONG {b:+.2f} (printed {s.printed_dlon_arcmin:+.4f})"
          for s, a, b in zip(stations, dlat, dlon, strict=True)],
        f"    largest difference from the printout: {dlat_difference:.2f}' lat, {dlon_difference:.2f}' lon "
        "(the printed parameters are rounded)",
        "  orbit fit to the five stations from no prior knowledge (Gauss-Newton; 1985 printout: subtrack 112, "
        "node 66.65, DEV 0.5687'/0.6017'):",
        *["    " + line for line in report.splitlines()],
        "  radar block (simulated AIDJEX, 3 strips, 16 days of drift; project in aidjex/, results in "
        "aidjex/simultaneous/ and aidjex/sequential/):",
        *["    " + line for line in block.report.splitlines()],
        "    both methods against the simulation's truth (RMS per coordinate x / y, km):",
        *["      " + line for line in comparison],
        *sequence_lines,
        f"  wrote {len(files)} files into {out_dir}/ (map.png, position_sigma.png, orbit_fit_report.txt, "
        "aidjex/simultaneous/report.txt, sequence/film.gif, ...)",
    ]
    summary = "\n".join(lines)
    return DemoResult(tuple(files), radar_lat.size, time_error, range_error, image_lat.size, round_trip,
                      dlat_difference, dlon_difference, fit.rms_km, float(fit.model.subtrack_pixel), summary)
