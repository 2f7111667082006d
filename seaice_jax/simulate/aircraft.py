"""A seeded simulator of an AIDJEX-like airborne radar block (source 000) with known truth.

Flight: parallel strips flown back and forth (180° turns), one look side, swaths overlapping by ``overlap``.
Each strip's truth is a great-circle flight at constant altitude (:class:`CircularTrajectory`). What the
instruments record is the truth corrupted by the error sources the sources describe, each switchable:

* inertial navigation: a drift growing ``drift_rate`` per hour of flight, a Schuler oscillation (84.4 min) of
  ``schuler_amplitude``, a random perturbation at each turn — applied as north/east offsets of the recorded
  positions, whose time derivative the recorded velocities carry — and white noise on each 10-s record:
  ``record_noise`` on the positions, ``velocity_noise`` on the velocities (north/east; an INS velocity is far
  more precise than its position: a few cm/s against tens of metres);
* the altimeter: Gaussian noise;
* the radar: each strip's true sweep delay and range scale differ from the nominal ones by a random calibration
  error (σ ``sweep_delay_error``, ``range_scale_error``); time marks jitter;
* image measurements: Gaussian noise in x and in the slant-range coordinate y; the ground-range error it causes
  grows toward near range as 1/sin θ (the ground-range resolution), through the geometry.

Features are points on the ice (height 0 on the sphere) imaged through the *true* geometry: the zero-Doppler time
on the true trajectory gives x (film along-track coordinate, ``film_rate`` mm/s after the strip start), the true
slant range gives y = r/f − c (mm).
"""

from dataclasses import dataclass, field, replace

import jax
import jax.numpy as jnp
import numpy as np

from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.earth import MEAN_RADIUS, latitude_longitude, north_east, unit_vector
from seaice_jax.geometry.projections import TangentPlane
from seaice_jax.geometry.range_doppler import LookSide, imaging_time_and_range, look_sign
from seaice_jax.geometry.trajectory import CircularTrajectory
from seaice_jax.sensors.navigation import SCHULER_PERIOD
from seaice_jax.sensors.strips import Coverage, Measurements, StripRecord, image_to_ground


def _north_east(position):
    return tuple(np.asarray(a) for a in north_east(np.asarray(position)))


@dataclass(frozen=True)
class ErrorModel:
    """Magnitudes of the simulated errors (0 switches one off). Distances in metres, times in seconds."""

    drift_rate: float = 750.0 / 3600.0  # m/s: 0.75 km per hour of flight
    schuler_amplitude: float = 2000.0
    turn_perturbation: float = 300.0
    record_noise: float = 30.0
    altimeter_noise: float = 5.0
    sweep_delay_error: float = 0.4  # mm, σ of each strip's sweep-delay calibration error
    range_scale_error: float = 0.005  # relative, σ of each strip's range-scale calibration error
    time_mark_jitter: float = 0.05  # s
    image_noise: float = 0.04  # mm, in x and in y (10 m of slant range at 250 m/mm)
    velocity_noise: float = 0.03  # m/s, white, on each recorded north/east velocity

    @classmethod
    def none(cls):
        """No errors at all (for checking the geometry end to end)."""
        return cls(**{name: 0.0 for name in cls.__dataclass_fields__})

    def only(self, *names):
        """This model with every error switched off except ``names``."""
        return replace(ErrorModel.none(), **{n: getattr(self, n) for n in names})


@dataclass(frozen=True)
class FlightPlan:
    """The block's geometry.

    Attributes:
        strips: number of parallel strips. altitude: m. speed: m/s (~600 km/h).
        strip_duration: s of imaging per strip. turn_duration: s between strips (180° turn).
        centre_latitude, centre_longitude: degrees, of the first strip's start.
        heading: degrees, of the first strip (the next ones alternate).
        near_angle, far_angle: look angles off nadir, degrees (swath edges). look_side: ``"right"``/``"left"``.
        overlap: fraction of the swath width shared by adjacent strips.
        record_interval: s between navigation records. film_rate: mm of film per second. time_mark_interval: s.
        sweep_delay, range_scale: nominal radar constants c0 (mm) and f0 (m/mm).
        nadir_trace: mm of film beyond the nadir return's line (slant range = flying height) in which no feature
            is read: the return's own trace, about one slant-range resolution cell (10 m at 250 m/mm). The film
            shows nothing inside the line (sources 000, 002: the nadir return is the first echo), so a mark read
            there, or on the trace, is not a measurement an operator makes (:func:`image_points`).
    """

    strips: int = 10
    altitude: float = 10_000.0
    speed: float = 167.0
    strip_duration: float = 15 * 60.0
    turn_duration: float = 3 * 60.0
    centre_latitude: float = 75.0
    centre_longitude: float = -150.0
    heading: float = 90.0
    near_angle: float = 5.0
    far_angle: float = 55.0
    look_side: LookSide = "right"
    overlap: float = 0.2
    record_interval: float = 10.0
    film_rate: float = 0.5
    time_mark_interval: float = 10.0
    sweep_delay: float = 10.0
    range_scale: float = 250.0
    nadir_trace: float = 0.04

    @property
    def near_range(self):
        return self.altitude / np.cos(np.radians(self.near_angle))

    @property
    def far_range(self):
        return self.altitude / np.cos(np.radians(self.far_angle))


def navigation_error(times, errors: ErrorModel, turn_offset, drift_direction=0.6435, schuler_phase=0.0):
    """North/east INS error ``(k, 2)`` (m) and its rate ``(k, 2)`` (m/s) at ``times`` (s after take-off) of one strip.

    A drift of ``errors.drift_rate`` toward ``drift_direction`` (radians from east... north = π/2), a Schuler
    oscillation of ``errors.schuler_amplitude`` (north) and 0.6 of it (east, a quarter period later) starting at
    ``schuler_phase``, and ``turn_offset`` ``(2,)``, the perturbations accumulated in the turns before this strip
    (they happen during the turns, before the strip's records begin).
    """
    times = np.asarray(times, float)
    phase = 2 * np.pi * times / SCHULER_PERIOD + schuler_phase
    unit = np.array([np.sin(drift_direction), np.cos(drift_direction)])  # (north, east)
    error = errors.drift_rate * times[:, None] * unit
    rate = np.tile(errors.drift_rate * unit, (times.size, 1))
    error += errors.schuler_amplitude * np.stack([np.sin(phase), 0.6 * np.cos(phase)], 1)
    rate += errors.schuler_amplitude * 2 * np.pi / SCHULER_PERIOD * np.stack([np.cos(phase), -0.6 * np.sin(phase)],
                                                                              1)
    error += np.asarray(turn_offset, float)
    return error, rate


@dataclass(frozen=True)
class StripTruth:
    """What a simulated strip's records do not say.

    Attributes:
        trajectory: the true flight. sweep_delay, range_scale: the true radar constants (mm, m/mm).
        navigation_error: ``(k, 2)`` m, the systematic north/east error of the recorded positions at the record
            times.
    """

    trajectory: CircularTrajectory
    sweep_delay: float
    range_scale: float
    navigation_error: np.ndarray = field(repr=False)


@dataclass(frozen=True)
class CoverageTruth:
    """What a simulated coverage's records do not say: ``positions`` ``(n, 2)`` true map positions of all features
    at this flight, and the truth of each strip."""

    positions: np.ndarray
    strips: tuple[StripTruth, ...]


def simulate_flight(plan: FlightPlan, errors: ErrorModel, rng: np.random.Generator,
                    take_off_time: float = 0.0) -> tuple[list[StripRecord], list[StripTruth]]:
    """Strips of a block (navigation, altimeter, time marks, radar constants) flown ``take_off_time`` s after
    take-off: what was recorded (:class:`StripRecord`) and, apart, the truth of each strip."""
    swath_near = plan.altitude * np.tan(np.radians(plan.near_angle))
    swath_far = plan.altitude * np.tan(np.radians(plan.far_angle))
    step = (1.0 - plan.overlap) * (swath_far - swath_near)
    start = unit_vector(np.radians(plan.centre_latitude), np.radians(plan.centre_longitude))
    heading = np.radians(plan.heading)
    north0, east0 = _north_east(start)
    forward = np.cos(heading) * north0 + np.sin(heading) * east0
    right = np.cross(forward, np.asarray(start))
    side = float(look_sign(plan.look_side))
    strip_starts = take_off_time + np.arange(plan.strips) * (plan.strip_duration + plan.turn_duration)
    turn_offsets = np.zeros((plan.strips, 2))
    turn_offsets[1:] = np.cumsum(rng.normal(0.0, errors.turn_perturbation, (plan.strips - 1, 2)), axis=0)
    drift_direction, schuler_phase = rng.uniform(0.0, 2 * np.pi, 2)  # each flight's INS errs its own way
    # each strip's recording has its own calibration error, drawn from a child generator so that the other
    # draws (and the simulations built on them) do not depend on whether the calibration errors are switched on
    calibration = rng.spawn(1)[0].normal(0.0, 1.0, (plan.strips, 2))
    true_sweeps = plan.sweep_delay + errors.sweep_delay_error * calibration[:, 0]
    true_scales = plan.range_scale * (1.0 + errors.range_scale_error * calibration[:, 1])
    records, truths = [], []
    for k in range(plan.strips):
        true_sweep, true_scale = true_sweeps[k], true_scales[k]
        direction = 1.0 if k % 2 == 0 else -1.0
        # across track (to the look side of strip 0), swath k spans [near + k step, far + k step]: a strip flown
        # the other way looks back across its line, so its line lies beyond its swath
        line = k * step if direction > 0 else k * step + swath_near + swath_far
        along = 0.0 if direction > 0 else plan.speed * plan.strip_duration
        position = np.asarray(start) + (along * forward + side * line * right) / MEAN_RADIUS
        position /= np.linalg.norm(position)
        # fly parallel to strip 0 in the map: its forward direction, made horizontal here (a heading taken from
        # the start would be off by the meridians' convergence, ~3° over 150 km at 75°N)
        direction_here = direction * (forward - (forward @ position) * position)
        direction_here /= np.linalg.norm(direction_here)
        radius = MEAN_RADIUS + plan.altitude
        truth = CircularTrajectory(jnp.asarray(position), jnp.asarray(direction_here), jnp.asarray(radius),
                                   jnp.asarray(plan.speed / radius), jnp.asarray(strip_starts[k]))
        t = np.arange(strip_starts[k] - 60.0, strip_starts[k] + plan.strip_duration + 60.0 + 1e-9,
                      plan.record_interval)
        true_position, true_velocity = (np.asarray(a) for a in truth(t))
        error, rate = navigation_error(t, errors, turn_offsets[k], drift_direction, schuler_phase)
        noise = rng.normal(0.0, errors.record_noise, (t.size, 2))
        offset = error + noise
        # the error is an offset along the north and east axes *at the recorded position* (a few fixed-point
        # steps, each gaining a factor |offset|/R), so the truth is exactly the record minus the offset there;
        # the recorded velocity is the time derivative of the recorded position without its noise (turning axes
        # included), plus its own white noise
        recorded_position = true_position
        for _ in range(4):
            north, east = _north_east(recorded_position)
            recorded_position = true_position + offset[:, :1] * north + offset[:, 1:] * east
        turning = jax.jvp(north_east, (jnp.asarray(recorded_position),), (jnp.asarray(true_velocity),))[1]
        north_rate, east_rate = (np.asarray(a) for a in turning)
        velocity_noise = rng.normal(0.0, errors.velocity_noise, (t.size, 2))
        recorded_velocity = (true_velocity + (rate[:, :1] + velocity_noise[:, :1]) * north
                             + (rate[:, 1:] + velocity_noise[:, 1:]) * east + error[:, :1] * north_rate
                             + error[:, 1:] * east_rate)
        altitudes = plan.altitude + rng.normal(0.0, errors.altimeter_noise, t.size)
        mark_times = np.arange(strip_starts[k], strip_starts[k] + plan.strip_duration + 1e-9,
                               plan.time_mark_interval)
        jitter = rng.normal(0.0, errors.time_mark_jitter, mark_times.size)
        mark_x = plan.film_rate * (mark_times - strip_starts[k] + jitter)
        # nadir returns: over ice the slant range of the nadir echo is the true flying height
        nadir_x = plan.film_rate * (mark_times - strip_starts[k])
        nadir_y = plan.altitude / true_scale - true_sweep + rng.normal(0.0, errors.image_noise, mark_times.size)
        records.append(StripRecord(
            f"S{k + 1:02d}", strip_starts[k], strip_starts[k] + plan.strip_duration, t, recorded_position,
            recorded_velocity, altitudes, mark_x, mark_times, nadir_x, nadir_y, plan.sweep_delay, plan.range_scale,
            plan.look_side))
        truths.append(StripTruth(truth, true_sweep, true_scale, error))
    return records, truths


def image_points(points, strips, truths, plan: FlightPlan, errors: ErrorModel, rng) -> Measurements:
    """Measure ground ``points`` ``(n, 3)`` on every strip (``truths``: their :class:`StripTruth`) whose swath and
    time span contain them, where the measured mark lies beyond the nadir return's trace (``plan.nadir_trace``).

    The swath's near edge (``plan.near_angle``, 5°: 38 m of slant range beyond the flying height) is a few σ of
    the reading noise (10 m of slant range) from the nadir line: without the trace test a near-edge point's noisy
    mark could fall inside the line (about one block in 200), a measurement no film can give and the block
    adjustment refuses by name. The mark is drawn first, so the random stream is the same whether it is kept."""
    rows = []
    for j, (strip, truth) in enumerate(zip(strips, truths, strict=True)):
        times, ranges = (np.asarray(a) for a in imaging_time_and_range(
            points, truth.trajectory, strip.start_time - 120.0, strip.end_time + 120.0, grid_points=65))
        position, velocity = (np.asarray(a) for a in truth.trajectory(times))
        offset = np.asarray(points) - position
        right = np.cross(velocity, position)
        on_side = np.sign(np.sum(offset * right, axis=1)) == float(look_sign(strip.look_side))
        inside = ((times >= strip.start_time) & (times <= strip.end_time) & (ranges >= plan.near_range)
                  & (ranges <= plan.far_range) & on_side)
        nearest = plan.altitude / truth.range_scale - truth.sweep_delay + plan.nadir_trace  # film y, mm
        for i in np.nonzero(inside)[0]:
            # y is slant range on the film: its measurement noise is constant; the ground-range error it causes
            # grows as 1/sin θ toward near range by the geometry itself. The film moves uniformly; the time marks
            # on it carry their own jitter.
            x = plan.film_rate * (times[i] - strip.start_time) + rng.normal(0.0, errors.image_noise)
            y = ranges[i] / truth.range_scale - truth.sweep_delay + rng.normal(0.0, errors.image_noise)
            if y >= nearest:
                rows.append((i, j, x, y))
    rows = np.array(rows, float).reshape(-1, 4)
    return Measurements(rows[:, 0].astype(int), rows[:, 1].astype(int), rows[:, 2], rows[:, 3])


@dataclass(frozen=True)
class Scenario:
    """A simulated project: coverages of the same features, in one map plane.

    Attributes:
        name: ``"aidjex"`` or ``"prudhoe"``. plane: the tangent-plane map projection. plan, errors: as flown.
        kinds: ``(n,)`` per feature: ``"ice"``, ``"station"`` or ``"land"``. coverages: in time order, as
            recorded. truth: per coverage, what the records do not say.
        floe: ``(n,)`` the floe each feature lies on (``None`` on land). floe_rotation: ``(floes,)`` each floe's
            own rotation between the coverages, radians counter-clockwise in the map.
    """

    name: str
    plane: object
    plan: FlightPlan
    errors: ErrorModel
    kinds: np.ndarray
    coverages: tuple[Coverage, ...]
    truth: tuple[CoverageTruth, ...]
    floe: np.ndarray | None = None
    floe_rotation: np.ndarray | None = None


def _known_position(position, sigma: float, rng) -> tuple[float, float, float]:
    """A control point: ``position`` ``(2,)`` m with an error of σ ``sigma`` m per coordinate, and that σ."""
    x, y = position + rng.normal(0.0, sigma, 2)
    return float(x), float(y), sigma


def _to_ground(plane, xy):
    lat, lon = plane.inverse(xy[:, 0], xy[:, 1])
    return np.asarray(unit_vector(lat, lon)) * MEAN_RADIUS


def _block_plane(plan: FlightPlan):
    """Tangent plane at the middle of the block flown by ``plan`` (flight lines step to the look side)."""
    start = unit_vector(np.radians(plan.centre_latitude), np.radians(plan.centre_longitude))
    north, east = _north_east(start)
    forward = np.cos(np.radians(plan.heading)) * north + np.sin(np.radians(plan.heading)) * east
    right = np.cross(forward, np.asarray(start))
    side = float(look_sign(plan.look_side))
    width = plan.altitude * (np.tan(np.radians(plan.far_angle)) - np.tan(np.radians(plan.near_angle)))
    across = side * ((plan.strips - 1) * (1 - plan.overlap) * width + width) / 2
    middle = np.asarray(start) + (plan.speed * plan.strip_duration / 2 * forward + across * right) / MEAN_RADIUS
    lat, lon = (float(a) for a in latitude_longitude(middle))
    return TangentPlane(lat, lon)


_STATIONS = ((-0.5, -0.4), (0.5, -0.4), (0.0, 0.5), (-0.8, 0.6), (0.8, 0.6))
"""Station positions as fractions of the block's half length (along) and half width (across): the AIDJEX
triangle first."""


def aidjex_scenario(seed: int = 0, plan: FlightPlan | None = None, errors: ErrorModel | None = None,
                    features: int = 600, days: float = 16.0, drift_per_day: float = 1900.0,
                    deformation: float = 0.10, station_sigma: float = 100.0, floe_size: float = 15_000.0,
                    floe_rotation: float = 0.5, floe_shift: float = 50.0, stations: int = 3) -> Scenario:
    """The AIDJEX experiment of source 000: a block of strips over drifting ice, flown twice ``days`` apart.

    Between the flights the ice drifts ``drift_per_day`` m/day westward and deforms by an affine ``deformation``
    (a 10 % stretch and shear about the block centre). The ice is broken into floes about ``floe_size`` m across
    (the Voronoi cells of random floe centres); each floe also turns about its centre by a random angle of σ
    ``floe_rotation`` degrees and shifts by σ ``floe_shift`` m. Manned drifting stations (three, forming a
    triangle, as in AIDJEX; up to five) are control points with satellite-fix accuracy ``station_sigma``; the
    second flight is shifted with the ice so it covers the same features.
    """
    plan = plan or FlightPlan()
    errors = errors or ErrorModel()
    rng = np.random.default_rng(seed)
    plane = _block_plane(plan)
    half_along = plan.speed * plan.strip_duration / 2
    width = plan.altitude * (np.tan(np.radians(plan.far_angle)) - np.tan(np.radians(plan.near_angle)))
    half_across = ((plan.strips - 1) * (1 - plan.overlap) * width + width) / 2
    heading = np.radians(plan.heading)
    along, across = np.array([np.sin(heading), np.cos(heading)]), np.array([np.cos(heading), -np.sin(heading)])
    side = float(look_sign(plan.look_side))
    local = np.stack([rng.uniform(-0.95, 0.95, features) * half_along,
                      rng.uniform(-0.95, 0.95, features) * half_across], 1)
    if not 0 <= stations <= len(_STATIONS):
        raise ValueError(f"stations must be 0 to {len(_STATIONS)}, got {stations}")
    local[:stations] = np.array(_STATIONS[:stations]) * [half_along, half_across]
    first = local[:, :1] * along + side * local[:, 1:] * across
    kinds = np.array(["station"] * stations + ["ice"] * (features - stations))
    shift = np.array([-drift_per_day * days, 0.0])  # westward
    matrix = np.array([[1.0 + deformation, 0.3 * deformation], [0.0, 1.0 - 0.5 * deformation]])
    floe_count = max(1, int(round(4 * half_along * half_across / floe_size**2)))
    centres = np.stack([rng.uniform(-1, 1, floe_count) * half_along, rng.uniform(-1, 1, floe_count) * half_across], 1)
    centres = centres[:, :1] * along + side * centres[:, 1:] * across
    floe = np.argmin(np.linalg.norm(first[:, None, :] - centres[None], axis=2), axis=1)
    turn = rng.normal(0.0, np.radians(floe_rotation), floe_count)
    moved = first @ matrix.T + shift
    moved_centres = centres @ matrix.T + shift
    cos, sin = np.cos(turn)[floe], np.sin(turn)[floe]
    arm = moved - moved_centres[floe]
    second = (moved_centres[floe] + np.stack([cos * arm[:, 0] - sin * arm[:, 1], sin * arm[:, 0] + cos * arm[:, 1]], 1)
              + rng.normal(0.0, floe_shift, (floe_count, 2))[floe])
    start = np.array([float(a) for a in plane.forward(np.radians(plan.centre_latitude),
                                                      np.radians(plan.centre_longitude))])
    coverages, truth = [], []
    for k, (positions, name) in enumerate(((first, "day 0"), (second, f"day {days:g}"))):
        lat, lon = plane.inverse(*(start + (shift if k else 0.0)))  # the second flight follows the ice
        flown = replace(plan, centre_latitude=float(np.degrees(lat)), centre_longitude=float(np.degrees(lon)))
        strips, strip_truth = simulate_flight(flown, errors, rng, take_off_time=3600.0)
        measurements = image_points(_to_ground(plane, positions), strips, strip_truth, flown, errors, rng)
        control = {i: _known_position(positions[i], station_sigma, rng) for i in range(stations)}
        coverages.append(Coverage(name, k * days * 86400.0, tuple(strips), measurements, control))
        truth.append(CoverageTruth(positions, tuple(strip_truth)))
    return Scenario("aidjex", plane, plan, errors, kinds, tuple(coverages), tuple(truth), floe, turn)


PRUDHOE_COAST = (-152.0, 69.0, -146.0, 72.0)
"""The GSHHG box (west, south, east, north degrees) the Prudhoe scenario takes its land from."""
_LAND_DRAWS = 50
"""Rounds of random swath positions drawn for the Prudhoe strip's land points before giving up."""


def prudhoe_scenario(seed: int = 0, errors: ErrorModel | None = None, control_points: int = 20,
                     map_sigma: float = 50.0, hours_after_take_off: float = 5.0) -> Scenario:
    """Prudhoe Bay (source 002): land (no motion) with ~20 map control points of ±50 m, imaged by single strips on
    two days along the meridian 149°15'W, each about 5 h after take-off (large accumulated navigation errors).

    The strip runs north from 69.7°N across the real coast (GSHHG, near Prudhoe Bay ~70.4°N) out over the Beaufort
    Sea; every feature and control point is drawn on GSHHG land inside the swath (the tundra of the North Slope and
    the islands along the coast)."""
    from seaice_jax.io.coastline import coastline

    errors = errors or ErrorModel()
    rng = np.random.default_rng(seed)
    plan = FlightPlan(strips=1, strip_duration=1200.0, centre_latitude=69.7, centre_longitude=-149.25,
                      heading=0.0)
    plane = _block_plane(plan)
    half_along = plan.speed * plan.strip_duration / 2
    width = plan.altitude * (np.tan(np.radians(plan.far_angle)) - np.tan(np.radians(plan.near_angle)))
    count = control_points + 60
    side = float(look_sign(plan.look_side))
    land = coastline(*PRUDHOE_COAST)
    positions = np.zeros((0, 2))
    for _ in range(_LAND_DRAWS):
        local = np.stack([rng.uniform(-0.9, 0.9, 4 * count) * half_along,
                          rng.uniform(-0.45, 0.45, 4 * count) * width], 1)
        candidates = np.stack([side * local[:, 1], local[:, 0]], 1)  # heading north: along = y, across = x
        lat, lon = (np.degrees(np.asarray(a)) for a in plane.inverse(candidates[:, 0], candidates[:, 1]))
        positions = np.concatenate([positions, candidates[land.contains(lat, lon)]])[:count]
        if len(positions) == count:
            break
    else:
        raise SeaiceError(f"the Prudhoe strip's swath holds too little GSHHG land for {count} land points")
    kinds = np.array(["land"] * count)
    coverages, truth = [], []
    for day in range(2):
        strips, strip_truth = simulate_flight(plan, errors, rng, take_off_time=hours_after_take_off * 3600.0)
        measurements = image_points(_to_ground(plane, positions), strips, strip_truth, plan, errors, rng)
        control = {i: _known_position(positions[i], map_sigma, rng) for i in range(control_points)}
        coverages.append(Coverage(f"day {5 * day}", day * 5 * 86400.0, tuple(strips), measurements, control))
        truth.append(CoverageTruth(positions, tuple(strip_truth)))
    return Scenario("prudhoe", plane, plan, errors, kinds, tuple(coverages), tuple(truth))


def render_strip(scene, strip: StripRecord, truth: StripTruth, pixel_size: float = 0.05,
                 radius: float = MEAN_RADIUS):
    """The radar image of ``scene`` (:class:`~seaice_jax.simulate.satellite.IceScene`, at time 0) on ``strip``'s
    film: a :class:`~seaice_jax.imagery.remap.StripRaster` of ``pixel_size`` mm from the first to the last time
    mark and from the nearest to the farthest range of the swath, each pixel the brightness of its ground point on
    the true trajectory with the true radar constants (``truth``; NaN where the range is shorter than the flying
    height)."""
    from seaice_jax.imagery.remap import StripRaster

    c, f = truth.sweep_delay, truth.range_scale
    altitude = float(np.median(strip.record_altitudes))
    y_near, y_far = altitude / f - c, 4.0 * altitude / f - c
    x = np.arange(strip.mark_x[0], strip.mark_x[-1], pixel_size)
    y = np.arange(y_near, y_far, pixel_size)
    xx, yy = np.meshgrid(x, y, indexing="ij")
    ground = image_to_ground(truth.trajectory, jnp.asarray(strip.mark_x), jnp.asarray(strip.mark_times),
                             jnp.asarray(xx), jnp.asarray(yy), c, f, look_sign(strip.look_side), radius)
    lat, lon = latitude_longitude(ground)
    xy = jnp.stack(scene.projection.forward(lat, lon), axis=-1)
    return StripRaster(jnp.asarray(scene.brightness(xy, 0.0)), x[0], y[0], pixel_size)
