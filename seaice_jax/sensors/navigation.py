"""Navigation records and their interpolation (sources 000 and 002: inertial navigation every 10 s).

:class:`NavigationSpline` is a trajectory (``t -> (position, velocity)``) usable by
:func:`seaice_jax.geometry.range_doppler.imaging_time_and_range`.
"""

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from seaice_jax.errors import SeaiceError


class NavigationSpline(eqx.Module):
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
        times = jnp.asarray(times, float)
        positions = jnp.asarray(positions, float)
        velocities = jnp.asarray(velocities, float)
        if times.ndim != 1 or times.shape[0] < 2:
            raise SeaiceError(f"navigation needs at least two records, got times of shape {times.shape}")
        if positions.shape != (times.shape[0], 3) or velocities.shape != (times.shape[0], 3):
            raise SeaiceError(f"navigation positions and velocities must be ({times.shape[0]}, 3), got "
                              f"{positions.shape} and {velocities.shape}")
        steps = jnp.diff(times)
        if not bool(jnp.all(steps > 0)):
            bad = int(jnp.argmax(steps <= 0)) + 1
            raise SeaiceError(f"navigation record {bad}: time {float(times[bad])} s does not increase "
                              f"(previous {float(times[bad - 1])} s)")
        self.times, self.positions, self.velocities = times, positions, velocities

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
