"""``seaice rectify``: fit a satellite image's scan model to manual control points, to control points found on the
coastline (``--auto-control``), or to both, print the 1985 VHR2 report and write the JSON and the coastline overlay.

The automatic control starts from a rough orbit as a user knows it — the ascending node's longitude and the
minutes from the node to the image's first scan line (orbital bulletins, the image's time), the image's angular
spans and subtrack pixel (the sensor and how the image was sampled) — and matches the image's coast to GSHHG
(:mod:`seaice_jax.imagery.coast_control`).
"""

import logging
import os
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seaice_jax.adjust.orbit.fit import OrbitFit, check_point_errors, fit_scan_model
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.earth import SIDEREAL_DAY
from seaice_jax.geometry.scan import Orbit, ScanModel, satellite_orbit
from seaice_jax.imagery.coast_control import CoastControl, coast_control, fit_with_snooping
from seaice_jax.io.coastline import Coastline, coastline, outline_box
from seaice_jax.io.sequence import read_image_file
from seaice_jax.io.stations import check_in_image, control_points, read_agrid, read_measurements

FilePath = str | os.PathLike
"""A file's path, as a string or a path object."""


@dataclass(frozen=True)
class RoughOrbit:
    """The pass as a user knows it (degrees, minutes, pixels).

    Attributes:
        node: longitude of the ascending node, degrees east. minutes_after_node: from the node crossing to the first
            scan line. scanner_span: Earth-central (H = 0) or scan angle (H > 0) from pixel 1 to the last pixel,
            degrees. orbital_span: orbital angle from the first to the last scan line, degrees. subtrack_pixel:
            ``None``: the middle pixel. Defaults: the 1985 NOAA-7 blow-up of source 001, Figure 3-3.
    """

    node: float
    minutes_after_node: float
    scanner_span: float = 6.9607
    orbital_span: float = 4.6088
    subtrack_pixel: float | None = None


def rough_model(rough: RoughOrbit, orbit: Orbit, n_pixels: int, n_scans: int, direction: str = "auto") -> ScanModel:
    """The scan model of a rough orbit; ``direction`` ``"auto"``: southbound if the first scan line is on the
    descending half of the orbit (orbital angle 90°-270° from the node), else northbound.

    Raises:
        SeaiceError: a given direction contradicts the pass time.
    """
    eta = 2 * np.pi * rough.minutes_after_node * 60.0 / float(orbit.period)
    descending = np.cos(eta) < 0
    implied = "south" if descending else "north"
    if direction not in ("auto", implied):
        raise SeaiceError(f"--direction {direction}: {rough.minutes_after_node} minutes after the ascending node "
                          f"(orbital angle {np.degrees(eta) % 360:.1f}°) is on the {implied}bound half of the orbit")
    subtrack = 0.5 * (1 + n_pixels) if rough.subtrack_pixel is None else rough.subtrack_pixel
    return ScanModel(np.radians(rough.scanner_span), subtrack, eta, np.radians(rough.orbital_span),
                     np.radians(rough.node), orbit, implied, n_pixels, n_scans)


def image_coastline(model: ScanModel, margin: float = 1.0) -> Coastline:
    """The GSHHG coastline of a box around the image's footprint through ``model``, widened by ``margin``
    degrees (enough for the model's error and the matching search)."""
    pixels = np.concatenate([np.linspace(1, model.n_pixels, 32), np.full(32, float(model.n_pixels)),
                             np.linspace(model.n_pixels, 1, 32), np.full(32, 1.0)])
    scans = np.concatenate([np.full(32, 1.0), np.linspace(1, model.n_scans, 32), np.full(32, float(model.n_scans)),
                            np.linspace(model.n_scans, 1, 32)])
    latitude, longitude = (np.degrees(np.asarray(a)) for a in model.forward_unchecked(pixels, scans))
    if not (np.all(np.isfinite(latitude)) and np.all(np.isfinite(longitude))):
        raise SeaiceError("the rough orbit does not put the image's edges on the Earth (check --node, "
                          "--pass-minutes, --scanner-span)")
    return coastline(*outline_box(longitude, float(latitude.min()), float(latitude.max()), margin))


@dataclass(frozen=True)
class Rectification:
    """The result of :func:`run_rectify`.

    Attributes:
        fit: the final fit. check_errors: ``{check point id: ground error of the fit there, km}`` (``None``: no
            check points given). names: station names by id.
        automatic: the coastline matching (``None`` without ``--auto-control``). overlay: the coastline-overlay
            figure written (``None``: no image given). written: every file written.
    """

    fit: OrbitFit
    check_errors: dict[str, float] | None
    names: dict
    automatic: CoastControl | None
    overlay: Path | None
    written: tuple[Path, ...]


def run_rectify(measurements: FilePath | None, *, satellite: str, altitude_km: float | None = None,
                max_latitude: float | None = None, period_minutes: float | None = None,
                earth_day_minutes: float | None = None, direction: str = "auto", method: str = "gauss-newton",
                sigma_km: float = 1.0, n_pixels: int = 512, n_scans: int = 512, stations: FilePath | None = None,
                check: FilePath | None = None, json_path: FilePath | None = None, image: FilePath | None = None,
                auto_control: bool = False, rough: RoughOrbit | None = None, search: int = 32,
                overlay: FilePath | None = None, overwrite: bool = False, say=None) -> Rectification:
    """Rectify one image (``seaice rectify``); see the module's docstring.

    Args:
        measurements: CSV of manual control points (``None``: only with ``auto_control``).
        image: ``.npy``/``.tif``/``.png`` of ``(n_scans, n_pixels)``; with it the coastline overlay is written to
            ``overlay`` (default: ``<image stem>_overlay.png`` beside ``json_path``, else in the current folder).
        auto_control: find control points on the coastline, from ``rough`` (needs ``image``); manual measurements,
            if given, join them in the final fit.
        say: a callable for progress messages (``None``: this module's logger, ``seaice_jax.workflows.rectify``, at
            INFO).

    Raises:
        SeaiceError: bad input, naming the file or option.
    """
    from seaice_jax.files import write_json
    from seaice_jax.outputs import output_file
    from seaice_jax.report.text import orbit_fit_json

    say = say or logging.getLogger(__name__).info
    if measurements is None and not auto_control:
        raise SeaiceError("give the control points' CSV (MEASUREMENTS), or --image with --auto-control")
    if auto_control and (image is None or rough is None):
        raise SeaiceError("--auto-control needs --image and the rough orbit (--node, --pass-minutes)")
    if auto_control and method != "gauss-newton":
        raise SeaiceError("--auto-control fits by Gauss-Newton (it needs the w-test); drop --method appendix_c")
    catalogue = read_agrid(stations) if stations else None
    manual, names = None, {}
    if measurements is not None:
        points = read_measurements(measurements, catalogue)
        check_in_image(points, n_pixels, n_scans, measurements)
        manual = control_points(points, sigma_km)
        names = {m.id: m.name for m in points}
    checked = control_points(read_measurements(check, catalogue), sigma_km) if check else None
    data, image_path = None, None
    if image is not None:
        image_path = Path(image)
        data = read_image_file(image_path)
        if data.shape != (n_scans, n_pixels):
            raise SeaiceError(f"{image}: the image is {data.shape[1]} pixels x {data.shape[0]} scan lines, not "
                              f"{n_pixels} x {n_scans} (--pixels, --scans)")
    orbit = satellite_orbit(
        satellite,
        altitude=None if altitude_km is None else altitude_km * 1000.0,
        earth_day=SIDEREAL_DAY if earth_day_minutes is None else earth_day_minutes * 60.0,
        period=None if period_minutes is None else period_minutes * 60.0,
        max_latitude=None if max_latitude is None else np.radians(max_latitude),
    )
    inputs = [p for p in (measurements, image) if p is not None]
    json_file = output_file(json_path, overwrite, inputs=inputs) if json_path else nullcontext()
    overlay_path = None
    if image_path is not None:
        folder = Path(json_path).parent if json_path is not None else Path()
        overlay_path = Path(overlay) if overlay else folder / f"{image_path.stem}_overlay.png"
    overlay_file = output_file(overlay_path, overwrite, inputs=inputs) if overlay_path else nullcontext()
    written: list[Path] = []
    automatic, coast = None, None
    with json_file as staging, overlay_file as figure_staging:
        if auto_control:
            assert data is not None and rough is not None
            start = rough_model(rough, orbit, n_pixels, n_scans, direction)
            coast = image_coastline(start)
            say(f"matching the image's coast to GSHHG from the rough {start.direction}bound orbit")
            automatic = coast_control(data, start, coast.contains, search=search)
            fit = automatic.fit
            say(f"{len(fit.control)} coastline control points ({sum(len(r) for r in automatic.rejected)} rejected "
                "by the w-test)")
            if manual is not None:
                coastal = np.arange(len(fit.control) + len(manual)) < len(fit.control)  # the manual points: independent
                fit, _ = fit_with_snooping(fit.control.joined(manual), fit.model, window=automatic.window,
                                           shared=coastal)
        else:
            assert manual is not None
            fit = fit_scan_model(manual, orbit, direction=direction, n_pixels=n_pixels, n_scans=n_scans,
                                 method=method)
        check_errors = None if checked is None else dict(zip(checked.ids, map(float, check_point_errors(
            fit.model, checked)), strict=True))
        if staging is not None:
            write_json(staging.path / staging.target.name, orbit_fit_json(fit, check_errors))
            written.append(staging.target)
        if figure_staging is not None and overlay_path is not None and image_path is not None:
            from seaice_jax.report.figures import plot_coastline_overlay

            coast = coast or image_coastline(fit.model)
            control = (np.asarray(fit.control.pixel), np.asarray(fit.control.scan))
            plot_coastline_overlay(figure_staging.path / figure_staging.target.name, data, fit.model, coast, control,
                                   title=f"{image_path.name}: coastline through the fitted model")
            written.append(overlay_path)
    return Rectification(fit, check_errors, names, automatic, overlay_path, tuple(written))
