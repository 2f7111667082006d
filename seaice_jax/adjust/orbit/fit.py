"""Orbit and scan parameters of a satellite image from ground control points (source 001, VHR2 module).

Two methods:

* ``"gauss-newton"`` (default): the five unknowns of :class:`~seaice_jax.geometry.scan.ScanModel` estimated by
  the weighted least-squares engine (:mod:`..engine.lsq`), minimising the squared ground distances at the
  control points (in latitude and longitude, each weighted by the point's σ in metres), with covariance and quality
  control. No starting values are needed: :func:`initial_guess` scans the ascending node and, for each node, fits
  the orbital and scanner angles of the control points by linear least squares.
* ``"appendix_c"``: the 1985 search of source 001 Appendix C, kept as the baseline (see :mod:`.appendix_c`).

``direction="auto"`` fits the southbound (descending) and the northbound (ascending) pass and keeps the better,
as the 1985 operators did by hand ("order of magnitude differences in the control point errors").
"""

import dataclasses
from dataclasses import dataclass, field
from functools import cached_property

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from seaice_jax._shapes import pad, padded_to_bucket
from seaice_jax.adjust.engine.lsq import Adjustment, Observations, Solver, least_squares, make_solver
from seaice_jax.adjust.engine.quality import DEFAULT_ALPHA, global_test
from seaice_jax.adjust.orbit.appendix_c import appendix_c_search
from seaice_jax.errors import ComputationError, RankDeficiencyError, SeaiceError
from seaice_jax.geometry.earth import great_circle_distance
from seaice_jax.geometry.earth import wrap_angle as _wrap
from seaice_jax.geometry.scan import SCAN_UNKNOWNS, Direction, Orbit, ScanModel, orbit_coordinates
from seaice_jax.sensors.control import ControlPoints

FREE_PARAMETERS = SCAN_UNKNOWNS
"""The five per-image unknowns, in the order the engine reports them."""

DECREASE_TOLERANCE = 1e-6
"""A fit has converged when the Gauss-Newton step left is below this many standard deviations of the estimates.
Gauss-Newton gains about three decades an iteration on these fits (NOAA passes, 7 control points of σ 1 km: 3e-2,
3e-5, 1e-7, 6e-10 σ from the minimum after 1-4 steps), so the estimates are then within ~1e-9 σ of the minimum; at
the engine's default 1e-10 7 % of 1 000 such fits took a fifth iteration, which under ``vmap`` every fit of the
batch pays (tests/test_orbit_fit.py checks the 1e-9 σ)."""

FLAG_ARCMIN = 3.0
"""Stations whose DLAT or DLONG exceeds this many arc minutes are flagged, as the 1985 program did."""

_distance = jax.jit(great_circle_distance)
"""Compiled once (eager, its operations would each compile on their own)."""


def _wrapped(angle):
    """:func:`~seaice_jax.geometry.earth.wrap_angle` in NumPy (host-side numbers: no compilation)."""
    return np.pi - np.mod(np.pi - angle, 2.0 * np.pi)


def free_mask(model: ScanModel):
    """The engine's ``free`` pytree for a scan model: the five unknowns free, the orbit fixed."""
    mask = jax.tree_util.tree_map(lambda _: False, model)
    return eqx.tree_at(lambda m: tuple(getattr(m, name) for name in FREE_PARAMETERS), mask,
                       replace=(True,) * len(FREE_PARAMETERS))


def _predict(model: ScanModel, args):
    """The control points' latitude and longitude (unwrapped next to ``reference_longitude``) from the model."""
    pixel, scan, reference_longitude = args
    latitude, longitude = model.forward(jnp.asarray(pixel, float), jnp.asarray(scan, float))
    return {"latitude": latitude, "longitude": reference_longitude + _wrap(longitude - reference_longitude)}


def _observations(control: ControlPoints, radius):
    """The control points' known positions and their σ in radians (NumPy: set up outside jit, no compilation)."""
    return _observation_groups(control.latitude, control.longitude, control.sigma, radius)


def _observation_groups(latitude, longitude, sigma, radius):
    """``{"latitude", "longitude"}`` observations of known positions (radians) with σ (m) turned into radians."""
    sigma, latitude, radius = np.asarray(sigma), np.asarray(latitude), float(radius)
    return {
        "latitude": Observations(latitude, sigma / radius),
        "longitude": Observations(longitude, sigma / (radius * np.cos(latitude))),
    }


def _padded_columns(control: ControlPoints):
    """``(pixel, scan, latitude, longitude, sigma)`` of the control points (NumPy) padded to :func:`bucket` rows by
    copies of the first point with σ = ∞ (no observation), so that images with 5-8 points share one compiled fit,
    9-16 another, ... (``seaice remap`` fits every image of a sequence, each with its own number of points)."""
    pixel, scan, latitude, longitude = (padded_to_bucket(np.asarray(a, float)) for a in (
        control.pixel, control.scan, control.latitude, control.longitude))
    return pixel, scan, latitude, longitude, pad(np.asarray(control.sigma, float), pixel.shape[0], np.inf)


def _padded(control: ControlPoints, radius):
    """The fit's observations and model arguments (as :func:`_observations`, :func:`control_args`) for the control
    points padded by :func:`_padded_columns`."""
    pixel, scan, latitude, longitude, sigma = _padded_columns(control)
    return _observation_groups(latitude, longitude, sigma, radius), (pixel, scan, longitude)


def _unpadded(adjustment: Adjustment, count: int) -> Adjustment:
    """A fit's adjustment on :func:`_padded` observations with the padding left out: each latitude and longitude
    table cut to the ``count`` points, the w-partners' flat indices (latitudes, then longitudes) renumbered."""
    rows = int(np.shape(adjustment.residuals["latitude"])[0])

    def cut(table):  # NumPy: slicing JAX arrays of every bucket's shape eagerly would compile each slice
        return {g: np.asarray(v)[:count] if g in ("latitude", "longitude") else np.asarray(v) for g, v in table.items()}

    partners = {g: np.where(v >= rows, v - rows + count, v) for g, v in cut(adjustment.w_partner).items()}
    return dataclasses.replace(
        adjustment, residuals=cut(adjustment.residuals), redundancy=cut(adjustment.redundancy),
        standardized_residuals=cut(adjustment.standardized_residuals),
        minimal_detectable_bias=cut(adjustment.minimal_detectable_bias),
        estimated_errors=cut(adjustment.estimated_errors), w_correlation=cut(adjustment.w_correlation),
        w_partner=partners)


def orbit_solver(control: ControlPoints, start: ScanModel, factorization: str = "jacobi",
                 decrease_tolerance: float = DECREASE_TOLERANCE) -> Solver:
    """A pure, jit/vmap-able :class:`~seaice_jax.adjust.engine.lsq.Solver` for this image's control-point layout.

    Call it as ``solver({"latitude": lat, "longitude": lon}, args=control_args(control))``; the σ and image
    positions are fixed, the known positions vary (Monte Carlo). ``factorization``: the engine's
    (:class:`~seaice_jax.adjust.engine.EngineOptions`); Jacobi (the default) for a batch under ``vmap``, where it
    vectorizes across the images; ``"lapack"`` is faster for one image at a time. ``decrease_tolerance``: where
    the iterations stop, in standard deviations of the estimates (:data:`DECREASE_TOLERANCE`).
    """
    return make_solver(_predict, start, _observations(control, start.orbit.radius), free=free_mask(start),
                       decrease_tolerance=decrease_tolerance, factorization=factorization)


def control_args(control: ControlPoints):
    """The model arguments for :func:`orbit_solver`: image positions and each point's known longitude, next to which
    its predicted longitude is unwrapped (so an image across ±180° fits as well as elsewhere)."""
    return control.pixel, control.scan, control.longitude


def _line_operator(x, weight):
    """``(2, n)``: the weighted least-squares straight line (intercept at x = 0, slope) through ``(x, y)`` is this
    times ``y · weight`` (weights ``weight²``; closed form by centred sums: no LAPACK call). Points all at one x
    leave the slope undetermined: 0 then (the adjustment names the unknowns it cannot determine)."""
    squared = weight**2
    mean = jnp.sum(squared * x) / jnp.sum(squared)
    spread = jnp.sum(squared * (x - mean) ** 2)
    slope = jnp.where(spread > 0, weight * (x - mean) / jnp.where(spread > 0, spread, 1.0), 0.0)
    return jnp.stack([weight / jnp.sum(squared) - mean * slope, slope])


@jax.jit
def _node_misfits(nodes, orbit, branch, latitude, longitude, pixel, scan, weight, reach=jnp.pi / 2):
    """For each trial node: the misfit of straight lines η(scan), ψ(pixel) through the control points, and the
    lines' coefficients (intercept at line/pixel 1, slope). Infinite misfit where a point's η is ``reach`` or more
    from the pass's branch (π/2: off the branch; more: across the orbit's apex, for an image that straddles it)."""
    scan_design = jnp.stack([jnp.ones_like(scan), scan - 1.0], 1) * weight[:, None]
    pixel_design = jnp.stack([jnp.ones_like(pixel), pixel - 1.0], 1) * weight[:, None]

    # the designs do not depend on the node: their least-squares operators once, outside vmap
    scan_inverse, pixel_inverse = _line_operator(scan - 1.0, weight), _line_operator(pixel - 1.0, weight)

    def misfit(node):
        eta, beta = orbit_coordinates(orbit, node, latitude, longitude, branch)
        psi = orbit.scanner_angle_from_central(beta)
        eta_line = scan_inverse @ (eta * weight)
        psi_line = pixel_inverse @ (psi * weight)
        cost = jnp.sum((scan_design @ eta_line - eta * weight) ** 2) + jnp.sum(
            (pixel_design @ psi_line - psi * weight) ** 2)
        on_branch = jnp.all(jnp.abs(_wrap(eta - branch)) < reach)
        return jnp.where(on_branch, cost, jnp.inf), eta_line, psi_line

    return jax.vmap(misfit)(nodes)


APEX_REACH = 3 * np.pi / 4
"""Radians of orbital angle from the middle of a pass's branch that :func:`initial_guess` accepts for an image across
the orbit's apex (its northernmost or southernmost point, the pole's side of a polar orbiter's pass): 45° of orbit
beyond the apex, when no node puts every control point on the pass's own branch."""


def initial_guess(control: ControlPoints, orbit: Orbit, direction: Direction, n_pixels: int, n_scans: int,
                  node_steps: int = 720) -> ScanModel:
    """Starting values from the control points alone (no operator input), for an image of ``n_pixels`` pixels by
    ``n_scans`` scan lines.

    For each trial ascending node on a grid of ``node_steps`` (then refined around the best on as many), every
    control point's orbital angle η and scanner angle ψ follow in closed form (:func:`orbit_coordinates`); the
    model says η is linear in scan line and ψ linear in pixel, so two weighted straight-line fits give the other
    four unknowns and a misfit. The node with the smallest misfit, among those putting every point on the pass's
    branch (descending for ``"south"``, ascending for ``"north"``), wins.
    """
    branch = np.pi if direction == "south" else 0.0
    pixel, scan, latitude, longitude, sigma = _padded_columns(control)  # padding: weight 0
    data = (orbit, jnp.asarray(branch), latitude, longitude, pixel, scan, float(orbit.radius) / sigma)
    step = 2 * np.pi / node_steps
    for reach in (np.pi / 2, APEX_REACH):  # the pass's own branch; else an image across the orbit's apex
        nodes = np.arange(node_steps) * step - np.pi
        costs = np.asarray(_node_misfits(jnp.asarray(nodes), *data, jnp.asarray(reach))[0])
        nodes = nodes[np.argmin(costs)] + np.linspace(-step, step, node_steps)  # same shape: no second compilation
        costs, eta_lines, psi_lines = (np.asarray(a) for a in _node_misfits(jnp.asarray(nodes), *data,
                                                                              jnp.asarray(reach)))
        k = int(np.argmin(costs))
        if np.isfinite(costs[k]):
            break
    else:
        raise SeaiceError(f"no {direction}bound pass of this orbit reaches all {len(control)} control points on its "
                          f"branch, or within {np.degrees(APEX_REACH) - 90:.0f}° of orbit across its apex; try the "
                          "other direction")
    sign = 1.0 if direction == "south" else -1.0
    eta_first, eta_rate = eta_lines[k]
    psi_first, psi_rate = psi_lines[k]
    return ScanModel(
        scanner_angle_span=-psi_rate * (n_pixels - 1),
        subtrack_pixel=1.0 - psi_first / psi_rate,
        orbital_angle_first=eta_first,
        orbital_angle_span=sign * eta_rate * (n_scans - 1),
        ascending_node=_wrapped(nodes[k]),
        orbit=orbit, direction=direction, n_pixels=n_pixels, n_scans=n_scans,
    )


@dataclass(frozen=True)
class OrbitFit:
    """A fitted image: the model, the control points and how well they agree.

    Attributes:
        model: the fitted :class:`ScanModel`.
        control: the control points used.
        method: ``"gauss-newton"`` or ``"appendix_c"``.
        iterations: nonlinear iterations (Gauss-Newton steps, or Appendix C position evaluations).
        adjustment: the engine's result (covariance, residuals, redundancy, w-tests); ``None`` for Appendix C.
        alternatives: ``{direction: RMS ground distance in km}`` of every direction tried.
        error_kurtosis: κ = E z⁴ / (E z²)² of the control points' whitened errors (3: normal). σ̂0² then varies
            (κ − 1)/r about 1, so :meth:`global_test` takes χ²(r')/r' with r' = 2r/(κ − 1) degrees of freedom (the
            moment-matched, Satterthwaite approximation). Automatic coastline points set theirs
            (:data:`~seaice_jax.imagery.coast_control.MATCH_ERROR_KURTOSIS`).
    """

    model: ScanModel
    control: ControlPoints
    method: str
    iterations: int
    adjustment: Adjustment | None = None
    alternatives: dict = field(default_factory=dict)
    error_kurtosis: float = 3.0

    def computed_positions(self):
        """Latitude and longitude (radians) the model gives at the control points."""
        return self._positions

    @cached_property
    def _positions(self):
        latitude, longitude = self.model.forward(self.control.pixel, self.control.scan)
        return np.asarray(latitude), np.asarray(longitude)

    @property
    def dlat_arcmin(self):
        """Computed minus known latitude at each control point, arc minutes (source 001 eq. C-8)."""
        return np.degrees(self._positions[0] - np.asarray(self.control.latitude)) * 60.0

    @property
    def dlon_arcmin(self):
        """Computed minus known longitude at each control point, arc minutes (eq. C-9)."""
        return np.degrees(_wrapped(self._positions[1] - np.asarray(self.control.longitude))) * 60.0

    @property
    def dev_arcmin(self):
        """The printout's DEV row: sample standard deviations of DLAT and DLONG (eqs C-13, C-14)."""
        n = len(self.control)
        if n < 2:
            return float("nan"), float("nan")
        return float(np.std(self.dlat_arcmin, ddof=1)), float(np.std(self.dlon_arcmin, ddof=1))

    @cached_property
    def error_km(self):
        """Ground distance between computed and known position at each control point, km."""
        return check_point_errors(self.model, self.control)

    @property
    def rms_km(self):
        """RMS ground distance at the control points, km."""
        return float(np.sqrt(np.mean(self.error_km**2)))

    @property
    def flagged_1985(self):
        """Stations with |DLAT| or |DLONG| beyond 3 arc minutes, as the 1985 program flagged them."""
        return (np.abs(self.dlat_arcmin) > FLAG_ARCMIN) | (np.abs(self.dlon_arcmin) > FLAG_ARCMIN)

    def w_statistics(self):
        """``(w_latitude, w_longitude)`` Baarda w-statistics per station (NaN for Appendix C)."""
        if self.adjustment is None:
            nan = np.full(len(self.control), np.nan)
            return nan, nan
        w = self.adjustment.standardized_residuals
        return np.asarray(w["latitude"]), np.asarray(w["longitude"])

    def global_test(self, alpha: float = 0.05) -> tuple[float, bool] | None:
        """``(p, accepted)`` of the global test of σ̂0² (χ², two-sided, at ``alpha``; with r' = 2r/(κ − 1)
        degrees of freedom for errors of kurtosis κ = :attr:`error_kurtosis`, r for normal ones); ``None`` without
        redundancy or for Appendix C."""
        dof = None if self.adjustment is None else self.adjustment.degrees_of_freedom
        if self.adjustment is None or dof is None or dof <= 0:
            return None
        _, p_value, accepted = global_test(self.adjustment.sigma0**2, dof, alpha, self.error_kurtosis)
        return float(p_value), bool(accepted)

    def flagged_w_test(self, alpha=DEFAULT_ALPHA):
        """Stations whose latitude or longitude w-statistic exceeds the critical value (data snooping)."""
        flagged = np.zeros(len(self.control), bool)
        if self.adjustment is not None:
            flagged[[flag.row for flag in self.adjustment.flagged(alpha, ("latitude", "longitude"))
                     if flag.row < flagged.size]] = True
        return flagged


LINE_TOLERANCE = 0.5
"""Pixels: control points all within this distance of one line of the image (a scan line, a pixel column or any
other) cannot determine the scan model's spans across that line (its observations are pixel positions, read to
about half a pixel)."""


def check_control_spread(control: ControlPoints, tolerance: float = LINE_TOLERANCE) -> None:
    """Refuse control points that lie on one line of the image: the spans across it are undetermined (the
    Gauss-Newton fit would divide by zero or report standard deviations of thousands of degrees, the Appendix C
    search a wrong span).

    Raises:
        RankDeficiencyError: naming the points, their line and the unknowns it leaves undetermined.
    """
    if len(control) < 3:
        return  # too few points: the fits name the undetermined unknowns themselves
    pixel, scan = np.asarray(control.pixel, float), np.asarray(control.scan, float)
    centred = np.column_stack([pixel, scan]) - [pixel.mean(), scan.mean()]
    across = np.linalg.svd(centred, full_matrices=False)[2][-1]  # the normal of the best-fitting line
    if np.abs(centred @ across).max() >= tolerance:
        return
    ids = ", ".join(control.ids[:8]) + (f" and {len(control) - 8} more" if len(control) > 8 else "")
    if np.ptp(pixel) < tolerance and np.ptp(scan) < tolerance:
        line, unknowns = f"at one image position (pixel {pixel.mean():g}, scan {scan.mean():g})", FREE_PARAMETERS
    elif np.ptp(scan) < 2 * tolerance:
        line, unknowns = f"on one scan line ({scan.mean():g})", ("orbital_angle_first", "orbital_angle_span")
    elif np.ptp(pixel) < 2 * tolerance:
        line, unknowns = f"on one pixel column ({pixel.mean():g})", ("scanner_angle_span", "subtrack_pixel")
    else:
        line, unknowns = "on one line of the image (pixel, scan)", FREE_PARAMETERS[:4]
    raise RankDeficiencyError(f"control points {ids} lie {line}, within {tolerance:g} px: they cannot determine "
                              f"{', '.join(unknowns)} apart (the spans across that line are undetermined); add "
                              "control points off that line", unknowns)


def check_image_size(control: ControlPoints, n_pixels, n_scans) -> None:
    """Refuse an image size that is not two whole numbers of at least 2, or control points outside the image of
    ``n_pixels`` pixels by ``n_scans`` scan lines (1-based: 0.5 to ``n + 0.5`` covers every pixel's area).

    Raises:
        SeaiceError: naming the size and, for points outside, the first few of them with their pixel and scan.
    """
    for name, value in (("n_pixels", n_pixels), ("n_scans", n_scans)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 2:
            raise SeaiceError(f"{name} must be a whole number of at least 2 (the image's size), got {value!r}")
    pixel, scan = np.asarray(control.pixel, float), np.asarray(control.scan, float)
    outside = np.flatnonzero(~((pixel >= 0.5) & (pixel <= n_pixels + 0.5) & (scan >= 0.5) & (scan <= n_scans + 0.5)))
    if outside.size:
        named = ", ".join(f"{control.ids[k]} (pixel {pixel[k]:g}, scan {scan[k]:g})" for k in outside[:3])
        more = f" and {outside.size - 3} more" if outside.size > 3 else ""
        raise SeaiceError(f"control point(s) {named}{more} lie outside the image of {n_pixels} pixels x {n_scans} "
                          "scan lines (n_pixels, n_scans): give the image's own size")


def fit_scan_model(control: ControlPoints, orbit: Orbit, *, n_pixels: int, n_scans: int, direction: str = "auto",
                   method: str = "gauss-newton", search_options: dict | None = None) -> OrbitFit:
    """Fit the five scan-model unknowns of one image to its control points.

    Args:
        control: at least three points (more to have redundancy and quality control).
        orbit: the satellite's orbit (inclination, period, altitude H — 0 for curvature-corrected images —
            and the Earth day T_e).
        n_pixels, n_scans: the image's size: pixels per scan line and scan lines (the scanner and orbital angle
            spans run from the first to the last of them, so a wrong size scales the fitted spans). Required: the
            1985 blow-ups were 512 x 512, other images are not.
        direction: ``"south"``, ``"north"`` or ``"auto"`` (fit both, keep the smaller RMS; a direction whose fit
            fails — a start past the horizon, no convergence — is left out, and the error is raised only if both fail).
        method: ``"gauss-newton"`` or ``"appendix_c"``.
        search_options: for ``"appendix_c"``, the operator's entries (``start_subtrack``, ``search_span``,
            ``initial_spans``, ``f_gamma``, ``f_beta``; see :func:`~.appendix_c.appendix_c_search`).

    Raises:
        RankDeficiencyError: naming the unknowns the control points cannot determine (too few, collinear).
        SeaiceError: an image size that is not two whole numbers >= 2, or control points outside that image.
    """
    check_image_size(control, n_pixels, n_scans)
    if direction not in ("south", "north", "auto"):
        raise SeaiceError(f"direction must be 'south', 'north' or 'auto', got {direction!r}")
    if method not in ("gauss-newton", "appendix_c"):
        raise SeaiceError(f"method must be 'gauss-newton' or 'appendix_c', got {method!r}")
    if method == "appendix_c" and len(control) < 3:
        # the search has no rank test: it would run its loops to their caps (10^8 evaluations) and report a fit
        raise RankDeficiencyError(
            f"{len(control)} control point(s) give {2 * len(control)} observations for the {len(FREE_PARAMETERS)} "
            f"unknowns: the observations cannot determine {', '.join(FREE_PARAMETERS)} (at least 3 points needed)",
            FREE_PARAMETERS)
    check_control_spread(control)
    directions = ("south", "north") if direction == "auto" else (direction,)
    fits, failures = {}, {}
    for candidate in directions:
        try:
            fits[candidate] = _fit_one(control, orbit, candidate, n_pixels, n_scans, method, search_options or {})
        except SeaiceError as error:  # auto: a direction that cannot start or converge leaves the other
            if direction != "auto":
                raise
            failures[candidate] = error
    if not fits:
        errors = list(failures.values())
        if all(isinstance(e, RankDeficiencyError) for e in errors):
            raise errors[0]  # too few or badly placed points: the first names the undetermined unknowns
        failed = ComputationError if all(type(e) is ComputationError for e in errors) else SeaiceError
        raise failed("; ".join(f"{d}: {e}" for d, e in failures.items()))
    alternatives = {d: f.rms_km for d, f in fits.items()}
    best = min(fits.values(), key=lambda f: f.rms_km)
    return OrbitFit(best.model, best.control, best.method, best.iterations, best.adjustment, alternatives)


def _fit_one(control, orbit, direction, n_pixels, n_scans, method, search_options):
    if method == "appendix_c":
        model, evaluations = appendix_c_search(control, orbit, direction, n_pixels, n_scans, **search_options)
        return OrbitFit(model, control, method, evaluations)
    start = initial_guess(control, orbit, direction, n_pixels, n_scans)
    # both directions as one southbound problem (the sign of η's rate in the span): one compiled solve for both
    southbound = start.reversed() if direction == "north" else start
    observations, args = _padded(control, orbit.radius)
    # from the initial guess the damped loop's Gauss-Newton steps are the fewest (6 where the trust region takes 12
    # from the far direction's start); a direction that does not fit is refused below after 100 of them
    adjustment = _unpadded(least_squares(_predict, southbound, observations, args=args, free=free_mask(southbound),
                                         decrease_tolerance=DECREASE_TOLERANCE, strategy="damped", max_steps=100,
                                         throw=False), len(control))
    if not bool(adjustment.converged):
        raise ComputationError(f"the {direction}bound Gauss-Newton fit did not converge in {int(adjustment.steps)} "
                               "steps")
    if direction == "north":
        sign = np.array([-1.0 if name == "orbital_angle_span" else 1.0 for name in FREE_PARAMETERS])
        flip = np.outer(sign, sign)
        adjustment = eqx.tree_at(lambda a: (a.parameters, a.cofactor, a.covariance), adjustment,
                                 (adjustment.parameters.reversed(), np.asarray(adjustment.cofactor) * flip,
                                  np.asarray(adjustment.covariance) * flip))
    return OrbitFit(adjustment.parameters, control, method, int(adjustment.steps), adjustment)


def check_point_errors(model: ScanModel, check: ControlPoints):
    """Ground distance (km) between the model's positions of check points and their known positions.

    Check points have known positions but take no part in the fit (independent accuracy).
    """
    pixel, scan, latitude, longitude, _ = _padded_columns(check)  # one compiled function per bucket of points
    lat, lon = model.forward(pixel, scan)
    return np.asarray(_distance(lat, lon, latitude, longitude, model.orbit.radius))[:len(check)] / 1000.0


def control_point_deviations(model: ScanModel, control: ControlPoints):
    """North and east deviations (m) of the model's positions of control points from their known positions (the
    1985 VHR2 printout's DLAT and DLONG, in metres on the sphere)."""
    lat, lon = (np.asarray(a) for a in model.forward(control.pixel, control.scan))
    radius = float(model.orbit.radius)
    known = np.asarray(control.latitude)
    return (lat - known) * radius, _wrapped(lon - np.asarray(control.longitude)) * radius * np.cos(known)


def position_uncertainty(fit: OrbitFit, pixel, scan, a_priori: bool = False):
    """Standard deviations (m) of the ground position of image points, from the fit's covariance.

    Propagates the covariance of the five unknowns through the forward model (autodiff Jacobian).

    Args:
        pixel, scan: ``(...)`` image coordinates (e.g. a grid, for a map of the uncertainty).
        a_priori: use the cofactor (σ of the control points taken as right) instead of σ̂0²·cofactor.

    Returns:
        ``(sigma_north, sigma_east)``, each ``(...)`` metres.
    """
    if fit.adjustment is None:
        raise SeaiceError("position uncertainty needs a Gauss-Newton fit (Appendix C gives no covariance)")
    covariance = fit.adjustment.cofactor if a_priori else fit.adjustment.covariance
    return propagate_position_sigma(fit.model, covariance, pixel, scan)


def position_jacobian(model: ScanModel, pixel, scan):
    """∂(north, east)/∂(five unknowns) of image points, ``(n, 2, 5)`` metres per unit of each unknown (in the order
    of :data:`FREE_PARAMETERS`), by forward-mode autodiff of the forward model; ``pixel, scan`` any shape,
    flattened."""
    radius = model.orbit.radius

    def position(values, p, s):
        m = eqx.tree_at(lambda mm: tuple(getattr(mm, n) for n in FREE_PARAMETERS), model,
                        replace=tuple(values))
        lat, lon = m.forward(p, s)
        # local north and east displacements: the parallel's radius is held fixed
        return jnp.stack([radius * lat, radius * jax.lax.stop_gradient(jnp.cos(lat)) * lon])

    values = jnp.stack([getattr(model, n) for n in FREE_PARAMETERS])
    pixel, scan = jnp.broadcast_arrays(jnp.asarray(pixel, float), jnp.asarray(scan, float))
    return jax.vmap(jax.jacfwd(position), in_axes=(None, 0, 0))(values, pixel.reshape(-1), scan.reshape(-1))


def propagate_position_sigma(model: ScanModel, covariance, pixel, scan):
    """σ (north, east) in metres of image points from a ``(5, 5)`` covariance of the five unknowns (in the order
    of :data:`FREE_PARAMETERS`), by the autodiff Jacobian of the forward model (:func:`position_jacobian`)."""
    pixel, scan = jnp.broadcast_arrays(jnp.asarray(pixel, float), jnp.asarray(scan, float))
    jac = position_jacobian(model, pixel, scan)
    variance = jnp.einsum("nij,jk,nik->ni", jac, jnp.asarray(covariance), jac)
    sigma = jnp.sqrt(variance)
    return sigma[:, 0].reshape(pixel.shape), sigma[:, 1].reshape(pixel.shape)
