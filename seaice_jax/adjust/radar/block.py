"""Simultaneous block adjustment of radar strips: the radar block *model* on the adjustment engine.

Source 000 (section 2) says "a rigorous method would solve for all unknowns simultaneously, thereby minimizing the
weighted square sum of all observation errors"; its sequential method (:mod:`seaice_jax.adjust.radar.sequential`)
approximates that. Here it is done rigorously, by :mod:`seaice_jax.adjust.engine`.

Unknowns (global, :mod:`.block_layout`):
  * the coefficients of a navigation-error model (north and east; constant, linear, Schuler or cubic B-spline,
    :func:`~seaice_jax.adjust.radar.navigation_basis.navigation_basis`), all in metres, either per strip
    (``scope="strip"``) or, as an inertial platform behaves, one continuous error per flight (``scope="flight"``:
    the drift and the Schuler oscillation are shared by all strips of a coverage, with the flight's offset at its
    start; each later strip has its own offset with the prior of the turn perturbations accumulated before it, and
    a small linear deviation with a tight prior, taking up what the filtered record noise leaves; sources 000, 002);
  * per strip (or one pair for the whole block) the corrections Δc (mm) and Δf (m/mm) to the nominal sweep delay
    and range scale.
Points (eliminated by the Schur backend): the map coordinates (x, y) of every tie, drift and control point, one
pair per coverage (ice moves between coverages) or, for land, one pair for all coverages.

Observation groups (residual blocks), every one w-tested:
  * ``"image"``: image measurements (x, y) of points, through eqs A1, A2 and A5: the time from the time marks, the
    slant range r = (y + c0 + Δc)(f0 + Δf), the sensor state from the filtered navigation minus the modelled error,
    the ground point by the range-Doppler intersection, projected into the map;
  * ``"control"``: control-point coordinates with their σ; ``"nadir"``: nadir returns against the altimeter
    (r_n = h_n, eq. A3); ``"prior"``: priors on the navigation-error coefficients and radar constants.

Where the residuals live: the forward model A5 maps an image measurement to the ground in closed form, so the
difference is formed in the map (adjusted point minus rectified position) and carried back to the image by
J⁻¹, J = ∂(map x, y)/∂(image x, y) at the current estimate (re-evaluated every iteration but not differentiated,
as in the Gauss-Helmert model: the incidence angle, hence the ground-range error of a slant-range error, changes
as the navigation is corrected by kilometres). To first order this is exactly the image-space adjustment, and the
residuals *are* image residuals, computed − observed, in film mm (component 0 along track, 1 in slant range),
so the w-tests name the image coordinate at fault. The inverse (ground -> image) would need an iterative
zero-Doppler search in every residual.

Small blocks go to the engine's dense backend, large ones to the Schur-complement backend; array sizes are padded
to buckets, so blocks of similar size share one compilation.
"""

import functools
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from seaice_jax._shapes import bucket, pad
from seaice_jax._small_linalg import inverse_2x2
from seaice_jax.adjust import engine
from seaice_jax.adjust.engine.datum import check_datum
from seaice_jax.adjust.engine.problem import Problem, ResidualBlock
from seaice_jax.adjust.engine.schur import schur_layout
from seaice_jax.adjust.engine.variance import robust_adjustment, variance_components
from seaice_jax.adjust.radar.layout import BlockLayout, layout_block
from seaice_jax.adjust.radar.navigation_basis import navigation_basis
from seaice_jax.adjust.radar.options import DENSE_LIMIT, SOLVERS, BlockOptions
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.earth import MEAN_RADIUS, latitude_longitude
from seaice_jax.geometry.range_doppler import ground_point

__all__ = ["SOLVERS", "Blunder", "BlockOptions", "BlockResult", "StripEstimate", "navigation_basis",
           "simultaneous_block"]

@dataclass(frozen=True)
class StripEstimate:
    """The adjusted constants of one strip and its navigation-error curve.

    Attributes:
        coverage, name: of the strip. start_time, end_time: s. model, knot_spacing: the error model;
            flight_start, flight_end: s, the flight's time span when the curve is shared by the strips of a flight
            (``None``: the strip's own curve).
        coefficients: ``(q, 2)`` north and east coefficients (m) of :func:`navigation_basis`. covariance:
            ``(2q, 2q)`` their cofactor (north block first; a priori σ).
        sweep_delay, range_scale: c0 + Δc (mm), f0 + Δf (m/mm); sigma_sweep_delay, sigma_range_scale: their σ.
    """

    coverage: str
    name: str
    start_time: float
    end_time: float
    model: str
    knot_spacing: float
    coefficients: np.ndarray
    covariance: np.ndarray
    sweep_delay: float
    sigma_sweep_delay: float
    range_scale: float
    sigma_range_scale: float
    flight_start: float | None = None
    flight_end: float | None = None

    def navigation_error(self, times):
        """North/east navigation error ``(n, 2)`` m at ``times`` and its σ ``(n, 2)`` (the curve and its band)."""
        flight = None if self.flight_start is None else (self.flight_start, self.flight_end)
        basis = navigation_basis(self.model, times, (self.start_time, self.end_time), flight, self.knot_spacing)[0]
        q = basis.shape[1]
        sigma = [np.sqrt(np.einsum("nq,qr,nr->n", basis, self.covariance[k * q:(k + 1) * q, k * q:(k + 1) * q],
                                   basis)) for k in range(2)]
        return basis @ self.coefficients, np.stack(sigma, axis=1)


@dataclass(frozen=True)
class Blunder:
    """An observation whose w-test fails.

    Attributes:
        point, coverage, strip: where (−1 where it does not apply: a control point has no strip, a nadir return
            no point, a prior neither).
        component: ``"x"``/``"y"`` (image: along track/slant range; control: map x/y), ``""`` for nadir and priors.
        w: Baarda's w. estimated_error: −v/r, the error of the observation (observed − true): mm on the film for
            image and nadir observations, metres for control points, the unknown's unit for priors.
        group: ``"image"``, ``"control"``, ``"nadir"`` or ``"prior"``. description: the observation in words.
        separable: False when the data cannot tell this error from one in ``confounded_with`` (their w are
            correlated beyond 0.98, e.g. a point measured on two strips only).
    """

    point: int
    coverage: int
    strip: int
    component: str
    w: float
    estimated_error: float
    group: str = "image"
    description: str = ""
    separable: bool = True
    confounded_with: str = ""


@dataclass(frozen=True)
class BlockResult:
    """A simultaneous block adjustment.

    Attributes:
        solver: ``"dense"`` or ``"schur"``. options: as used.
        positions: per coverage ``(points, 2)`` adjusted map positions (NaN where not measured).
        covariances: per coverage ``(points, 2, 2)`` their covariance (a priori σ; NaN where not measured).
        drift, drift_covariance: per pair of consecutive coverages ``(points, 2)`` displacement (later minus
            earlier) and ``(points, 2, 2)`` covariance (NaN unless measured in both); empty for static points.
        strips: per strip, in coverage order: :class:`StripEstimate`.
        sigma0: a posteriori σ̂0 (1 when the a priori σ are right). degrees_of_freedom: redundancy.
        iterations, converged: of Gauss-Newton.
        coverage_of, strip_of, point_of: ``(m,)`` per image observation; ground: ``(m, 2)`` its rectified map
            position with the adjusted constants; residuals: ``(m, 2)`` image residuals (mm, computed −
            observed, x and y); redundancy, w: ``(m, 2)``.
        blunders: observations of every group failing the w-test (|w| > critical value at ``options.alpha``),
            worst first.
        parameter_names: the unknowns other than the points (navigation-error coefficients, radar constants).
        adjustment: the engine's result (per group: residuals, redundancy, w, MDB, estimated errors; variance
            components or robust weights when asked for).
    """

    solver: str
    options: BlockOptions
    positions: tuple[np.ndarray, ...]
    covariances: tuple[np.ndarray, ...]
    drift: tuple[np.ndarray, ...]
    drift_covariance: tuple[np.ndarray, ...]
    strips: tuple[StripEstimate, ...]
    sigma0: float
    degrees_of_freedom: int
    iterations: int
    converged: bool
    coverage_of: np.ndarray = field(repr=False)
    strip_of: np.ndarray = field(repr=False)
    point_of: np.ndarray = field(repr=False)
    ground: np.ndarray = field(repr=False)
    residuals: np.ndarray = field(repr=False)
    redundancy: np.ndarray = field(repr=False)
    w: np.ndarray = field(repr=False)
    blunders: tuple[Blunder, ...] = ()
    parameter_names: tuple[str, ...] = ()
    adjustment: engine.Adjustment | None = field(default=None, repr=False)

    def tie_discrepancies(self, coverage: int):
        """``(k, 2)`` map differences (m) between the adjusted ground positions of each point measured on two
        strips of ``coverage`` (later strip minus earlier), as the sequential method's eq. B1."""
        rows = np.nonzero(self.coverage_of == coverage)[0]
        found = {}
        out = []
        for o in rows[np.lexsort((self.strip_of[rows], self.point_of[rows]))]:
            p = self.point_of[o]
            if p in found:
                out.append(self.ground[o] - self.ground[found[p]])
            found[p] = o
        return np.array(out).reshape(-1, 2)


def _rectified(theta, row, radius, shift):
    """Map position ``(2,)`` of one image observation by A1, A2, A5 with the corrected navigation and radar
    constants; ``theta``: the row's unknowns (navigation coefficients north and east, Δc, Δf); ``shift`` =
    (Δt s, Δy mm) moves the observation along track and in range (for ∂map/∂image)."""
    q = row["basis"].shape[0]
    basis, rates = row["basis"], row["rates"]
    error_n, error_e = basis @ theta[:q], basis @ theta[q:2 * q]
    rate_n, rate_e = rates @ theta[:q], rates @ theta[q:2 * q]
    # the corrected velocity is the time derivative of the corrected position (the local axes turn along the track)
    velocity = (row["velocity"] - rate_n * row["north"] - rate_e * row["east"] - error_n * row["north_rate"]
                - error_e * row["east_rate"])
    position = row["position"] - error_n * row["north"] - error_e * row["east"] + shift[0] * velocity
    slant = (row["y"] + shift[1] + row["sweep_delay"] + theta[2 * q]) * (row["range_scale"] + theta[2 * q + 1])
    ground = ground_point(position, velocity, slant, radius, row["sign"], on_failure="nan")
    return jnp.stack(row["plane"].forward(*latitude_longitude(ground)))


@functools.lru_cache(maxsize=8)
def _image_function(radius: float):
    """The image block's residual (one function object per Earth radius, so the engine's compile is reused)."""

    def residual(theta, point, row):
        """J⁻¹ (point − rectified): the point's image position minus the measured one, film mm ``(2,)``."""
        def shifted(shift):
            value = _rectified(theta, row, radius, shift)
            return value, value

        # one pass gives the map position and ∂map/∂(Δt, Δy)
        jacobian, rectified = jax.jacfwd(shifted, has_aux=True)(jnp.zeros(2))
        jacobian = jacobian * jnp.stack([row["time_per_mm"], jnp.ones(())])[None, :]
        to_image = jax.lax.stop_gradient(inverse_2x2(jacobian))
        return to_image @ (point - rectified)

    return residual


def _nadir_residual(theta, _, row):
    """Nadir return (eq. A3: r_n = (y_n + c) f = h_n) in image space: y_n + c − h_n / f, mm ``(1,)``.

    In image space because y_n is the measured quantity: written as (y_n + c) f − h_n, the fit could shrink the
    scatter of the noisy y_n by shrinking f, a regression-dilution bias of the range scale (several per cent in
    level flight, where y_n hardly varies).
    """
    return jnp.atleast_1d(row["y"] + row["sweep_delay"] + theta[0] - row["altitude"] / (row["range_scale"] + theta[1]))


def _control_residual(_, point, row):
    """Adjusted minus known map position of a control point, m ``(2,)``."""
    return point - row["xy"]


def _prior_residual(theta, _, row):
    """A correction minus its prior value 0 ``(1,)``, or (``row["relative"]`` 1) its difference from another
    unknown: ``theta`` = (the unknown, the other one; the unknown twice for a plain prior). A turn's perturbation is
    the difference of consecutive strips' offsets (a random walk along the flight)."""
    return jnp.atleast_1d(theta[0] - row["relative"] * theta[1])


def image_sigmas(options: BlockOptions, mark_weight) -> np.ndarray:
    """``(m, 2)`` σ (mm) of the image observations along track and in slant range: the reading σ
    (``options.image_sigma``) and, along track, the time marks' σ carried through eq. A1's interpolation
    (``mark_weight`` = (1 − u)² + u² per observation)."""
    reading = np.asarray(options.image_sigma, float)
    marks = options.time_mark_sigma or 0.0
    along = np.sqrt(reading[0] ** 2 + marks**2 * np.asarray(mark_weight, float))
    return np.stack([along, np.full(along.shape, reading[1])], axis=1)


@functools.partial(jax.jit, static_argnames="radius")
def _all_rectified(theta, block: ResidualBlock, radius: float):
    """``(m, 2)`` map positions of all image observations with the unknowns ``theta``."""
    return jax.vmap(lambda t, row: _rectified(t, row, radius, jnp.zeros(2)))(theta[block.global_index], block.data)


_IMAGE_FIELDS = ("basis", "rates", "position", "velocity", "north", "east", "north_rate", "east_rate", "y",
                 "sweep_delay", "range_scale", "sign", "time_per_mm")


_FEW_ROWS = 8
"""Rows of the control block at least. The control and prior blocks are always there, padded (rows with σ = inf):
the control points to ``max(bucket(n), _FEW_ROWS)``, the priors to the bucket of the number of global unknowns (at
most one prior each), so blocks with 0 to 8 control points, and options switching priors on and off, share one
compiled solve and datum check; these few rows of padding cost little even in the dense backend."""


def _few(n: int) -> int:
    return max(bucket(n), _FEW_ROWS)


def block_problem(layout: BlockLayout, options: BlockOptions, plane, radius: float, padded: bool) -> Problem:
    """The engine's problem of a block (image and nadir sizes padded to buckets when ``padded``, the control and
    prior blocks always, see :data:`_FEW_ROWS`: rows with σ = inf)."""
    obs, nadir, control = layout.observations, layout.nadir, layout.control
    m, n_points = obs["point"].size, len(layout.point_key)
    size = (lambda n: bucket(n)) if padded else (lambda n: n)
    rows, points = size(m), size(n_points)
    image = {k: jnp.asarray(pad(obs[k], rows, obs[k][0])) for k in _IMAGE_FIELDS}
    image["plane"] = jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (rows,) + jnp.shape(a)), plane)
    sigma = pad(image_sigmas(options, obs["mark_weight"]), rows, np.inf)
    blocks = {"image": ResidualBlock(_image_function(float(radius)), image, jnp.asarray(sigma),
                                     jnp.asarray(pad(obs["index"], rows, obs["index"][0])),
                                     jnp.asarray(pad(obs["point"], rows, points - 1)))}
    if nadir["y"].size:
        count = size(nadir["y"].size)
        nadir_sigma = np.hypot(options.image_sigma[1], options.altimeter_sigma / nadir["range_scale"])
        blocks["nadir"] = ResidualBlock(
            _nadir_residual, {k: jnp.asarray(pad(nadir[k], count, nadir[k][0])) for k in
                              ("y", "sweep_delay", "range_scale", "altitude")},
            jnp.asarray(pad(nadir_sigma[:, None], count, np.inf)), jnp.asarray(pad(nadir["index"], count, 0)))
    count = _few(control["point"].size)
    blocks["control"] = ResidualBlock(
        _control_residual, {"xy": jnp.asarray(pad(control["xy"], count, 0.0))},
        jnp.asarray(pad(np.repeat(control["sigma"][:, None], 2, axis=1), count, np.inf)),
        jnp.zeros((count, 0), int), jnp.asarray(pad(control["point"], count, points - 1)))
    priors = np.nonzero(np.isfinite(layout.prior_sigma))[0]
    count = _few(len(layout.names))
    previous = layout.prior_previous[priors]
    relative = previous >= 0
    index = np.stack([priors, np.where(relative, previous, priors)], axis=1)
    blocks["prior"] = ResidualBlock(_prior_residual, {"relative": jnp.asarray(pad(relative * 1.0, count, 0.0))},
                                    jnp.asarray(pad(layout.prior_sigma[priors][:, None], count, np.inf)),
                                    jnp.asarray(pad(index, count, 0)))
    start = pad(layout.start_points, points, 0.0)
    return Problem(blocks, jnp.asarray(layout.start_theta), jnp.asarray(start))


def _drift_points(layout: BlockLayout, coverages, n_points, static):
    """Per pair of consecutive coverages: the ids measured in both and their point indices (earlier, later)."""
    lookup = {key: u for u, key in enumerate(layout.point_key)}
    pairs = []
    for c in range(1, 0 if static else len(coverages)):
        both = [(p, lookup[(c - 1, p)], lookup[(c, p)]) for p in range(n_points)
                if (c - 1, p) in lookup and (c, p) in lookup]
        pairs.append(np.array(both, int).reshape(-1, 3))
    return pairs


def simultaneous_block(coverages, plane, n_points: int, options: BlockOptions | None = None,
                       radius: float = MEAN_RADIUS, point_ids=None) -> BlockResult:
    """Adjust a radar block (one or several coverages) with every unknown in one solve.

    Args:
        coverages: objects with ``name``, ``strips`` (:class:`~seaice_jax.sensors.strips.StripRecord`),
            ``measurements`` (:class:`~seaice_jax.sensors.strips.Measurements`) and ``control``
            (``{point: (x, y, σ)}`` map metres), e.g. a project's or a simulation's coverages.
        plane: the map projection (``forward(lat, lon) -> (x, y)``), e.g. the project's tangent plane.
        n_points: number of point ids (the size of the per-coverage position arrays).
        options: see :class:`BlockOptions`.
        point_ids: the points' names (a project's ids) for messages; default their indices.

    Raises:
        RankDeficiencyError: a datum defect (e.g. no control and no navigation priors), naming the unknowns.
    """
    options = options or BlockOptions()
    layout = layout_block(coverages, n_points, plane, options, radius, point_ids)
    n_real = len(layout.point_key)
    total = len(layout.names) + 2 * n_real
    solver = options.solver if options.solver != "auto" else ("dense" if total <= DENSE_LIMIT else "schur")
    # the datum check on the padded problem whatever the solver: one compile per bucket of sizes
    padded = block_problem(layout, options, plane, radius, padded=True)
    problem = padded if solver == "schur" else block_problem(layout, options, plane, radius, padded=False)
    drift_points = _drift_points(layout, coverages, n_points, options.static_points)
    cross = np.concatenate([d[:, 1:] for d in drift_points]) if drift_points else np.zeros((0, 2), int)
    tables = schur_layout(padded, cross)
    coverage = np.array([key[0] for key in layout.point_key])
    check_datum(padded, tables, layout.names, coverage, layout.start_points)
    # the image whitening follows the estimate: square sums before and after a step differ in weights, so every
    # Gauss-Newton step is taken (as the block adjustment always did)
    settings = engine.EngineOptions(solver, options.max_iterations, 0.0, options.tolerance, options.tolerance,
                                    monotone=False)
    solve_options = {"cross_points": cross, "layout": tables if solver == "schur" else None}
    names = tuple(layout.names)
    # the control block is there (all padding) when there is no control point: no factor for it then
    groups = ("image", "nadir", "control") if layout.control["point"].size else ("image", "nadir")
    if options.variance_components:
        result = variance_components(problem, settings, names, groups=groups, split_components=("image", "control"),
                                     **solve_options)
    elif options.robust is not None:
        result = robust_adjustment(problem, options.robust, settings, names, groups=groups, **solve_options)
    else:
        result = engine.solve(problem, settings, names, throw=False, **solve_options)
    if solver == "schur" and not np.all(np.isfinite(np.asarray(result.cofactor))):
        raise SeaiceError("the Schur-complement solve broke down (the reduced normal matrix is not numerically "
                          "positive definite: the block is held only weakly, e.g. no control and no navigation "
                          "priors); add control points or priors, or use solver='dense'")
    return _result(layout, problem, options, solver, coverages, n_points, result, drift_points, point_ids, radius)


def _describe(layout: BlockLayout, coverages, point_ids, flag: engine.Flag):
    """``(point, coverage, strip, component, description)`` of a flagged observation."""
    def point_name(p):
        return str(p if point_ids is None else point_ids[p])

    if flag.group == "image":
        o = flag.row
        c, j, p = int(layout.coverage_of[o]), int(layout.strip_of[o]), int(layout.point_of[o])
        component = "xy"[flag.component]
        return p, c, j, component, (f"image {component} of point {point_name(p)} on {coverages[c].name}/"
                                    f"{coverages[c].strips[j].name}")
    if flag.group == "control":
        c, p = layout.point_key[int(layout.control["point"][flag.row])]
        component = "xy"[flag.component]
        where = "all coverages" if c < 0 else coverages[c].name
        return p, c, -1, component, f"control {component} of point {point_name(p)} ({where})"
    if flag.group == "nadir":
        c, j = int(layout.nadir["coverage"][flag.row]), int(layout.nadir["strip"][flag.row])
        return -1, c, j, "", f"nadir return {flag.row} of {coverages[c].name}/{coverages[c].strips[j].name}"
    index = int(np.nonzero(np.isfinite(layout.prior_sigma))[0][flag.row])
    previous = int(layout.prior_previous[index])
    if previous >= 0:  # a turn's perturbation: this strip's offset minus the previous strip's
        strip = layout.names[previous].split(" navigation ")[0].rsplit("/", 1)[-1]
        return -1, -1, -1, "", f"prior of {layout.names[index]} minus {strip}'s (the turn before it)"
    return -1, -1, -1, "", f"prior of {layout.names[index]}"


def _blunders(layout, coverages, point_ids, adjustment, alpha):
    out = []
    for flag in adjustment.flagged(alpha):
        point, coverage, strip, component, description = _describe(layout, coverages, point_ids, flag)
        other = ""
        if flag.confounded_with is not None:
            group, row, which = flag.confounded_with
            other = _describe(layout, coverages, point_ids, engine.Flag(group, row, which, 0.0, 0.0, 0.0, True,
                                                                        None))[4]
        out.append(Blunder(point, coverage, strip, component, flag.w, flag.estimated_error, flag.group, description,
                           flag.separable, other))
    return tuple(out)


def _result(layout: BlockLayout, problem: Problem, options, solver, coverages, n_points, adjustment, drift_points,
            point_ids, radius) -> BlockResult:
    n_real = len(layout.point_key)
    m = layout.observations["point"].size
    unknowns = np.asarray(adjustment.parameters["theta"])
    points = np.asarray(adjustment.parameters["points"])[:n_real]
    cofactor = np.asarray(adjustment.cofactor)
    point_cofactor = np.asarray(adjustment.point_cofactor)[:n_real]
    residuals = np.asarray(adjustment.residuals["image"])[:m]
    redundancy = np.asarray(adjustment.redundancy["image"])[:m]
    w = np.asarray(adjustment.standardized_residuals["image"])[:m]
    ground = np.asarray(_all_rectified(jnp.asarray(unknowns), problem.blocks["image"], float(radius)))[:m]
    positions, covariances = [], []
    key = np.array(layout.point_key, int).reshape(-1, 2)  # (coverage, point) of each point unknown
    for c in range(len(coverages)):
        where = np.full((n_points, 2), np.nan)
        cov = np.full((n_points, 2, 2), np.nan)
        mine = np.nonzero(key[:, 0] == (-1 if options.static_points else c))[0]
        where[key[mine, 1]], cov[key[mine, 1]] = points[mine], point_cofactor[mine]
        positions.append(where)
        covariances.append(cov)
    drift, drift_cov = [], []
    cross = np.asarray(adjustment.point_pair_cofactor)
    start = 0
    for both in drift_points:
        displacement = np.full((n_points, 2), np.nan)
        covariance = np.full((n_points, 2, 2), np.nan)
        if both.size:
            ids, a, b = both.T
            block = cross[start:start + ids.size]
            displacement[ids] = points[b] - points[a]
            covariance[ids] = point_cofactor[a] + point_cofactor[b] - block - np.swapaxes(block, 1, 2)
        start += both.shape[0]
        drift.append(displacement)
        drift_cov.append(covariance)
    strips = []
    q = layout.q
    for (c, j, navigation, radar, flight_span) in layout.strip_slices:
        strip = coverages[c].strips[j]
        strips.append(StripEstimate(
            coverages[c].name, strip.name, strip.start_time, strip.end_time, options.navigation_model,
            options.knot_spacing, unknowns[navigation].reshape(2, q).T, cofactor[np.ix_(navigation, navigation)],
            strip.sweep_delay + unknowns[radar[0]], float(np.sqrt(cofactor[radar[0], radar[0]])),
            strip.range_scale + unknowns[radar[1]], float(np.sqrt(cofactor[radar[1], radar[1]])),
            *(flight_span or (None, None))))
    return BlockResult(solver, options, tuple(positions), tuple(covariances), tuple(drift), tuple(drift_cov),
                       tuple(strips), float(adjustment.sigma0), adjustment.degrees_of_freedom,
                       int(adjustment.steps), bool(adjustment.converged), layout.coverage_of, layout.strip_of,
                       layout.point_of, ground, residuals, redundancy, w,
                       _blunders(layout, coverages, point_ids, adjustment, options.alpha), tuple(layout.names),
                       adjustment)
