"""Options of the radar block adjustment (:func:`~.block.simultaneous_block`): the navigation-error
model and its scope, the stochastic model's defaults (what each σ stands for), the solver and the quality control."""

from dataclasses import dataclass

import numpy as np

from seaice_jax.adjust.engine.quality import DEFAULT_ALPHA
from seaice_jax.adjust.engine.variance import ROBUST
from seaice_jax.errors import SeaiceError
from seaice_jax.sensors.navigation import ERROR_MODELS

SOLVERS = ("auto", "dense", "schur")
DENSE_LIMIT = 400
"""Unknowns up to which ``solver="auto"`` uses the dense backend."""


SCOPE_OFFSET_PRIOR = {"flight": 530.0, "strip": 530.0}
"""Default σ (m) of the navigation offset at a flight's first strip, per scope: the INS drift before that strip (530 m
per component: 0.75 km/h in an unknown direction over the hour from take-off; 600 m before issue 29's strip model,
whose flight-scope residuals had 0.75-0.84 of their expected square sum). A flight's curve starts there; in strip
scope each later strip's own offset carries more, the drift and the turns' perturbations accumulated since
(:meth:`BlockOptions.accumulated_offset_prior`: 0.6-2.3 km per component from 1 to 4 h after take-off with the
defaults' INS and 300 m per turn). Before issue 29 the strip scope took one σ for every strip (2 km, then 1.5 km):
its priors' residuals had 0.44-0.55 of their expected square sum (1.5 km is 2.5 times the first strips' errors and
0.65 of the last ones') and σ̂0 0.992-0.996."""

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
        image_sigma: ``(σx, σy)`` mm of reading the image measurements (along track, slant range).
        time_mark_sigma: σ (mm, along the film) of each time mark's position, independent from mark to mark (the
            marks' jitter and their reading). Eq. A1 interpolates a point's time between the two marks around it
            (u its fraction of the way), so its along-track coordinate gains the variance
            ((1 − u)² + u²) time_mark_sigma² (``None`` or 0: the marks are exact).
        altimeter_sigma: m.
        offset_prior: σ (m) of the navigation offsets and spline values (``None``: no prior; ``"scope"``: by the
            navigation scope, :data:`SCOPE_OFFSET_PRIOR`).
        shape_prior: σ (m) of the other navigation coefficients: the drift coefficient (rate × the curve's time
            span) and the Schuler amplitudes without ``schuler_prior`` (``None``: no prior; ``"scope"``:
            ``drift_rate_prior`` × the span of each curve, the flight's or the strip's, :meth:`drift_prior`).
        schuler_prior: σ (m) of the Schuler sine and cosine amplitudes if they differ from ``shape_prior`` (the
            INS drift over a short flight is far smaller than its Schuler oscillation): one σ, or ``(north, east)``
            (an INS's north and east channels oscillate with different amplitudes). With a random phase each
            coefficient of an oscillation of amplitude A has σ A/√2: the default (1400, 850) m is the simulated
            INS's 2 km north and 1.2 km east (1.3 km for both before: the north terms' residuals had 1.2-1.5 and
            the east ones' 0.4-0.7 of their expected square sum, in either scope).
        drift_rate_prior: σ (m/s, per component) of the INS drift rate. The drift coefficient of a curve spanning
            T seconds has σ drift_rate_prior·T (``shape_prior="scope"``: the flight's in flight scope, the strip's
            in strip scope); in strip scope a strip's own offset is the error accumulated since the flight began,
            so its σ grows with the strip's time (:meth:`accumulated_offset_prior`; ``None``: no growth, and no
            drift prior by scope). The default 530 m/h: 0.75 km/h in an unknown direction.
        take_off_time: s on the strips' clock when the flights took off (``None``: unknown). In flight scope the
            flight's curve then starts at take-off: its offset is the INS alignment error (``offset_prior``) and its
            drift grows from zero there, so the drift accumulated before the first strip is tied to the drift
            the ties see (without it the flight's offset at its first strip has to carry that drift). In strip
            scope the strips' offset priors grow from take-off (:meth:`accumulated_offset_prior`).
        turn_prior: σ (m) of the INS perturbation of one turn. Flight scope: the perturbations add up along the
            flight, a random walk, so the prior is on the difference of consecutive strips' offsets (σ turn_prior
            each; the first strip's offset is the flight's reference, 0), which gives strip k the marginal σ
            turn_prior·√k and strips j, k the covariance turn_prior²·min(j, k) (``None``: no prior). Strip scope:
            strip k's own offset prior includes the k turns' turn_prior·√k.
        deviation_prior: σ (m) of each strip's linear deviation from the flight's curve (its change over the
            strip; flight scope only): the low-frequency part of the record noise that the filter lets through
            (``None``: no prior). The default 3 m: the 180-s filter's trajectory through records with 30 m and
            0.03 m/s of white noise changes by 3.0 m RMS per component over a 15-min strip (25 m before issue 29:
            its w-tested residuals had 0.37 of their expected square sum).
        sweep_delay_prior: σ of Δc, mm. range_scale_prior: σ of Δf relative to f0.
        static_points: land: one position per point for all coverages (no drift).
        solver: ``"auto"``, ``"dense"`` or ``"schur"``.
        max_iterations, tolerance: Gauss-Newton stops when no unknown changes by more than ``tolerance`` (m, mm)
            or the step is smaller than ``tolerance`` standard deviations (ΔᵀNΔ < tolerance²).
        alpha: significance level of the w-tests that flag blunders.
        variance_components: estimate a variance factor for the image x and y coordinates, the nadir returns and
            the control points (iterated Förstner/Helmert, :func:`~..engine.variance.variance_components`)
            and adjust with the σ rescaled by them.
        robust: ``None``, ``"huber"`` or ``"danish"``: iteratively reweighted (the w-tests of the final weights).

    The default σ describe an AIDJEX-era inertial platform and film (sources 000, 002): 0.04 mm of film reading
    along track and in slant range, time marks placed to 0.025 mm along the film (0.05 s at 0.5 mm/s: along track
    0.044-0.047 mm in all, 0.045 mm RMS between the marks); an offset of 530 m at a flight's first strip (the drift
    in the hour before it; a later strip's own curve adds the drift and turns since), a drift of 530 m/h per
    component (1.56 km over a 2.95-h flight, 133 m over a 15-min strip) and a Schuler oscillation of 2 km north and
    1.2 km east (coefficients' σ 1.4 and 0.85 km); 300 m per turn (a random walk over the strips) and 3 m of
    low-frequency record noise left over a strip by the 180-s filter; each strip's sweep delay known to 0.4 mm and
    its range scale to 0.5 %. On blunder-free simulated AIDJEX blocks they give σ̂0 ≈ 1, the global and w-tests
    their false-alarm rates and predicted σ that match the errors (``experiments/block_statistics.py``); other
    platforms need their own.
    """

    navigation_model: str = "schuler"
    navigation_scope: str = "flight"
    knot_spacing: float = 300.0
    radar_constants: str = "strip"
    filter_window: float | None = 180.0
    image_sigma: tuple[float, float] = (0.04, 0.04)
    time_mark_sigma: float | None = 0.025
    altimeter_sigma: float = 5.0
    offset_prior: float | str | None = "scope"
    shape_prior: float | str | None = "scope"
    schuler_prior: float | tuple[float, float] | None = (1400.0, 850.0)
    drift_rate_prior: float | None = 530.0 / 3600.0
    take_off_time: float | None = None
    turn_prior: float | None = 300.0
    deviation_prior: float | None = 3.0
    sweep_delay_prior: float | None = 0.4
    range_scale_prior: float | None = 0.005
    static_points: bool = False
    solver: str = "auto"
    max_iterations: int = 15
    tolerance: float = 1e-4
    alpha: float = DEFAULT_ALPHA
    variance_components: bool = False
    robust: str | None = None

    def resolved_offset_prior(self) -> float | None:
        """σ (m) of the navigation offsets: ``offset_prior``, or by the scope when it is ``"scope"``."""
        if self.offset_prior == "scope":
            return SCOPE_OFFSET_PRIOR[self.navigation_scope]
        return None if self.offset_prior is None else float(self.offset_prior)

    def accumulated_offset_prior(self, time: float, turns: int, first_start: float) -> float | None:
        """σ (m, per component) of a strip's own navigation offset in strip scope: the INS error accumulated by
        ``time`` (s, the strip's middle, where its offset is the error), after ``turns`` turns since the flight's
        first strip, which started at ``first_start`` s (``None``: no offset prior).

        The drift keeps its direction through a flight, so its part grows linearly in time, not in quadrature: from
        the offset σ at the first strip's start σ0 (``offset_prior``: alignment and the drift before it),
        σ0 + σ_ḋ (t − t_first); with ``take_off_time`` known, from the alignment error σ0 at take-off,
        √(σ0² + σ_ḋ² (t − t_take-off)²). The turns' perturbations add in quadrature (a random walk):
        σ² = σ_drift² + turns · turn_prior². σ_ḋ is ``drift_rate_prior`` (no growth when ``None``)."""
        base = self.resolved_offset_prior()
        if base is None:
            return None
        rate = self.drift_rate_prior or 0.0
        if self.take_off_time is not None:
            drift = float(np.hypot(base, rate * (time - self.take_off_time)))
        else:
            drift = base + rate * (time - first_start)
        return float(np.sqrt(drift**2 + (self.turn_prior or 0.0) ** 2 * turns))

    def drift_prior(self, span: float) -> float | None:
        """σ (m, per component) of the drift coefficient of a navigation curve spanning ``span`` s (and of its
        Schuler terms without ``schuler_prior``): ``shape_prior``, or with ``"scope"`` the drift accumulated over
        the span, ``drift_rate_prior`` × ``span`` (``None``: no prior).

        Issue 29: a fixed 1.5 km for the flight scope (the drift over "about 3 h") was 4 % small for the simulated
        AIDJEX flights of 2.95 h (1.56 km): the drift priors' w² was 1.09 ± 0.02 over 1400 blocks, 1.00 with the
        span (``experiments/results/calibration.md``)."""
        if self.shape_prior == "scope":
            return None if self.drift_rate_prior is None else float(self.drift_rate_prior * span)
        return None if self.shape_prior is None else float(self.shape_prior)

    def __post_init__(self):
        for name in ("offset_prior", "shape_prior"):
            value = getattr(self, name)
            if isinstance(value, str) and value != "scope":
                raise SeaiceError(f"{name} must be a σ in metres, None or 'scope', got {value!r}")
        if self.schuler_prior is not None:
            try:
                schuler = np.asarray(self.schuler_prior, float)
            except (TypeError, ValueError):
                schuler = np.zeros(0)
            if schuler.size not in (1, 2) or not np.all(schuler > 0):
                raise SeaiceError(f"schuler_prior must be a σ in metres, a (north, east) pair of them or None, got "
                                  f"{self.schuler_prior!r}")
        if self.drift_rate_prior is not None and not self.drift_rate_prior >= 0:
            raise SeaiceError(f"drift_rate_prior must be a σ in m/s (≥ 0) or None, got {self.drift_rate_prior!r}")
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
        if self.time_mark_sigma is not None and not self.time_mark_sigma >= 0:
            raise SeaiceError(f"time_mark_sigma must be a σ in mm (≥ 0) or None, got {self.time_mark_sigma!r}")
        if self.robust is not None and self.robust not in ROBUST:
            raise SeaiceError(f"robust must be None or one of {', '.join(ROBUST)}, got {self.robust!r}")
        if self.solver not in SOLVERS:
            raise SeaiceError(f"solver must be one of {', '.join(SOLVERS)}, got {self.solver!r}")
        if self.variance_components and self.robust is not None:
            raise SeaiceError("variance_components and robust are alternatives (the robust weights would be "
                              "rescaled away): choose one")
