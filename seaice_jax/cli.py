"""The ``seaice`` command. Thin: parses arguments, calls the library, prints, exits with a clear message.

Every command takes ``-q``/``--quiet`` (errors only: no progress bars, no report), ``-v``/``--verbose`` (also the
elapsed time and, on an error, the traceback) and ``--overwrite``; ``--help`` shows each option's default. Exit
codes (:mod:`seaice_jax.errors`): 0 done, 1 runtime failure, 2 usage or bad input, 130/143 interrupted.
"""

import argparse
import contextlib
import logging
import math
import os
import sys
import time
import traceback
from collections.abc import Iterator
from pathlib import Path

# One BLAS thread unless the user says otherwise, set before NumPy loads OpenBLAS (the outputs import below): the
# command's matrices are small (reduced normal systems of hundreds to a few thousand unknowns), and OpenBLAS's
# threads competing with XLA's for a few busy cores made a 250 x 250 Cholesky 350 times slower (0.25 s against
# 0.7 ms; docs/getting-started.md, «The command line»).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from seaice_jax import __version__  # noqa: E402
from seaice_jax._compilation_cache import CACHE_VARIABLE, enable_compilation_cache  # noqa: E402
from seaice_jax.errors import EXIT_FAILURE, EXIT_OK, SeaiceError, exit_code  # noqa: E402
from seaice_jax.outputs import Interrupted, check_interrupted, interrupts_raise  # noqa: E402


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


def _tracking_option(name: str, high: int):
    """An argparse type for the integer tracking option ``name``: at most ``high`` and accepted by
    :class:`~seaice_jax.imagery.tracking.TrackingOptions` (its rule, the one place it is written; imported only when
    the option is given, so that ``--help`` loads neither OpenCV nor JAX)."""
    in_range = _in_range(int, None, high)

    def convert(text: str) -> int:
        value = in_range(text)
        from seaice_jax.imagery.tracking import TrackingOptions

        try:
            TrackingOptions(**{name: value})
        except SeaiceError as error:
            raise argparse.ArgumentTypeError(str(error)) from None
        return value

    return convert
QUIET, NORMAL, VERBOSE = 0, 1, 2
"""Verbosity levels: ``-q`` (errors only), default (report and progress bars), ``-v`` (also timings, tracebacks)."""


def _say(args, text: str) -> None:
    """Print ``text`` (a report, the files written) unless ``-q``."""
    if args.verbosity >= NORMAL:
        print(text)


def _progress(args) -> bool:
    """Progress bars on stderr unless ``-q``."""
    return args.verbosity >= NORMAL


def _stages(args):
    """A ``say`` for the workflows: each stage's message on stderr with the seconds since the command started,
    unless ``-q``."""
    start = time.perf_counter()

    def say(message: str) -> None:
        if args.verbosity >= NORMAL:
            print(f"seaice {args.command} [{time.perf_counter() - start:4.0f} s]: {message}", file=sys.stderr,
                  flush=True)

    return say


class _HelpFormatter(argparse.HelpFormatter):
    """``--help`` with each option's default appended (``(default: ...)``), except for flags (options without a
    value), options without a default, and where the help already says it."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if (default is None or action.nargs == 0 or default is argparse.SUPPRESS or "default" in text
                or not action.option_strings):
            return text
        return f"{text} (default: %(default)s)"


def _demo(args) -> int:
    from seaice_jax.workflows.demo import run_demo

    _say(args, run_demo(args.out, overwrite=args.overwrite, say=_stages(args)).summary)
    return EXIT_OK


def _rectify(args) -> int:
    from seaice_jax.report.text import orbit_fit_report
    from seaice_jax.workflows.rectify import RoughOrbit, run_rectify

    rough = None
    if args.node is not None and args.pass_minutes is not None:
        rough = RoughOrbit(args.node, args.pass_minutes, args.scanner_span, args.orbital_span, args.subtrack)
    result = run_rectify(
        args.measurements, satellite=args.satellite, altitude_km=args.altitude, max_latitude=args.max_latitude,
        period_minutes=args.period, earth_day_minutes=args.earth_day, direction=args.direction, method=args.method,
        sigma_km=args.sigma, n_pixels=args.pixels, n_scans=args.scans, stations=args.stations, check=args.check,
        json_path=args.json, image=args.image, auto_control=args.auto_control, rough=rough, search=args.search,
        overlay=args.overlay, overwrite=args.overwrite, say=_stages(args))
    _say(args, orbit_fit_report(result.fit, result.check_errors, names=result.names))
    for path in result.written:
        _say(args, f"wrote {path}")
    return EXIT_OK


def _simulate(args) -> int:
    from seaice_jax.outputs import check_output

    check_output(args.out, args.overwrite)  # before the simulation is even loaded
    _stages(args)(f"simulating the {args.scenario} scenario (seed {args.seed})")
    if args.scenario == "lancaster":
        from seaice_jax.workflows.simulated_sequence import write_simulated_sequence

        path = write_simulated_sequence(args.out, args.seed, args.images, args.size, args.clouds,
                                        overwrite=args.overwrite)
        _say(args, f"wrote {path} (images, control points, land_mask.npy, static_mask.npy, truth/)")
        return EXIT_OK
    from seaice_jax.io.project import write_project
    from seaice_jax.simulate.aircraft import FlightPlan, aidjex_scenario, prudhoe_scenario

    if args.scenario == "aidjex":
        scenario = aidjex_scenario(args.seed, plan=FlightPlan(strips=args.strips), features=args.features)
    else:
        scenario = prudhoe_scenario(args.seed)
    _say(args, f"wrote {write_project(scenario, args.out, overwrite=args.overwrite)} (and truth.csv beside it)")
    return EXIT_OK


def _block(args) -> int:
    from seaice_jax.adjust.radar.block import BlockOptions
    from seaice_jax.workflows.radar_block import run_block

    options = BlockOptions(navigation_model=args.navigation_model, navigation_scope=args.navigation_scope,
                           knot_spacing=args.knot_spacing, radar_constants=args.radar_constants,
                           take_off_time=args.take_off_time, image_sigma=tuple(args.image_sigma),
                           time_mark_sigma=args.time_mark_sigma,
                           variance_components=args.variance_components, robust=args.robust)
    run = run_block(args.project, args.out, args.method, options, overwrite=args.overwrite, say=_stages(args))
    _say(args, run.report)
    _say(args, f"wrote {len(run.files)} files into {args.out}")
    return EXIT_OK


def _adjust(args) -> int:
    from seaice_jax.workflows.sequence_adjust import run_adjust

    step = run_adjust(args.project, args.out, method=args.method, static=args.static, progress=_progress(args),
                      overwrite=args.overwrite)
    _say(args, step.report)
    _say(args, f"wrote {len(step.files)} files into {args.out}")
    return EXIT_OK


def _remap(args) -> int:
    if args.workers or args.scheduler:  # on Dask (imported only here)
        from seaice_jax.workflows.archive import run_remap_archive

        step = run_remap_archive(args.project, args.out, method=args.method, fill=args.fill,
                                 progress=_progress(args), overwrite=args.overwrite, models_path=args.models,
                                 workers=args.workers, scheduler=args.scheduler)
        _say(args, step.report)
        _say(args, f"wrote {len(step.files)} files into {args.out}")
        return EXIT_OK
    from seaice_jax.workflows.remap import run_remap

    step = run_remap(args.project, args.out, method=args.method, fill=args.fill, progress=_progress(args),
                     overwrite=args.overwrite, models_path=args.models)
    _say(args, step.report)
    _say(args, f"wrote {len(step.files)} files into {args.out}")
    return EXIT_OK


def _track(args) -> int:
    from seaice_jax.imagery.tracking import TrackingOptions
    from seaice_jax.workflows.track import run_track

    options = TrackingOptions(patch=args.patch, search=args.search, spacing=args.spacing,
                              min_correlation=args.min_correlation, first_guess=args.first_guess,
                              sigma_floor=args.tracking_sigma)
    land = None if args.land == "none" else args.land
    sources = args.remapped
    geotiffs = len(sources) > 1 or Path(sources[0]).suffix.lower() in (".tif", ".tiff")
    if not geotiffs and args.times:
        raise SeaiceError("--times is for GeoTIFF files; a folder of `seaice remap` has its own times")
    if args.workers or args.scheduler:  # on Dask (imported only here)
        from seaice_jax.workflows.archive import run_track_archive

        step = run_track_archive(sources if geotiffs else sources[0], args.out, options, progress=_progress(args),
                                 layout=args.layout, overwrite=args.overwrite, land=land, workers=args.workers,
                                 scheduler=args.scheduler)
    else:
        step = run_track(sources if geotiffs else sources[0], args.out, options, progress=_progress(args),
                         layout=args.layout, overwrite=args.overwrite, times=args.times, land=land)
    _say(args, step.report)
    _say(args, f"wrote {len(step.files)} files into {args.out}")
    return EXIT_OK


def _velocities(args) -> int:
    from seaice_jax.workflows.velocities import run_velocities

    step = run_velocities(args.records, args.out, projection=args.projection, box_size=args.box_km * 1000.0,
                          velocity_sigma=args.velocity_sigma, overwrite=args.overwrite)
    _say(args, step.report)
    _say(args, f"wrote {len(step.files)} files into {args.out}")
    return EXIT_OK


def _movie(args) -> int:
    from seaice_jax.workflows.movie import run_movie

    step = run_movie(args.remapped, args.out, land_mask=args.land_mask, records=args.records, fps=args.fps,
                     scale=args.scale, overwrite=args.overwrite)
    _say(args, step.report)
    return EXIT_OK


def _examples(args) -> int:
    import shutil
    from importlib.resources import as_file, files

    from seaice_jax.outputs import output_folder

    with as_file(files("seaice_jax") / "examples") as source, output_folder(args.folder, args.overwrite) as folder:
        names = sorted(path.name for path in Path(source).iterdir() if path.is_file())
        for name in names:
            shutil.copyfile(Path(source) / name, folder.path / name)
    _say(args, f"wrote {len(names)} example files into {args.folder}: {', '.join(names)}")
    return EXIT_OK


def _sar_geolocate(args) -> int:
    from seaice_jax.workflows.sar import run_geolocate

    result = run_geolocate(args.annotation, args.out, reference=args.reference, overwrite=args.overwrite,
                           say=_stages(args))
    _say(args, result.check.report())
    for path in result.files:
        _say(args, f"wrote {path}")
    return EXIT_OK


def _sar_remap(args) -> int:
    from seaice_jax.workflows.sar import run_sar_remap

    result = run_sar_remap(args.annotation, args.image, args.out, spacing=args.spacing, height=args.height,
                           orbit_sigma=args.orbit_sigma, decimation=args.decimation, overwrite=args.overwrite,
                           say=_stages(args))
    _say(args, result.report)
    for path in result.files:
        _say(args, f"wrote {path}")
    return EXIT_OK


def _sar_commands(commands, common) -> None:
    sar = commands.add_parser("sar", help="spaceborne radar (Sentinel-1) products: geolocation on the WGS84 "
                              "ellipsoid", description="Spaceborne radar products (Sentinel-1 SLC and GRD): the "
                              "zero-Doppler range-Doppler model on the WGS84 ellipsoid, from the product's "
                              "annotation (orbit state vectors, timing, geolocation grid).",
                              formatter_class=_HelpFormatter)
    verbs = sar.add_subparsers(dest="sar_command", required=True, metavar="VERB")
    geolocate = _command(verbs, common, "geolocate", "recompute a Sentinel-1 annotation's geolocation grid and "
                         "compare it with ESA's, point by point",
                         "Recompute every point of a Sentinel-1 annotation's geolocation grid with the zero-Doppler "
                         "model on WGS84 (forward: time, range, height -> latitude, longitude; inverse; and image "
                         "line/pixel -> time through bursts, GRD polynomials and the bistatic shift) and write the "
                         "grid, our points and the differences (geolocation.csv), a map figure (geolocation.png) and "
                         "a report.")
    geolocate.add_argument("annotation", help="the product's annotation XML (SAFE annotation/s1?-*.xml)")
    geolocate.add_argument("--out", required=True, help="output folder")
    geolocate.add_argument("--reference", help="the middle sub-swath's annotation (IW2, EW3) of the same product: "
                                               "the bistatic reference of a side sub-swath (default: recovered "
                                               "from the file's own grid)")
    geolocate.set_defaults(run=_sar_geolocate)
    remap = _command(verbs, common, "remap", "put a Sentinel-1 GRD (or stripmap) image onto a polar stereographic "
                     "grid with the exact zero-Doppler model",
                     "Remap a Sentinel-1 GRD or stripmap image onto the NSIDC polar stereographic grid (EPSG:3413 "
                     "north, 3976 south) that covers it: every cell centre -> zero-Doppler azimuth time and slant "
                     "range on the WGS84 ellipsoid -> image line and pixel -> bilinear sample. Writes remapped.tif, "
                     "position_sigma.tif (the horizontal σ of each cell from the orbit's position σ), remapped.png "
                     "and report.txt.")
    remap.add_argument("annotation", help="the product's annotation XML")
    remap.add_argument("image", help="the measurement image (.tif from the SAFE measurement/ folder, or .npy)")
    remap.add_argument("--out", required=True, help="output folder")
    remap.add_argument("--spacing", type=_POSITIVE, default=200.0, help="grid cell size, m")
    remap.add_argument("--height", type=_in_range(float, -1000.0, 9000.0),
                       help="ellipsoidal height of the surface, m (default: the heights of the annotation's "
                            "geolocation grid between its points: the processor's terrain, the geoid over the sea)")
    remap.add_argument("--orbit-sigma", type=_POSITIVE, default=5.0,
                       help="m per axis, the orbit's position σ for the per-cell σ: give your orbit product's "
                            "stated accuracy (precise orbits: a few cm); the default 5.0 m is an assumption for "
                            "the downlinked orbit of the annotation, not an ESA figure")
    remap.add_argument("--decimation", type=_in_range(int, 1, 1000), default=1,
                       help="the image keeps every N-th line and sample of the product (a quick-look)")
    remap.set_defaults(run=_sar_remap)


def _command(commands, common, name: str, summary: str, description: str | None = None):
    """A sub-command with the shared options (``common``) and the defaults shown in its ``--help``."""
    return commands.add_parser(name, help=summary, description=description or summary[0].upper() + summary[1:] + ".",
                               parents=[common], formatter_class=_HelpFormatter)


def _sequence_commands(commands, common) -> None:
    adjust = _command(commands, common, "adjust", "find the scan models of an image sequence: all images at once on "
                      "automatic tie points and the control points, or per image")
    adjust.add_argument("project", help="sequence project (TOML: grid, images, times, control points)")
    adjust.add_argument("--out", required=True, help="output folder (models.npz with the joint covariance, "
                                                     "models.csv, ties.csv)")
    adjust.add_argument("--method", choices=["simultaneous", "per-image"], default="simultaneous",
                        help="simultaneous: one least-squares adjustment of every image's scan model on the tie "
                             "points between images and the control points; per-image: each image on its own "
                             "control points (the 1985 practice)")
    adjust.add_argument("--static", help=".npy bool array on the project's grid, True on land and fast ice (where "
                                         "ties are sought); default: static_mask.npy, else land_mask.npy beside the "
                                         "project, else the GSHHG coastline's land on the grid")
    adjust.set_defaults(run=_adjust)

    remap = _command(commands, common, "remap", "rectify an image-sequence project and remap it into its map grid")
    remap.add_argument("project", help="sequence project (TOML)")
    remap.add_argument("--models", help="models.npz written by `seaice adjust`: adopt those scan models and their "
                                        "joint covariance instead of fitting each image")
    remap.add_argument("--out", required=True, help="output folder (GeoTIFFs, remapped.npz, rectification.csv)")
    remap.add_argument("--method", choices=["bilinear", "nearest"], default="bilinear",
                       help="how a map pixel takes its value from the image pixels around its source point")
    remap.add_argument("--fill", type=_in_range(int, 0, 1000), default=1,
                       help="passes of the 1985 fill over missing pixels (each pass gives a missing pixel the mean "
                            "of its valid neighbours; 0: none)")
    remap.add_argument("--workers", type=_in_range(int, 1, 10_000), help="run on a local Dask cluster of this many "
                       "worker processes, one image per task (default: one process, no Dask)")
    remap.add_argument("--scheduler", help="run on the running Dask cluster at this address (tcp://host:8786); its "
                       "workers must see the project and the output's folder at the same paths")
    remap.set_defaults(run=_remap)

    track = _command(commands, common, "track", "track the ice between consecutive remapped images",
                     "Track the ice between consecutive images of one map grid: the folder written by `seaice "
                     "remap`, or two or more single-band GeoTIFFs of one grid made by any tool (any projected CRS, "
                     "north-up; their times from --times or their TIFF DateTime tags).")
    track.add_argument("remapped", nargs="+", help="folder written by `seaice remap`, or GeoTIFF files in time order")
    track.add_argument("--times", nargs="+", help="ISO 8601 UTC time of each GeoTIFF (default: its DateTime tag)")
    track.add_argument("--out", required=True, help="output folder (CF-NetCDF drift, floes.csv, GeoJSON)")
    track.add_argument("--patch", type=_tracking_option("patch", 1001), default=15,
                       help="side of the square template matched between the images, pixels (odd, >= 5)")
    track.add_argument("--search", type=_tracking_option("search", 1000), default=6,
                       help="largest displacement searched, pixels")
    track.add_argument("--spacing", type=_in_range(int, 1, 10_000), default=8, help="pixels between tracked points")
    track.add_argument("--min-correlation", type=_in_range(float, -1.0, 1.0), default=0.6,
                       help="smallest normalised cross-correlation of a match kept as a good vector")
    track.add_argument("--first-guess", choices=["zero", "features"], default="zero",
                       help="features: ORB matches and a RANSAC similarity transform predict the motion")
    track.add_argument("--tracking-sigma", type=_POSITIVE, default=0.04,
                       help="σ floor of a tracked displacement, pixels per axis: added in quadrature to each "
                            "vector's σ from its correlation peak, before the variance is scaled by the "
                            "neighbour statistic (calibrated: experiments/results/tracking_calibration.md)")
    track.add_argument("--land", default="coastline",
                       help="land: a vector that starts or ends on it is flagged 'on land' (never good) and no floe is "
                            "followed onto it: 'coastline' (GSHHG full resolution, offline), a .npy bool array on the "
                            "grid, or 'none' (no land mask)")
    track.add_argument("--layout", choices=["project", "osisaf"], default="project",
                       help="osisaf: also write each pair as drift_<a>_<b>_osisaf.nc in the layout of the OSI SAF "
                            "(EUMETSAT Ocean and Sea Ice Satellite Application Facility) low-resolution drift "
                            "product (dX, dY in km, uncert_dX_and_dY, dt0/dt1, OSI SAF status codes)")
    track.add_argument("--workers", type=_in_range(int, 1, 10_000), help="run on a local Dask cluster of this many "
                       "worker processes, one image pair per task (default: one process, no Dask)")
    track.add_argument("--scheduler", help="run on the running Dask cluster at this address (tcp://host:8786); its "
                       "workers must see the remapped folder and the output's folder at the same paths")
    track.set_defaults(run=_track)

    speeds = _command(commands, common, "velocities", "velocities, box averages, time series, deformation and "
                      "trajectories from floe records")
    speeds.add_argument("records", help="floe record CSV (floe_id,time,image,pixel,scan,latitude,longitude)")
    speeds.add_argument("--out", required=True, help="output folder")
    speeds.add_argument("--projection", default="nsidc-north",
                        help="the grid whose axes the grid-relative components follow: nsidc-north or nsidc-south "
                             "(NSIDC sea-ice polar stereographic, EPSG:3413 and EPSG:3976) or any projected CRS "
                             "pyproj knows (EPSG:code, PROJ string)")
    speeds.add_argument("--box-km", type=_POSITIVE, default=50.0, help="side of the averaging boxes, km")
    speeds.add_argument("--velocity-sigma", type=_POSITIVE, default=None,
                        help="σ of each velocity component (m/s) for the deformation's σ (default: 1 km "
                             "position σ per fix)")
    speeds.set_defaults(run=_velocities)

    movie = _command(commands, common, "movie", "time-lapse film (GIF or MP4) of a remapped sequence")
    movie.add_argument("remapped", help="folder written by `seaice remap`")
    movie.add_argument("--out", required=True, help="film file, .gif or .mp4")
    movie.add_argument("--land-mask", help=".npy bool array on the grid: land drawn filled")
    movie.add_argument("--records", help="floe record CSV: the floes marked on every frame")
    movie.add_argument("--fps", type=_in_range(float, 0.0, 1000.0, above=True), default=2.0,
                       help="frames per second")
    movie.add_argument("--scale", type=_in_range(int, 1, 64), default=2,
                       help="pixel replication (each map pixel drawn as scale x scale film pixels)")
    movie.set_defaults(run=_movie)


@contextlib.contextmanager
def _library_logging(verbosity: int) -> Iterator[None]:
    """While a command runs, the library's log records (the ``seaice_jax`` loggers) go to stderr as
    ``seaice: message``: warnings and information by default, also debug messages with ``-v``, errors only with
    ``-q``. The logger's level, handlers and propagation are restored afterwards (``main`` may run in a process that
    configures logging itself)."""
    logger = logging.getLogger("seaice_jax")
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("seaice: %(message)s"))
    level = logging.ERROR if verbosity <= QUIET else logging.DEBUG if verbosity >= VERBOSE else logging.INFO
    handler.setLevel(level)
    saved = logger.level, logger.propagate
    logger.addHandler(handler)
    logger.setLevel(level)
    logger.propagate = False
    try:
        yield
    finally:
        logger.removeHandler(handler)
        logger.setLevel(saved[0])
        logger.propagate = saved[1]


def _add_verbosity(parser: argparse.ArgumentParser, default) -> None:
    """``-q``/``--quiet`` and ``-v``/``--verbose`` (either before or after the command's name: the command's own
    take ``argparse.SUPPRESS`` as default, so that they do not hide the ones given before it)."""
    loudness = parser.add_mutually_exclusive_group()
    loudness.add_argument("-q", "--quiet", dest="verbosity", action="store_const", const=QUIET, default=default,
                          help="print errors only (no progress bars, no report)")
    loudness.add_argument("-v", "--verbose", dest="verbosity", action="store_const", const=VERBOSE, default=default,
                          help="also print the elapsed time and, on an error, its traceback")


def _common_options() -> argparse.ArgumentParser:
    """The options of every command: verbosity and ``--overwrite``."""
    common = argparse.ArgumentParser(add_help=False)
    _add_verbosity(common, argparse.SUPPRESS)
    common.add_argument("--overwrite", action="store_true",
                        help="replace an existing output folder (or file) whole; without it one that is not "
                             "empty is refused")
    return common


_EPILOG = ("exit codes: 0 done; 1 runtime failure (an adjustment that did not converge, an output that could not be "
           "written); 2 usage or bad input (an unknown option, a value out of range, a missing or malformed input "
           "file); 130/143 interrupted by Ctrl-C/SIGTERM (nothing partial left). "
           "`seaice COMMAND --help` describes each command.")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="seaice", description="Sea-ice mapping and drift from radar strips and "
                                     "satellite images (seaice_jax).", epilog=_EPILOG, formatter_class=_HelpFormatter)
    parser.add_argument("--version", action="version", version=f"seaice_jax {__version__}")
    _add_verbosity(parser, NORMAL)
    parser.add_argument("--no-compile-cache", dest="compile_cache", action="store_false",
                        help="do not keep JAX's compilations between runs (by default they are kept in "
                             f"${CACHE_VARIABLE}, else $XDG_CACHE_HOME/seaice_jax/jax or ~/.cache/seaice_jax/jax; "
                             f"an empty ${CACHE_VARIABLE} also turns the cache off)")
    common = _common_options()
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    demo = _command(commands, common, "demo", "run the main job on the built-in scenario (a few minutes)",
                    "Run every step on built-in data: geolocate a radar strip and the 1985 satellite image, fit its "
                    "orbit, adjust a simulated radar block and track a simulated image sequence; write the files "
                    "and figures into one folder.")
    demo.add_argument("--out", default="seaice-demo", help="output folder")
    demo.set_defaults(run=_demo)

    examples = _command(commands, common, "examples", "copy the example files the README's commands use",
                        "Copy the packaged example files (the control points and AGRID station catalogue of the "
                        "1985 report's Figure 3-3) into FOLDER, so that the README's commands run from any folder.")
    examples.add_argument("folder", nargs="?", default="examples", help="folder to create (default: ./examples)")
    examples.set_defaults(run=_examples)

    rectify = _command(
        commands, common, "rectify", "fit a satellite image's orbit and scan parameters to ground control points",
        "Fit the great-circle scan model of a whisk-broom satellite image (NOAA AVHRR, Landsat MSS; the model of the "
        "1985 report, 'source 001', section 3.3, whose program VHR2 rectified Very High Resolution Radiometer "
        "images) to control points of known latitude and longitude, and print a report in the layout of the 1985 "
        "line printer (Figure 3-3) with the parameters' covariance and w-tests (Baarda's data snooping: a "
        "standardised residual beyond its critical value flags a point).")
    rectify.add_argument("measurements", nargs="?",
                         help="CSV: id,pixel,scan,latitude_deg,longitude_deg[,sigma_m][,name] (degrees, metres; the "
                              "control files seaice simulate writes; lat,lon and sigma_km read too), or id,pixel,scan "
                              "with --stations (optional with --auto-control)")
    rectify.add_argument("--stations", help="AGRID station catalogue (the 1985 fixed-column file of numbered "
                                            "stations with latitude and longitude in degrees and minutes) to take "
                                            "the positions from")
    rectify.add_argument("--satellite", required=True, help="NOAA-4, NOAA-5, NOAA-6, NOAA-7, TIROS-N, LANDSAT-1..3")
    rectify.add_argument("--altitude", type=_in_range(float, 0.0, 100_000.0),
                         help="km; 0 for images corrected for Earth curvature (default: the satellite's)")
    rectify.add_argument("--max-latitude", type=_in_range(float, 0.0, 90.0, above=True),
                         help="degrees (overrides the satellite table)")
    rectify.add_argument("--period", type=_POSITIVE, help="minutes (overrides the satellite table)")
    rectify.add_argument("--earth-day", type=_POSITIVE, help="minutes of one Earth rotation (default: sidereal day; "
                                                         "the 1985 program used 1440)")
    rectify.add_argument("--direction", choices=["south", "north", "auto"], default="auto",
                         help="the satellite's direction along its orbit; auto: fit both, keep the better")
    rectify.add_argument("--method", choices=["gauss-newton", "appendix_c"], default="gauss-newton",
                         help="appendix_c: the 1985 search of the report's Appendix C (no covariance)")
    rectify.add_argument("--sigma", type=_POSITIVE, default=1.0, help="km, ground σ of points without sigma_m")
    rectify.add_argument("--pixels", type=_in_range(int, 2, 100_000), default=512, help="pixels per scan line")
    rectify.add_argument("--scans", type=_in_range(int, 2, 100_000), default=512, help="scan lines")
    rectify.add_argument("--check", help="CSV of check points: known positions, not used in the fit")
    rectify.add_argument("--json", help="also write the report as JSON here, with what rebuilds the model and its "
                                        "covariance (orbit, image size, unknowns, units)")
    rectify.add_argument("--image", help="the image (.npy, .tif, .png; scan lines x pixels): writes the coastline "
                                         "overlay of the fit, and is what --auto-control matches")
    rectify.add_argument("--overlay", help="PNG of the coastline overlay (default: IMAGE-stem_overlay.png beside "
                                           "--json, else in the current folder)")
    rectify.add_argument("--auto-control", action="store_true",
                         help="find control points on the coastline (GSHHG) from the rough orbit (--node, "
                              "--pass-minutes); manual points, if given, join them")
    rectify.add_argument("--node", type=_in_range(float, -360.0, 360.0),
                         help="rough longitude of the ascending node, degrees east (--auto-control)")
    rectify.add_argument("--pass-minutes", type=_in_range(float, 0.0, 1000.0),
                         help="rough minutes from the ascending node to the first scan line (--auto-control)")
    rectify.add_argument("--scanner-span", type=_POSITIVE, default=6.9607,
                         help="degrees from pixel 1 to the last pixel (default: the 1985 blow-up of Figure 3-3)")
    rectify.add_argument("--orbital-span", type=_POSITIVE, default=4.6088,
                         help="degrees of orbit from the first to the last scan line (default: Figure 3-3's)")
    rectify.add_argument("--subtrack", type=float, help="subtrack pixel of the rough orbit (default: the middle)")
    rectify.add_argument("--search", type=_in_range(int, 2, 1000), default=32,
                         help="± pixels the coast is sought around the rough orbit's prediction")
    rectify.set_defaults(run=_rectify)

    simulate = _command(commands, common, "simulate", "write a simulated radar project (TOML + CSV) with its truth, "
                        "or an image sequence (lancaster)",
                        "Write a simulated project with its truth: aidjex (a radar block over drifting ice, after "
                        "the 1975 AIDJEX experiment), prudhoe (a radar block near Prudhoe Bay with land control) or "
                        "lancaster (a satellite image sequence of Lancaster Sound).")
    simulate.add_argument("scenario", choices=["aidjex", "prudhoe", "lancaster"])
    simulate.add_argument("--out", required=True, help="folder to write the project into")
    simulate.add_argument("--seed", type=_in_range(int, 0, 2**32 - 1), default=0, help="random seed")
    simulate.add_argument("--strips", type=_in_range(int, 1, 100), default=10, help="strips per coverage (aidjex)")
    simulate.add_argument("--features", type=_in_range(int, 1, 100_000), default=600, help="ice features (aidjex)")
    simulate.add_argument("--images", type=_in_range(int, 1, 1000), default=6,
                          help="images of the sequence (lancaster)")
    simulate.add_argument("--size", type=_in_range(int, 16, 4096), default=256,
                          help="pixels and scan lines per image (lancaster)")
    simulate.add_argument("--clouds", action="store_true", help="cloud patches on the images (lancaster)")
    simulate.set_defaults(run=_simulate)

    block = _command(commands, common, "block", "adjust a radar block project and measure the drift",
                     "Adjust a block of side-looking radar strips (a 'block': overlapping strips flown over "
                     "drifting ice, tied by features seen on several strips) and measure the ice drift between "
                     "coverages.")
    block.add_argument("project", help="project TOML")
    block.add_argument("--method", choices=["simultaneous", "sequential"], default="simultaneous",
                       help="simultaneous: every unknown in one adjustment; sequential: the 1979 method of the "
                            "AIDJEX report ('source 000'): strip by strip")
    block.add_argument("--navigation-model", choices=["constant", "linear", "schuler", "spline"], default="schuler",
                       help="navigation-error model of the simultaneous method (schuler: the 84-minute Schuler "
                            "oscillation of an inertial navigation system's error)")
    block.add_argument("--navigation-scope", choices=["flight", "strip"], default="flight",
                       help="flight: one error curve per coverage, an offset per strip (the INS error runs on "
                            "through the turns); strip: every strip its own curve (needed by the spline model)")
    block.add_argument("--knot-spacing", type=_POSITIVE, default=300.0, help="s, of the spline model")
    block.add_argument("--take-off-time", type=_in_range(float, None, None), default=None,
                       help="s on the strips' clock when the flights took off: the INS error curve then starts "
                            "there (drift from zero, offset = alignment error); default: from the first strip")
    block.add_argument("--radar-constants", choices=["strip", "shared"], default="strip",
                       help="sweep delay and range scale (the radar's range calibration) per strip or one pair for "
                            "the block")
    block.add_argument("--image-sigma", type=_POSITIVE, nargs=2, default=(0.04, 0.04), metavar=("ALONG", "RANGE"),
                       help="mm, σ of reading the image measurements along track and in slant range (simultaneous)")
    block.add_argument("--time-mark-sigma", type=_in_range(float, 0.0, None), default=0.025, metavar="MM",
                       help="mm, σ of each time mark's position along the film (simultaneous): eq. A1's "
                            "interpolation between the marks adds it to the along-track σ, (1 − u)² + u² of its "
                            "variance at the fraction u between two marks; 0: exact marks")
    block.add_argument("--variance-components", action="store_true",
                       help="estimate a variance factor per observation group (image x, image y, nadir, control; "
                            "iterated Förstner/Helmert) and adjust with the σ rescaled by them")
    block.add_argument("--robust", choices=["huber", "danish"], default=None,
                       help="reweight the observations iteratively by their standardized residuals, for "
                            "blunder-heavy data (the w-tests are those of the final weights)")
    block.add_argument("--out", required=True, help="output folder")
    block.set_defaults(run=_block)
    _sequence_commands(commands, common)
    _sar_commands(commands, common)
    return parser


def main(argv=None) -> int:
    """Run the ``seaice`` command; returns its exit code (:mod:`seaice_jax.errors`)."""
    start = time.perf_counter()
    args = None
    try:
        with interrupts_raise():  # from the start: a Ctrl-C while JAX loads is not lost (nor a traceback)
            args = build_parser().parse_args(argv)
            with _library_logging(args.verbosity):
                if args.compile_cache:  # the default folder, or none for an empty $SEAICE_JAX_CACHE_DIR
                    enable_compilation_cache()
                check_interrupted()  # one swallowed while JAX loaded (by its garbage-collection callback)
                code = args.run(args)
    except Interrupted as interrupt:
        name = "seaice" if args is None else f"seaice {args.command}"
        left = ("" if not interrupt.left else f", but its temporary folder {', '.join(map(str, interrupt.left))} "
                "could not be removed (the next run into the same output removes it)")
        print(f"{name}: {interrupt}; the output was left as it was before the run{left}", file=sys.stderr)
        return interrupt.exit_code
    except Exception as error:
        if args is None:  # not from a command (the parser reports its own errors by SystemExit)
            raise
        code = exit_code(error)
        if args.verbosity >= VERBOSE:
            traceback.print_exc()
        kind = "error" if isinstance(error, ValueError | OSError) else f"unexpected error ({type(error).__name__})"
        hint = "" if args.verbosity >= VERBOSE or code != EXIT_FAILURE else " (-v shows the traceback)"
        print(f"seaice {args.command}: {kind}: {error}{hint}", file=sys.stderr)
        return code
    if args.verbosity >= VERBOSE:
        print(f"seaice {args.command}: done in {time.perf_counter() - start:.1f} s", file=sys.stderr)
    return code


if __name__ == "__main__":
    sys.exit(main())
