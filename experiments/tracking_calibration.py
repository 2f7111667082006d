"""Calibration of the per-vector tracking σ (:mod:`seaice_jax.imagery.tracking`) by Monte Carlo against simulated
image pairs whose drift is known.

Each seed simulates two NOAA-7-like 256 x 256 images of Lancaster-Sound-like pack ice one day apart
(:func:`~seaice_jax.simulate.satellite.simulate_sequence`: real GSHHG coast, fast ice, pack ice on an affine
velocity field, no clouds), adds white sensor noise of a level drawn per seed (uniform 0 to ``MAX_NOISE`` of the
0-1 brightness: clean images to a correlation of ~0.9), remaps both with their *true* scan models into a 150 x 150
EPSG:3413 grid at 2.5 km (so the error is the tracking's alone, not the geolocation's), and tracks them as
``seaice track`` does, with the simulated land as the land mask. The error of a good vector is its displacement
minus the true displacement of the surface at its start (grid pixels, per axis).

The σ model is σ² = ``sigma_floor``² + κ C₁ per axis, C₁ = 2 (1 − ρ)/N (−H)⁻¹ the peak covariance with all N
template pixels independent (κ = ``correlation_area``). Both constants are fitted by maximum likelihood (errors
Gaussian with that variance, both axes pooled) on the tuning seeds, over the vectors whose patch sees one motion
(all pack ice or all static within 10 grid pixels of the start: a patch across the fast-ice edge measures a mix of
two motions, which no precision describes; those are reported apart). The package flags such vectors
:data:`~seaice_jax.imagery.tracking.MIXED_MOTION` from what it sees (land in the patch, or its satellite patches
disagreeing, :func:`~seaice_jax.imagery.tracking.neighbour_disagreement`); the tables give the flag's false alarms
(one motion), its detections (two motions) and the ratio of the good vectors it leaves. The package's defaults
(:data:`~seaice_jax.imagery.tracking.CORRELATION_AREA`, :data:`~seaice_jax.imagery.tracking.SIGMA_FLOOR`, the
fitted values rounded) are then checked on fresh seeds. The package scales each σ² by a + b χ²_ν / m, χ²_ν the
neighbour statistic of the vector and m its median over the pair's vectors the flag leaves
(:data:`~seaice_jax.imagery.tracking.DISAGREEMENT_SCALE`, :func:`~seaice_jax.imagery.tracking.disagreement_reference`):
(a, b) are fitted by
maximum likelihood on the good vectors of one motion of the tuning seeds (the constants of the peak model fixed at
the package's), and the tables give the stated σ with that scale (the product's) and, for comparison, without it.
The check: the ratio of the empirical to the stated σ,
RMS(error / σ) per axis, overall, by quartile of the stated σ and by noise level, with a 90 % interval from
resampling whole seeds (neighbouring vectors share pixels and noise; a seed is the independent unit).

Writes experiments/results/tracking_calibration.md.
Run: ``.venv/bin/python experiments/tracking_calibration.py [--tune 0 30] [--tune-more 64000 64030] [--check 1000
1030]`` (``--tune-more``: more tuning seeds for the fit of a, b, as the package's was fitted).
"""

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from seaice_jax import MapGrid, TrackingOptions, remap, simulate_sequence, track
from seaice_jax.imagery.tracking import (
    CORRELATION_AREA,
    DISAGREEMENT_SCALE,
    MIXED_MOTION,
    MIXED_MOTION_THRESHOLD,
    SIGMA_FLOOR,
    disagreement_reference,
    disagreement_variance_scale,
)
from seaice_jax.simulate.satellite import land_mask, true_displacement

sys.path.insert(0, str(Path(__file__).parent))
from block_statistics import wilson  # noqa: E402  (the experiments' one Wilson interval)

RESULTS = Path(__file__).with_name("results")
SIZE = 256
GRID_PIXEL = 2500.0  # m
GRID_SHAPE = 150
MAX_NOISE = 0.08
UNIFORM_MARGIN = 10  # grid pixels around the start that must all be pack ice, or all static
RESAMPLES = 2000


def pair_errors(seed: int) -> dict:
    """The vectors of one simulated pair that are good before the mixed-motion test: ``error``, ``c1`` ``(n, 2)``
    pixels / pixels² (row, column axes), ``correlation``, ``uniform`` (the ground within ``UNIFORM_MARGIN`` of the
    start moves as one), ``mixed`` (flagged :data:`~seaice_jax.imagery.tracking.MIXED_MOTION` by the package's
    defaults), ``land_in_patch`` (of those, for land in the patch) and ``disagreement`` (the neighbour statistic
    χ²_ν of the package's defaults; NaN where not measured) ``(n,)``, and the seed's noise level."""
    noise = float(np.random.default_rng([seed, 1]).uniform(0.0, MAX_NOISE))
    sequence = simulate_sequence(seed, n_images=2, size=SIZE)
    scene, (first, second) = sequence.scene, sequence.images
    latitude, longitude = scene.projection.inverse(*scene.centre)
    grid = MapGrid.centred(scene.projection, latitude, longitude, GRID_PIXEL, GRID_PIXEL, GRID_SHAPE, GRID_SHAPE)
    rng = np.random.default_rng([seed, 2])
    data = [image.data + rng.normal(0.0, noise, image.data.shape) for image in sequence.images]
    (a, b), (valid_a, valid_b) = remap(data, [first.model, second.model], grid)
    land = land_mask(scene, grid)
    # σ² = C₁ per axis, and no neighbour test (its χ² needs the package's σ): good here = good before the flag
    raw = TrackingOptions(correlation_area=1.0, sigma_floor=0.0, mixed_motion_threshold=None,
                          disagreement_scale=None)
    d = track(a, b, raw, valid_first=valid_a, valid_second=valid_b, land=land)
    product = track(a, b, valid_first=valid_a, valid_second=valid_b, land=land)  # the package's defaults
    assert product.disagreement is not None
    x, y = (np.asarray(v) for v in grid.to_xy(d.row, d.column))
    start = np.stack([x, y], -1)
    end = start + true_displacement(scene, start, first.time, second.time)
    true_row, true_column = (np.asarray(v) for v in grid.to_pixel(end[:, 0], end[:, 1]))
    pack = np.asarray(scene.is_pack(start))
    steps = np.linspace(-UNIFORM_MARGIN, UNIFORM_MARGIN, 5) * GRID_PIXEL
    uniform = np.all([np.asarray(scene.is_pack(start + np.array([p, q]))) == pack for p in steps for q in steps],
                     axis=0)
    good = d.good | (d.status == MIXED_MOTION)  # MIXED_MOTION here: land in the patch
    error = np.stack([d.d_row - (true_row - d.row), d.d_column - (true_column - d.column)], 1)[good]
    c1 = np.stack([d.sigma_row, d.sigma_column], 1)[good] ** 2
    return {"error": error, "c1": c1, "correlation": d.correlation[good], "uniform": uniform[good],
            "mixed": (product.status == MIXED_MOTION)[good], "land_in_patch": (d.status == MIXED_MOTION)[good],
            "disagreement": product.disagreement[good], "noise": noise, "tracked": int(d.status.size)}


def stated_sigma(run, correlation_area: float, sigma_floor: float, scale=DISAGREEMENT_SCALE) -> np.ndarray:
    """``(n, 2)`` pixels: the stated σ of ``run``'s vectors, √((sigma_floor² + correlation_area C₁) (a + b χ²_ν /
    m)) with ``scale`` = (a, b) (``None``: σ from the peak alone), m the pair's reference (its statistics are all
    in ``run``), as :func:`~seaice_jax.imagery.tracking.track` states it."""
    variance = sigma_floor**2 + correlation_area * run["c1"]
    if scale is None:
        return np.sqrt(variance)
    factor = disagreement_variance_scale(run["disagreement"], TrackingOptions(disagreement_scale=scale))
    return np.sqrt(variance * factor[:, None])


def collect(seeds) -> list[dict]:
    runs = []
    for seed in seeds:
        begin = time.perf_counter()
        run = pair_errors(seed)
        runs.append({**run, "seed": seed})
        print(f"seed {seed}: noise {run['noise']:.3f}, {len(run['error'])} good vectors "
              f"({run['uniform'].sum()} of one motion), {time.perf_counter() - begin:.1f} s", flush=True)
    return runs


def _gaussian_deviance(error, variance) -> float:
    """−2 log-likelihood (less its constant) of zero-mean normal ``error`` of ``variance`` (∞ where a variance is
    not positive): what :func:`fit` and :func:`fit_scale` minimise."""
    if not np.all(variance > 0):
        return np.inf
    return float(np.sum(error**2 / variance + np.log(variance)))


def fit(runs) -> tuple[float, float]:
    """``(correlation_area κ, sigma_floor f)``: maximum likelihood of the errors of one motion under
    N(0, f² + κ C₁), both axes pooled."""
    error = np.concatenate([r["error"][r["uniform"]].ravel() for r in runs])
    c1 = np.concatenate([r["c1"][r["uniform"]].ravel() for r in runs])

    def negative_log_likelihood(log_parameters):
        kappa, floor = np.exp(log_parameters)
        return _gaussian_deviance(error, floor**2 + kappa * c1)

    result = minimize(negative_log_likelihood, np.log([3.0, 0.05]), method="Nelder-Mead",
                      options={"xatol": 1e-6, "fatol": 1e-8})
    kappa, floor = np.exp(result.x)
    return float(kappa), float(floor)


def fit_scale(runs) -> tuple[float, float]:
    """``(a, b)``: maximum likelihood of the errors of the good vectors of one motion with a neighbour statistic
    χ²_ν under N(0, (SIGMA_FLOOR² + CORRELATION_AREA C₁) (a + b χ²_ν / m)), m the pair's reference, both axes
    pooled."""
    select = [r["uniform"] & ~r["mixed"] & np.isfinite(r["disagreement"]) for r in runs]
    error = np.concatenate([r["error"][s].ravel() for r, s in zip(runs, select, strict=True)])
    variance = np.concatenate([(SIGMA_FLOOR**2 + CORRELATION_AREA * r["c1"][s]).ravel()
                               for r, s in zip(runs, select, strict=True)])
    statistic = np.concatenate([np.repeat(r["disagreement"][s] / disagreement_reference(r["disagreement"]), 2)
                                for r, s in zip(runs, select, strict=True)])

    def negative_log_likelihood(parameters):
        return _gaussian_deviance(error, variance * (parameters[0] + parameters[1] * statistic))

    result = minimize(negative_log_likelihood, [1.0, 0.1], method="Nelder-Mead",
                      options={"xatol": 1e-6, "fatol": 1e-8})
    return float(result.x[0]), float(result.x[1])


def ratios(runs, correlation_area: float, sigma_floor: float, select, scale=DISAGREEMENT_SCALE
           ) -> tuple[np.ndarray, float, tuple]:
    """RMS(error/σ) of the vectors ``select(run) -> (n,) bool``, σ of :func:`stated_sigma`: ``((2,) per axis, both
    axes, 90 % interval of both from resampling whole seeds)``."""
    normalised = []
    for r in runs:
        normalised.append((r["error"] / stated_sigma(r, correlation_area, sigma_floor, scale))[select(r)])
    normalised = [n for n in normalised if n.size]  # seeds without such vectors do not count
    per_axis = np.sqrt(np.mean(np.concatenate(normalised) ** 2, axis=0))
    both = float(np.sqrt(np.mean(np.concatenate(normalised) ** 2)))
    rng = np.random.default_rng(0)
    sums = np.array([np.sum(n**2) for n in normalised])
    counts = np.array([n.size for n in normalised])
    draws = rng.integers(0, len(normalised), (RESAMPLES, len(normalised)))
    resampled = np.sqrt(sums[draws].sum(axis=1) / counts[draws].sum(axis=1))
    return per_axis, both, tuple(np.percentile(resampled, [5, 95]))


def table(runs, correlation_area, sigma_floor, detail: bool = True, scale=DISAGREEMENT_SCALE) -> list[str]:
    """Rows: every vector of one motion (good before the mixed-motion flag: the σ model's domain), with ``detail``
    by quartile of stated σ (of the pooled set) and by noise level; then the vectors across two motions, all before
    the flag, those the flag takes (one motion: false alarms, two: detections) and those it leaves good. σ: of
    :func:`stated_sigma` with ``scale``."""
    sigma_all = np.concatenate([stated_sigma(r, correlation_area, sigma_floor, scale)[r["uniform"]].mean(axis=1)
                                for r in runs])
    edges = np.percentile(sigma_all, [0, 25, 50, 75, 100])
    edges[-1] = np.inf

    def line(label, select):
        per_axis, both, (low, high) = ratios(runs, correlation_area, sigma_floor, select, scale)
        count = sum(int(select(r).sum()) for r in runs)
        stated = np.concatenate([stated_sigma(r, correlation_area, sigma_floor, scale)[select(r)] for r in runs])
        empirical = np.concatenate([r["error"][select(r)] for r in runs])
        return (f"| {label} | {count} | {np.sqrt(np.mean(stated**2)):.3f} | {np.sqrt(np.mean(empirical**2)):.3f} | "
                f"{per_axis[0]:.2f} / {per_axis[1]:.2f} | **{both:.2f}** ({low:.2f}-{high:.2f}) |")

    def quartile(k):
        def select(r):
            s = stated_sigma(r, correlation_area, sigma_floor, scale).mean(axis=1)
            return r["uniform"] & (s >= edges[k]) & (s < edges[k + 1])
        return select

    lines = ["| vectors | count | stated σ, RMS (px) | error, RMS (px) | empirical / stated σ: row / column | both "
             "axes (90 % over seeds) |", "|---|---|---|---|---|---|",
             line("one motion (the calibration's domain)", one_motion)]
    if detail:
        lines += [line(f"one motion, stated σ quartile {k + 1} ({edges[k]:.3f}-{edges[k + 1]:.3f} px)"
                       .replace("-inf", "+"), quartile(k)) for k in range(4)]
        for low, high in ((0.0, MAX_NOISE / 3), (MAX_NOISE / 3, 2 * MAX_NOISE / 3), (2 * MAX_NOISE / 3, MAX_NOISE)):
            lines.append(line(f"one motion, noise {low:.3f}-{high:.3f}",
                              lambda r, low=low, high=high: r["uniform"] & (low <= r["noise"] < high)))
    lines.append(line("across two motions (fast-ice edge or coast)", two_motions))
    lines.append(line("all vectors before the mixed-motion flag", lambda r: np.ones(len(r["uniform"]), bool)))
    lines.append(line("one motion, flagged mixed motion (false alarms)", lambda r: r["uniform"] & r["mixed"]))
    lines.append(line("across two motions, flagged mixed motion (detections)", lambda r: ~r["uniform"] & r["mixed"]))
    lines.append(line("one motion, good (not flagged)", lambda r: r["uniform"] & ~r["mixed"]))
    lines.append(line("across two motions, good (not flagged)", lambda r: ~r["uniform"] & ~r["mixed"]))
    lines.append(line("**all good vectors** (the product's)", lambda r: ~r["mixed"]))
    return lines


DISAGREEMENT_BINS = (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, MIXED_MOTION_THRESHOLD)
"""Bins of the neighbour statistic χ²_ν of :func:`disagreement_table` (the last ends at the flag's threshold)."""


def disagreement_table(runs) -> list[str]:
    """Rows per bin of the neighbour statistic (:data:`DISAGREEMENT_BINS`), the good vectors of one motion and those
    across two motions the flag leaves: RMS(error/σ) both axes (90 % over seeds) with σ from the peak alone and
    with the disagreement scale."""
    lines = ["| χ²_ν | one motion: count | σ from the peak | scaled | across two motions, not flagged: count | σ "
             "from the peak | scaled |", "|---|---|---|---|---|---|---|"]
    bins = [*zip(DISAGREEMENT_BINS[:-1], DISAGREEMENT_BINS[1:], strict=True), (np.nan, np.nan)]
    for low, high in bins:
        cells = []
        for motion in (one_motion, two_motions):
            def select(r, low=low, high=high, motion=motion):
                inside = np.isnan(r["disagreement"]) if np.isnan(low) else (low <= r["disagreement"]) & (
                    r["disagreement"] < high)
                return motion(r) & ~r["mixed"] & inside
            count = sum(int(select(r).sum()) for r in runs)
            cells.append(str(count))
            for scale in (None, DISAGREEMENT_SCALE):
                _, both, (lower, upper) = ratios(runs, CORRELATION_AREA, SIGMA_FLOOR, select, scale) if count else (
                    None, np.nan, (np.nan, np.nan))
                cells.append(f"{both:.2f} ({lower:.2f}-{upper:.2f})")
        label = "not measured" if np.isnan(low) else f"{low:.1f}-{high:.1f}"
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return lines


def flag_rates(runs) -> str:
    """The mixed-motion flag's rate among the vectors of one motion (false alarms) and across two (detections), with
    the part for land in the patch, and 95 % Wilson intervals."""
    def rate(select):
        flagged = sum(int((select(r) & r["mixed"]).sum()) for r in runs)
        land = sum(int((select(r) & r["land_in_patch"]).sum()) for r in runs)
        count = sum(int(select(r).sum()) for r in runs)
        low, high = wilson(flagged, count)
        return (f"{flagged}/{count} = {100 * flagged / count:.1f} % ({100 * low:.1f}-{100 * high:.1f} %; land in the "
                f"patch {100 * land / count:.1f} %, the neighbour test {100 * (flagged - land) / count:.1f} %)")

    return (f"Flagged mixed motion: of one motion {rate(one_motion)} (false alarms); across two motions "
            f"{rate(two_motions)} (detections).")


def one_motion(run) -> np.ndarray:
    return run["uniform"]


def two_motions(run) -> np.ndarray:
    return ~run["uniform"]


def gross(runs, correlation_area, sigma_floor, select) -> str:
    errors = np.concatenate([(r["error"] / stated_sigma(r, correlation_area, sigma_floor))[select(r)] for r in runs])
    beyond = np.abs(errors).max(axis=1)
    return f"{np.mean(beyond > 3) * 100:.1f} % beyond 3σ, {np.mean(beyond > 5) * 100:.1f} % beyond 5σ"


def main():
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--tune", type=int, nargs=2, default=(0, 30), metavar=("FIRST", "END"))
    parser.add_argument("--tune-more", type=int, nargs=2, default=(64000, 64030), metavar=("FIRST", "END"),
                        help="more tuning seeds for the fit of the disagreement scale (a, b)")
    parser.add_argument("--check", type=int, nargs=2, default=(1000, 1030), metavar=("FIRST", "END"))
    args = parser.parse_args()
    begin = time.perf_counter()
    tuning = collect(range(*args.tune))
    kappa, floor = fit(tuning)
    print(f"fitted: correlation_area {kappa:.3f}, sigma_floor {floor:.4f} px", flush=True)
    more = collect(range(*args.tune_more))
    scale, scale_first, scale_more = fit_scale(tuning + more), fit_scale(tuning), fit_scale(more)
    fresh = collect(range(*args.check))
    refit = fit(fresh)
    seconds = time.perf_counter() - begin
    load = os.getloadavg()
    lines = [
        "# Calibration of the per-vector tracking σ (experiments/tracking_calibration.py)",
        "",
        f"Per seed: two simulated NOAA-7-like {SIZE} x {SIZE} images one day apart (GSHHG coast, fast ice, pack ice "
        f"on an affine field, no clouds), white noise of a level drawn uniformly in 0-{MAX_NOISE} (brightness 0-1), "
        f"remapped with the true models into a {GRID_SHAPE} x {GRID_SHAPE} grid of {GRID_PIXEL:.0f} m, tracked "
        "with the defaults of `seaice track` and the scene's land as mask; error = tracked minus true displacement "
        "at the start (grid pixels). σ² = (sigma_floor² + correlation_area · C₁) (a + b χ²_ν / m) per axis, C₁ = "
        "2(1 − ρ)/N (−H)⁻¹, χ²_ν the neighbour statistic below, m its median over the pair's vectors the flag "
        "leaves (a + b χ²_ν / m = 1 where it is not measured). "
        "Vectors are counted if good before the mixed-motion test; the package flags as `MIXED_MOTION` (OSI SAF "
        "close_to_coast_or_edge) those with land in their patch and those whose neighbour test (χ² per degree of "
        f"freedom of the vector and its 8 satellite patches about their mean) exceeds {MIXED_MOTION_THRESHOLD} "
        "(tuned on seeds 0-29 and 64000-64029); the product's good vectors are those left.",
        "",
        f"Run: `.venv/bin/python experiments/tracking_calibration.py --tune {args.tune[0]} {args.tune[1]} "
        f"--tune-more {args.tune_more[0]} {args.tune_more[1]} --check {args.check[0]} {args.check[1]}` "
        f"({seconds:.0f} s, load average {load[0]:.2f} / {load[1]:.2f} / "
        f"{load[2]:.2f} at the end, 2 cores).",
        "",
        f"Fitted by maximum likelihood on the tuning seeds {args.tune[0]}-{args.tune[1] - 1} (vectors of one motion): "
        f"correlation_area {kappa:.3f}, sigma_floor {floor:.4f} px. The package's defaults: correlation_area "
        f"{CORRELATION_AREA}, sigma_floor {SIGMA_FLOOR} px. (Fitted on the fresh seeds instead: {refit[0]:.3f}, "
        f"{refit[1]:.4f} px.)",
        "",
        f"Disagreement scale fitted by maximum likelihood on the good vectors of one motion of the tuning seeds "
        f"{args.tune[0]}-{args.tune[1] - 1} and {args.tune_more[0]}-{args.tune_more[1] - 1}: a {scale[0]:.3f}, b "
        f"{scale[1]:.3f} (on each part: {scale_first[0]:.3f}, {scale_first[1]:.3f} and {scale_more[0]:.3f}, "
        f"{scale_more[1]:.3f}). The package's: a {DISAGREEMENT_SCALE[0]}, b {DISAGREEMENT_SCALE[1]}.",
        "",
        f"## Fresh seeds {args.check[0]}-{args.check[1] - 1} (not tuned on), the package's defaults",
        "",
        *table(fresh, CORRELATION_AREA, SIGMA_FLOOR),
        "",
        f"Gross errors: of one motion {gross(fresh, CORRELATION_AREA, SIGMA_FLOOR, one_motion)}; across two "
        f"motions {gross(fresh, CORRELATION_AREA, SIGMA_FLOOR, two_motions)}; good across two motions (not "
        f"flagged) {gross(fresh, CORRELATION_AREA, SIGMA_FLOOR, lambda r: ~r['uniform'] & ~r['mixed'])}.",
        "",
        flag_rates(fresh),
        "",
        f"## Fresh seeds {args.check[0]}-{args.check[1] - 1} by the neighbour statistic χ²_ν: σ from the peak alone "
        "and with the disagreement scale",
        "",
        *disagreement_table(fresh),
        "",
        f"## Fresh seeds {args.check[0]}-{args.check[1] - 1}, σ from the peak alone (no disagreement scale)",
        "",
        *table(fresh, CORRELATION_AREA, SIGMA_FLOOR, detail=False, scale=None),
        "",
        f"## Tuning seeds {args.tune[0]}-{args.tune[1] - 1}, the package's defaults",
        "",
        *table(tuning, CORRELATION_AREA, SIGMA_FLOOR),
        "",
        f"Gross errors: of one motion {gross(tuning, CORRELATION_AREA, SIGMA_FLOOR, one_motion)}; across two "
        f"motions {gross(tuning, CORRELATION_AREA, SIGMA_FLOOR, two_motions)}; good across two motions (not "
        f"flagged) {gross(tuning, CORRELATION_AREA, SIGMA_FLOOR, lambda r: ~r['uniform'] & ~r['mixed'])}.",
        "",
        flag_rates(tuning),
        "",
        "## Before: the former constant 0.2 pixel per axis, fresh seeds",
        "",
        *table(fresh, 0.0, 0.2, detail=False, scale=None),
        "",
    ]
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "tracking_calibration.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
