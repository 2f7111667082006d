"""The radar block's stochastic model against what the simulator draws (issue 29): the turns' perturbations, a
random walk along a flight, and the time marks' jitter carried into the image x. Monte Carlo over simulated flights
(no adjustment: the priors and σ are compared with the draws they describe), a few seconds."""

from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np
import pytest

from seaice_jax.adjust.radar.block import BlockOptions, image_sigmas
from seaice_jax.adjust.radar.layout import block_unknowns, mark_weight
from seaice_jax.sensors.slar import imaging_time
from seaice_jax.simulate.aircraft import ErrorModel, FlightPlan, simulate_flight

PLAN = FlightPlan(strips=6)
FLIGHTS = 300


@pytest.fixture(scope="module")
def flights():
    """``FLIGHTS`` simulated flights with only the turn perturbations and the time-mark jitter on."""
    errors = ErrorModel().only("turn_perturbation", "time_mark_jitter")
    return [simulate_flight(PLAN, errors, np.random.default_rng(900_000 + k)) for k in range(FLIGHTS)]


def _turn_rows(options):
    """The prior rows on the north turn offsets of one flight: whitening matrix ``(rows, strips)`` (row r: the
    prior's residual over its σ as a function of the strips' offsets)."""
    starts = np.arange(PLAN.strips) * (PLAN.strip_duration + PLAN.turn_duration)
    records = [SimpleNamespace(name=f"S{k + 1:02d}", start_time=start, end_time=start + PLAN.strip_duration,
                               range_scale=PLAN.range_scale) for k, start in enumerate(starts)]
    names, sigma, previous, _, _ = block_unknowns([SimpleNamespace(name="day 0", strips=records)], options)
    turns = [i for i, name in enumerate(names) if name.endswith("north turn offset")]
    assert len(turns) == PLAN.strips
    whitening = np.zeros((PLAN.strips, PLAN.strips))
    for row, i in enumerate(turns):
        whitening[row, row] = 1.0 / sigma[i]
        if previous[i] >= 0:
            whitening[row, turns.index(int(previous[i]))] = -1.0 / sigma[i]
    return whitening


def test_the_turn_prior_is_the_random_walk_the_simulator_draws(flights):
    """The prior rows imply the covariance σ²·min(j, k) of strips j, k's offsets (a random walk from the flight's
    first strip), and on simulated flights the whitened prior residuals are independent N(0, 1): mean square,
    lag-1 correlation and the 5 % two-sided exceedances within 4 standard errors. The prior of issue 12 (each strip
    independent, σ·√k) has the right variances but whitened residuals correlated ≈ 0.8, which this detects."""
    options = BlockOptions()
    assert options.turn_prior is not None
    whitening = _turn_rows(options)
    covariance = np.linalg.inv(whitening.T @ whitening)
    steps = np.arange(PLAN.strips)
    np.testing.assert_allclose(covariance, options.turn_prior**2 * np.minimum.outer(steps, steps), atol=1.0)

    offsets = np.array([[truth.navigation_error[0] for truth in strips] for _, strips in flights])  # (F, k, 2)
    assert np.all(offsets[:, 0] == 0.0)  # the first strip is the reference
    z = np.einsum("rk,fkc->frc", whitening, offsets)[:, 1:]  # the turns' whitened residuals (first: reference)
    n = z.size
    assert np.mean(z**2) == pytest.approx(1.0, abs=4 * np.sqrt(2.0 / n))
    lag = np.mean(z[:, 1:] * z[:, :-1]) / np.mean(z**2)
    assert abs(lag) < 4 / np.sqrt(z[:, 1:].size)
    exceed = np.mean(np.abs(z) > 1.959964)
    assert exceed == pytest.approx(0.05, abs=4 * np.sqrt(0.05 * 0.95 / n))

    independent = offsets[:, 1:] / (options.turn_prior * np.sqrt(steps[1:]))[None, :, None]  # issue 12's prior
    assert np.mean(independent**2) == pytest.approx(1.0, abs=4 * np.sqrt(2.0 / n))  # right variances ...
    assert np.mean(independent[:, 1:] * independent[:, :-1]) > 0.6  # ... but not independent


def test_the_image_x_sigma_carries_the_time_marks_jitter(flights):
    """Eq. A1 interpolates a point's time between time marks placed with the simulator's jitter (0.05 s at
    0.5 mm/s): the x error that makes, over the σ the model gives it (√((1 − u)² + u²) × time_mark_sigma), has unit
    mean square, at the marks and between them; the reading σ adds to it."""
    options = BlockOptions()
    assert options.time_mark_sigma is not None
    rng = np.random.default_rng(1)
    ratios, at_marks = [], []
    for records, _ in flights[:100]:
        for strip in records:
            x = rng.uniform(strip.mark_x[0], strip.mark_x[-1], 200)  # true film x (the film moves uniformly)
            error = PLAN.film_rate * (np.asarray(imaging_time(jnp.asarray(x), strip.mark_x, strip.mark_times))
                                      - strip.start_time) - x
            weight = mark_weight(strip.mark_x, x)
            ratios.append(error**2 / (options.time_mark_sigma**2 * weight))
            at_marks.append(weight > 0.9)
    ratios, at_marks = np.concatenate(ratios), np.concatenate(at_marks)
    assert options.time_mark_sigma == pytest.approx(ErrorModel().time_mark_jitter * PLAN.film_rate)
    assert np.mean(ratios) == pytest.approx(1.0, abs=0.05)
    assert np.mean(ratios[at_marks]) == pytest.approx(1.0, abs=0.1)
    sigma = image_sigmas(options, np.array([1.0, 0.5]))
    np.testing.assert_allclose(sigma[:, 0], np.hypot(0.04, [0.025, 0.025 * np.sqrt(0.5)]))
    np.testing.assert_allclose(sigma[:, 1], 0.04)
