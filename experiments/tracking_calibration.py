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
fitted values rounded) are then checked on fresh seeds: the ratio of the empirical to the stated σ,
RMS(error / σ) per axis, overall, by quartile of the stated σ and by noise level, with a 90 % interval from
resampling whole seeds (neighbouring vectors share pixels and noise; a seed is the independent unit).

Writes experiments/results/tracking_calibration.md.
Run: ``.venv/bin/python experiments/tracking_calibration.py [--tune 0 30] [--check 1000 1030]``.
"""

import argparse
import os
import time
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from seaice_jax import MapGrid, TrackingOptions, remap, simulate_sequence, track
from seaice_jax.imagery.tracking import CORRELATION_AREA, MIXED_MOTION, MIXED_MOTION_THRESHOLD, SIGMA_FLOOR
from seaice_jax.simulate.satellite import land_mask, true_displacement

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
    defaults) and ``land_in_patch`` (of those, for land in the patch) ``(n,)``, and the seed's noise level."""
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
    raw = TrackingOptions(correlation_area=1.0, sigma_floor=0.0, mixed_motion_threshold=None)
    d = track(a, b, raw, valid_first=valid_a, valid_second=valid_b, land=land)
    product = track(a, b, valid_first=valid_a, valid_second=valid_b, land=land).status  # the package's defaults
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
            "mixed": (product == MIXED_MOTION)[good], "land_in_patch": (d.status == MIXED_MOTION)[good],
            "noise": noise, "tracked": int(d.status.size)}


def collect(seeds) -> list[dict]:
    runs = []
    for seed in seeds:
        begin = time.perf_counter()
        run = pair_errors(seed)
        runs.append({**run, "seed": seed})
        print(f"seed {seed}: noise {run['noise']:.3f}, {len(run['error'])} good vectors "
              f"({run['uniform'].sum()} of one motion), {time.perf_counter() - begin:.1f} s", flush=True)
    return runs


def fit(runs) -> tuple[float, float]:
    """``(correlation_area κ, sigma_floor f)``: maximum likelihood of the errors of one motion under
    N(0, f² + κ C₁), both axes pooled."""
    error = np.concatenate([r["error"][r["uniform"]].ravel() for r in runs])
    c1 = np.concatenate([r["c1"][r["uniform"]].ravel() for r in runs])

    def negative_log_likelihood(log_parameters):
        kappa, floor = np.exp(log_parameters)
        variance = floor**2 + kappa * c1
        return float(np.sum(error**2 / variance + np.log(variance)))

    result = minimize(negative_log_likelihood, np.log([3.0, 0.05]), method="Nelder-Mead",
                      options={"xatol": 1e-6, "fatol": 1e-8})
    kappa, floor = np.exp(result.x)
    return float(kappa), float(floor)


def ratios(runs, correlation_area: float, sigma_floor: float, select) -> tuple[np.ndarray, float, tuple]:
    """RMS(error/σ) of the vectors ``select(run) -> (n,) bool``: ``((2,) per axis, both axes, 90 % interval of
    both from resampling whole seeds)``."""
    normalised = []
    for r in runs:
        sigma = np.sqrt(sigma_floor**2 + correlation_area * r["c1"])
        normalised.append((r["error"] / sigma)[select(r)])
    normalised = [n for n in normalised if n.size]  # seeds without such vectors do not count
    per_axis = np.sqrt(np.mean(np.concatenate(normalised) ** 2, axis=0))
    both = float(np.sqrt(np.mean(np.concatenate(normalised) ** 2)))
    rng = np.random.default_rng(0)
    sums = np.array([np.sum(n**2) for n in normalised])
    counts = np.array([n.size for n in normalised])
    draws = rng.integers(0, len(normalised), (RESAMPLES, len(normalised)))
    resampled = np.sqrt(sums[draws].sum(axis=1) / counts[draws].sum(axis=1))
    return per_axis, both, tuple(np.percentile(resampled, [5, 95]))


def table(runs, correlation_area, sigma_floor, detail: bool = True) -> list[str]:
    """Rows: every vector of one motion (good before the mixed-motion flag: the σ model's domain), with ``detail``
    by quartile of stated σ (of the pooled set) and by noise level; then the vectors across two motions, all before
    the flag, those the flag takes (one motion: false alarms, two: detections) and those it leaves good."""
    sigma_all = np.concatenate([np.sqrt(sigma_floor**2 + correlation_area * r["c1"][r["uniform"]]).mean(axis=1)
                                for r in runs])
    edges = np.percentile(sigma_all, [0, 25, 50, 75, 100])
    edges[-1] = np.inf

    def line(label, select):
        per_axis, both, (low, high) = ratios(runs, correlation_area, sigma_floor, select)
        count = sum(int(select(r).sum()) for r in runs)
        stated = np.concatenate([np.sqrt(sigma_floor**2 + correlation_area * r["c1"][select(r)]) for r in runs])
        empirical = np.concatenate([r["error"][select(r)] for r in runs])
        return (f"| {label} | {count} | {np.sqrt(np.mean(stated**2)):.3f} | {np.sqrt(np.mean(empirical**2)):.3f} | "
                f"{per_axis[0]:.2f} / {per_axis[1]:.2f} | **{both:.2f}** ({low:.2f}-{high:.2f}) |")

    def quartile(k):
        def select(r):
            s = np.sqrt(sigma_floor**2 + correlation_area * r["c1"]).mean(axis=1)
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


def flag_rates(runs) -> str:
    """The mixed-motion flag's rate among the vectors of one motion (false alarms) and across two (detections), with
    the part for land in the patch, and 95 % Wilson intervals."""
    def rate(select):
        flagged = sum(int((select(r) & r["mixed"]).sum()) for r in runs)
        land = sum(int((select(r) & r["land_in_patch"]).sum()) for r in runs)
        count = sum(int(select(r).sum()) for r in runs)
        low, high = _wilson(flagged, count)
        return (f"{flagged}/{count} = {100 * flagged / count:.1f} % ({100 * low:.1f}-{100 * high:.1f} %; land in the "
                f"patch {100 * land / count:.1f} %, the neighbour test {100 * (flagged - land) / count:.1f} %)")

    return (f"Flagged mixed motion: of one motion {rate(one_motion)} (false alarms); across two motions "
            f"{rate(two_motions)} (detections).")


def _wilson(successes: int, trials: int, z: float = 1.959964) -> tuple[float, float]:
    """95 % Wilson score interval of a binomial proportion."""
    p = successes / trials
    centre = (p + z**2 / (2 * trials)) / (1 + z**2 / trials)
    half = z / (1 + z**2 / trials) * np.sqrt(p * (1 - p) / trials + z**2 / (4 * trials**2))
    return max(centre - half, 0.0), min(centre + half, 1.0)


def one_motion(run) -> np.ndarray:
    return run["uniform"]


def two_motions(run) -> np.ndarray:
    return ~run["uniform"]


def gross(runs, correlation_area, sigma_floor, select) -> str:
    errors = np.concatenate([(r["error"] / np.sqrt(sigma_floor**2 + correlation_area * r["c1"]))[select(r)]
                             for r in runs])
    beyond = np.abs(errors).max(axis=1)
    return f"{np.mean(beyond > 3) * 100:.1f} % beyond 3σ, {np.mean(beyond > 5) * 100:.1f} % beyond 5σ"


def main():
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--tune", type=int, nargs=2, default=(0, 30), metavar=("FIRST", "END"))
    parser.add_argument("--check", type=int, nargs=2, default=(1000, 1030), metavar=("FIRST", "END"))
    args = parser.parse_args()
    begin = time.perf_counter()
    tuning = collect(range(*args.tune))
    kappa, floor = fit(tuning)
    print(f"fitted: correlation_area {kappa:.3f}, sigma_floor {floor:.4f} px", flush=True)
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
        "at the start (grid pixels). σ² = sigma_floor² + correlation_area · C₁ per axis, C₁ = 2(1 − ρ)/N (−H)⁻¹. "
        "Vectors are counted if good before the mixed-motion test; the package flags as `MIXED_MOTION` (OSI SAF "
        "close_to_coast_or_edge) those with land in their patch and those whose neighbour test (χ² per degree of "
        f"freedom of the vector and its 8 satellite patches about their mean) exceeds {MIXED_MOTION_THRESHOLD} "
        "(tuned on seeds 0-29 and 64000-64029); the product's good vectors are those left.",
        "",
        f"Run: `.venv/bin/python experiments/tracking_calibration.py --tune {args.tune[0]} {args.tune[1]} --check "
        f"{args.check[0]} {args.check[1]}` ({seconds:.0f} s, load average {load[0]:.2f} / {load[1]:.2f} / "
        f"{load[2]:.2f} at the end, 2 cores).",
        "",
        f"Fitted by maximum likelihood on the tuning seeds {args.tune[0]}-{args.tune[1] - 1} (vectors of one motion): "
        f"correlation_area {kappa:.3f}, sigma_floor {floor:.4f} px. The package's defaults: correlation_area "
        f"{CORRELATION_AREA}, sigma_floor {SIGMA_FLOOR} px. (Fitted on the fresh seeds instead: {refit[0]:.3f}, "
        f"{refit[1]:.4f} px.)",
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
        *table(fresh, 0.0, 0.2, detail=False),
        "",
    ]
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "tracking_calibration.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
