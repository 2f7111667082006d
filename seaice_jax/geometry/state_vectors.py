"""An orbit given by state vectors: position and velocity every few seconds, interpolated.

Spaceborne radar products (Sentinel-1, ERS, Envisat, RADARSAT) annotate the platform's Earth-fixed position and
velocity at regular times (Sentinel-1: every 10 s). Positions and velocities are interpolated *separately* by
Lagrange polynomials over the nearest ``order`` vectors. A velocity differentiated from the position polynomial
would be off by 1-2 cm/s on Sentinel-1 products (the annotated velocities are the orbit determination's own, not
the derivative of its rounded positions), which moves a zero-Doppler point by ~2-3 m along track.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from seaice_jax._shapes import is_traced
from seaice_jax.geometry._vectors import as_float
from seaice_jax.geometry.trajectory import Trajectory

DEFAULT_ORDER = 8
"""Number of state vectors in each Lagrange window (a degree-7 polynomial). On the Sentinel-1 annotations of the
tests the ESA geolocation grid points then satisfy the range equation to 0.02 mm and the zero-Doppler equation to
1.4 cm or better (measured on all their grid points)."""

ORBIT_BUCKET = 32
"""State vectors an orbit is padded to (:meth:`StateVectorOrbit.padded`) where many products share one compiled
geolocation (a Sentinel-1 annotation holds 14-18)."""


class StateVectorOrbit(Trajectory):
    """Orbit interpolated from state vectors: a :class:`~seaice_jax.geometry.trajectory.Trajectory`.

    Attributes:
        times: ``(n,)`` seconds from the product's epoch, increasing.
        positions: ``(n, 3)`` Earth-fixed (ECEF) positions, m.
        velocities: ``(n, 3)`` Earth-fixed velocities, m/s.
        order: vectors per interpolation window (static), at most ``n``.
        count: the number of real vectors, the first ``count`` rows (default ``n``); rows after them are padding
            (see :meth:`padded`), never used.
    """

    times: Float[Array, " n"]
    positions: Float[Array, "n 3"]
    velocities: Float[Array, "n 3"]
    order: int = eqx.field(static=True)
    count: Int[Array, ""]

    def __init__(self, times, positions, velocities, order: int = DEFAULT_ORDER, count=None):
        self.times, self.positions, self.velocities = (as_float(v) for v in (times, positions, velocities))
        self.order = order
        self.count = jnp.asarray(self.times.shape[0] if count is None else count)

    def __check_init__(self):
        times = self.times
        if is_traced(times, self.count):
            return
        n = int(self.count)
        if self.positions.shape != self.velocities.shape or self.positions.shape != (times.shape[0], 3):
            raise ValueError(f"state vectors: {times.shape[0]} times but positions {self.positions.shape} and "
                             f"velocities {self.velocities.shape} (expected ({times.shape[0]}, 3) each)")
        if n < self.order:
            raise ValueError(f"state vectors: {n} given, the interpolation needs at least {self.order}")
        steps = np.diff(np.asarray(times))
        if np.any(steps <= 0):
            bad = int(np.argmax(steps <= 0))
            raise ValueError(f"state vectors: times must increase; vector {bad + 1} is at {float(times[bad + 1])} s, "
                             f"not after vector {bad} at {float(times[bad])} s")

    @property
    def time_span(self) -> tuple[float, float]:
        """First and last state-vector time, s."""
        return float(self.times[0]), float(self.times[int(self.count) - 1])

    def bucketed(self) -> "StateVectorOrbit":
        """This orbit :meth:`padded` to :data:`ORBIT_BUCKET` vectors, or left as it is if it has more."""
        return self.padded(max(ORBIT_BUCKET, self.times.shape[0]))

    def padded(self, size: int) -> "StateVectorOrbit":
        """This orbit with rows appended up to ``size`` vectors (times far beyond the last, positions and velocities
        copied from it) and :attr:`count` kept: orbits of different lengths padded to one size share one compiled
        geolocation. Results are the same as the unpadded orbit's."""
        n = self.times.shape[0]
        if size < n:
            raise ValueError(f"cannot pad {n} state vectors to {size}")
        extra = size - n
        times = jnp.concatenate([self.times, self.times[-1] + 1e6 * jnp.arange(1, extra + 1)])
        positions = jnp.concatenate([self.positions, jnp.broadcast_to(self.positions[-1], (extra, 3))])
        velocities = jnp.concatenate([self.velocities, jnp.broadcast_to(self.velocities[-1], (extra, 3))])
        return StateVectorOrbit(times, positions, velocities, self.order, self.count)

    @jax.jit
    def __call__(self, time):
        """Position ``(..., 3)`` m and velocity ``(..., 3)`` m/s at ``time`` ``(...)`` seconds from the epoch.

        Outside the state vectors' span the window's polynomial extrapolates (as every orbit interpolator does);
        callers keep times within :attr:`time_span`."""
        time = jnp.asarray(time, float)
        position, velocity = jax.vmap(self._interpolate)(time.reshape(-1))
        return position.reshape(time.shape + (3,)), velocity.reshape(time.shape + (3,))

    def _interpolate(self, time):
        start = jnp.clip(jnp.searchsorted(self.times, time) - self.order // 2, 0, self.count - self.order)
        window = jax.lax.dynamic_slice_in_dim(self.times, start, self.order)
        centre = window[self.order // 2]
        nodes = window - centre
        offset = (time - centre) - nodes
        differences = nodes[:, None] - nodes[None, :]
        off_diagonal = ~jnp.eye(self.order, dtype=bool)
        numerator = jnp.prod(jnp.where(off_diagonal, offset[None, :], 1.0), axis=1)
        denominator = jnp.prod(jnp.where(off_diagonal, differences, 1.0), axis=1)
        weights = numerator / denominator
        positions = jax.lax.dynamic_slice_in_dim(self.positions, start, self.order)
        velocities = jax.lax.dynamic_slice_in_dim(self.velocities, start, self.order)
        return weights @ positions, weights @ velocities
