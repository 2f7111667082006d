"""Closed-form sensor trajectories: position and velocity as pure functions of time.

A :class:`Trajectory` maps time to ``(position (3,), velocity (3,))`` in geocentric Earth-fixed metres and m/s.
Navigation records interpolated by :class:`seaice_jax.sensors.navigation.NavigationSpline` are trajectories;
:class:`CircularTrajectory` is the analytic one used by simulations and tests (a constant-altitude great-circle
flight, or a circular orbit ignoring Earth rotation).
"""

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from seaice_jax.geometry._vectors import along
from seaice_jax.geometry.earth import MEAN_RADIUS, unit_vector


class Trajectory(eqx.Module):
    """A sensor trajectory: position and velocity as a pure (jit-, vmap- and grad-able) function of time."""

    @abc.abstractmethod
    def __call__(self, time):
        """Position ``(..., 3)`` m and velocity ``(..., 3)`` m/s (Earth-centred, Earth-fixed) at ``time`` ``(...)``
        seconds."""


class CircularTrajectory(Trajectory):
    """Uniform motion on a circle about the Earth's centre: s(t) = ρ (cos θ e1 + sin θ e2), θ = ω (t − epoch).

    Attributes:
        first_axis: ``(3,)`` unit vector of the position at ``epoch``.
        second_axis: ``(3,)`` unit vector of the direction of motion at ``epoch`` (orthogonal to ``first_axis``).
        orbit_radius: ρ, metres from the Earth's centre.
        angular_rate: ω, rad/s (speed / ρ).
        epoch: seconds.
    """

    first_axis: Float[Array, "3"]
    second_axis: Float[Array, "3"]
    orbit_radius: Float[Array, ""]
    angular_rate: Float[Array, ""]
    epoch: Float[Array, ""]

    @classmethod
    def from_heading(cls, latitude, longitude, heading, altitude, speed, radius=MEAN_RADIUS, epoch=0.0):
        """A great-circle flight at constant altitude.

        Args:
            latitude, longitude: radians, sub-sensor point at ``epoch``.
            heading: radians clockwise from north at ``epoch``.
            altitude: metres above the sphere of ``radius``.
            speed: ground-relative speed at flight altitude, m/s.
        """
        up = unit_vector(latitude, longitude)
        east = jnp.stack([-jnp.sin(longitude), jnp.cos(longitude), jnp.zeros_like(longitude)])
        north = jnp.cross(up, east)
        forward = jnp.cos(heading) * north + jnp.sin(heading) * east
        orbit_radius = jnp.asarray(radius + altitude, float)
        return cls(up, forward, orbit_radius, jnp.asarray(speed, float) / orbit_radius, jnp.asarray(epoch, float))

    @jax.jit
    def __call__(self, time):
        """Position ``(..., 3)`` m and velocity ``(..., 3)`` m/s at ``time`` ``(...)`` seconds."""
        angle = (jnp.asarray(time, float) - self.epoch) * self.angular_rate
        c, s = jnp.cos(angle), jnp.sin(angle)
        position = self.orbit_radius * (along(c, self.first_axis) + along(s, self.second_axis))
        velocity = self.orbit_radius * self.angular_rate * (along(c, self.second_axis) - along(s, self.first_axis))
        return position, velocity

