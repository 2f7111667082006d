"""The ``seaice`` command. Thin: parses arguments, calls the library, prints, exits with a clear message."""

import argparse
import math
import os
import sys
from contextlib import nullcontext
from pathlib import Path

from seaice_jax import __version__
from seaice_jax.errors import SeaiceError
from seaice_jax.outputs import Interrupted, interrupts_raise

CACHE_VARIABLE = "SEAICE_JAX_CACHE_DIR"
"""Environment variable naming the folder of JAX's persistent compilation cache (empty: no cache)."""


def _in_range(kind, low, high, above: bool = False):
    """An argparse type: a finite ``kind`` (int or float) within ``[low, high]`` (``above``: strictly above
    ``low``; None: unbounded), so that a bad option is a usage error naming it (exit code 2)."""

    def convert(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}") \
                from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{text!r} is not finite")
        if low is not None and (value <= low if above else value < low):
            raise argparse.ArgumentTypeError(f"must be {'>' if above else '>='} {low}, got {text}")
        if high is not None and value > high:
            raise argparse.ArgumentTypeError(f"must be <= {high}, got {text}")
        return value

    return convert


_POSITIVE = _in_range(float, 0.0, None, above=True)


def _demo(args) -> int:
    from seaice_jax.workflows.demo import run_demo

    print(run_demo(args.out, overwrite=args.overwrite).summary)
    return 0


def _rectify(args) -> int:
    import numpy as np

    from seaice_jax.adjust.orbit_fit import fit_scan_model
    from seaice_jax.files import write_json
    from seaice_jax.geometry.earth import SIDEREAL_DAY
    from seaice_jax.geometry.scan import satellite_orbit
    from seaice_jax.io.stations import check_in_image, control_points, read_agrid, read_measurements
    from seaice_jax.outputs import output_file
    from seaice_jax.report.text import orbit_fit_json, orbit_fit_report

    catalogue = read_agrid(args.stations) if args.stations else None
    measurements = read_measurements(args.measurements, catalogue)
    check_in_image(measurements, args.pixels, args.scans, args.measurements)
    control = control_points(measurements, args.sigma)
    check = None
    if args.check:
        check = control_points(read_measurements(args.check, catalogue), args.sigma)
    orbit = satellite_orbit(
        args.satellite,
        altitude=None if args.altitude is None else args.altitude * 1000.0,
        earth_day=SIDEREAL_DAY if args.earth_day is None else args.earth_day * 60.0,
        period=None if args.period is None else args.period * 60.0,
        max_latitude=None if args.max_latitude is None else np.radians(args.max_latitude),
    )
    json_file = output_file(args.json, args.overwrite, inputs=(args.measurements,)) if args.json else nullcontext()
    with json_file as staging:
        fit = fit_scan_model(control, orbit, direction=args.direction, n_pixels=args.pixels, n_scans=args.scans,
                             method=args.method)
        print(orbit_fit_report(fit, check, names={m.id: m.name for m in measurements}))
        if staging is not None:
            write_json(staging.path / staging.target.name, orbit_fit_json(fit, check))
    if args.json:
        print(f"wrote {args.json}")
    return 0


def _simulate(args) -> int:
    from seaice_jax.io.project import write_project
    from seaice_jax.simulate.aircraft import FlightPlan, aidjex_scenario, prudhoe_scenario

    if args.scenario == "lancaster":
        from seaice_jax.workflows.image_sequence import write_simulated_sequence

        path = write_simulated_sequence(args.out, args.seed, args.images, args.size, args.clouds,
                                        overwrite=args.overwrite)
        print(f"wrote {path} (images, control points, land_mask.npy, static_mask.npy, truth/)")
        return 0
    if args.scenario == "aidjex":
        scenario = aidjex_scenario(args.seed, plan=FlightPlan(strips=args.strips), features=args.features)
    else:
        scenario = prudhoe_scenario(args.seed)
    print(f"wrote {write_project(scenario, args.out, overwrite=args.overwrite)} (and truth.csv beside it)")
    return 0


def _block(args) -> int:
    from seaice_jax.adjust.block import BlockOptions
    from seaice_jax.workflows.radar_block import run_block

    options = BlockOptions(navigation_model=args.navigation_model, navigation_scope=args.navigation_scope,
                           knot_spacing=args.knot_spacing, radar_constants=args.radar_constants,
                           take_off_time=args.take_off_time)
    run = run_block(args.project, args.out, args.method, options, overwrite=args.overwrite)
    print(run.report)
    print(f"wrote {len(run.files)} files into {args.out}")
    return 0


def _adjust(args) -> int:
    from seaice_jax.workflows.sequence_adjust import run_adjust

    step = run_adjust(args.project, args.out, method=args.method, static=args.static, progress=not args.quiet,
                      overwrite=args.overwrite)
    print(step.report)
    print(f"wrote {len(step.files)} files into {args.out}")
    return 0


def _remap(args) -> int:
    from seaice_jax.workflows.image_sequence import run_remap

    step = run_remap(args.project, args.out, method=args.method, fill=args.fill, progress=not args.quiet,
                     overwrite=args.overwrite, models_path=args.models)
    print(step.report)
    print(f"wrote {len(step.files)} files into {args.out}")
    return 0


def _track(args) -> int:
    from seaice_jax.imagery.tracking import TrackingOptions
    from seaice_jax.workflows.image_sequence import run_track

    options = TrackingOptions(patch=args.patch, search=args.search, spacing=args.spacing,
                              min_correlation=args.min_correlation, first_guess=args.first_guess)
    step = run_track(args.remapped, args.out, options, tracking_sigma=args.tracking_sigma, progress=not args.quiet,
                     layout=args.layout, overwrite=args.overwrite)
    print(step.report)
    print(f"wrote {len(step.files)} files into {args.out}")
    return 0


def _velocities(args) -> int:
    from seaice_jax.workflows.image_sequence import run_velocities

    step = run_velocities(args.records, args.out, projection=args.projection, box_size=args.box_km * 1000.0,
                          velocity_sigma=args.velocity_sigma, overwrite=args.overwrite)
    print(step.report)
    print(f"wrote {len(step.files)} files into {args.out}")
    return 0


def _movie(args) -> int:
    from seaice_jax.workflows.image_sequence import run_movie

    step = run_movie(args.remapped, args.out, land_mask=args.land_mask, records=args.records, fps=args.fps,
                     scale=args.scale, overwrite=args.overwrite)
    print(step.report)
    return 0


def _sequence_commands(commands) -> None:
    adjust = commands.add_parser("adjust", help="find the scan models of an image sequence: all images at once on "
                                                "automatic tie points and the control points, or per image")
    adjust.add_argument("project", help="sequence TOML")
    adjust.add_argument("--out", required=True, help="output folder (models.npz with the joint covariance, "
                                                     "models.csv, ties.csv)")
    adjust.add_argument("--method", choices=["simultaneous", "per-image"], default="simultaneous",
                        help="per-image: each image on its own control points (the 1985 practice)")
    adjust.add_argument("--static", help=".npy bool array on the project's grid, True on land and fast ice (where "
                                         "ties are sought); default: static_mask.npy, else land_mask.npy beside the "
                                         "project")
    adjust.add_argument("--quiet", action="store_true", help="no progress bars")
    adjust.set_defaults(run=_adjust)

    remap = commands.add_parser("remap", help="rectify an image-sequence project and remap it into its map grid")
    remap.add_argument("project", help="sequence TOML")
    remap.add_argument("--models", help="models.npz written by `seaice adjust`: adopt those scan models and their "
                                        "joint covariance instead of fitting each image")
    remap.add_argument("--out", required=True, help="output folder (GeoTIFFs, remapped.npz, rectification.csv)")
    remap.add_argument("--method", choices=["bilinear", "nearest"], default="bilinear")
    remap.add_argument("--fill", type=_in_range(int, 0, 1000), default=1,
                       help="passes of the 1985 fill over missing pixels (0: none)")
    remap.add_argument("--quiet", action="store_true", help="no progress bars")
    remap.set_defaults(run=_remap)

    track = commands.add_parser("track", help="track the ice between consecutive remapped images")
    track.add_argument("remapped", help="folder written by `seaice remap`")
    track.add_argument("--out", required=True, help="output folder (CF-NetCDF drift, floes.csv, GeoJSON)")
    track.add_argument("--patch", type=_in_range(int, 3, 1001), default=15, help="template side, pixels (odd)")
    track.add_argument("--search", type=_in_range(int, 1, 1000), default=6,
                       help="largest displacement searched, pixels")
    track.add_argument("--spacing", type=_in_range(int, 1, 10_000), default=8, help="pixels between tracked points")
    track.add_argument("--min-correlation", type=_in_range(float, -1.0, 1.0), default=0.6)
    track.add_argument("--first-guess", choices=["zero", "features"], default="zero",
                       help="features: ORB matches and a RANSAC similarity transform predict the motion")
    track.add_argument("--tracking-sigma", type=_POSITIVE, default=0.2, help="σ of a tracked displacement, pixels")
    track.add_argument("--layout", choices=["project", "osisaf"], default="project",
                       help="osisaf: also write each pair as drift_<a>_<b>_osisaf.nc in the OSI SAF low-resolution "
                       "drift layout (dX, dY in km, uncert_dX_and_dY, dt0/dt1, OSI SAF status codes)")
    track.add_argument("--quiet", action="store_true", help="no progress bars")
    track.set_defaults(run=_track)

    speeds = commands.add_parser("velocities", help="velocities, box averages, time series, deformation and "
                                                    "trajectories from floe records")
    speeds.add_argument("records", help="floe record CSV (floe_id,time,image,pixel,scan,latitude,longitude)")
    speeds.add_argument("--out", required=True, help="output folder")
    speeds.add_argument("--projection", choices=["nsidc-north", "nsidc-south"], default="nsidc-north",
                        help="the grid whose axes the grid-relative components follow")
    speeds.add_argument("--box-km", type=_POSITIVE, default=50.0, help="side of the averaging boxes, km")
    speeds.add_argument("--velocity-sigma", type=_POSITIVE, default=None,
                        help="σ of each velocity component (m/s) for the deformation's σ (default: 1 km "
                             "position σ per fix)")
    speeds.set_defaults(run=_velocities)

    movie = commands.add_parser("movie", help="time-lapse film (GIF or MP4) of a remapped sequence")
    movie.add_argument("remapped", help="folder written by `seaice remap`")
    movie.add_argument("--out", required=True, help="film file, .gif or .mp4")
    movie.add_argument("--land-mask", help=".npy bool array on the grid: land drawn filled")
    movie.add_argument("--records", help="floe record CSV: the floes marked on every frame")
    movie.add_argument("--fps", type=_in_range(float, 0.0, 1000.0, above=True), default=2.0)
    movie.add_argument("--scale", type=_in_range(int, 1, 64), default=2, help="pixel replication")
    movie.set_defaults(run=_movie)


def compile_cache_folder(enabled: bool = True) -> Path | None:
    """Folder of JAX's persistent compilation cache for the ``seaice`` command, or None for no cache.

    ``$SEAICE_JAX_CACHE_DIR`` when set (empty: no cache), else ``$XDG_CACHE_HOME/seaice_jax/jax`` (default
    ``~/.cache/seaice_jax/jax``); None when ``enabled`` is false (``--no-compile-cache``).
    """
    if not enabled:
        return None
    if CACHE_VARIABLE in os.environ:
        return Path(os.environ[CACHE_VARIABLE]).expanduser() if os.environ[CACHE_VARIABLE] else None
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache").expanduser() / "seaice_jax" / "jax"


def _use_compile_cache(folder: Path | None) -> None:
    """Turn on JAX's persistent compilation cache in ``folder`` (every compilation, however short, is kept: a second
    run of a command then skips XLA's compilations), or leave it off for None."""
    if folder is None:
        return
    import jax

    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="seaice", description="Sea-ice mapping and drift from radar strips and "
                                     "satellite images (seaice_jax).")
    parser.add_argument("--version", action="version", version=f"seaice_jax {__version__}")
    parser.add_argument("--no-compile-cache", dest="compile_cache", action="store_false",
                        help="do not keep JAX's compilations between runs (by default they are kept in "
                             f"${CACHE_VARIABLE}, else $XDG_CACHE_HOME/seaice_jax/jax or ~/.cache/seaice_jax/jax; "
                             f"an empty ${CACHE_VARIABLE} also turns the cache off)")
    commands = parser.add_subparsers(dest="command", required=True)
    demo = commands.add_parser("demo", help="run the main job on the built-in scenario")
    demo.add_argument("--out", default="seaice-demo", help="output folder (default: ./seaice-demo)")
    demo.set_defaults(run=_demo)

    rectify = commands.add_parser(
        "rectify", help="fit a satellite image's orbit and scan parameters to ground control points (VHR2)",
        description="Fit the great-circle scan model (source 001, section 3.3) to control points and print a "
                    "report in the layout of the 1985 line printer (Figure 3-3), with covariance and w-tests.")
    rectify.add_argument("measurements", help="CSV: id,name,pixel,scan,lat,lon (degrees) [,sigma_km], or "
                                              "id,pixel,scan with --stations")
    rectify.add_argument("--stations", help="AGRID station catalogue to take positions from")
    rectify.add_argument("--satellite", required=True, help="NOAA-4, NOAA-5, NOAA-6, NOAA-7, TIROS-N, LANDSAT-1..3")
    rectify.add_argument("--altitude", type=_in_range(float, 0.0, 100_000.0),
                         help="km; 0 for images corrected for Earth curvature "
                                                        "(default: the satellite's)")
    rectify.add_argument("--max-latitude", type=_in_range(float, 0.0, 90.0, above=True),
                         help="degrees (overrides the satellite table)")
    rectify.add_argument("--period", type=_POSITIVE, help="minutes (overrides the satellite table)")
    rectify.add_argument("--earth-day", type=_POSITIVE, help="minutes of one Earth rotation (default: sidereal day; "
                                                         "the 1985 program used 1440)")
    rectify.add_argument("--direction", choices=["south", "north", "auto"], default="auto")
    rectify.add_argument("--method", choices=["gauss-newton", "appendix_c"], default="gauss-newton")
    rectify.add_argument("--sigma", type=_POSITIVE, default=1.0, help="km, ground σ of points without sigma_km")
    rectify.add_argument("--pixels", type=_in_range(int, 2, 100_000), default=512,
                         help="pixels per scan line (default 512)")
    rectify.add_argument("--scans", type=_in_range(int, 2, 100_000), default=512, help="scan lines (default 512)")
    rectify.add_argument("--check", help="CSV of check points: known positions, not used in the fit")
    rectify.add_argument("--json", help="also write the report as JSON here")
    rectify.set_defaults(run=_rectify)

    simulate = commands.add_parser("simulate", help="write a simulated radar project (TOML + CSV) with its truth, "
                                                    "or an image sequence (lancaster)")
    simulate.add_argument("scenario", choices=["aidjex", "prudhoe", "lancaster"])
    simulate.add_argument("--out", required=True, help="folder to write the project into")
    simulate.add_argument("--seed", type=_in_range(int, 0, 2**32 - 1), default=0)
    simulate.add_argument("--strips", type=_in_range(int, 1, 100), default=10, help="strips per coverage (aidjex)")
    simulate.add_argument("--features", type=_in_range(int, 1, 100_000), default=600, help="ice features (aidjex)")
    simulate.add_argument("--images", type=_in_range(int, 1, 1000), default=6,
                          help="images of the sequence (lancaster)")
    simulate.add_argument("--size", type=_in_range(int, 16, 4096), default=256,
                          help="pixels and scan lines per image (lancaster)")
    simulate.add_argument("--clouds", action="store_true", help="cloud patches on the images (lancaster)")
    simulate.set_defaults(run=_simulate)

    block = commands.add_parser("block", help="adjust a radar block project and measure the drift")
    block.add_argument("project", help="project TOML")
    block.add_argument("--method", choices=["simultaneous", "sequential"], default="simultaneous",
                       help="simultaneous: every unknown in one adjustment (default); sequential: the 1979 method of "
                            "source 000")
    block.add_argument("--navigation-model", choices=["constant", "linear", "schuler", "spline"], default="schuler",
                       help="navigation-error model (simultaneous method)")
    block.add_argument("--navigation-scope", choices=["flight", "strip"], default="flight",
                       help="flight: one error curve per coverage, an offset per strip (the INS error runs on "
                            "through the turns); strip: every strip its own curve (needed by the spline model)")
    block.add_argument("--knot-spacing", type=_POSITIVE, default=300.0, help="s, of the spline model")
    block.add_argument("--take-off-time", type=_in_range(float, None, None), default=None,
                       help="s on the strips' clock when the flights took off: the INS error curve then starts "
                            "there (drift from zero, offset = alignment error); default: from the first strip")
    block.add_argument("--radar-constants", choices=["strip", "shared"], default="strip",
                       help="sweep delay and range scale per strip or one pair for the block")
    block.add_argument("--out", required=True, help="output folder")
    block.set_defaults(run=_block)
    _sequence_commands(commands)
    for command in commands.choices.values():
        command.add_argument("--overwrite", action="store_true",
                             help="replace an existing output folder (or file) whole; without it one that is not "
                                  "empty is refused")
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    _use_compile_cache(compile_cache_folder(args.compile_cache))
    try:
        with interrupts_raise():
            return args.run(args)
    except (SeaiceError, ValueError, OSError) as error:
        print(f"seaice {args.command}: error: {error}", file=sys.stderr)
        return 2
    except Interrupted as interrupt:
        print(f"seaice {args.command}: {interrupt}; the output was left as it was before the run", file=sys.stderr)
        return interrupt.exit_code


if __name__ == "__main__":
    sys.exit(main())
