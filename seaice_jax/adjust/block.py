"""Simultaneous block adjustment of radar strips: every unknown of a block in one Gauss-Newton solve.

Source 000 (section 2) says "a rigorous method would solve for all unknowns simultaneously, thereby minimizing the
weighted square sum of all observation errors"; its sequential method (:mod:`seaice_jax.adjust.sequential`)
approximates that. Here it is done rigorously.

Unknowns:
  * the coefficients of a navigation-error model (north and east; constant, linear, Schuler or cubic B-spline,
    :func:`~seaice_jax.sensors.navigation.error_basis`), all in metres, either per strip (``scope="strip"``) or, as
    an inertial platform behaves, one continuous error per flight (``scope="flight"``: the drift and the Schuler
    oscillation are shared by all strips of a coverage, with the flight's offset at its start; each later strip has
    its own offset with the prior of the turn perturbations accumulated before it, and a small linear deviation with
    a tight prior, taking up what the filtered record noise leaves; sources 000 and 002);
  * per strip (or one pair for the whole block) the corrections Δc (mm) and Δf (m/mm) to the nominal sweep delay
    and range scale;
  * the map coordinates (x, y) of every tie, drift and control point, one pair per coverage (ice moves between
    coverages) or, for land, one pair for all coverages.

Observations:
  * image measurements (x, y) of points, through eqs A1, A2 and A5: the time from the time marks, the slant range
    r = (y + c0 + Δc)(f0 + Δf), the sensor state from the filtered navigation minus the modelled error, the ground
    point by the range-Doppler intersection, projected into the map;
  * control-point coordinates with their σ; nadir returns against the altimeter (r_n = h_n, eq. A3);
  * priors on the navigation-error coefficients and radar constants (pseudo-observations).

Where the residuals live: the forward model A5 maps an image measurement to the ground in closed form, so the
residual is formed in the map (rectified minus adjusted position) and weighted by the image-measurement
covariance propagated through the same model: the ground residual is whitened by W = diag(σx, σy)⁻¹ J⁻¹, with
J = ∂(map x, y)/∂(image x, y) at the current estimate (re-evaluated every iteration but not differentiated, as
in the Gauss-Helmert model: the incidence angle, hence the ground-range error of a slant-range error, changes as
the navigation is corrected by kilometres). To first order this is exactly the image-space adjustment (the map of
an image point is locally a bijection), and the whitened residuals *are* the image residuals in units of their σ
(component 0 along track, 1 in slant range), so the w-tests name the image coordinate at fault. The inverse
(ground -> image) would need an iterative zero-Doppler search in every residual.

Two linear-algebra paths, chosen automatically: small blocks go through the engine
(:func:`~seaice_jax.adjust.lsq.make_solver`, dense JᵀJ); large ones eliminate the point unknowns by the Schur
complement (each point touches one to three strips, so its 2 × 2 block of the normal matrix is inverted
independently) and solve the reduced system of strip unknowns, so the work grows linearly with the number of
points. Array sizes are padded to buckets, so blocks of similar size share one compilation.
"""

import functools
from dataclasses import dataclass, field

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from seaice_jax._shapes import bucket, pad
from seaice_jax.adjust.lsq import Observations, make_solver
from seaice_jax.adjust.quality import DEFAULT_ALPHA, critical_value, w_test
from seaice_jax.errors import RankDeficiencyError, SeaiceError
from seaice_jax.geometry.earth import MEAN_RADIUS, latitude_longitude, north_east
from seaice_jax.geometry.range_doppler import ground_point, look_sign
from seaice_jax.sensors.navigation import ERROR_MODELS, error_basis, error_basis_size
from seaice_jax.sensors.slar import imaging_time
from seaice_jax.sensors.strips import image_to_ground, nadir_altitudes, strip_navigation

SOLVERS = ("auto", "dense", "schur")
DENSE_LIMIT = 1500
"""Unknowns up to which ``solver="auto"`` uses the dense engine path."""
_COMPONENTS = ("north", "east")
_REFERENCE_SIGMA = 1e-3
"""m: prior σ of the first strip's turn offset (none: the flight's own offset is the error there)."""


@dataclass(frozen=True)
class BlockOptions:
    """Choices of a simultaneous block adjustment.

    Attributes:
        navigation_model: ``"constant"``, ``"linear"``, ``"schuler"`` or ``"spline"``.
        navigation_scope: ``"flight"`` (one error curve per coverage, plus per strip an offset and a linear
            deviation: the INS drift and Schuler oscillation run on through the turns) or ``"strip"`` (every strip
            its own curve, nothing shared; the spline model needs this).
        knot_spacing: s, of the spline model.
        radar_constants: ``"strip"`` (Δc, Δf per strip) or ``"shared"`` (one pair for the block).
        filter_window: s of the navigation moving average applied first (``None``: none).
        image_sigma: ``(σx, σy)`` mm of the image measurements (along track, slant range).
        altimeter_sigma: m.
        offset_prior: σ (m) of the navigation offsets and spline values (``None``: no prior).
        shape_prior: σ (m) of the other navigation coefficients: rate × strip (or flight) duration, Schuler
            amplitudes (``None``: no prior).
        schuler_prior: σ (m) of the Schuler sine and cosine amplitudes if they differ from ``shape_prior`` (the
            INS drift over a short flight is far smaller than its Schuler oscillation).
        take_off_time: s on the strips' clock when the flights took off (flight scope; ``None``: unknown). The
            flight's curve then starts at take-off: its offset is the INS alignment error (``offset_prior``) and its
            drift grows from zero there, so the drift accumulated before the first strip is tied to the drift
            the ties see (without it the flight's offset at its first strip has to carry that drift).
        turn_prior: σ (m) of the INS perturbation of one turn (flight scope): strip k of a flight is offset from the
            flight's curve by σ turn_prior·√k (the perturbations add up; ``None``: no prior).
        deviation_prior: σ (m) of each strip's linear deviation from the flight's curve (its change over the
            strip; flight scope only): the low-frequency part of the record noise that the filter lets through
            (``None``: no prior).
        sweep_delay_prior: σ of Δc, mm. range_scale_prior: σ of Δf relative to f0.
        static_points: land: one position per point for all coverages (no drift).
        solver: ``"auto"``, ``"dense"`` or ``"schur"``.
        max_iterations, tolerance: Gauss-Newton stops when no unknown changes by more than ``tolerance`` (m, mm)
            or the step is smaller than ``tolerance`` standard deviations (ΔᵀNΔ < tolerance²).
        alpha: significance level of the w-tests that flag blunders.
    """

    navigation_model: str = "schuler"
    navigation_scope: str = "flight"
    knot_spacing: float = 300.0
    radar_constants: str = "strip"
    filter_window: float | None = 180.0
    image_sigma: tuple[float, float] = (0.04, 0.04)
    altimeter_sigma: float = 5.0
    offset_prior: float | None = 5000.0
    shape_prior: float | None = 3000.0
    schuler_prior: float | None = None
    take_off_time: float | None = None
    turn_prior: float | None = 500.0
    deviation_prior: float | None = 50.0
    sweep_delay_prior: float | None = 2.0
    range_scale_prior: float | None = 0.02
    static_points: bool = False
    solver: str = "auto"
    max_iterations: int = 15
    tolerance: float = 1e-4
    alpha: float = DEFAULT_ALPHA

    def __post_init__(self):
        if self.navigation_model not in ERROR_MODELS:
            raise SeaiceError(f"navigation_model must be one of {', '.join(ERROR_MODELS)}, got "
                              f"{self.navigation_model!r}")
        if self.navigation_scope not in ("flight", "strip"):
            raise SeaiceError(f"navigation_scope must be 'flight' or 'strip', got {self.navigation_scope!r}")
        if self.navigation_scope == "flight" and self.navigation_model == "spline":
            raise SeaiceError("the spline navigation model is per strip: use navigation_scope='strip' (a spline's "
                              "values already include each strip's offset)")
        if self.radar_constants not in ("strip", "shared"):
            raise SeaiceError(f"radar_constants must be 'strip' or 'shared', got {self.radar_constants!r}")
        if self.solver not in SOLVERS:
            raise SeaiceError(f"solver must be one of {', '.join(SOLVERS)}, got {self.solver!r}")


class _Data(eqx.Module):
    """Everything the residuals need, as arrays (padded rows have zero weight)."""

    index: Int[Array, "m k"]  # unknowns of the strip part touched by each image observation
    point: Int[Array, " m"]
    basis: Float[Array, "m q"]
    rates: Float[Array, "m q"]
    position: Float[Array, "m 3"]
    velocity: Float[Array, "m 3"]
    north: Float[Array, "m 3"]
    east: Float[Array, "m 3"]
    north_rate: Float[Array, "m 3"]
    east_rate: Float[Array, "m 3"]
    y: Float[Array, " m"]
    sweep_delay: Float[Array, " m"]
    range_scale: Float[Array, " m"]
    sign: Float[Array, " m"]
    time_per_mm: Float[Array, " m"]  # dt/dx of eq. A1 at each observation, s/mm
    weight: Float[Array, " m"]  # 1, or 0 for padding
    image_sigma: Float[Array, "2"]
    nadir_index: Int[Array, "n 2"]
    nadir_y: Float[Array, " n"]
    nadir_sweep_delay: Float[Array, " n"]
    nadir_range_scale: Float[Array, " n"]
    nadir_altitude: Float[Array, " n"]
    nadir_weight: Float[Array, " n"]
    control_point: Int[Array, " c"]
    control_xy: Float[Array, "c 2"]
    control_weight: Float[Array, " c"]
    prior_weight: Float[Array, " u"]
    point_prior: Float[Array, " p"]
    pair_first: Int[Array, " r"]
    pair_second: Int[Array, " r"]
    pair_weight: Float[Array, " r"]
    plane: eqx.Module
    radius: float = eqx.field(static=True)


def _rectified(strip_unknowns, row, data: _Data, shift):
    """Map position ``(2,)`` of image observation ``row`` by A1, A2, A5 with the corrected navigation and radar
    constants; ``shift`` = (Δt s, Δy mm) moves the observation along track and in range (for ∂map/∂image)."""
    q = data.basis.shape[1]
    basis, rates = data.basis[row], data.rates[row]
    error_n, error_e = basis @ strip_unknowns[:q], basis @ strip_unknowns[q:2 * q]
    rate_n, rate_e = rates @ strip_unknowns[:q], rates @ strip_unknowns[q:2 * q]
    # the corrected velocity is the time derivative of the corrected position (the local axes turn along the track)
    velocity = (data.velocity[row] - rate_n * data.north[row] - rate_e * data.east[row]
                - error_n * data.north_rate[row] - error_e * data.east_rate[row])
    position = data.position[row] - error_n * data.north[row] - error_e * data.east[row] + shift[0] * velocity
    slant = (data.y[row] + shift[1] + data.sweep_delay[row] + strip_unknowns[2 * q]) * (data.range_scale[row]
                                                                                         + strip_unknowns[2 * q + 1])
    ground = ground_point(position, velocity, slant, data.radius, data.sign[row], on_failure="nan")
    return jnp.stack(data.plane.forward(*latitude_longitude(ground)))


def _whitening(strip_unknowns, row, data: _Data):
    """W = diag(σx, σy)⁻¹ (∂map/∂image)⁻¹ ``(2, 2)`` at the current unknowns (zero for padding rows)."""
    jacobian = jax.jacfwd(_rectified, argnums=3)(strip_unknowns, row, data, jnp.zeros(2))
    jacobian = jacobian * jnp.stack([data.time_per_mm[row], jnp.ones(())])[None, :]
    return jnp.linalg.inv(jacobian) / data.image_sigma[:, None] * data.weight[row]


def _image_residual(strip_unknowns, point, row, data: _Data):
    """Whitened residual ``(2,)`` of one image observation: W (rectified map position − point).

    The weight matrix W follows the unknowns (it is evaluated at the current estimate) but is not differentiated,
    as in the Gauss-Helmert model.
    """
    whiten = jax.lax.stop_gradient(_whitening(strip_unknowns, row, data))
    return whiten @ (_rectified(strip_unknowns, row, data, jnp.zeros(2)) - point)


def _image_residuals(unknowns, points, data: _Data):
    rows = jnp.arange(data.point.shape[0])
    return jax.vmap(_image_residual, in_axes=(0, 0, 0, None))(unknowns[data.index], points[data.point], rows, data)


def _nadir_residuals(unknowns, data: _Data):
    """Whitened residuals of the nadir returns (eq. A3: r_n = (y_n + c) f = h_n), in image space:
    (y_n + c − h_n / f) / σ with σ² = σy² + (σh / f0)².

    In image space because y_n is the measured quantity: written as (y_n + c) f − h_n with a fixed weight, the
    fit could shrink the scatter of the noisy y_n by shrinking f, a regression-dilution bias of the range scale
    (several per cent in level flight, where y_n hardly varies).
    """
    sweep_delay = data.nadir_sweep_delay + unknowns[data.nadir_index[:, 0]]
    range_scale = data.nadir_range_scale + unknowns[data.nadir_index[:, 1]]
    return (data.nadir_y + sweep_delay - data.nadir_altitude / range_scale) * data.nadir_weight


def _control_residuals(points, data: _Data):
    return (points[data.control_point] - data.control_xy) * data.control_weight[:, None]


def _normal_equations(unknowns, points, data: _Data):
    """Reduced normal equations of the strip unknowns (points eliminated) and what back-substitution needs."""
    size = unknowns.shape[0]
    n_points = points.shape[0]
    rows = jnp.arange(data.point.shape[0])
    value_and_jacobians = jax.vmap(
        lambda t, p, r: (_image_residual(t, p, r, data),
                         jax.jacfwd(_image_residual, argnums=(0, 1))(t, p, r, data)), in_axes=(0, 0, 0))
    e, (j_strip, j_point) = value_and_jacobians(unknowns[data.index], points[data.point], rows)
    normal = jnp.zeros((size, size)).at[data.index[:, :, None], data.index[:, None, :]].add(
        jnp.einsum("mik,mil->mkl", j_strip, j_strip))
    right = jnp.zeros(size).at[data.index].add(-jnp.einsum("mik,mi->mk", j_strip, e))
    nadir = _nadir_residuals(unknowns, data)
    j_nadir = jax.jacfwd(_nadir_residuals)(unknowns, data)
    normal = normal + j_nadir.T @ j_nadir + jnp.diag(data.prior_weight**2)
    right = right - j_nadir.T @ nadir - data.prior_weight**2 * unknowns
    point_normal = jnp.zeros((n_points, 2, 2)).at[data.point].add(jnp.einsum("mik,mil->mkl", j_point, j_point))
    point_right = jnp.zeros((n_points, 2)).at[data.point].add(-jnp.einsum("mik,mi->mk", j_point, e))
    eye = jnp.eye(2)
    point_normal = point_normal.at[data.control_point].add(data.control_weight[:, None, None] ** 2 * eye[None])
    point_right = point_right.at[data.control_point].add(-_control_residuals(points, data)
                                                         * data.control_weight[:, None])
    point_normal = point_normal + data.point_prior[:, None, None] * eye[None]
    point_inverse = jnp.linalg.inv(point_normal)
    coupling = jnp.einsum("mik,mil->mkl", j_strip, j_point)  # A_o = J_θᵀ J_p, (m, k, 2)
    first, second = data.pair_first, data.pair_second
    pair_point = data.point[first]
    schur = jnp.einsum("rka,rab,rlb->rkl", coupling[first], point_inverse[pair_point], coupling[second])
    normal = normal.at[data.index[first][:, :, None], data.index[second][:, None, :]].add(
        -schur * data.pair_weight[:, None, None])
    reduced_right = right.at[data.index].add(
        -jnp.einsum("mka,mab,mb->mk", coupling, point_inverse[data.point], point_right[data.point]))
    return normal, reduced_right, point_inverse, point_right, coupling, e, (j_strip, j_point), right


_reduced_normal_equations = jax.jit(_normal_equations)


@jax.jit
def _all_rectified(unknowns, data: _Data):
    """``(m, 2)`` map positions of all image observations with the current unknowns."""
    rows = jnp.arange(data.point.shape[0])
    return jax.vmap(lambda t, r: _rectified(t, r, data, jnp.zeros(2)))(unknowns[data.index], rows)


@jax.jit
def _schur_step(unknowns, points, data: _Data):
    """One Gauss-Newton step by the Schur complement: ``(Δ strip unknowns, Δ points, ΔᵀNΔ)``.

    ΔᵀNΔ = Δᵀb is the decrease of the whitened square sum the step predicts (twice the cost decrease): the step's
    size measured in standard deviations of the unknowns.
    """
    normal, reduced_right, point_inverse, point_right, coupling, *_, right = _normal_equations(unknowns, points,
                                                                                               data)
    step = jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(normal), reduced_right)
    back = jnp.zeros_like(points).at[data.point].add(jnp.einsum("mka,mk->ma", coupling, step[data.index]))
    point_step = jnp.einsum("pab,pb->pa", point_inverse, point_right - back)
    return step, point_step, step @ right + jnp.sum(point_step * point_right)


@jax.jit
def _schur_statistics(unknowns, points, data: _Data):
    """Cofactors, redundancy numbers and w-tests at the solution (a priori σ; scale by σ̂0² for a posteriori)."""
    normal, _, point_inverse, _, coupling, e, (j_strip, j_point), _ = _normal_equations(unknowns, points, data)
    cofactor = jnp.linalg.inv(normal)
    first, second = data.pair_first, data.pair_second
    pair_point = data.point[first]
    block = cofactor[data.index[first][:, :, None], data.index[second][:, None, :]]
    weight = data.pair_weight[:, None, None]
    inner = jnp.zeros_like(point_inverse).at[pair_point].add(
        weight * jnp.einsum("rka,rkl,rlb->rab", coupling[first], block, coupling[second]))
    point_cofactor = point_inverse + point_inverse @ inner @ point_inverse
    mixed = jnp.zeros_like(coupling).at[first].add(weight * jnp.einsum("rkl,rlb->rkb", block, coupling[second]))
    strip_point = -jnp.einsum("mka,mab->mkb", mixed, point_inverse[data.point])  # Q_θp rows of each observation
    local = jnp.concatenate([
        jnp.concatenate([cofactor[data.index[:, :, None], data.index[:, None, :]], strip_point], axis=2),
        jnp.concatenate([jnp.swapaxes(strip_point, 1, 2), point_cofactor[data.point]], axis=2)], axis=1)
    jacobian = jnp.concatenate([j_strip, j_point], axis=2)
    redundancy = 1.0 - jnp.einsum("miu,muv,miv->mi", jacobian, local, jacobian)
    return cofactor, point_cofactor, e, redundancy


def _cross_cofactor(cofactor, point_inverse_a, point_inverse_b, coupling, index, first, second, group, groups):
    """Cofactor blocks ``(g, 2, 2)`` between pairs of points, from observation pairs (o ∈ a, o′ ∈ b) of group g."""
    block = cofactor[index[first][:, :, None], index[second][:, None, :]]
    inner = np.zeros((groups, 2, 2))
    np.add.at(inner, group, np.einsum("rka,rkl,rlb->rab", coupling[first], block, coupling[second]))
    return point_inverse_a @ inner @ np.swapaxes(point_inverse_b, 1, 2)


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
    """An image observation whose w-test fails: point, where it was measured, and the size of the error."""

    point: int
    coverage: int
    strip: int
    component: str  # "x" (along track) or "y" (slant range)
    w: float
    estimated_error: float  # mm on the film


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
        blunders: observations failing the w-test (|w| > critical value at ``options.alpha``), worst first.
        parameter_names: the unknowns other than the points (navigation-error coefficients, radar constants).
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


@dataclass
class _Problem:
    """The host-side layout of a block: unknown names, observation tables, start values."""

    names: list
    prior_sigma: np.ndarray
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


@functools.partial(jax.jit, static_argnames=("model", "duration", "knot_spacing"))
def _error_basis(model, elapsed, duration, knot_spacing):
    """:func:`error_basis` of times ``elapsed`` since the strip start (the bases are translation invariant)."""
    return error_basis(model, elapsed, 0.0, duration, knot_spacing)


def navigation_basis(model: str, times, strip_span, flight_span=None, knot_spacing: float = 300.0):
    """Basis of a strip's navigation error in the block adjustment: e(t) = values(t) @ C, ė(t) = rates(t) @ C.

    Without ``flight_span``, the model's :func:`~seaice_jax.sensors.navigation.error_basis` over the strip. With
    it: first the strip's turn offset (1), then the model's basis over the whole flight with the drift term taken
    relative to its value at the flight's start (the drift grows from there; the Schuler sine and cosine stay as
    they are, an oscillation already under way), then the strip's linear deviation (t − t_mid) / duration, in
    metres of change over the strip.

    Args:
        times: ``(n,)`` s. strip_span, flight_span: (start, end) s.

    Returns:
        ``(values (n, q), rates (n, q))`` NumPy arrays, rates in 1/s.
    """
    times = np.asarray(times, float)
    span = strip_span if flight_span is None else flight_span
    at = np.concatenate([times - span[0], [0.0]])  # the last row: the span's start
    values, rates = (np.asarray(a) for a in _error_basis(model, jnp.asarray(at), span[1] - span[0], knot_spacing))
    if flight_span is None:
        return values[:-1], rates[:-1]
    values = values[:-1] - np.where(np.arange(values.shape[1]) == 1, values[-1], 0.0)  # column 1: the drift
    duration = strip_span[1] - strip_span[0]
    deviation = (times - 0.5 * (strip_span[0] + strip_span[1])) / duration
    ones, zeros = np.ones((times.size, 1)), np.zeros((times.size, 1))
    return (np.concatenate([ones, values, deviation[:, None]], axis=1),
            np.concatenate([zeros, rates[:-1], np.full((times.size, 1), 1.0 / duration)], axis=1))


def _strip_observations(strip, x, y, options, plane, radius, flight_span):
    """Per-observation geometry of one strip and the start map positions, with the navigation-error basis
    (:func:`navigation_basis`)."""
    navigation = strip_navigation(strip, options.filter_window)
    n = len(x)
    size = bucket(n)  # padded, so strips of similar size share one compilation
    geometry = _strip_geometry(navigation, jnp.asarray(strip.mark_x), jnp.asarray(strip.mark_times),
                               jnp.asarray(pad(x, size, x[0])), jnp.asarray(pad(y, size, y[0])),
                               strip.sweep_delay, strip.range_scale, look_sign(strip.look_side), plane, radius)
    times, time_per_mm, position, velocity, north, east, north_rate, east_rate, start, jacobian = (
        np.asarray(a)[:n] for a in geometry)
    basis, rates = navigation_basis(options.navigation_model, times, (strip.start_time, strip.end_time), flight_span,
                                    options.knot_spacing)
    # rows without a ground solution (range errors putting a near-range point inside the flying height) are dropped
    usable = np.isfinite(start).all(axis=1) & (np.abs(np.linalg.det(np.nan_to_num(jacobian))) > 0)
    return dict(basis=basis, rates=rates, position=position, velocity=velocity, north=north, east=east,
                north_rate=north_rate, east_rate=east_rate, y=np.asarray(y, float),
                sweep_delay=np.full(n, strip.sweep_delay), range_scale=np.full(n, strip.range_scale),
                sign=np.full(n, float(look_sign(strip.look_side))), time_per_mm=time_per_mm), start, usable


def _layout(coverages, n_points, plane, options: BlockOptions, radius, point_ids=None) -> _Problem:
    """Unknowns, observation tables and start values of a block."""
    names, prior = [], []
    strip_slices = []
    model = options.navigation_model
    coefficient_names = {"constant": ["offset"], "linear": ["offset", "rate"],
                         "schuler": ["offset", "rate", "Schuler sine", "Schuler cosine"]}
    offset_sigma = options.offset_prior if options.offset_prior is not None else np.inf
    shape_sigma = options.shape_prior if options.shape_prior is not None else np.inf
    schuler_sigma = options.schuler_prior if options.schuler_prior is not None else shape_sigma
    shape = {"constant": [], "linear": [shape_sigma], "schuler": [shape_sigma, schuler_sigma, schuler_sigma]}.get(
        model)  # prior σ of the coefficients after the offset (the spline's values all take the offset's)
    turn_sigma = options.turn_prior if options.turn_prior is not None else np.inf
    flight = options.navigation_scope == "flight"
    shared_radar = None
    q = None
    for c, coverage in enumerate(coverages):
        flown = (min(s.start_time for s in coverage.strips), max(s.end_time for s in coverage.strips))
        if flight and options.take_off_time is not None:
            if options.take_off_time > flown[0]:
                raise SeaiceError(f"coverage {coverage.name!r}: take_off_time {options.take_off_time} s is after its "
                                  f"first strip starts ({flown[0]} s)")
            flown = (options.take_off_time, flown[1])
        shared = {}  # flight scope: the coefficients after the offset, one set per coverage and component
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
            for component in _COMPONENTS:
                if not flight:
                    navigation += range(len(names), len(names) + q)
                    names += [f"{label} navigation {component} {term}" for term in terms]
                    prior += [offset_sigma] * q if model == "spline" else [offset_sigma] + shape
                    continue
                if component not in shared:
                    shared[component] = list(range(len(names), len(names) + q - 2))
                    names += [f"{coverage.name} navigation {component} {term}" for term in terms]
                    prior += [offset_sigma] + shape
                navigation += [len(names), *shared[component], len(names) + 1]
                names += [f"{label} navigation {component} turn offset", f"{label} navigation {component} deviation"]
                # the turns' perturbations add up along the flight; the first strip is the flight's reference
                prior += [turn_sigma * np.sqrt(j) if j else _REFERENCE_SIGMA,
                          options.deviation_prior if options.deviation_prior is not None else np.inf]
            if options.radar_constants == "strip" or shared_radar is None:
                radar_label = label if options.radar_constants == "strip" else "block"
                radar = [len(names), len(names) + 1]
                names += [f"{radar_label} sweep delay", f"{radar_label} range scale"]
                prior += [options.sweep_delay_prior if options.sweep_delay_prior is not None else np.inf,
                          options.range_scale_prior * strip.range_scale if options.range_scale_prior is not None
                          else np.inf]
                shared_radar = radar
            strip_slices.append((c, j, np.array(navigation), shared_radar, flown if flight else None))
    point_key, point_unknown, sums, counts = [], {}, [], []
    tables = {k: [] for k in ("index", "point", "basis", "rates", "position", "velocity", "north", "east",
                              "north_rate", "east_rate", "y",
                              "sweep_delay", "range_scale", "sign", "time_per_mm")}
    coverage_of, strip_of, point_of = [], [], []
    unsolved = set()  # (coverage, point, strip) of measurements without a ground solution at the start
    nadir = {k: [] for k in ("index", "y", "sweep_delay", "range_scale", "altitude")}
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
                nadir["altitude"].append(nadir_altitudes(strip))
            if rows.size == 0:
                continue
            table, start, valid = _strip_observations(strip, m.x[rows], m.y[rows], options, plane, radius,
                                                      flight_span)
            unsolved.update((c, int(p), strip.name) for p in m.point[rows[~valid]])
            for key in table:
                tables[key].append(table[key][valid])
            tables["index"].append(np.tile(np.concatenate([navigation, radar]), (int(valid.sum()), 1)))
            for o, p in zip(rows[valid], m.point[rows[valid]], strict=True):
                key = (-1 if options.static_points else c, int(p))
                if key not in point_unknown:
                    point_unknown[key] = len(point_key)
                    point_key.append(key)
                    sums.append(np.zeros(2))
                    counts.append(0)
                u = point_unknown[key]
                tables["point"].append(np.array([u]))
                sums[u] = sums[u] + start[np.searchsorted(rows, o)]
                counts[u] += 1
                coverage_of.append(c)
                strip_of.append(j)
                point_of.append(int(p))
    if not point_key:
        raise SeaiceError("no image measurement gives a ground point: nothing to adjust")
    for c, p, strip_name in sorted(unsolved):
        if p in coverages[c].control and (-1 if options.static_points else c, p) not in point_unknown:
            name = p if point_ids is None else point_ids[p]
            raise SeaiceError(f"coverage {coverages[c].name!r}: control point {name} is measured (strip {strip_name}) "
                              "but has no ground solution with the nominal radar constants and the navigation (a "
                              "slant range shorter than the flying height?): nothing would hold it; correct or "
                              "remove its measurement")
    observations = {k: np.concatenate(v) for k, v in tables.items()}
    observations["point"] = observations["point"].astype(int)
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
    return _Problem(names, np.array(prior, float), np.array(sums) / np.array(counts)[:, None], point_key,
                    strip_slices, observations, nadir, control, np.array(coverage_of), np.array(strip_of),
                    np.array(point_of), q)


def _pairs(point, size):
    """Observation pairs (o, o′) measuring the same point, both orders and o = o′, as index arrays."""
    order = np.argsort(point, kind="stable")
    first, second = [], []
    groups = np.split(order, np.nonzero(np.diff(point[order]))[0] + 1)
    for group in groups:
        first.append(np.repeat(group, group.size))
        second.append(np.tile(group, group.size))
    first, second = np.concatenate(first), np.concatenate(second)
    return first, second, size


def _data(problem: _Problem, options: BlockOptions, plane, radius, padded_sizes: bool) -> _Data:
    obs, nadir, control = problem.observations, problem.nadir, problem.control
    m, n_points = obs["point"].size, len(problem.point_key)
    first, second, _ = _pairs(obs["point"], m)
    sizes = (bucket(m), bucket(n_points), bucket(first.size), bucket(max(nadir["y"].size, 1)),
             bucket(max(control["point"].size, 1))) if padded_sizes else (m, n_points, first.size, nadir["y"].size,
                                                                   control["point"].size)
    padded = {k: pad(v, sizes[0], v[0]) for k, v in obs.items()}
    padded["point"] = pad(obs["point"], sizes[0], 0)
    nadir_weight = 1.0 / np.hypot(options.image_sigma[1], options.altimeter_sigma / nadir["range_scale"])
    nadir_pad = {k: pad(v, sizes[3], 1 if k == "range_scale" else 0) for k, v in nadir.items()}
    if nadir["y"].size == 0:
        nadir_pad["index"] = np.zeros((sizes[3], 2), int)
    weight = np.where(np.isfinite(problem.prior_sigma), 1.0 / problem.prior_sigma, 0.0)
    return _Data(
        index=jnp.asarray(padded["index"]), point=jnp.asarray(padded["point"]), basis=jnp.asarray(padded["basis"]),
        rates=jnp.asarray(padded["rates"]), position=jnp.asarray(padded["position"]),
        velocity=jnp.asarray(padded["velocity"]), north=jnp.asarray(padded["north"]),
        east=jnp.asarray(padded["east"]), north_rate=jnp.asarray(padded["north_rate"]),
        east_rate=jnp.asarray(padded["east_rate"]), y=jnp.asarray(padded["y"]),
        sweep_delay=jnp.asarray(padded["sweep_delay"]),
        range_scale=jnp.asarray(padded["range_scale"]), sign=jnp.asarray(padded["sign"]),
        time_per_mm=jnp.asarray(padded["time_per_mm"]), weight=jnp.asarray(pad(np.ones(m), sizes[0], 0.0)),
        image_sigma=jnp.asarray(options.image_sigma, float), nadir_index=jnp.asarray(nadir_pad["index"], int),
        nadir_y=jnp.asarray(nadir_pad["y"], float), nadir_sweep_delay=jnp.asarray(nadir_pad["sweep_delay"], float),
        nadir_range_scale=jnp.asarray(nadir_pad["range_scale"], float),
        nadir_altitude=jnp.asarray(nadir_pad["altitude"], float),
        nadir_weight=jnp.asarray(pad(nadir_weight, sizes[3], 0.0)),
        control_point=jnp.asarray(pad(control["point"], sizes[4], 0)),
        control_xy=jnp.asarray(pad(control["xy"], sizes[4], 0.0)),
        control_weight=jnp.asarray(pad(1.0 / control["sigma"], sizes[4], 0.0)),
        prior_weight=jnp.asarray(weight),
        point_prior=jnp.asarray(np.concatenate([np.zeros(n_points), np.ones(sizes[1] - n_points)])),
        pair_first=jnp.asarray(pad(first, sizes[2], 0)), pair_second=jnp.asarray(pad(second, sizes[2], 0)),
        pair_weight=jnp.asarray(pad(np.ones(first.size), sizes[2], 0.0)), plane=plane, radius=radius)


def _check_datum(problem: _Problem, data: _Data, unknowns, points):
    """Raise :class:`RankDeficiencyError` if the reduced normal matrix is singular, saying which free motions of
    the block nothing fixes (shift, rotation) and which unknowns they involve."""
    equations = _reduced_normal_equations(unknowns, points, data)
    normal, point_inverse, coupling = (np.asarray(equations[k]) for k in (0, 2, 4))
    scale = np.sqrt(np.diag(normal))
    dead = scale <= 0
    scaled = normal / np.outer(np.where(dead, 1.0, scale), np.where(dead, 1.0, scale))
    values, vectors = np.linalg.eigh(scaled)
    # condition > 1e8: exactly singular, or held only by second-order effects such as the Earth's curvature (a
    # block with one control point can turn about it: its rotation is then "determined" at the 1e-9 level)
    null = vectors[:, values <= 1e-8 * values[-1]]
    if null.shape[1] == 0 and not dead.any():
        return
    index, point = np.asarray(data.index), np.asarray(data.point)
    n_real = len(problem.point_key)
    where = np.asarray(points)[:n_real]
    coverage = np.array([key[0] for key in problem.point_key])
    motions = set()
    for z in null.T:
        z = z / np.where(dead, 1.0, scale)
        moved = np.zeros_like(np.asarray(points))
        np.add.at(moved, point, np.einsum("mka,mk->ma", coupling, z[index]))
        moved = -np.einsum("pab,pb->pa", point_inverse, moved)[:n_real]
        if np.linalg.norm(moved) <= 1e-9 * np.linalg.norm(z):
            motions.add("separation of unknowns that act alike (no point moves)")
            continue
        for c in np.unique(coverage):  # each coverage's points: an affine motion of the whole, or more?
            on = coverage == c
            if np.linalg.norm(moved[on]) <= 1e-6 * np.linalg.norm(moved):
                continue
            centred = where[on] - where[on].mean(axis=0)
            design = np.concatenate([np.ones((int(on.sum()), 1)), centred], axis=1)
            fit, *_ = np.linalg.lstsq(design, moved[on], rcond=None)  # rows: shift, then the 2 x 2 matrix
            if np.linalg.norm(design @ fit - moved[on]) > 0.1 * np.linalg.norm(moved[on]):
                motions.add("deformation")
                continue
            extent = np.sqrt(np.mean(np.sum(centred**2, axis=1)))
            matrix = fit[1:].T
            parts = {"shift": np.hypot(*fit[0]), "rotation": abs(matrix[1, 0] - matrix[0, 1]) / 2 * extent,
                     "stretch": np.linalg.norm((matrix + matrix.T) / 2) * extent}
            motions.update(k for k, v in parts.items() if v > 0.3 * max(parts.values()))
    involved = sorted(set(np.nonzero(dead)[0].tolist()) | set(np.nonzero(np.any(np.abs(null) > 0.1, axis=1))[0]
                                                                .tolist()))
    names = [problem.names[k] for k in involved]
    shown = ", ".join(names[:8]) + (f" and {len(names) - 8} more" if len(names) > 8 else "")
    raise RankDeficiencyError(
        f"datum defect: nothing fixes the block's {' and '.join(sorted(motions)) or 'unknowns'} ({null.shape[1]} free "
        f"combination(s) of the unknowns {shown}); add control points (one fixes a shift, two also the rotation) or "
        "priors on the navigation errors", names)


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
    problem = _layout(coverages, n_points, plane, options, radius, point_ids)
    size = len(problem.names)
    n_real = len(problem.point_key)
    total = size + 2 * n_real
    solver = options.solver if options.solver != "auto" else ("dense" if total <= DENSE_LIMIT else "schur")
    data = _data(problem, options, plane, radius, padded_sizes=solver == "schur")
    unknowns = jnp.zeros(size)
    points = jnp.asarray(pad(problem.start_points, data.point_prior.shape[0], 0.0))
    _check_datum(problem, data, unknowns, points)
    if solver == "dense":
        unknowns, points, iterations, converged, cofactors = _dense_solve(problem, data, options, unknowns, points)
    else:
        iterations, converged = 0, False
        while iterations < options.max_iterations and not converged:
            step, point_step, decrease = _schur_step(unknowns, points, data)
            unknowns, points = unknowns + step, points + point_step
            iterations += 1
            small = max(float(jnp.max(jnp.abs(step))), float(jnp.max(jnp.abs(point_step)))) < options.tolerance
            converged = small or float(decrease) < options.tolerance**2
            if not (np.isfinite(float(decrease)) and bool(jnp.all(jnp.isfinite(point_step)))):
                raise SeaiceError("the Schur-complement solve broke down (the reduced normal matrix is not "
                                  "numerically positive definite: the block is held only weakly, e.g. no control and "
                                  "no navigation priors); add control points or priors, or use solver='dense'")
        cofactors = _schur_statistics(unknowns, points, data)
    return _result(problem, data, options, solver, coverages, n_points, unknowns, points, iterations, converged,
                   cofactors)


def _dense_solve(problem, data, options, unknowns, points):
    """The engine path: optimistix Gauss-Newton on the whitened residuals, dense (JᵀJ)⁻¹."""
    n_real = len(problem.point_key)
    m = problem.observations["point"].size

    def model(parameters, _):
        image = _image_residuals(parameters["strips"], parameters["points"], data)
        predicted = {"image": image, "nadir": _nadir_residuals(parameters["strips"], data),
                     "control": _control_residuals(parameters["points"], data)}
        return {g: predicted[g] for g in groups}

    parameters = {"strips": unknowns, "points": points}
    groups = {"image": Observations(jnp.zeros((m, 2)), 1.0),
              "nadir": Observations(jnp.zeros(data.nadir_y.shape), 1.0),
              "control": Observations(jnp.zeros(data.control_xy.shape), 1.0)}
    groups = {g: v for g, v in groups.items() if v.values.size}
    prior = {"strips": jnp.asarray(problem.prior_sigma), "points": None}
    # steps of 1e-7 (relative for the points, absolute for the corrections) are converged: the map positions
    # themselves carry roundoff of ~1e-9 m from the Earth-centred geometry
    solver = make_solver(model, parameters, groups, prior_sigma=prior, max_steps=4 * options.max_iterations,
                         tolerance=1e-7)
    adjustment = solver({g: groups[g].values for g in groups})
    size = unknowns.shape[0]
    # the engine orders the unknowns by key: "points" (2n) before "strips"
    order = np.concatenate([np.arange(2 * n_real, 2 * n_real + size), np.arange(2 * n_real)])
    cofactor = np.asarray(adjustment.cofactor)[np.ix_(order, order)]
    point_cofactor = cofactor[size:, size:].reshape(n_real, 2, n_real, 2)[np.arange(n_real), :, np.arange(n_real)]
    e = adjustment.residuals["image"]
    redundancy = adjustment.redundancy["image"]
    return (adjustment.parameters["strips"], adjustment.parameters["points"], int(adjustment.steps),
            bool(adjustment.converged), (cofactor, point_cofactor, e, redundancy))


def _result(problem, data, options, solver, coverages, n_points, unknowns, points, iterations, converged,
            cofactors) -> BlockResult:
    cofactor, point_cofactor, e, redundancy = (np.asarray(a) for a in cofactors)
    size = unknowns.shape[0]
    n_real = len(problem.point_key)
    m = problem.observations["point"].size
    e, redundancy = e[:m], redundancy[:m]
    unknowns, points = np.asarray(unknowns), np.asarray(points)[:n_real]
    strip_cofactor = cofactor[:size, :size]
    point_cofactor = point_cofactor[:n_real]
    nadir = np.asarray(_nadir_residuals(jnp.asarray(unknowns), data))
    control = np.asarray(_control_residuals(jnp.asarray(pad(points, data.point_prior.shape[0], 0.0)), data))
    prior = np.asarray(data.prior_weight) * unknowns
    square_sum = float(np.sum(e**2) + np.sum(nadir**2) + np.sum(control**2) + np.sum(prior**2))
    n_observations = 2 * m + problem.nadir["y"].size + 2 * problem.control["point"].size + int(
        np.isfinite(problem.prior_sigma).sum())
    dof = n_observations - size - 2 * n_real
    sigma0 = float(np.sqrt(square_sum / dof)) if dof > 0 else float("nan")
    w = np.asarray(w_test(jnp.asarray(e), jnp.asarray(redundancy)))
    ground = np.asarray(_all_rectified(jnp.asarray(unknowns), data))[:m]
    sigma_image = np.asarray(options.image_sigma, float)
    residuals = e * sigma_image
    positions, covariances = [], []
    static = options.static_points
    lookup = {key: u for u, key in enumerate(problem.point_key)}
    for c in range(len(coverages)):
        where = np.full((n_points, 2), np.nan)
        cov = np.full((n_points, 2, 2), np.nan)
        for (cc, p), u in lookup.items():
            if cc == (-1 if static else c):
                where[p], cov[p] = points[u], point_cofactor[u]
        positions.append(where)
        covariances.append(cov)
    drift, drift_cov = [], []
    if not static:
        for c in range(1, len(coverages)):
            both = [(p, lookup[(c - 1, p)], lookup[(c, p)]) for p in range(n_points)
                    if (c - 1, p) in lookup and (c, p) in lookup]
            displacement = np.full((n_points, 2), np.nan)
            covariance = np.full((n_points, 2, 2), np.nan)
            if both:
                ids, a, b = (np.array(v) for v in zip(*both, strict=True))
                cross = _drift_cross_cofactor(problem, data, cofactor, unknowns, points, a, b)
                displacement[ids] = points[b] - points[a]
                covariance[ids] = point_cofactor[a] + point_cofactor[b] - cross - np.swapaxes(cross, 1, 2)
            drift.append(displacement)
            drift_cov.append(covariance)
    strips = []
    q = problem.q
    for (c, j, navigation, radar, flight_span) in problem.strip_slices:
        strip = coverages[c].strips[j]
        strips.append(StripEstimate(
            coverages[c].name, strip.name, strip.start_time, strip.end_time, options.navigation_model,
            options.knot_spacing, unknowns[navigation].reshape(2, q).T,
            strip_cofactor[np.ix_(navigation, navigation)], strip.sweep_delay + unknowns[radar[0]],
            float(np.sqrt(strip_cofactor[radar[0], radar[0]])), strip.range_scale + unknowns[radar[1]],
            float(np.sqrt(strip_cofactor[radar[1], radar[1]])), *(flight_span or (None, None))))
    limit = float(critical_value(options.alpha))
    bad = np.argwhere(np.abs(w) > limit)
    order = np.argsort(-np.abs(w[bad[:, 0], bad[:, 1]])) if bad.size else []
    blunders = tuple(Blunder(int(problem.point_of[o]), int(problem.coverage_of[o]), int(problem.strip_of[o]),
                             "xy"[k], float(w[o, k]), float(-residuals[o, k] / max(redundancy[o, k], 1e-12)))
                     for o, k in (bad[i] for i in order))
    return BlockResult(solver, options, tuple(positions), tuple(covariances), tuple(drift), tuple(drift_cov),
                       tuple(strips), sigma0, dof, iterations, converged, problem.coverage_of, problem.strip_of,
                       problem.point_of, ground, residuals, redundancy, w, blunders, tuple(problem.names))


def _drift_cross_cofactor(problem, data, cofactor, unknowns, points, first_points, second_points):
    """Cofactor blocks ``(g, 2, 2)`` between the earlier and later unknowns of each drift point (they are
    correlated through shared strip unknowns, e.g. shared radar constants)."""
    padded = jnp.asarray(pad(points, data.point_prior.shape[0], 0.0))
    _, _, point_inverse, _, coupling, *_ = _reduced_normal_equations(jnp.asarray(unknowns), padded, data)
    point_inverse, coupling = np.asarray(point_inverse), np.asarray(coupling)
    index = np.asarray(data.index)
    point = problem.observations["point"]
    rows = {}
    for o, u in enumerate(point):
        rows.setdefault(int(u), []).append(o)
    first, second, group = [], [], []
    for g, (a, b) in enumerate(zip(first_points, second_points, strict=True)):
        for o in rows[int(a)]:
            for o2 in rows[int(b)]:
                first.append(o)
                second.append(o2)
                group.append(g)
    first, second, group = np.array(first, int), np.array(second, int), np.array(group, int)
    return _cross_cofactor(cofactor, point_inverse[first_points], point_inverse[second_points], coupling, index,
                           first, second, group, len(first_points))
