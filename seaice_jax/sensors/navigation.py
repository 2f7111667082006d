"""Navigation records, their interpolation and filtering, and models of their errors (sources 000 and 002).

* :class:`NavigationSpline`: a trajectory (``t -> (position, velocity)``) through the records, usable by
  :func:`seaice_jax.geometry.range_doppler.imaging_time_and_range`.
* :func:`moving_average`: the low-pass filter of source 002 (moving polynomial, flat or distance⁻³ weights).
* :func:`fit_navigation`: one smooth trajectory fitted to the recorded positions *and* velocities, so that the
  velocity used (the zero-Doppler plane's normal) is the derivative of the position used.
* Error models as JAX functions of their coefficients (unknowns of the block adjustment): :class:`ConstantError`,
  :class:`LinearError`, :class:`SchulerError` (84.4-min oscillation), :class:`SplineError` (cubic B-spline).
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from seaice_jax._shapes import bucket
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.trajectory import Trajectory


class NavigationSpline(Trajectory):
    """Piecewise cubic Hermite interpolation of recorded positions and velocities.

    Position and velocity are consistent: the velocity returned is the exact time derivative of the
    interpolated position, and both reproduce the records at the record times. A cubic trajectory is reproduced
    exactly.

    Attributes:
        times: ``(n,)`` seconds, strictly increasing.
        positions: ``(n, 3)`` geocentric Earth-fixed metres.
        velocities: ``(n, 3)`` m/s.
    """

    times: Float[Array, " n"]
    positions: Float[Array, "n 3"]
    velocities: Float[Array, "n 3"]

    def __init__(self, times, positions, velocities):
        # checked on the host (no JAX dispatch per check), stored as JAX arrays
        times, positions, velocities = (np.asarray(a, float) for a in (times, positions, velocities))
        if times.ndim != 1 or times.shape[0] < 2:
            raise SeaiceError(f"navigation needs at least two records, got times of shape {times.shape}")
        if positions.shape != (times.shape[0], 3) or velocities.shape != (times.shape[0], 3):
            raise SeaiceError(f"navigation positions and velocities must be ({times.shape[0]}, 3), got "
                              f"{positions.shape} and {velocities.shape}")
        steps = np.diff(times)
        if not np.all(steps > 0):
            bad = int(np.argmax(~(steps > 0))) + 1
            raise SeaiceError(f"navigation record {bad}: time {float(times[bad])} s does not increase "
                              f"(previous {float(times[bad - 1])} s)")
        self.times, self.positions, self.velocities = (jnp.asarray(a) for a in (times, positions, velocities))

    @jax.jit
    def __call__(self, time):
        """Position ``(..., 3)`` m and velocity ``(..., 3)`` m/s at ``time`` ``(...)`` s (extrapolates the end
        intervals' cubics outside the record span)."""
        time = jnp.asarray(time, float)
        i = jnp.clip(jnp.searchsorted(self.times, time, side="right") - 1, 0, self.times.shape[0] - 2)
        t0, t1 = self.times[i], self.times[i + 1]
        h = (t1 - t0)[..., None]
        u = ((time - t0) / (t1 - t0))[..., None]
        p0, p1 = self.positions[i], self.positions[i + 1]
        v0, v1 = self.velocities[i] * h, self.velocities[i + 1] * h
        h00, h10, h01, h11 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u, -2 * u**3 + 3 * u**2, u**3 - u**2
        d00, d10, d01, d11 = 6 * u**2 - 6 * u, 3 * u**2 - 4 * u + 1, -6 * u**2 + 6 * u, 3 * u**2 - 2 * u
        position = h00 * p0 + h10 * v0 + h01 * p1 + h11 * v1
        velocity = (d00 * p0 + d10 * v0 + d01 * p1 + d11 * v1) / h
        return position, velocity


SCHULER_PERIOD = 84.4 * 60.0
"""Schuler period of inertial navigation errors, seconds (84.4 min; sources 000, 002)."""


def moving_average(times, values, window: float = 180.0, order: int = 2, weighting: str = "flat"):
    """Low-pass filter of navigation records by a moving local polynomial (source 002, section 2.4).

    At each record time a polynomial of degree ``order`` is fitted to the records within ±window/2 and evaluated
    there; its derivative is the filtered velocity. ``order=0`` is the plain moving average. Source 002 found a
    second-order moving average over 3 minutes of 10-s records, with flat weights, best ("Table 1"): weights
    ∝ distance⁻³ from the estimation point (``weighting="inverse_cube"``) were worse.

    Args:
        times: ``(n,)`` seconds, increasing. values: ``(n, k)`` e.g. positions.
        window: seconds. order: polynomial degree (0, 1, 2, ...). weighting: ``"flat"`` or ``"inverse_cube"``
            (the distance is floored at half the record spacing so the centre point has a finite weight).

    Returns:
        ``(smoothed (n, k), derivative (n, k))``.
    """
    times = np.asarray(times, float)
    values = np.asarray(values, float)
    if values.ndim == 1:
        values = values[:, None]
    if weighting not in ("flat", "inverse_cube"):
        raise SeaiceError(f"weighting must be 'flat' or 'inverse_cube', got {weighting!r}")
    spacing = float(np.median(np.diff(times))) if times.size > 1 else 1.0
    half = window / 2
    # the records within each point's window are contiguous (times increase): gather them as (point, record) rows
    first = np.searchsorted(times, times - half - 1e-9, side="left")
    count = np.searchsorted(times, times + half + 1e-9, side="right") - first
    if np.any(count <= order):
        i = int(np.argmax(count <= order))
        raise SeaiceError(f"navigation record {i}: only {int(count[i])} records within the {window:g}-s window "
                          f"for a degree-{order} moving polynomial")
    offset = np.arange(count.max())
    inside = offset[None, :] < count[:, None]
    record = np.minimum(first[:, None] + offset[None, :], times.size - 1)
    dt = times[record] - times[:, None]
    weight = inside * (1.0 if weighting == "flat" else 1.0 / np.maximum(np.abs(dt), spacing / 2) ** 3)
    # every point's weighted fit at once, in time scaled by the half window (the powers stay O(1)), by the SVD of
    # each whitened design matrix
    root = np.sqrt(weight)
    design = (dt / half)[:, :, None] ** np.arange(order + 1) * root[:, :, None]
    u, s, vt = np.linalg.svd(design, full_matrices=False)
    inverse = np.swapaxes(vt, 1, 2) / np.where(s > s[:, :1] * 1e-13, s, np.inf)[:, None, :]
    coefficients = np.einsum("nab,ncb,nck->nak", inverse, u, root[:, :, None] * values[record], optimize=True)
    smoothed = coefficients[:, 0]
    derivative = coefficients[:, 1] / half if order >= 1 else np.full_like(values, np.nan)
    return smoothed, derivative


class NavigationFit(eqx.Module):
    """A trajectory fitted to navigation records (:func:`fit_navigation`).

    Attributes:
        trajectory: the fitted trajectory (its velocity is the derivative of its position).
        position_sigma: m, velocity_sigma: m/s — the records' noise (per coordinate), as given or as estimated
            from the fit's residuals.
        velocity_error: m/s, the predicted σ (per coordinate, root mean square over the records) of the fitted
            velocity, propagated from the records' noise.
    """

    trajectory: NavigationSpline
    position_sigma: float
    velocity_sigma: float
    velocity_error: float


def fit_navigation(times, positions, velocities, knot_spacing: float | None = None, position_sigma=None,
                   velocity_sigma=None, iterations: int = 20) -> NavigationFit:
    """A cubic B-spline trajectory fitted by least squares to recorded positions and velocities together.

    The inertial records hold both s and ṡ (sources 000, 002); interpolating them separately, or giving the
    spline positions and slopes from different local fits, leaves a velocity that is not the derivative of the
    position and carries the position noise differentiated over one record interval (tenths of m/s for 30 m of
    position noise at 10 s), which tilts the zero-Doppler plane and moves far-range points tens of metres along
    track. Here both records are observations of one C² spline s(t) (knots every ``knot_spacing`` s from the
    first record): positions with σ_s, velocities of ṡ(t) with σ_v. The precise velocities carry the shape of the
    trajectory, the positions its level; the velocity returned is the spline's derivative, with the noise of the
    recorded velocities averaged, not that of the positions differentiated.

    The record noise σ_s, σ_v (pooled over the three coordinates) are estimated from the residuals by iterated
    variance components (Förstner: σ̂² = vᵀv / Σ r_i over each group, r_i the redundancy numbers) unless given.

    Args:
        times: ``(n,)`` s, increasing. positions: ``(n, 3)`` m. velocities: ``(n, 3)`` m/s.
        knot_spacing: s (default: the median record interval, knots at the records).
        position_sigma, velocity_sigma: σ of the records (m, m/s); ``None``: estimated.
        iterations: of the variance-component estimation.

    Returns:
        :class:`NavigationFit`; its trajectory interpolates the fitted spline's positions and velocities at the
        record times (exact when the knots fall on records).
    """
    times = np.asarray(times, float)
    positions = np.asarray(positions, float)
    velocities = np.asarray(velocities, float)
    NavigationSpline(times, positions, velocities)  # the shapes and the times checked, records named
    if times.size < 4:
        raise SeaiceError(f"navigation: a fitted trajectory needs at least four records, got {times.size}")
    spacing = float(np.median(np.diff(times))) if knot_spacing is None else float(knot_spacing)
    if not spacing > 0:
        raise SeaiceError(f"navigation: knot_spacing must be positive, got {knot_spacing}")
    values, rates = (np.asarray(a) for a in error_basis("spline", times - times[0], 0.0, times[-1] - times[0],
                                                        spacing))
    basis = np.concatenate([values, rates])
    observed = np.concatenate([positions - positions[0], velocities])  # relative: no 6e6 m in the squares
    group = np.repeat([0, 1], times.size)
    given = np.array([position_sigma is not None, velocity_sigma is not None])
    sigma = np.array([position_sigma or 1.0, velocity_sigma or 1.0 / spacing], float)
    for _ in range(1 if given.all() else iterations):
        coefficients, inverse, redundancy = _weighted_fit(basis, observed, sigma[group])
        residuals = basis @ coefficients - observed
        square = np.array([np.sum(residuals[group == g] ** 2) for g in (0, 1)])
        dof = 3.0 * np.array([np.sum(redundancy[group == g]) for g in (0, 1)])
        estimated = np.maximum(np.sqrt(square / np.maximum(dof, 1e-12)), [_SIGMA_FLOOR * spacing, _SIGMA_FLOOR])
        updated = np.where(given, sigma, estimated)
        converged = bool(np.all(np.abs(updated / sigma - 1.0) < 1e-6))
        sigma = updated
        if converged:
            break
    coefficients, inverse, _ = _weighted_fit(basis, observed, sigma[group])
    velocity_error = float(np.sqrt(np.mean(np.einsum("ij,jk,ik->i", rates, inverse, rates))))
    trajectory = NavigationSpline(times, values @ coefficients + positions[0], rates @ coefficients)
    return NavigationFit(trajectory, float(sigma[0]), float(sigma[1]), velocity_error)


def _weighted_fit(basis, observed, sigma):
    """Weighted least squares of ``observed`` ``(n, k)`` (σ ``(n,)``) on ``basis`` ``(n, q)``: coefficients
    ``(q, k)``, their cofactor ``(q, q)`` (by the SVD of the whitened basis) and the redundancy numbers ``(n,)``."""
    whitened = basis / sigma[:, None]
    u, singular, vt = np.linalg.svd(whitened, full_matrices=False)
    keep = singular > singular[0] * 1e-12
    u, singular, vt = u[:, keep], singular[keep], vt[keep]
    coefficients = vt.T @ ((u.T @ (observed / sigma[:, None])) / singular[:, None])
    inverse = (vt.T / singular**2) @ vt
    return coefficients, inverse, 1.0 - np.sum(u**2, axis=1)


_SIGMA_FLOOR = 1e-6
"""m/s: the smallest record noise the variance components may reach (noise-free records)."""


def _scaled(factor, vector):
    """``(..., k)``: each of the ``(...)`` factors times the ``(k,)`` vector."""
    return factor[..., None] * jnp.broadcast_to(vector, factor.shape + vector.shape)


class ConstantError(eqx.Module):
    """Navigation error constant in time: e(t) = offset. ``offset``: ``(k,)`` (e.g. north, east in metres)."""

    offset: Float[Array, " k"]

    @jax.jit
    def __call__(self, time):
        time = jnp.asarray(time, float)
        return jnp.broadcast_to(self.offset, time.shape + self.offset.shape)


class LinearError(eqx.Module):
    """e(t) = offset + rate (t − epoch): the drift of an inertial platform (0.5-1 km per hour of flight)."""

    offset: Float[Array, " k"]
    rate: Float[Array, " k"]
    epoch: Float[Array, ""] = eqx.field(converter=lambda x: jnp.asarray(x, float), default=0.0)

    @jax.jit
    def __call__(self, time):
        dt = jnp.asarray(time, float) - self.epoch
        return _scaled(jnp.ones_like(dt), self.offset) + _scaled(dt, self.rate)


class SchulerError(eqx.Module):
    """e(t) = offset + rate (t − epoch) + sine sin ω(t − epoch) + cosine cos ω(t − epoch), ω = 2π / 84.4 min."""

    offset: Float[Array, " k"]
    rate: Float[Array, " k"]
    sine: Float[Array, " k"]
    cosine: Float[Array, " k"]
    epoch: Float[Array, ""] = eqx.field(converter=lambda x: jnp.asarray(x, float), default=0.0)
    period: float = eqx.field(static=True, default=SCHULER_PERIOD)

    @jax.jit
    def __call__(self, time):
        dt = jnp.asarray(time, float) - self.epoch
        phase = 2.0 * jnp.pi / self.period * dt
        return (_scaled(jnp.ones_like(dt), self.offset) + _scaled(dt, self.rate) + _scaled(jnp.sin(phase), self.sine)
                + _scaled(jnp.cos(phase), self.cosine))


class SplineError(eqx.Module):
    """Uniform cubic B-spline in time: e(t) = Σ_j B_j(t) c_j, knots every ``spacing`` seconds from ``start``.

    Attributes:
        coefficients: ``(m, k)`` control values, m >= 4; the spline covers [start, start + (m − 3) spacing]
            (beyond it the end pieces extend).
        start, spacing: seconds.
    """

    coefficients: Float[Array, "m k"]
    start: Float[Array, ""] = eqx.field(converter=lambda x: jnp.asarray(x, float))
    spacing: Float[Array, ""] = eqx.field(converter=lambda x: jnp.asarray(x, float))

    @classmethod
    def zeros(cls, start, end, spacing, components=2):
        """A zero spline covering [start, end] with knots every ``spacing`` seconds."""
        return cls(jnp.zeros((_spline_pieces(start, end, spacing) + 3, components)), start, spacing)

    @jax.jit
    def __call__(self, time):
        position = (jnp.asarray(time, float) - self.start) / self.spacing
        pieces = self.coefficients.shape[0] - 3
        i = jnp.clip(jnp.floor(position), 0, pieces - 1).astype(int)
        u = (position - i)[..., None]
        basis = ((1 - u) ** 3 / 6, (3 * u**3 - 6 * u**2 + 4) / 6, (-3 * u**3 + 3 * u**2 + 3 * u + 1) / 6, u**3 / 6)
        return sum((b * self.coefficients[i + j] for j, b in enumerate(basis)), jnp.zeros(()))


def _spline_pieces(start, end, spacing) -> int:
    """Number of cubic pieces of a spline covering [start, end] with knots every ``spacing`` seconds (at least 1)."""
    return max(int(np.ceil((end - start) / spacing)), 1)


ERROR_MODELS = ("constant", "linear", "schuler", "spline")
"""Navigation-error models of the block adjustment, in order of flexibility."""


def _error_model(model, coefficients, start, end, knot_spacing):
    """The error model of ``coefficients`` ``(q, k)``, each coefficient in metres (rates per strip duration)."""
    span, middle = end - start, 0.5 * (start + end)
    if model == "constant":
        return ConstantError(coefficients[0])
    if model == "linear":
        return LinearError(coefficients[0], coefficients[1] / span, middle)
    if model == "schuler":
        return SchulerError(coefficients[0], coefficients[1] / span, coefficients[2], coefficients[3], middle)
    return SplineError(coefficients, start, knot_spacing)


def error_basis_size(model: str, start: float, end: float, knot_spacing: float = 300.0) -> int:
    """Number q of basis functions (coefficients per component) of an error model over [start, end] s."""
    if model not in ERROR_MODELS:
        raise SeaiceError(f"navigation-error model must be one of {', '.join(ERROR_MODELS)}, got {model!r}")
    if model == "spline":
        return _spline_pieces(start, end, knot_spacing) + 3
    return {"constant": 1, "linear": 2, "schuler": 4}[model]


def error_basis(model: str, times, start: float, end: float, knot_spacing: float = 300.0):
    """Basis functions of a navigation-error model: e(t) = values(t) @ C and ė(t) = rates(t) @ C.

    The models are linear in their coefficients C ``(q, k)``, scaled so that every coefficient is in metres: an
    offset; a rate times the strip duration (linear, about the strip's middle); the Schuler sine and cosine
    amplitudes; the B-spline control values with knots every ``knot_spacing`` s from ``start``.

    Args:
        times: ``(n,)`` seconds. start, end: the strip's time span.

    Returns:
        ``(values (n, q), rates (n, q))`` NumPy arrays (host side), rates in 1/s.
    """
    q = error_basis_size(model, start, end, knot_spacing)
    times = np.asarray(times, float)
    n = times.shape[0]
    # padded to a bucket and the span traced: strips of one model and basis size share one compile
    padded = np.pad(times, (0, bucket(n) - n), mode="edge")
    basis, rates = _error_basis(model, q, padded, float(start), float(end), float(knot_spacing))
    return np.asarray(basis)[:n], np.asarray(rates)[:n]


@functools.partial(jax.jit, static_argnames=("model", "q"))
def _error_basis(model, q, times, start, end, knot_spacing):
    """:func:`error_basis` by autodiff of the model: the Jacobian in C, and its time derivative by a JVP."""

    def values(t):
        return jax.jacfwd(lambda c: _error_model(model, c, start, end, knot_spacing)(t)[..., 0])(jnp.zeros((q, 1)))[
            ..., 0]

    return jax.jvp(values, (times,), (jnp.ones_like(times),))
