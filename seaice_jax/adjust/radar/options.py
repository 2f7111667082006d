"""Options of the radar block adjustment (:func:`~.block.simultaneous_block`): the navigation-error
model and its scope, the stochastic model's defaults (what each σ stands for), the solver and the quality control."""

from dataclasses import dataclass

from seaice_jax.adjust.engine.quality import DEFAULT_ALPHA
from seaice_jax.adjust.engine.variance import ROBUST
from seaice_jax.errors import SeaiceError
from seaice_jax.sensors.navigation import ERROR_MODELS

SOLVERS = ("auto", "dense", "schur")
DENSE_LIMIT = 400
"""Unknowns up to which ``solver="auto"`` uses the dense backend."""


SCOPE_OFFSET_PRIOR = {"flight": 600.0, "strip": 1500.0}
"""Default σ (m) of the navigation offsets per scope: a flight's curve starts from the INS alignment error and the
drift before its first strip; a strip's own curve carries everything accumulated by then (the drift since take-off
and the turns' perturbations, its Schuler terms apart: 0.6-2.2 km per component from 1 to 4 h after take-off with
the defaults' INS and 300 m per turn, 1.5 km RMS; 2 km, the default before issue 29, was loose)."""

SCOPE_SHAPE_PRIOR = {"flight": 1500.0, "strip": 130.0}
"""Default σ (m) of the navigation drift coefficient (rate × the curve's time span) per scope: an INS drifting
0.75 km/h in an unknown direction (0.53 km/h per component) over a flight of about 3 h, or over one 15-min strip
(the strip's own curve; the flight's 1.5 km there left the strips' drift 11 times looser than the INS: σ̂0 0.988 and
the global test rejecting 15 % of strip-scope blocks, issue 29)."""


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
        shape_prior: σ (m) of the other navigation coefficients: rate × strip (or flight) duration, Schuler
            amplitudes (``None``: no prior; ``"scope"``: by the navigation scope, :data:`SCOPE_SHAPE_PRIOR`).
        schuler_prior: σ (m) of the Schuler sine and cosine amplitudes if they differ from ``shape_prior`` (the
            INS drift over a short flight is far smaller than its Schuler oscillation).
        take_off_time: s on the strips' clock when the flights took off (flight scope; ``None``: unknown). The
            flight's curve then starts at take-off: its offset is the INS alignment error (``offset_prior``) and its
            drift grows from zero there, so the drift accumulated before the first strip is tied to the drift
            the ties see (without it the flight's offset at its first strip has to carry that drift).
        turn_prior: σ (m) of the INS perturbation of one turn (flight scope): the perturbations add up along the
            flight, a random walk, so the prior is on the difference of consecutive strips' offsets (σ turn_prior
            each; the first strip's offset is the flight's reference, 0), which gives strip k the marginal σ
            turn_prior·√k and strips j, k the covariance turn_prior²·min(j, k) (``None``: no prior).
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
    0.044-0.047 mm in all, 0.045 mm RMS between the marks); an offset of 600 m for a flight's curve (alignment and
    the drift before its first strip) or 1.5 km for a strip's own curve (all the error accumulated by then), a drift
    of 1.5 km over a flight (130 m over a strip) and a Schuler oscillation of 1.3 km amplitude; 300 m per turn (a
    random walk over the strips) and 3 m of low-frequency record noise left over a strip by the 180-s filter; each
    strip's sweep delay known to 0.4 mm and its range scale to 0.5 %. On blunder-free simulated AIDJEX blocks they
    give σ̂0 ≈ 1, the global and w-tests their false-alarm rates and predicted σ that match the errors
    (``experiments/block_statistics.py``); other platforms need their own.
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
    schuler_prior: float | None = 1300.0
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

    def resolved_shape_prior(self) -> float | None:
        """σ (m) of the drift coefficient (and of the Schuler terms without ``schuler_prior``): ``shape_prior``, or
        by the scope when it is ``"scope"``."""
        if self.shape_prior == "scope":
            return SCOPE_SHAPE_PRIOR[self.navigation_scope]
        return None if self.shape_prior is None else float(self.shape_prior)

    def __post_init__(self):
        for name in ("offset_prior", "shape_prior"):
            value = getattr(self, name)
            if isinstance(value, str) and value != "scope":
                raise SeaiceError(f"{name} must be a σ in metres, None or 'scope', got {value!r}")
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
