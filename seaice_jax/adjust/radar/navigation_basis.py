"""The navigation-error basis of a strip in the block adjustment (per strip, or shared by a flight)."""

import numpy as np

from seaice_jax.sensors.navigation import error_basis


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
    # times since the span's start (the bases are translation invariant)
    values, rates = (np.asarray(a) for a in error_basis(model, at, 0.0, span[1] - span[0], knot_spacing))
    if flight_span is None:
        return values[:-1], rates[:-1]
    values = values[:-1] - np.where(np.arange(values.shape[1]) == 1, values[-1], 0.0)  # column 1: the drift
    duration = strip_span[1] - strip_span[0]
    deviation = (times - 0.5 * (strip_span[0] + strip_span[1])) / duration
    ones, zeros = np.ones((times.size, 1)), np.zeros((times.size, 1))
    return (np.concatenate([ones, values, deviation[:, None]], axis=1),
            np.concatenate([zeros, rates[:-1], np.full((times.size, 1), 1.0 / duration)], axis=1))

