"""``seaice demo``: the main job on the built-in scenario (grows with the project).

Geolocates a simulated radar strip (range-Doppler, source 000 eq. A5) and the satellite image of source 001
Figure 3-3 (great-circle scan model), checks both by their inverses, compares the Figure 3-3 stations with the
printed deviations, fits the image's orbit and scan parameters to the five stations from no prior knowledge
(Gauss-Newton, with covariance), adjusts a small radar block by both methods, and runs a short simulated image
sequence through rectification, remapping, tracking, velocities and a film; writes CSV tables, reports, NetCDF,
GeoTIFF, GeoJSON and PNG maps.
"""

import logging
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from seaice_jax.adjust.orbit.fit import fit_scan_model, position_uncertainty
from seaice_jax.errors import SeaiceError
from seaice_jax.files import atomic_path, write_csv, write_json
from seaice_jax.geometry.earth import latitude_longitude
from seaice_jax.geometry.projections import TangentPlane, nsidc_polar_stereographic
from seaice_jax.geometry.range_doppler import ground_point, imaging_time_and_range
from seaice_jax.geometry.scan import ScanModel
from seaice_jax.imagery.remap import remap
from seaice_jax.imagery.tracking import track
from seaice_jax.io.coastline import land_mask_of_grid
from seaice_jax.io.project import write_project
from seaice_jax.outputs import foreign_output, output_folder, write_manifest
from seaice_jax.report.figures import MapLayer, MapPanel, plot_image_field, plot_maps
from seaice_jax.report.text import orbit_fit_json, orbit_fit_report
from seaice_jax.sensors.control import ControlPoints
from seaice_jax.simulate.aircraft import FlightPlan, aidjex_scenario
from seaice_jax.simulate.satellite import simulate_sequence, true_displacement
from seaice_jax.simulate.scenarios import FIGURE_3_3_STATIONS, demo_radar_strip, figure_3_3_image
from seaice_jax.workflows.movie import run_movie
from seaice_jax.workflows.radar_block import run_block
from seaice_jax.workflows.remap import run_remap
from seaice_jax.workflows.sequence_adjust import run_adjust
from seaice_jax.workflows.simulated_sequence import write_simulated_sequence
from seaice_jax.workflows.track import run_track
from seaice_jax.workflows.velocities import run_velocities


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
        result = run.result
        index = np.array([int(p[1:]) - 1 for p in result.point_ids])  # write_project names feature i "P{i + 1:04d}"
        truth = [c.positions[index] for c in scenario.truth]
        kinds = scenario.kinds[index]
        stations = kinds == "station"
        station = np.concatenate([result.positions[c][stations] - truth[c][stations] for c in range(2)])
        drift = (result.positions[1] - result.positions[0]) - (truth[1] - truth[0])
        drift = drift[(kinds == "ice") & np.isfinite(drift).all(axis=1)]
        s, d = (np.sqrt(np.mean(v**2, axis=0)) / 1000 for v in (station, drift))
        lines.append(f"{name:<18} stations {s[0]:.3f} / {s[1]:.3f}, drift {d[0]:.3f} / {d[1]:.3f}")
    return lines


def _image_sequence(out_dir: Path, images: int, size: int, say: Callable[[str], None]):
    """``images`` simulated NOAA-7-like images (``size`` pixels square) of moving pack ice (one cloudy) through the
    whole workflow (``seaice adjust``: all images at once, ties on land and fast ice; remap with the adjusted
    models, track, velocities, film), and the tracked drift against the simulation's truth with the per-image fits,
    the adjusted and the true models."""
    say(f"image sequence: simulating {images} images of {size} x {size} pixels")
    sequence = simulate_sequence(0, n_images=images, size=size, clouds=True)
    project = write_simulated_sequence(out_dir / "project", sequence=sequence)
    say("image sequence: adjusting all images at once (ties on land and fast ice)")
    adjusted = run_adjust(project, out_dir / "adjusted", progress=False)
    say("image sequence: remapping with the adjusted models")
    remapped = run_remap(project, out_dir / "remapped", progress=False, models_path=out_dir / "adjusted" / "models.npz")
    say("image sequence: tracking the ice")
    tracked = run_track(out_dir / "remapped", out_dir / "drift", progress=False)
    say("image sequence: velocities, deformation and the film")
    speeds = run_velocities(out_dir / "drift" / "floes.csv", out_dir / "velocities", box_size=75_000.0)
    film = run_movie(out_dir / "remapped", out_dir / "film.gif", land_mask=out_dir / "project" / "land_mask.npy",
                     records=out_dir / "drift" / "floes.csv")
    # tracked displacements of the first pair against the truth, with the fitted and with the true scan models (land
    # masked as `seaice track` masks it)
    grid = remapped.result.grid
    land = land_mask_of_grid(grid)
    first, second = sequence.images[:2]
    errors = {}
    for label, models in (("per image", adjusted.result.start), ("adjusted", remapped.result.models),
                          ("true", [first.model, second.model])):
        values, valid = remap([first.data, second.data], models[:2], grid)
        d = track(values[0], values[1], valid_first=valid[0], valid_second=valid[1], land=land)
        vectors = d.in_map(grid)
        xy = np.stack([vectors["x"], vectors["y"]], 1)[d.good]
        truth = true_displacement(sequence.scene, xy, first.time, second.time)
        measured = np.stack([vectors["dx"], vectors["dy"]], 1)[d.good]
        length = np.hypot(*(measured - truth).T)
        errors[label] = (float(np.median(length)) / 1000, float(np.sqrt(np.mean(length**2))) / 1000, d.good.sum())
    lines = [f"  satellite image sequence ({images} simulated NOAA-7 passes over Lancaster-like pack ice, one day "
             "apart; sequence/):",
             *["    " + line for line in adjusted.report.splitlines()],
             *["    " + line for line in remapped.report.splitlines()],
             *["    " + line for line in tracked.report.splitlines()],
             *["    " + line for line in speeds.report.splitlines()],
             f"    {film.report.replace(str(out_dir.parent) + os.sep, '')}",
             f"    tracked drift of the first pair against the truth ({errors['adjusted'][2]} vectors), error "
             f"length median / RMS: {errors['per image'][0]:.2f} / {errors['per image'][1]:.2f} km with the "
             f"per-image fits (1985), {errors['adjusted'][0]:.2f} / {errors['adjusted'][1]:.2f} km with the "
             f"simultaneous adjustment, {errors['true'][0]:.2f} / {errors['true'][1]:.2f} km with the true models; "
             "good vectors only: those whose patch straddles the fast-ice edge or a coast are flagged mixed motion"]
    return lines, [*adjusted.files, *remapped.files, *tracked.files, *speeds.files, *film.files]


@dataclass(frozen=True)
class RadarStripCheck:
    """A simulated radar strip geolocated (every image line x range sample) and checked by the inverse.

    Attributes:
        times, ranges: ``(lines, samples)`` s and m. latitude, longitude: ``(lines, samples)`` rad.
        plane: the tangent plane at the strip centre; x, y: ``(lines, samples)`` m in it.
        time_error, range_error: largest error of inverse(forward), s and m. duration: s of flight.
    """

    times: np.ndarray
    ranges: np.ndarray
    latitude: np.ndarray
    longitude: np.ndarray
    plane: TangentPlane
    x: np.ndarray
    y: np.ndarray
    time_error: float
    range_error: float
    duration: float


@dataclass(frozen=True)
class ImageCheck:
    """The satellite image of source 001 Figure 3-3 geolocated on a pixel/scan grid and checked by the inverse,
    and its five stations against the printed deviations.

    Attributes:
        model: the printed scan model. pixel, scan: ``(17, 17)`` grid. latitude, longitude: rad; x, y: m in
        EPSG:3413. round_trip: largest inverse(forward) error, pixels. dlat, dlon: ``(5,)`` computed minus known
        station positions, arc minutes.
    """

    model: ScanModel
    pixel: np.ndarray
    scan: np.ndarray
    latitude: np.ndarray
    longitude: np.ndarray
    x: np.ndarray
    y: np.ndarray
    round_trip: float
    dlat: np.ndarray
    dlon: np.ndarray

    @property
    def printed_dlat(self) -> np.ndarray:
        return np.array([s.printed_dlat_arcmin for s in FIGURE_3_3_STATIONS])

    @property
    def printed_dlon(self) -> np.ndarray:
        return np.array([s.printed_dlon_arcmin for s in FIGURE_3_3_STATIONS])


def geolocate_radar_strip() -> RadarStripCheck:
    """Every image line (time) x range sample of the demo strip -> ground point (source 000 eq. A5), and back."""
    strip = demo_radar_strip()
    position, velocity = strip.trajectory(jnp.asarray(strip.times))
    shape = (strip.times.size, strip.slant_ranges.size)
    points = ground_point(jnp.broadcast_to(position[:, None, :], shape + (3,)),
                          jnp.broadcast_to(velocity[:, None, :], shape + (3,)),
                          jnp.broadcast_to(jnp.asarray(strip.slant_ranges)[None, :], shape),
                          look_side=strip.look_side)
    time_back, range_back = imaging_time_and_range(points, strip.trajectory, strip.times[0] - 60.0,
                                                   strip.times[-1] + 60.0)
    times, ranges = np.meshgrid(strip.times, strip.slant_ranges, indexing="ij")
    latitude, longitude = (np.asarray(a) for a in latitude_longitude(points))
    plane = TangentPlane(float(np.mean(latitude)), float(np.mean(longitude)))
    x, y = (np.asarray(a) for a in plane.forward(latitude, longitude))
    return RadarStripCheck(times, ranges, latitude, longitude, plane, x, y,
                           float(np.max(np.abs(np.asarray(time_back) - times))),
                           float(np.max(np.abs(np.asarray(range_back) - ranges))),
                           float(strip.times[-1] - strip.times[0]))


def geolocate_figure_3_3() -> ImageCheck:
    """A pixel/scan grid of the Figure 3-3 image -> latitude/longitude (great-circle scan model) and back; the
    stations' computed minus known positions."""
    model = figure_3_3_image()
    pixel, scan = np.meshgrid(np.linspace(1, 512, 17), np.linspace(1, 512, 17), indexing="ij")
    latitude, longitude = (np.asarray(a) for a in model.forward(pixel, scan))
    pixel_back, scan_back = model.inverse(latitude, longitude)
    x, y = (np.asarray(a) for a in nsidc_polar_stereographic("north").forward(latitude, longitude))
    stations = FIGURE_3_3_STATIONS
    station_lat, station_lon = (np.degrees(np.asarray(a)) for a in model.forward(
        np.array([s.pixel for s in stations], float), np.array([s.scan for s in stations], float)))
    return ImageCheck(model, pixel, scan, latitude, longitude, x, y,
                      float(np.max(np.hypot(np.asarray(pixel_back) - pixel, np.asarray(scan_back) - scan))),
                      (station_lat - np.array([s.latitude_deg for s in stations])) * 60.0,
                      (station_lon - np.array([s.longitude_deg for s in stations])) * 60.0)


def _write_geolocation(radar: RadarStripCheck, image: ImageCheck, out_dir: Path) -> list[Path]:
    """``radar_strip.csv``, ``satellite_image.csv``, ``figure_3_3_stations.csv`` and ``map.png``."""
    stations = FIGURE_3_3_STATIONS
    polar = nsidc_polar_stereographic("north")
    known_x, known_y = (np.asarray(a) for a in polar.forward(
        np.radians([s.latitude_deg for s in stations]), np.radians([s.longitude_deg for s in stations])))
    return [
        write_csv(out_dir / "radar_strip.csv", {
            "time_s": radar.times, "slant_range_m": radar.ranges, "latitude_deg": np.degrees(radar.latitude),
            "longitude_deg": np.degrees(radar.longitude), "tangent_plane_x_m": radar.x, "tangent_plane_y_m": radar.y}),
        write_csv(out_dir / "satellite_image.csv", {
            "pixel": image.pixel, "scan": image.scan, "latitude_deg": np.degrees(image.latitude),
            "longitude_deg": np.degrees(image.longitude), "epsg3413_x_m": image.x, "epsg3413_y_m": image.y}),
        write_csv(out_dir / "figure_3_3_stations.csv", {
            "id": [s.number for s in stations], "name": [s.name for s in stations],
            "pixel": [s.pixel for s in stations], "scan": [s.scan for s in stations],
            "latitude_deg": [s.latitude_deg for s in stations], "longitude_deg": [s.longitude_deg for s in stations],
            "dlat_arcmin": image.dlat, "dlon_arcmin": image.dlon,
            "printed_dlat_arcmin": image.printed_dlat, "printed_dlon_arcmin": image.printed_dlon}),
        plot_maps(out_dir / "map.png", [
            MapPanel(radar.plane, [MapLayer("radar strip: lines every 20 s, ranges 10.5-30 km", radar.x, radar.y,
                                            "grid")],
                     "Simulated radar strip (range-Doppler, right-looking)\ntangent plane at the strip centre"),
            MapPanel(polar, [
                MapLayer("NOAA-7 image of source 001 Fig. 3-3 (every 32nd pixel/line)", image.x, image.y, "grid"),
                MapLayer("reference stations", known_x, known_y, "labelled", [s.name for s in stations]),
            ], "Satellite image (great-circle scan model)\nNSIDC polar stereographic EPSG:3413"),
        ], "seaice_jax demo: geolocation by the two geometric models"),
    ]


def _orbit_fit(model: ScanModel, out_dir: Path):
    """The orbit fit from the five stations alone (no starting values): ``(fit, report, files)`` with the report,
    its JSON and the position-uncertainty map."""
    stations = FIGURE_3_3_STATIONS
    control = ControlPoints.from_degrees([s.pixel for s in stations], [s.scan for s in stations],
                                         [s.latitude_deg for s in stations], [s.longitude_deg for s in stations],
                                         1.0, [str(s.number) for s in stations])
    fit = fit_scan_model(control, model.orbit, direction="auto", n_pixels=model.n_pixels,
                         n_scans=model.n_scans)
    report = orbit_fit_report(fit, names={str(s.number): s.name for s in stations})
    report_path = out_dir / "orbit_fit_report.txt"
    with atomic_path(report_path) as temporary:
        temporary.write_text(report + "\n")
    grid_pixel, grid_scan = np.meshgrid(np.linspace(1, 512, 33), np.linspace(1, 512, 33))
    sigma_north, sigma_east = (np.asarray(a) for a in position_uncertainty(fit, grid_pixel, grid_scan,
                                                                            a_priori=True))
    files = [report_path, write_json(out_dir / "orbit_fit.json", orbit_fit_json(fit)), plot_image_field(
        out_dir / "position_sigma.png", grid_pixel, grid_scan, np.hypot(sigma_north, sigma_east) / 1000.0,
        "Position uncertainty of the fitted image (5 stations, 1 km each)\n"
        "from the covariance of the five orbit/scan unknowns", "σ of ground position (km)",
        ([s.pixel for s in stations], [s.scan for s in stations], [s.name for s in stations]))]
    return fit, report, files


def _radar_block(out_dir: Path, say: Callable[[str], None]):
    """A small simulated AIDJEX-like block (3 strips, two coverages 16 days apart) by both methods: the report
    lines and files."""
    say("radar block: simulating 3 strips over drifting ice")
    scenario = aidjex_scenario(0, plan=FlightPlan(strips=3), features=200)
    project = write_project(scenario, out_dir / "aidjex")
    say("radar block: simultaneous adjustment")
    block = run_block(project, out_dir / "aidjex" / "simultaneous")
    say("radar block: the sequential method of 1979")
    sequential = run_block(project, out_dir / "aidjex" / "sequential", method="sequential")
    lines = ["  radar block (simulated AIDJEX, 3 strips, 16 days of drift; project in aidjex/, results in "
             "aidjex/simultaneous/ and aidjex/sequential/):",
             *["    " + line for line in block.report.splitlines()],
             "    both methods against the simulation's truth (RMS per coordinate x / y, km):",
             *["      " + line for line in _compare_methods(scenario, {"sequential (1979)": sequential,
                                                                      "simultaneous": block})]]
    return lines, [project, *block.files, *sequential.files]


def _summary(radar: RadarStripCheck, image: ImageCheck, fit_report: str) -> list[str]:
    stations = FIGURE_3_3_STATIONS
    return [
        "seaice_jax demo",
        f"  radar strip: {radar.latitude.size} points, {radar.duration:.0f} s of flight at 10 km, "
        f"ground swath {np.ptp(radar.y) / 1000:.0f} x {np.ptp(radar.x) / 1000:.0f} km",
        f"    inverse(forward): time error {radar.time_error:.1e} s, range error {radar.range_error:.1e} m",
        f"  satellite image (source 001 Fig. 3-3, NOAA-7, southbound): {image.latitude.size} grid points,",
        f"    latitude {np.degrees(np.min(image.latitude)):.2f}..{np.degrees(np.max(image.latitude)):.2f} deg, "
        f"longitude {np.degrees(np.min(image.longitude)):.2f}..{np.degrees(np.max(image.longitude)):.2f} deg",
        f"    inverse(forward): {image.round_trip:.1e} pixel",
        "    Figure 3-3 stations, computed minus known vs printed (arc minutes):",
        *[f"      {s.number} {s.name:<11} DLAT {a:+.2f} (printed {s.printed_dlat_arcmin:+.4f})  "
          f"DLONG {b:+.2f} (printed {s.printed_dlon_arcmin:+.4f})"
          for s, a, b in zip(stations, image.dlat, image.dlon, strict=True)],
        f"    largest difference from the printout: {np.max(np.abs(image.dlat - image.printed_dlat)):.2f}' lat, "
        f"{np.max(np.abs(image.dlon - image.printed_dlon)):.2f}' lon (the printed parameters are rounded)",
        "  orbit fit to the five stations from no prior knowledge (Gauss-Newton; 1985 printout: subtrack 112, "
        "node 66.65, DEV 0.5687'/0.6017'):",
        *["    " + line for line in fit_report.splitlines()],
    ]


_log = logging.getLogger(__name__)
"""Where :func:`run_demo` reports its stages when no ``say`` is given (INFO)."""


DEMO_COMMAND = "seaice demo"
"""The command named in the demo folder's manifest (:data:`~seaice_jax.outputs.MANIFEST`)."""


def demo_may_replace(out_dir: str | os.PathLike, overwrite: bool = False) -> bool:
    """Whether the demo replaces ``out_dir``: with ``overwrite``, or when ``out_dir`` is a demo folder an earlier
    run wrote (its :data:`~seaice_jax.outputs.MANIFEST` names :data:`DEMO_COMMAND` and lists every file in it);
    False for an absent or empty folder.

    Raises:
        SeaiceError: naming ``out_dir`` and why it is not the demo's own, for any other non-empty folder without
            ``overwrite``.
    """
    if overwrite:
        return True
    reason = foreign_output(out_dir, DEMO_COMMAND)
    if reason is None:
        return Path(out_dir).is_dir() and any(Path(out_dir).iterdir())
    raise SeaiceError(f"{out_dir}: not a folder an earlier `{DEMO_COMMAND}` wrote ({reason}); pass --overwrite to "
                      "replace it whole, or choose another --out")


def run_demo(out_dir: str | os.PathLike = "seaice-demo", overwrite: bool = False, quick: bool = False,
             say: Callable[[str], None] | None = None) -> DemoResult:
    """Run the demo and write its files into ``out_dir`` as one run (:func:`~seaice_jax.outputs.output_folder`),
    with a :data:`~seaice_jax.outputs.MANIFEST` of them. A folder an earlier demo wrote is replaced whole, in one
    step, when the new one is complete; any other non-empty folder only with ``overwrite`` (:func:`demo_may_replace`).
    ``quick``: a shorter image sequence (3 images of 128 pixels instead of 4 of 160), the same steps; ``say``
    receives a message as each stage starts (the command line prints them; default: this module's logger,
    ``seaice_jax.workflows.demo``, at INFO)."""
    say = say or _log.info
    out_dir = Path(out_dir)
    with output_folder(out_dir, demo_may_replace(out_dir, overwrite)) as folder:
        say("geolocating a radar strip and the 1985 satellite image")
        radar, image = geolocate_radar_strip(), geolocate_figure_3_3()
        files = _write_geolocation(radar, image, folder.path)
        say("fitting the satellite image's orbit to the Figure 3-3 stations")
        fit, fit_report, fit_files = _orbit_fit(image.model, folder.path)
        block_lines, block_files = _radar_block(folder.path, say)
        sequence_lines, sequence_files = _image_sequence(folder.path / "sequence", *((3, 128) if quick else (4, 160)),
                                                         say=say)
        files = list(folder.final(files + fit_files + block_files + sequence_files))
        files.append(write_manifest(folder, DEMO_COMMAND))
    written = sum(path.is_file() for path in out_dir.rglob("*"))  # the steps' own files too, as the manifest lists
    lines = [*_summary(radar, image, fit_report), *block_lines, *sequence_lines,
             f"  wrote {written} files into {out_dir}/ (map.png, position_sigma.png, orbit_fit_report.txt, "
             "aidjex/simultaneous/report.txt, sequence/film.gif, ...)"]
    return DemoResult(tuple(files), radar.latitude.size, radar.time_error, radar.range_error, image.latitude.size,
                      image.round_trip, float(np.max(np.abs(image.dlat - image.printed_dlat))),
                      float(np.max(np.abs(image.dlon - image.printed_dlon))), fit.rms_km,
                      float(fit.model.subtrack_pixel), "\n".join(lines))
