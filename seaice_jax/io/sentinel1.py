"""Sentinel-1 product annotation (the SAFE ``annotation/*.xml`` of one swath and polarisation).

What the range-Doppler model needs from a Level-1 product: the orbit state vectors (Earth-fixed, every 10 s), the
image timing (first line, line interval, bursts of TOPS SLC), the range sampling (first sample's two-way time and
sampling rate; for GRD the ground-to-slant-range polynomials), and the ESA processor's own geolocation grid, against
which the model is checked.

Image coordinates -> radar coordinates (:meth:`Sentinel1Annotation.radar_coordinates`):

* Slant range time of a pixel: SLC τ = τ₀ + pixel / f_s; GRD: the ground range pixel · Δx goes through the
  ground-to-slant polynomial whose azimuth time is *nearest* to the line's (the processor applies the nearest one;
  blending two neighbours is off by up to metres where they differ).
* Azimuth time of a line: first line time + line · Δt (SLC: the line's burst start + its line in the burst · Δt).
* The bistatic shift. The annotated grid's azimuth times are zero-Doppler times of the point on the annotated orbit;
  an image line's time is not, by (τ − τ_ref)/2 (the echo of a far pixel arrives later, while the satellite moved on;
  the processor's bistatic correction refers to τ_ref, the mid-swath range time of the middle sub-swath: IW2, EW3, or
  the single swath of stripmap). So the zero-Doppler time of (line, pixel) is t_line + (τ − τ_ref)/2. The annotation
  of a stripmap product or of the middle sub-swath gives τ_ref itself; that of another sub-swath does not, and τ_ref
  is then taken from the middle sub-swath's annotation when given (``reference=``), or else recovered from the file's
  own geolocation grid (one number per file: the median over its points).

Every error names the file and the XML element.
"""

import os
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.state_vectors import StateVectorOrbit
from seaice_jax.geometry.zero_doppler import SPEED_OF_LIGHT

MIDDLE_SWATHS = ("IW2", "EW3")
"""Sub-swaths whose mid-range time is the bistatic reference of a TOPS product (IW, EW)."""


@dataclass(frozen=True)
class GeolocationGrid:
    """The processor's geolocation grid: ``(k,)`` arrays of image line and pixel, zero-Doppler azimuth time (s from
    the annotation's epoch), two-way slant range time (s), latitude, longitude (degrees), ellipsoidal height (m) and
    incidence angle (degrees)."""

    line: np.ndarray
    pixel: np.ndarray
    azimuth_time: np.ndarray
    slant_range_time: np.ndarray
    latitude: np.ndarray
    longitude: np.ndarray
    height: np.ndarray
    incidence_angle: np.ndarray

    @property
    def slant_range(self) -> np.ndarray:
        """m: c τ / 2."""
        return self.slant_range_time * SPEED_OF_LIGHT / 2.0

    def table(self, values) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``values`` ``(k,)`` given per grid point as a table: ``(lines (m,), pixels (n,), table (m, n))``, rows by
        increasing line, columns by increasing pixel.

        Raises:
            SeaiceError: the grid is not a full rectangle of lines x pixels (ESA writes it as one).
        """
        lines, pixels = np.unique(self.line), np.unique(self.pixel)
        if lines.size * pixels.size != self.line.size:
            raise SeaiceError(f"the geolocation grid is not a full rectangle of lines x pixels ({self.line.size} "
                              f"points on {lines.size} lines and {pixels.size} pixels)")
        table = np.full((lines.size, pixels.size), np.nan)
        table[np.searchsorted(lines, self.line), np.searchsorted(pixels, self.pixel)] = values
        return lines, pixels, table


@dataclass(frozen=True)
class GroundToSlant:
    """GRD ground-range -> slant-range polynomials (``coordinateConversion``): ``(m,)`` azimuth times (s), ground
    range origins gr0 (m) and ``(m, d)`` coefficients (slant range in m of ground range in m above gr0)."""

    azimuth_time: np.ndarray
    ground_range_origin: np.ndarray
    coefficients: np.ndarray


@dataclass(frozen=True)
class Sentinel1Annotation:
    """One Sentinel-1 annotation file. Times are seconds from ``epoch`` (the first state vector's time, UTC).

    Attributes:
        path: the file read.
        mission, mode, swath, polarisation, product_type, pass_direction: as annotated (``S1A``, ``EW``, ``EW1``,
            ``HH``, ``SLC`` / ``GRD``, ``Descending``).
        epoch: ``numpy.datetime64`` (ns), UTC.
        orbit_times, orbit_positions, orbit_velocities: ``(n,)`` s, ``(n, 3)`` m and m/s, Earth-fixed.
        first_line_time: s; line_interval: azimuth time between lines, s.
        lines, samples: image size.
        first_range_time: two-way slant range time of pixel 0, s; range_sampling_rate: Hz.
        range_pixel_spacing, azimuth_pixel_spacing: m (slant range for SLC, ground range for GRD).
        radar_frequency: Hz.
        lines_per_burst, burst_times: TOPS SLC bursts (``burst_times`` empty otherwise).
        ground_to_slant: GRD polynomials (None for SLC).
        grid: the geolocation grid.
        bistatic_reference_time: τ_ref of the bistatic shift (module docstring), s.
        bistatic_reference_source: where τ_ref came from (``"mid-swath"``, ``"reference annotation <name>"`` or
            ``"geolocation grid"``).
    """

    path: Path
    mission: str
    mode: str
    swath: str
    polarisation: str
    product_type: str
    pass_direction: str
    epoch: np.datetime64
    orbit_times: np.ndarray
    orbit_positions: np.ndarray
    orbit_velocities: np.ndarray
    first_line_time: float
    line_interval: float
    lines: int
    samples: int
    first_range_time: float
    range_sampling_rate: float
    range_pixel_spacing: float
    azimuth_pixel_spacing: float
    radar_frequency: float
    lines_per_burst: int
    burst_times: np.ndarray
    ground_to_slant: GroundToSlant | None
    grid: GeolocationGrid
    bistatic_reference_time: float = field(default=np.nan)
    bistatic_reference_source: str = ""

    @property
    def mid_swath_range_time(self) -> float:
        """Two-way slant range time of the swath's middle sample, s (SLC: τ₀ + N / (2 f_s))."""
        return self.first_range_time + self.samples / (2.0 * self.range_sampling_rate)

    def orbit(self, epoch: np.datetime64 | None = None) -> StateVectorOrbit:
        """The annotated orbit as a :class:`~seaice_jax.geometry.state_vectors.StateVectorOrbit`, times in seconds
        from ``epoch`` (default :attr:`epoch`; give one epoch to the orbits of several images adjusted together)."""
        shift = 0.0 if epoch is None else float(_seconds(self.epoch, np.asarray(epoch, "datetime64[ns]")))
        return StateVectorOrbit(self.orbit_times + shift, self.orbit_positions, self.orbit_velocities)

    def line_time(self, line) -> np.ndarray:
        """Azimuth time (s) of image lines (fractional lines interpolate linearly), before the bistatic shift."""
        line = np.asarray(line, float)
        if self.burst_times.size == 0:
            return self.first_line_time + line * self.line_interval
        burst = np.clip(np.floor(line / self.lines_per_burst).astype(int), 0, self.burst_times.size - 1)
        return self.burst_times[burst] + (line - burst * self.lines_per_burst) * self.line_interval

    def slant_range_time(self, pixel, azimuth_time=None) -> np.ndarray:
        """Two-way slant range time (s) of pixels; GRD needs the azimuth time (s) to pick the nearest polynomial."""
        pixel = np.asarray(pixel, float)
        if self.ground_to_slant is None:
            return self.first_range_time + pixel / self.range_sampling_rate
        if azimuth_time is None:
            raise ValueError(f"{self.path.name}: a GRD pixel's slant range needs the azimuth time of its line")
        table = self.ground_to_slant
        times = np.asarray(azimuth_time, float)
        nearest = np.abs(times[..., None] - table.azimuth_time).argmin(axis=-1)
        ground = pixel * self.range_pixel_spacing - table.ground_range_origin[nearest]
        coefficients = table.coefficients[nearest]
        powers = ground[..., None] ** np.arange(coefficients.shape[-1])
        return 2.0 * np.sum(coefficients * powers, axis=-1) / SPEED_OF_LIGHT

    def radar_coordinates(self, line, pixel) -> tuple[np.ndarray, np.ndarray]:
        """Zero-Doppler azimuth time (s from :attr:`epoch`) and slant range (m) of image ``line``, ``pixel``
        (broadcast), with the bistatic shift (module docstring)."""
        line, pixel = np.broadcast_arrays(np.asarray(line, float), np.asarray(pixel, float))
        time = self.line_time(line)
        tau = self.slant_range_time(pixel, time)
        return time + (tau - self.bistatic_reference_time) / 2.0, tau * SPEED_OF_LIGHT / 2.0

    def image_coordinates(self, azimuth_time, slant_range) -> tuple[np.ndarray, np.ndarray]:
        """Inverse of :meth:`radar_coordinates`: fractional image ``(line, pixel)`` of zero-Doppler azimuth times
        (s from :attr:`epoch`) and slant ranges (m). GRD and stripmap; a TOPS SLC's bursts overlap in time (a time
        has two lines), so its image coordinates are refused.

        Raises:
            SeaiceError: for a TOPS SLC (bursts).
        """
        if self.burst_times.size:
            raise SeaiceError(f"{self.path.name}: a TOPS SLC's bursts overlap in azimuth time: image coordinates of "
                              f"a ground point are ambiguous (use the GRD product)")
        time, slant = np.broadcast_arrays(np.asarray(azimuth_time, float), np.asarray(slant_range, float))
        tau = 2.0 * slant / SPEED_OF_LIGHT
        line_time = time - (tau - self.bistatic_reference_time) / 2.0
        line = (line_time - self.first_line_time) / self.line_interval
        if self.ground_to_slant is None:
            return line, (tau - self.first_range_time) * self.range_sampling_rate
        table = self.ground_to_slant
        nearest = np.abs(line_time[..., None] - table.azimuth_time).argmin(axis=-1)
        coefficients = table.coefficients[nearest]
        powers = np.arange(coefficients.shape[-1])
        ground = (slant - coefficients[..., 0]) / coefficients[..., 1]
        for _ in range(6):  # Newton on the monotone ground-to-slant polynomial
            value = np.sum(coefficients * ground[..., None] ** powers, axis=-1) - slant
            slope = np.sum(coefficients[..., 1:] * powers[1:] * ground[..., None] ** (powers[1:] - 1), axis=-1)
            ground = ground - value / slope
        return line, (ground + table.ground_range_origin[nearest]) / self.range_pixel_spacing

    def decimated(self, factor: int) -> "Sentinel1Annotation":
        """The annotation of the image that keeps every ``factor``-th line and sample (``image[::factor, ::factor]``,
        a quick-look): line ``k`` is the product's line ``k · factor``, likewise pixels. GRD and stripmap."""
        if factor < 1 or int(factor) != factor:
            raise SeaiceError(f"decimation factor must be a positive integer, got {factor}")
        if self.burst_times.size:
            raise SeaiceError(f"{self.path.name}: a TOPS SLC cannot be decimated line by line (bursts)")
        grid = replace(self.grid, line=self.grid.line / factor, pixel=self.grid.pixel / factor)
        return replace(self, lines=-(-self.lines // factor), samples=-(-self.samples // factor),
                       line_interval=self.line_interval * factor,
                       range_sampling_rate=self.range_sampling_rate / factor,
                       range_pixel_spacing=self.range_pixel_spacing * factor,
                       azimuth_pixel_spacing=self.azimuth_pixel_spacing * factor, grid=grid)

    def with_bistatic_reference(self, reference: "Sentinel1Annotation") -> "Sentinel1Annotation":
        """This annotation with τ_ref from ``reference``, the middle sub-swath's annotation of the same product."""
        if reference.swath not in MIDDLE_SWATHS:
            raise SeaiceError(f"{reference.path.name}: the bistatic reference must be the middle sub-swath's "
                              f"annotation ({' or '.join(MIDDLE_SWATHS)}), not {reference.swath}")
        return replace(self, bistatic_reference_time=reference.mid_swath_range_time,
                       bistatic_reference_source=f"reference annotation {reference.path.name}")


def read_annotation(path: str | os.PathLike, reference: str | os.PathLike | None = None) -> Sentinel1Annotation:
    """Read a Sentinel-1 Level-1 annotation XML (SLC or GRD, any mode).

    Args:
        path: the ``annotation/s1?-*.xml`` file of one swath and polarisation.
        reference: optional annotation of the middle sub-swath (IW2 / EW3) of the same product, for the bistatic
            reference of a side sub-swath (module docstring).

    Raises:
        SeaiceError: a file that is not XML, not a Sentinel-1 annotation, or lacks or garbles an element; the
            message names the file and the element.
    """
    path = Path(path)
    root = _parse(path)
    reader = _Reader(path, root)
    annotation = reader.annotation()
    if reference is not None:
        return annotation.with_bistatic_reference(read_annotation(reference))
    return annotation


def _parse(path: Path):
    try:
        root = ElementTree.parse(path).getroot()
    except ElementTree.ParseError as error:
        line, column = error.position
        raise SeaiceError(f"{path}: not well-formed XML at line {line}, column {column} ({error})") from None
    except OSError as error:
        raise SeaiceError(f"{path}: cannot be read ({error.strerror or error})") from None
    if root.tag != "product" or root.find("adsHeader") is None:
        raise SeaiceError(f"{path}: not a Sentinel-1 annotation (root element <{root.tag}>, expected <product> with "
                          f"an <adsHeader>)")
    return root


def _seconds(moments, epoch) -> np.ndarray:
    """Seconds from ``epoch`` of ``numpy.datetime64`` values (nanosecond exact)."""
    return (moments - epoch) / np.timedelta64(1, "ns") * 1e-9


class _Reader:
    """Element access that names the file and element on every failure."""

    def __init__(self, path: Path, root):
        self.path, self.root = path, root

    def fail(self, where: str, what: str):
        raise SeaiceError(f"{self.path}: <{where}> {what}")

    def element(self, where: str, parent=None):
        found = (self.root if parent is None else parent).find(where)
        if found is None:
            self.fail(where, "is missing")
        return found

    def text(self, where: str, parent=None) -> str:
        text = self.element(where, parent).text
        if text is None or not text.strip():
            self.fail(where, "is empty")
        return text.strip()

    def number(self, where: str, parent=None) -> float:
        text = self.text(where, parent)
        try:
            value = float(text)
        except ValueError:
            self.fail(where, f"is not a number: {text[:40]!r}")
            raise
        if not np.isfinite(value):
            self.fail(where, f"is not finite: {text!r}")
        return value

    def integer(self, where: str, parent=None) -> int:
        text = self.text(where, parent)
        try:
            return int(text)
        except ValueError:
            self.fail(where, f"is not an integer: {text[:40]!r}")
            raise

    def numbers(self, where: str, parent=None) -> np.ndarray:
        text = self.text(where, parent)
        try:
            values = np.array(text.split(), float)
        except ValueError:
            self.fail(where, f"holds a value that is not a number: {text[:60]!r}")
        if not np.all(np.isfinite(values)):
            self.fail(where, "holds a value that is not finite")
        return values

    def time(self, where: str, parent=None) -> np.datetime64:
        text = self.text(where, parent)
        try:
            return np.datetime64(text.rstrip("Z"), "ns")
        except ValueError:
            self.fail(where, f"is not an ISO 8601 time: {text!r}")
            raise

    def all(self, where: str, minimum: int = 1) -> list:
        found = self.root.findall(where)
        if len(found) < minimum:
            self.fail(where, f"occurs {len(found)} time(s), at least {minimum} needed")
        return found

    def annotation(self) -> Sentinel1Annotation:
        header = "adsHeader"
        orbit = self.all("generalAnnotation/orbitList/orbit", minimum=8)
        epoch = self.time("time", orbit[0])
        times = np.array([_seconds(self.time("time", o), epoch) for o in orbit])
        if np.any(np.diff(times) <= 0):
            bad = int(np.argmax(np.diff(times) <= 0)) + 1
            self.fail(f"generalAnnotation/orbitList/orbit[{bad + 1}]/time", "does not follow the previous state "
                      "vector's time")
        for o in orbit:
            frame = o.find("frame")
            if frame is not None and frame.text and frame.text.strip() != "Earth Fixed":
                self.fail("generalAnnotation/orbitList/orbit/frame", f"is {frame.text.strip()!r}, expected "
                          "'Earth Fixed'")
        positions = np.array([[self.number(f"position/{c}", o) for c in "xyz"] for o in orbit])
        velocities = np.array([[self.number(f"velocity/{c}", o) for c in "xyz"] for o in orbit])
        info = "imageAnnotation/imageInformation"
        product_type = self.text(f"{header}/productType")
        if product_type not in ("SLC", "GRD"):
            self.fail(f"{header}/productType", f"is {product_type!r}: only SLC and GRD are read")
        lines = self.integer(f"{info}/numberOfLines")
        samples = self.integer(f"{info}/numberOfSamples")
        first_line = self.time(f"{info}/productFirstLineUtcTime")
        bursts = self.root.findall("swathTiming/burstList/burst")
        lines_per_burst = self.integer("swathTiming/linesPerBurst") if bursts else 0
        burst_times = np.array([_seconds(self.time("azimuthTime", b), epoch) for b in bursts])
        annotation = Sentinel1Annotation(
            path=self.path, mission=self.text(f"{header}/missionId"), mode=self.text(f"{header}/mode"),
            swath=self.text(f"{header}/swath"), polarisation=self.text(f"{header}/polarisation"),
            product_type=product_type, pass_direction=self.text("generalAnnotation/productInformation/pass"),
            epoch=epoch, orbit_times=times, orbit_positions=positions, orbit_velocities=velocities,
            first_line_time=float(_seconds(first_line, epoch)),
            line_interval=self.number(f"{info}/azimuthTimeInterval"), lines=lines, samples=samples,
            first_range_time=self.number(f"{info}/slantRangeTime"),
            range_sampling_rate=self.number("generalAnnotation/productInformation/rangeSamplingRate"),
            range_pixel_spacing=self.number(f"{info}/rangePixelSpacing"),
            azimuth_pixel_spacing=self.number(f"{info}/azimuthPixelSpacing"),
            radar_frequency=self.number("generalAnnotation/productInformation/radarFrequency"),
            lines_per_burst=lines_per_burst, burst_times=burst_times,
            ground_to_slant=self.ground_to_slant(epoch) if product_type == "GRD" else None,
            grid=self.grid(epoch, lines, samples),
        )
        return self.with_own_bistatic_reference(annotation)

    def ground_to_slant(self, epoch) -> GroundToSlant:
        where = "coordinateConversion/coordinateConversionList/coordinateConversion"
        entries = self.all(where)
        coefficients = [self.numbers("grsrCoefficients", e) for e in entries]
        if len({c.size for c in coefficients}) != 1:
            self.fail(f"{where}/grsrCoefficients", "has a different number of coefficients in different entries")
        return GroundToSlant(np.array([_seconds(self.time("azimuthTime", e), epoch) for e in entries]),
                             np.array([self.number("gr0", e) for e in entries]), np.array(coefficients))

    def grid(self, epoch, lines: int, samples: int) -> GeolocationGrid:
        where = "geolocationGrid/geolocationGridPointList/geolocationGridPoint"
        points = self.all(where, minimum=4)
        names = ("line", "pixel", "slantRangeTime", "latitude", "longitude", "height", "incidenceAngle")
        values = np.array([[self.number(n, p) for n in names] for p in points])
        times = np.array([_seconds(self.time("azimuthTime", p), epoch) for p in points])
        grid = GeolocationGrid(values[:, 0], values[:, 1], times, *values[:, 2:].T)
        checks = [(np.abs(grid.latitude) > 90, "latitude outside ±90°"),
                  (np.abs(grid.longitude) > 180, "longitude outside ±180°"),
                  ((grid.line < 0) | (grid.line > lines), f"line outside the image's {lines} lines"),
                  ((grid.pixel < 0) | (grid.pixel > samples), f"pixel outside the image's {samples} samples"),
                  (grid.slant_range_time <= 0, "slant range time not positive")]
        for bad, reason in checks:
            if np.any(bad):
                self.fail(f"{where}[{int(np.argmax(bad)) + 1}]", f"has a {reason}")
        return grid

    def with_own_bistatic_reference(self, annotation: Sentinel1Annotation) -> Sentinel1Annotation:
        single_swath = annotation.mode not in ("IW", "EW")
        if annotation.product_type == "SLC" and (single_swath or annotation.swath in MIDDLE_SWATHS):
            return replace(annotation, bistatic_reference_time=annotation.mid_swath_range_time,
                           bistatic_reference_source="mid-swath")
        grid = annotation.grid
        line_times = annotation.line_time(grid.line)
        implied = grid.slant_range_time - 2.0 * (grid.azimuth_time - line_times)
        return replace(annotation, bistatic_reference_time=float(np.median(implied)),
                       bistatic_reference_source="geolocation grid")
