"""The ``seaice`` command. Thin: parses arguments, calls the library, prints, exits with a clear message."""

import argparse
import sys

from seaice_jax import __version__
from seaice_jax.errors import SeaiceError


def _demo(args) -> int:
    from seaice_jax.workflows.demo import run_demo

    print(run_demo(args.out).summary)
    return 0


def _rectify(args) -> int:
    import numpy as np

    from seaice_jax.adjust.orbit_fit import fit_scan_model
    from seaice_jax.files import write_json
    from seaice_jax.geometry.earth import SIDEREAL_DAY
    from seaice_jax.geometry.scan import satellite_orbit
    from seaice_jax.io.stations import control_points, read_agrid, read_measurements
    from seaice_jax.report.text import orbit_fit_json, orbit_fit_report

    catalogue = read_agrid(args.stations) if args.stations else None
    measurements = read_measurements(args.measurements, catalogue)
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
    fit = fit_scan_model(control, orbit, direction=args.direction, n_pixels=args.pixels, n_scans=args.scans,
                         method=args.method)
    print(orbit_fit_report(fit, check, names={m.id: m.name for m in measurements}))
    if args.json:
        write_json(args.json, orbit_fit_json(fit, check))
        print(f"wrote {args.json}")
    return 0


def _simulate(args) -> int:
    from seaice_jax.io.project import write_project
    from seaice_jax.simulate.aircraft import FlightPlan, aidjex_scenario, prudhoe_scenario

    if args.scenario == "lancaster":
        from seaice_jax.workflows.image_sequence import write_simulated_sequence

        path = write_simulated_sequence(args.out, args.seed, args.images, args.size, args.clouds)
        print(f"wrote {path} (images, control points, land_mask.npy)")
        return 0
    if args.scenario == "aidjex":
        scenario = aidjex_scenario(args.seed, plan=FlightPlan(strips=args.strips), features=args.features)
    else:
        scenario = prudhoe_scenario(args.seed)
    print(f"wrote {write_project(scenario, args.out)} (and truth.csv beside it)")
    return 0


def _block(args) -> int:
    from seaice_jax.adjust.block import BlockOptions
    from seaice_jax.workflows.radar_block import run_block

    options = BlockOptions(navigation_model=args.navigation_model, navigation_scope=args.navigation_scope,
                           knot_spacing=args.knot_spacing, radar_constants=args.radar_constants,
                           take_off_time=args.take_off_time)
    run = run_block(args.project, args.out, args.method, options)
    print(run.report)
    print(f"wrote {len(run.files)} files into {args.out}")
    return 0


def _remap(args) -> int:
    from seaice_jax.workflows.image_sequence import run_remap

    step = run_remap(args.project, args.out, method=args.method, fill=args.fill, progress=not args.quiet)
    print(step.report)
    print(f"wrote {len(step.files)} files into {args.out}")
    return 0


def _track(args) -> int:
    from seaice_jax.imagery.tracking import TrackingOptions
    from seaice_jax.workflows.image_sequence import run_track

    options = TrackingOptions(patch=args.patch, search=args.search, spacing=args.spacing,
                              min_correlation=args.min_correlation, first_guess=args.first_guess)
    step = run_track(args.remapped, args.out, options, tracking_sigma=args.tracking_sigma, progress=not args.quiet)
    print(step.report)
    print(f"wrote {len(step.files)} files into {args.out}")
    return 0


def _velocities(args) -> int:
    from seaice_jax.workflows.image_sequence import run_velocities

    step = run_velocities(args.records, args.out, projection=args.projection, box_size=args.box_km * 1000.0,
                          velocity_sigma=args.velocity_sigma)
    print(step.report)
    print(f"wrote {len(step.files)} files into {args.out}")
    return 0


def _movie(args) -> int:
    from seaice_jax.workflows.image_sequence import run_movie

    step = run_movie(args.remapped, args.out, land_mask=args.land_mask, records=args.records, fps=args.fps,
                     scale=args.scale)
    print(step.report)
    return 0


def _sequence_commands(commands) -> None:
    remap = commands.add_parser("remap", help="rectify an image-sequence project and remap it into its map grid")
    remap.add_argument("project", help="sequence TOML")
    remap.add_argument("--out", required=True, help="output folder (GeoTIFFs, remapped.npz, rectification.csv)")
    remap.add_argument("--method", choices=["bilinear", "nearest"], default="bilinear")
    remap.add_argument("--fill", type=int, default=1, help="passes of the 1985 fill over missing pixels (0: none)")
    remap.add_argument("--quiet", action="store_true", help="no progress bars")
    remap.set_defaults(run=_remap)

    track = commands.add_parser("track", help="track the ice between consecutive remapped images")
    track.add_argument("remapped", help="folder written by `seaice remap`")
    track.add_argument("--out", required=True, help="output folder (CF-NetCDF drift, floes.csv, GeoJSON)")
    track.add_argument("--patch", type=int, default=15, help="template side, pixels (odd)")
    track.add_argument("--search", type=int, default=6, help="largest displacement searched, pixels")
    track.add_argument("--spacing", type=int, default=8, help="pixels between tracked points")
    track.add_argument("--min-correlation", type=float, default=0.6)
    track.add_argument("--first-guess", choices=["zero", "features"], default="zero",
                       help="features: ORB matches and a RANSAC similarity transform predict the motion")
    track.add_argument("--tracking-sigma", type=float, default=0.2, help="σ of a tracked displacement, pixels")
    track.add_argument("--quiet", action="store_true", help="no progress bars")
    track.set_defaults(run=_track)

    speeds = commands.add_parser("velocities", help="velocities, box averages, time series, deformation and "
                                                    "trajectories from floe records")
    speeds.add_argument("records", help="floe record CSV (floe_id,time,image,pixel,scan,latitude,longitude)")
    speeds.add_argument("--out", required=True, help="output folder")
    speeds.add_argument("--projection", choices=["nsidc-north", "nsidc-south"], default="nsidc-north",
                        help="the grid whose axes the grid-relative components follow")
    speeds.add_argument("--box-km", type=float, default=50.0, help="side of the averaging boxes, km")
    speeds.add_argument("--velocity-sigma", type=float, default=None,
                        help="σ of each velocity component (m/s) for the deformation's σ (default: 1 km "
                             "position σ per fix)")
    speeds.set_defaults(run=_velocities)

    movie = commands.add_parser("movie", help="time-lapse film (GIF or MP4) of a remapped sequence")
    movie.add_argument("remapped", help="folder written by `seaice remap`")
    movie.add_argument("--out", required=True, help="film file, .gif or .mp4")
    movie.add_argument("--land-mask", help=".npy bool array on the grid: land drawn filled")
    movie.add_argument("--records", help="floe record CSV: the floes marked on every frame")
    movie.add_argument("--fps", type=float, default=2.0)
    movie.add_argument("--scale", type=int, default=2, help="pixel replication")
    movie.set_defaults(run=_movie)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="seaice", description="Sea-ice mapping and drift from radar strips and "
                                     "satellite images (seaice_jax).")
    parser.add_argument("--version", action="version", version=f"seaice_jax {__version__}")
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
    rectify.add_argument("--altitude", type=float, help="km; 0 for images corrected for Earth curvature "
                                                        "(default: the satellite's)")
    rectify.add_argument("--max-latitude", type=float, help="degrees (overrides the satellite table)")
    rectify.add_argument("--period", type=float, help="minutes (overrides the satellite table)")
    rectify.add_argument("--earth-day", type=float, help="minutes of one Earth rotation (default: sidereal day; "
                                                         "the 1985 program used 1440)")
    rectify.add_argument("--direction", choices=["south", "north", "auto"], default="auto")
    rectify.add_argument("--method", choices=["gauss-newton", "appendix_c"], default="gauss-newton")
    rectify.add_argument("--sigma", type=float, default=1.0, help="km, ground σ of points without sigma_km")
    rectify.add_argument("--pixels", type=int, default=512, help="pixels per scan line (default 512)")
    rectify.add_argument("--scans", type=int, default=512, help="scan lines (default 512)")
    rectify.add_argument("--check", help="CSV of check points: known positions, not used in the fit")
    rectify.add_argument("--json", help="also write the report as JSON here")
    rectify.set_defaults(run=_rectify)

    simulate = commands.add_parser("simulate", help="write a simulated radar project (TOML + CSV) with its truth, "
                                                    "or an image sequence (lancaster)")
    simulate.add_argument("scenario", choices=["aidjex", "prudhoe", "lancaster"])
    simulate.add_argument("--out", required=True, help="folder to write the project into")
    simulate.add_argument("--seed", type=int, default=0)
    simulate.add_argument("--strips", type=int, default=10, help="strips per coverage (aidjex)")
    simulate.add_argument("--features", type=int, default=600, help="ice features (aidjex)")
    simulate.add_argument("--images", type=int, default=6, help="images of the sequence (lancaster)")
    simulate.add_argument("--size", type=int, default=256, help="pixels and scan lines per image (lancaster)")
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
    block.add_argument("--knot-spacing", type=float, default=300.0, help="s, of the spline model")
    block.add_argument("--take-off-time", type=float, default=None,
                       help="s on the strips' clock when the flights took off: the INS error curve then starts "
                            "there (drift from zero, offset = alignment error); default: from the first strip")
    block.add_argument("--radar-constants", choices=["strip", "shared"], default="strip",
                       help="sweep delay and range scale per strip or one pair for the block")
    block.add_argument("--out", required=True, help="output folder")
    block.set_defaults(run=_block)
    _sequence_commands(commands)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.run(args)
    except (SeaiceError, ValueError, OSError) as error:
        print(f"seaice {args.command}: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
