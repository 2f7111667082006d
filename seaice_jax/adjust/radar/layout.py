"""Host-side layout of a radar block: the unknowns' names and priors, the observation tables, start values.

Everything here runs once per block, in NumPy (with one jitted geometry evaluation per strip); the arrays it
builds become the residual blocks of :mod:`seaice_jax.adjust.radar.block`.
"""

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from seaice_jax._shapes import bucket, pad
from seaice_jax.adjust.radar.navigation_basis import navigation_basis
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.earth import latitude_longitude, north_east
from seaice_jax.geometry.range_doppler import look_sign
from seaice_jax.sensors.navigation import error_basis_size
from seaice_jax.sensors.slar import imaging_time
from seaice_jax.sensors.strips import image_to_ground, nadir_altitudes, strip_navigation

_COMPONENTS = ("north", "east")
_REFERENCE_SIGMA = 1e-3
"""m: prior σ of the first strip's turn offset (none: the flight's own offset is the error there)."""


@dataclass
class BlockLayout:
    """The host-side layout of a block: unknown names, observation tables, start values."""

    names: list
    prior_sigma: np.ndarray  # σ of each unknown's prior (inf: none)
    prior_previous: np.ndarray  # the unknown whose value the prior is relative to (−1: the prior is on the value)
    start_points: np.ndarray
    point_key: list  # (coverage, point) of each point unknown (coverage −1 for static points)
    strip_slices: list  # (coverage index, strip index, navigation indices, radar indices, flight span or None)
    observations: dict
    nadir: dict
    control: dict
    coverage_of: np.ndarray
    strip_of: np.ndarray
    point_of: np.ndarray
    q: int
    start_theta: np.ndarray  # start values of the global unknowns: 0 but the sweep delays (see _sweep_delay_starts)


@jax.jit
def _strip_geometry(navigation, mark_x, mark_times, x, y, sweep_delay, range_scale, sign, plane, radius):
    """Sensor state, local axes, start map positions and ∂map/∂image at image points ``(n,)`` of one strip."""
    times, time_per_mm = jax.jvp(lambda v: imaging_time(v, mark_x, mark_times), (x,), (jnp.ones_like(x),))
    position, velocity = navigation(times)
    (north, east), (north_rate, east_rate) = jax.jvp(north_east, (position,), (velocity,))

    def to_map(xy):
        g = image_to_ground(navigation, mark_x, mark_times, xy[0], xy[1], sweep_delay, range_scale, sign, radius)
        return jnp.stack(plane.forward(*latitude_longitude(g)))

    image = jnp.stack([x, y], axis=1)
    return (times, time_per_mm, position, velocity, north, east, north_rate, east_rate, jax.vmap(to_map)(image),
            jax.vmap(jax.jacfwd(to_map))(image))



def mark_weight(mark_x, x):
    """``(n,)`` (1 − u)² + u², u the fraction of the way from the time mark before each image x to the next (eq. A1
    interpolates the time between them; beyond the first or last mark the end interval is extended): an error of σ
    in each mark's along-track position moves the point's time as an error of σ·√((1 − u)² + u²) in its x."""
    mark_x, x = np.asarray(mark_x, float), np.asarray(x, float)
    i = np.clip(np.searchsorted(mark_x, x, side="right") - 1, 0, mark_x.size - 2)
    u = (x - mark_x[i]) / (mark_x[i + 1] - mark_x[i])
    return (1.0 - u) ** 2 + u**2


def _strip_observations(strip, x, y, options, plane, radius, flight_span, sweep_delay_start):
    """Per-observation geometry of one strip and the start map positions (with the sweep delay
    ``sweep_delay_start``, mm), with the navigation-error basis (:func:`navigation_basis`)."""
    navigation = strip_navigation(strip, options.filter_window)
    n = len(x)
    size = bucket(n)  # padded, so strips of similar size share one compilation
    geometry = _strip_geometry(navigation, jnp.asarray(strip.mark_x), jnp.asarray(strip.mark_times),
                               jnp.asarray(pad(x, size, x[0])), jnp.asarray(pad(y, size, y[0])),
                               sweep_delay_start, strip.range_scale, look_sign(strip.look_side), plane, radius)
    times, time_per_mm, position, velocity, north, east, north_rate, east_rate, start, jacobian = (
        np.asarray(a)[:n] for a in geometry)
    basis, rates = navigation_basis(options.navigation_model, times, (strip.start_time, strip.end_time), flight_span,
                                    options.knot_spacing)
    # rows without a ground solution (a slant range shorter than the flying height) are refused by layout_block
    usable = np.isfinite(start).all(axis=1) & (np.abs(np.linalg.det(np.nan_to_num(jacobian))) > 0)
    return dict(mark_weight=mark_weight(strip.mark_x, x), basis=basis, rates=rates, position=position,
                velocity=velocity, north=north, east=east,
                north_rate=north_rate, east_rate=east_rate, y=np.asarray(y, float),
                sweep_delay=np.full(n, strip.sweep_delay), range_scale=np.full(n, strip.range_scale),
                sign=np.full(n, float(look_sign(strip.look_side))), time_per_mm=time_per_mm), start, usable


def _sweep_delay_starts(coverages, strip_slices, altitudes, size):
    """Start values ``(size,)`` of the global unknowns: zero, except each sweep-delay correction Δc, which starts at
    the value that fits the nadir returns of its strips with the nominal range scale (eq. A3 in image space:
    Δc = mean(h_n / f0 − y_n − c0)); zero where its strips have no nadir returns. ``altitudes[c][j]``: the
    altimeter heights at strip j's nadir returns (:func:`~seaice_jax.sensors.strips.nadir_altitudes`).

    From the nominal constants a sweep-delay error of a few tenths of a mm puts the near-range edge of every strip
    inside the flying height (no ground point); started here, the block starts where the nadir returns put the
    film's range origin, as the sequential method's nadir calibration does.
    """
    offsets = {}
    for c, j, _, radar, _ in strip_slices:
        strip = coverages[c].strips[j]
        if strip.nadir_y.size:
            offsets.setdefault(radar[0], []).append(altitudes[c][j] / strip.range_scale - strip.nadir_y
                                                    - strip.sweep_delay)
    theta = np.zeros(size)
    for index, values in offsets.items():
        theta[index] = float(np.mean(np.concatenate(values)))
    return theta


def block_unknowns(coverages, options):
    """The global unknowns of a block and their priors, from the coverages' strips alone (``name``, ``strips`` with
    ``name``, ``start_time``, ``end_time``, ``range_scale``).

    Returns:
        ``(names, prior_sigma (n,), prior_previous (n,), strip_slices, q)``: a prior with ``prior_previous`` ≥ 0 is
        on the difference from that unknown (a turn's perturbation: the random walk of the strips' offsets along a
        flight); strip_slices: per strip ``(coverage index, strip index, navigation indices, radar indices, flight
        span or None)``; q: navigation coefficients per component of a strip.
    """
    names, prior, previous = [], [], []
    strip_slices = []
    model = options.navigation_model
    coefficient_names = {"constant": ["offset"], "linear": ["offset", "rate"],
                         "schuler": ["offset", "rate", "Schuler sine", "Schuler cosine"]}
    offset = options.resolved_offset_prior()
    offset_sigma = offset if offset is not None else np.inf
    schuler_prior = None if options.schuler_prior is None else np.broadcast_to(np.asarray(options.schuler_prior,
                                                                                           float), 2)

    def shapes(span) -> dict:
        """Per component, the prior σ of the coefficients after the offset of a curve spanning ``span`` (s, s)
        (the spline's values all take the offset's)."""
        drift = options.drift_prior(span[1] - span[0])
        drift_sigma = drift if drift is not None else np.inf
        schuler = schuler_prior if schuler_prior is not None else np.full(2, drift_sigma)  # north, east
        return {component: {"constant": [], "linear": [drift_sigma],
                            "schuler": [drift_sigma, schuler[k], schuler[k]]}.get(model, [])
                for k, component in enumerate(_COMPONENTS)}

    turn_sigma = options.turn_prior if options.turn_prior is not None else np.inf
    flight = options.navigation_scope == "flight"
    shared_radar = None
    q = None
    for c, coverage in enumerate(coverages):
        flown = (min(s.start_time for s in coverage.strips), max(s.end_time for s in coverage.strips))
        if options.take_off_time is not None and options.take_off_time > flown[0]:
            raise SeaiceError(f"coverage {coverage.name!r}: take_off_time {options.take_off_time} s is after its "
                              f"first strip starts ({flown[0]} s)")
        first_start = flown[0]
        if flight and options.take_off_time is not None:
            flown = (options.take_off_time, flown[1])
        shared = {}  # flight scope: the coefficients after the offset, one set per coverage and component
        last_turn = {}  # flight scope: the previous strip's turn offset, per component
        for j, strip in enumerate(coverage.strips):
            span = flown if flight else (strip.start_time, strip.end_time)
            size = error_basis_size(model, *span, options.knot_spacing) + 2 * flight
            if q is not None and size != q:
                raise SeaiceError(f"coverage {coverage.name!r} strip {strip.name}: the {model} model has {size} "
                                  f"coefficients here but {q} on the first strip; give all strips the same duration "
                                  "or choose a knot spacing that divides them equally")
            q = size
            label = f"{coverage.name}/{strip.name}"
            terms = coefficient_names.get(model, [f"spline[{k}]" for k in range(q)])
            navigation = []
            if not flight:  # the strip's own offset: the error accumulated by its middle, j turns after the first
                accumulated = options.accumulated_offset_prior(0.5 * (strip.start_time + strip.end_time), j,
                                                               first_start)
                offset_sigma = accumulated if accumulated is not None else np.inf
            for component in _COMPONENTS:
                if not flight:
                    navigation += range(len(names), len(names) + q)
                    names += [f"{label} navigation {component} {term}" for term in terms]
                    prior += [offset_sigma] * q if model == "spline" else [offset_sigma] + shapes(span)[component]
                    previous += [-1] * q
                    continue
                if component not in shared:
                    shared[component] = list(range(len(names), len(names) + q - 2))
                    names += [f"{coverage.name} navigation {component} {term}" for term in terms]
                    prior += [offset_sigma] + shapes(span)[component]
                    previous += [-1] * (q - 2)
                navigation += [len(names), *shared[component], len(names) + 1]
                # the turns' perturbations add up along the flight (a random walk): each turn's perturbation, the
                # difference of consecutive strips' offsets, has the prior; the first strip is the flight's reference
                previous += [last_turn.get(component, -1), -1]
                last_turn[component] = len(names)
                names += [f"{label} navigation {component} turn offset", f"{label} navigation {component} deviation"]
                prior += [turn_sigma if j else _REFERENCE_SIGMA,
                          options.deviation_prior if options.deviation_prior is not None else np.inf]
            if options.radar_constants == "strip" or shared_radar is None:
                radar_label = label if options.radar_constants == "strip" else "block"
                radar = [len(names), len(names) + 1]
                names += [f"{radar_label} sweep delay", f"{radar_label} range scale"]
                previous += [-1, -1]
                prior += [options.sweep_delay_prior if options.sweep_delay_prior is not None else np.inf,
                          options.range_scale_prior * strip.range_scale if options.range_scale_prior is not None
                          else np.inf]
                shared_radar = radar
            strip_slices.append((c, j, np.array(navigation), shared_radar, flown if flight else None))
    return names, np.array(prior, float), np.array(previous, int), strip_slices, q or 0


def layout_block(coverages, n_points, plane, options, radius, point_ids=None) -> BlockLayout:
    """Unknowns, observation tables and start values of a block."""
    names, prior, previous, strip_slices, q = block_unknowns(coverages, options)
    altitudes = [[nadir_altitudes(strip) for strip in coverage.strips] for coverage in coverages]
    start_theta = _sweep_delay_starts(coverages, strip_slices, altitudes, len(names))
    point_unknown, starts = {}, []
    tables = {k: [] for k in ("index", "point", "mark_weight", "basis", "rates", "position", "velocity", "north",
                              "east", "north_rate", "east_rate", "y",
                              "sweep_delay", "range_scale", "sign", "time_per_mm")}
    coverage_of, strip_of, point_of = [], [], []
    unsolved = set()  # (coverage, point, strip) of measurements without a ground solution at the start
    nadir = {k: [] for k in ("index", "y", "sweep_delay", "range_scale", "altitude", "coverage", "strip")}
    slices = iter(strip_slices)
    for c, coverage in enumerate(coverages):
        m = coverage.measurements
        for j, strip in enumerate(coverage.strips):
            _, _, navigation, radar, flight_span = next(slices)
            rows = np.nonzero(m.strip == j)[0]
            if strip.nadir_y.size:
                nadir["index"].append(np.tile(radar, (strip.nadir_y.size, 1)))
                nadir["y"].append(strip.nadir_y)
                nadir["sweep_delay"].append(np.full(strip.nadir_y.size, strip.sweep_delay))
                nadir["range_scale"].append(np.full(strip.nadir_y.size, strip.range_scale))
                nadir["altitude"].append(altitudes[c][j])
                nadir["coverage"].append(np.full(strip.nadir_y.size, c))
                nadir["strip"].append(np.full(strip.nadir_y.size, j))
            if rows.size == 0:
                continue
            table, start, valid = _strip_observations(strip, m.x[rows], m.y[rows], options, plane, radius,
                                                      flight_span, strip.sweep_delay + start_theta[radar[0]])
            unsolved.update((c, int(p), strip.name) for p in m.point[rows[~valid]])
            for key in table:
                tables[key].append(table[key][valid])
            tables["index"].append(np.tile(np.concatenate([navigation, radar]), (int(valid.sum()), 1)))
            ids = m.point[rows[valid]].astype(int).tolist()
            owner = -1 if options.static_points else c
            for p in dict.fromkeys(ids):  # new points numbered in order of first measurement
                point_unknown.setdefault((owner, p), len(point_unknown))
            units = np.array([point_unknown[(owner, p)] for p in ids], int)
            tables["point"].append(units)
            starts.append(start[valid])
            coverage_of.append(np.full(units.size, c))
            strip_of.append(np.full(units.size, j))
            point_of.append(np.array(ids, int))
    if unsolved:
        c, p, strip_name = min(unsolved)
        name = p if point_ids is None else point_ids[p]
        role = "control point" if p in coverages[c].control else "point"
        more = f" (and {len(unsolved) - 1} more such measurements)" if len(unsolved) > 1 else ""
        raise SeaiceError(f"coverage {coverages[c].name!r}: {role} {name} is measured (strip {strip_name}) but has no "
                          "ground solution with the start radar constants (nominal, sweep delay fitted to the nadir "
                          "returns) and the navigation: its slant range is shorter than the flying height, off the "
                          f"film's ground range{more}; correct or remove its measurement")
    if not point_unknown:
        raise SeaiceError("no image measurement gives a ground point: nothing to adjust")
    point_key = list(point_unknown)
    observations = {k: np.concatenate(v) for k, v in tables.items()}
    observations["point"] = observations["point"].astype(int)
    # each point starts at the mean of its measurements' ground points
    sums = np.zeros((len(point_key), 2))
    np.add.at(sums, observations["point"], np.concatenate(starts))
    counts = np.bincount(observations["point"], minlength=len(point_key))
    nadir = {k: np.concatenate(v) if v else np.zeros((0, 2) if k == "index" else 0) for k, v in nadir.items()}
    control = {"point": [], "xy": [], "sigma": []}
    for c, coverage in enumerate(coverages):
        for p, (x, y, sigma) in coverage.control.items():
            key = (-1 if options.static_points else c, int(p))
            if key in point_unknown:
                control["point"].append(point_unknown[key])
                control["xy"].append((x, y))
                control["sigma"].append(sigma)
    control = {"point": np.array(control["point"], int), "xy": np.array(control["xy"], float).reshape(-1, 2),
               "sigma": np.array(control["sigma"], float)}
    return BlockLayout(names, prior, previous, sums / counts[:, None], point_key, strip_slices, observations, nadir,
                       control, np.concatenate(coverage_of), np.concatenate(strip_of), np.concatenate(point_of), q,
                       start_theta)


