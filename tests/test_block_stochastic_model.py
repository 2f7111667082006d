"""The radar block's stochastic model against what the simulator draws (issue 29): the turns' perturbations, a
random walk along a flight, and the time marks' jitter carried into the image x. Monte Carlo over simulated flights
(no adjustment: the priors and σ are compared with the draws they describe), a few seconds."""

from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np
import pytest

from seaice_jax.adjust.radar.block import BlockOptions, image_sigmas
from seaice_jax.adjust.radar.layout import block_unknowns, mark_weight
from seaice_jax.adjust.radar.navigation_basis import navigation_basis
from seaice_jax.errors import SeaiceError
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


@pytest.mark.parametrize("strips", [6, 10])
def test_the_drift_prior_is_the_drift_the_simulator_draws_over_the_curve(strips):
    """The drift coefficient of a navigation curve (rate × its time span, per component) has the prior σ
    drift_rate_prior × span, in flight scope (the flight's span) and strip scope (the strip's). The simulated INS
    drifts 0.75 km/h in a random direction, so per flight the north and east coefficients' squares add up to
    (0.75 km/h × span)² whatever the direction: their mean over the components over σ² is 1 to 1 % on every flight.
    The fixed σ before (1.5 km per flight, 130 m per strip) was 0.77 or 1.09 of that for flights of 6 or 10 strips."""
    plan = FlightPlan(strips=strips)
    errors = ErrorModel().only("drift_rate")
    for scope in ("flight", "strip"):
        for k in range(3):
            records, truths = simulate_flight(plan, errors, np.random.default_rng(980_000 + k), take_off_time=3600.0)
            times = np.concatenate([r.record_times for r in records])
            error = np.concatenate([t.navigation_error for t in truths])
            rate = np.linalg.lstsq(np.stack([np.ones_like(times), times], 1), error, rcond=None)[0][1]  # (2,) m/s
            names, sigma, _, _, _ = block_unknowns([SimpleNamespace(name="day 0", strips=records)],
                                                   BlockOptions(navigation_scope=scope))
            span = (records[-1].end_time - records[0].start_time if scope == "flight"
                    else records[0].end_time - records[0].start_time)
            drift = [i for i, name in enumerate(names) if name.endswith(" rate")]
            assert len(drift) == 2 * (1 if scope == "flight" else strips)
            np.testing.assert_allclose(np.mean((rate * span) ** 2) / sigma[drift] ** 2, 1.0, rtol=0.01)


STRIP_FLIGHTS = 200


@pytest.fixture(scope="module")
def strip_scope_truth():
    """The true strip-scope navigation coefficients ``(F, strips, component, term)`` (offset, rate, Schuler sine,
    cosine of each strip's own curve about its middle) of ``STRIP_FLIGHTS`` simulated flights with the INS errors
    only (drift, Schuler oscillation, turns), flown an hour after take-off as in the AIDJEX scenario, and the
    strip-scope priors ``(strips, component, term)`` the block gives them."""
    errors = ErrorModel().only("drift_rate", "schuler_amplitude", "turn_perturbation")
    truth = []
    for k in range(STRIP_FLIGHTS):
        records, strips = simulate_flight(PLAN, errors, np.random.default_rng(950_000 + k), take_off_time=3600.0)
        flight = []
        for record, strip in zip(records, strips, strict=True):
            basis, _ = navigation_basis("schuler", record.record_times, (record.start_time, record.end_time))
            flight.append(np.linalg.lstsq(basis, strip.navigation_error, rcond=None)[0].T)  # (component, term)
        truth.append(flight)
    coverage = SimpleNamespace(name="day 0", strips=records)
    names, sigma, _, _, q = block_unknowns([coverage], BlockOptions(navigation_scope="strip"))
    navigation = [i for i, name in enumerate(names) if " navigation " in name]
    assert q == 4 and len(navigation) == PLAN.strips * 2 * q
    return np.array(truth), sigma[navigation].reshape(PLAN.strips, 2, q)


def test_the_strip_scope_priors_are_the_errors_the_simulator_draws(strip_scope_truth):
    """Strip scope: each strip's own offset is the INS error accumulated by its middle (drift since take-off and the
    turns' random walk), so its prior grows along the flight; the Schuler terms have the north and east channels'
    own σ. On simulated flights the true coefficients over their prior σ have unit mean square per strip and per
    component (tolerance: 4 standard errors over the flights, whose drift direction and Schuler phase are shared by
    their strips). The model before (one offset σ 1.5 km for every strip, one Schuler σ 1.3 km) fails: the first
    strip's offsets and the east Schuler terms at about 0.16 and 0.43."""
    truth, sigma = strip_scope_truth
    ratio = (truth / sigma[None]) ** 2  # (F, strips, component, term)

    def check(values, expected=1.0):
        per_flight = values.reshape(values.shape[0], -1).mean(axis=1)
        tolerance = 4 * per_flight.std(ddof=1) / np.sqrt(per_flight.size)
        return abs(per_flight.mean() - expected) < tolerance, per_flight.mean(), tolerance

    for strip in (0, PLAN.strips // 2, PLAN.strips - 1):
        for component in range(2):
            ok, mean, tolerance = check(ratio[:, strip, component, 0])
            assert ok, f"strip {strip} component {component}: offsets' mean square {mean:.2f} (±{tolerance:.2f})"
    for component in range(2):
        for term in (1, 2, 3):
            ok, mean, tolerance = check(ratio[:, :, component, term])
            assert ok, f"component {component} term {term}: mean square {mean:.2f} (±{tolerance:.2f})"

    before = (truth / np.array([1500.0, 130.0, 1300.0, 1300.0])) ** 2  # issue 12's strip-scope priors
    assert not check(before[:, 0, 0, 0])[0]
    assert not check(before[:, :, 1, 2:])[0]


@pytest.mark.parametrize("value", ["large", (1400.0, 850.0, 1.0), (-1.0, 850.0), 0.0])
def test_a_schuler_prior_that_is_not_one_or_two_sigmas_is_refused(value):
    with pytest.raises(SeaiceError, match="schuler_prior must be a σ in metres, a \\(north, east\\) pair"):
        BlockOptions(schuler_prior=value)
