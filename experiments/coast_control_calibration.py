"""Calibration of the σ of the control points found on the coastline (:mod:`seaice_jax.imagery.coast_control`)
by Monte Carlo against simulated images whose scan model is known.

One simulated NOAA-7-like 512 x 512 image of Lancaster Sound per seed, set up as ``experiments/coast_control.py``
sets up its images (its ``k``-th image with ``k`` = seed: pass direction, subtrack on or off the image, the pack
ice at its own time, a rough start 0.5° off in the node and 20 km along the track), each seed with its own scene
(ice texture) and pass. :func:`~seaice_jax.imagery.coast_control.coast_control` rectifies it from the rough start;
of its final fit (after Baarda's data snooping) the script records σ̂0 and the degrees of freedom, and for every
control point kept the true error of its image position: the ground distance (north, east) between where the true
model puts the point's pixel and the ground position the control point states, against its stated σ (m).

The stated σ is ``match_sigma_scale`` times the σ from the correlation peak (the larger axis of
C = (1 − ρ²)/(ρ n) (−H_ρ)⁻¹) per pixel, at least ``minimum_sigma`` pixel. ``match_sigma_scale`` is tuned so that
the pooled σ̂0 of the tuning seeds' fits is 1: the tuning seeds are run at each of ``--scales`` and the scale where
σ̂0 crosses 1 is interpolated (σ̂0 does not fall as 1/scale: a larger σ lets the w-test keep more of the moderately
wrong matches); with one scale nothing is tuned. At each scale the run estimates the fits' effective kurtosis κ, the
package's
``MATCH_ERROR_KURTOSIS`` (:func:`effective_kurtosis`): σ̂0² of a coastline fit varies more than χ²(r)/r, because
the matches' errors are heavy-tailed and their σ off by a factor shared by an image's points, so the global test
takes r' = 2r/(κ − 1) degrees of freedom; the package takes κ from the moments of the tuning fits (where the test
rejects exactly α of them rests on their few most extreme fits, which fresh sets did not share). It also gives the
points' correlated-error model by maximum likelihood (:func:`error_model`: the package's
``MATCH_OVERLAP_CORRELATION``, ``COAST_DATUM_SIGMA`` and ``COAST_DATUM_GRADIENT_SIGMA``) and their error shared per
imaging geometry (:func:`shared_error`). The package's
defaults are then checked on fresh seeds (``--check``; ``experiments/calibration.py``'s coast row checks them on
its own fresh seeds).

Writes experiments/results/coast_control_calibration.md; each image's summary is cached
(``experiments/results/.cache/coast_tuning/<scale>/<seed>.pkl``), so a run resumes.
Run: ``.venv/bin/python experiments/coast_control_calibration.py [--tune 0 30] [--check 1000 1030] [--scales 1
1.7]`` (about 10-13 s an image on one core; the package's constants: ``--tune 61000 61200 --check 0 0 --scales
0.89``; ``--lean 61000 61100``: the last level's bias against the true model's prediction, per matcher variant,
``coast_control_calibration.md``'s companion ``coast_matcher_lean.md``). Run two processes on two cores with
``OMP_NUM_THREADS=1``: the maximum likelihood takes seconds then, minutes when the linear algebra's threads contend.
"""

import argparse
import dataclasses
import os
import pickle
import sys
import time
from pathlib import Path

import cv2
import jax.numpy as jnp
import numpy as np
from scipy.linalg import solve_triangular
from scipy.ndimage import map_coordinates

from seaice_jax import MEAN_RADIUS
from seaice_jax.adjust.engine.quality import global_test
from seaice_jax.imagery.coast_control import (
    DEFAULT_LEVELS,
    MATCH_SIGMA_SCALE,
    CoastErrors,
    centroid_offsets,
    coast_control,
    coast_point_covariance,
    match_coast,
    predicted_land,
    signed_distance,
)
from seaice_jax.io.coastline import coastline_of_grid
from seaice_jax.simulate.satellite import DAY, ice_scene, render

sys.path.insert(0, str(Path(__file__).parent))
from coast_control import SIZE, check_rms, rough_start, true_pass  # noqa: E402  (the setup of the coast-control experiment)

RESULTS = Path(__file__).with_name("results")
GLOBAL_ALPHA = 0.05


def simulated(seed: int):
    """The image of ``seed``: ``(true model, image, coastline, rng)``, the rng to draw the rough start from."""
    rng = np.random.default_rng([seed, 7])
    scene = ice_scene(np.random.default_rng(seed))
    coast = coastline_of_grid(scene.land)
    lat0, lon0 = (float(a) for a in scene.projection.inverse(*scene.centre))
    truth = true_pass(seed, rng, lat0, lon0)
    image = np.asarray(render(scene, truth, float(rng.uniform(0, 10) * DAY)))
    return truth, image, coast, rng


def rectified(seed: int, scale: float) -> dict:
    """One image of ``seed`` rectified from its rough start: σ̂0, degrees of freedom, check-point RMS (pixels),
    points kept and removed, the kept points' true ground errors ``(n, 2)`` m (north, east) and stated σ
    ``(n,)`` m, and the final fit (an ``OrbitFit``) and the true model (used by ``experiments/calibration.py``)."""
    truth, image, coast, rng = simulated(seed)
    direction = truth.direction
    start = rough_start(truth, rng)
    result = coast_control(image, start, coast.contains, match_sigma_scale=scale)
    control = result.fit.control
    latitude, longitude = (np.asarray(a) for a in truth.forward(jnp.asarray(control.pixel),
                                                                 jnp.asarray(control.scan)))
    error = MEAN_RADIUS * np.stack([latitude - control.latitude,
                                    (longitude - control.longitude) * np.cos(control.latitude)], 1)
    adjustment = result.fit.adjustment
    assert adjustment is not None  # a Gauss-Newton fit
    return {"seed": seed, "direction": direction, "sigma0": float(adjustment.sigma0),
            "dof": int(adjustment.degrees_of_freedom), "check": check_rms(result.model, truth),
            "points": len(control), "removed": sum(len(r) for r in result.rejected), "error": error,
            "sigma": np.broadcast_to(np.asarray(control.sigma, float), (len(control),)),
            "pixel": np.asarray(control.pixel, float), "scan": np.asarray(control.scan, float),
            "latitude": np.asarray(control.latitude, float), "longitude": np.asarray(control.longitude, float),
            "fit": result.fit, "truth": truth}


CACHE = RESULTS / ".cache" / "coast_tuning"
"""Each image's summary (without the fit) per scale and seed, ``<scale>/<seed>.pkl``: a long run can be resumed.
Keyed by the scale only: when the matcher or the error model changes, move the folder aside (as
``coast_tuning_<commit>``), or the run mixes images of the old code with the new."""


def collect(seeds, scale: float) -> list[dict]:
    rows = []
    for seed in seeds:
        path = CACHE / f"{scale:g}" / f"{seed}.pkl"
        if path.exists():
            rows.append(pickle.loads(path.read_bytes()))
            continue
        begin = time.perf_counter()
        r = {k: v for k, v in rectified(seed, scale).items() if k not in ("fit", "truth")}
        rows.append(r)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(pickle.dumps(r))
        print(f"seed {seed}: σ̂0 {r['sigma0']:.3f} ({r['dof']} dof), {r['points']} points ({r['removed']} removed), "
              f"check RMS {r['check']:.2f} px, {time.perf_counter() - begin:.0f} s, load {os.getloadavg()[0]:.1f}",
              flush=True)
    return rows


def critical_kurtosis(rows, alpha: float = GLOBAL_ALPHA) -> np.ndarray:
    """``(n,)``: per fit, the smallest κ at which its global test (σ̂0² against χ²(r')/r', r' = 2r/(κ − 1),
    two-sided at ``alpha``: ``OrbitFit.global_test``) accepts it, on a grid of κ from 1.01 to 60 (60: rejected
    there too). The test rejects the fits whose critical κ exceeds the κ it uses."""
    grid = np.geomspace(1.01, 60.0, 3000)
    sigma0_squared = np.array([r["sigma0"] ** 2 for r in rows])[:, None]
    dof = np.array([r["dof"] for r in rows], float)[:, None]
    accepted = np.asarray(global_test(sigma0_squared, dof, alpha, grid[None])[2])
    return np.where(accepted.any(axis=1), grid[np.argmax(accepted, axis=1)], grid[-1])


def effective_kurtosis(rows, alpha: float = GLOBAL_ALPHA) -> dict:
    """κ (effective) of the fits' errors, two estimates with 90 % intervals by resampling the images:
    ``"moments"``: σ̂0² varies (κ − 1)/r about 1, so κ = 1 + mean r (σ̂0² − 1)² (dominated by the few fits with
    matches that should have been removed); ``"level"``: the κ at which the global test rejects ``alpha`` of the
    fits, the (1 − α) quantile of :func:`critical_kurtosis` (the package's ``MATCH_ERROR_KURTOSIS``: the test's
    level set where it is used, a rejected fit counting once however far out)."""
    terms = np.array([r["dof"] * (r["sigma0"] ** 2 - 1.0) ** 2 for r in rows])
    critical = critical_kurtosis(rows, alpha)
    draws = np.random.default_rng(0).integers(0, len(rows), (2000, len(rows)))
    return {"moments": (float(1.0 + terms.mean()), tuple(np.percentile(1.0 + terms[draws].mean(axis=1), [5, 95]))),
            "level": (float(np.quantile(critical, 1.0 - alpha)),
                      tuple(np.percentile(np.quantile(critical[draws], 1.0 - alpha, axis=1), [5, 95])))}


def error_model(rows) -> dict:
    """The coastline points' correlated-error model by maximum likelihood (the package's
    ``MATCH_OVERLAP_CORRELATION``, ``COAST_DATUM_SIGMA`` and ``COAST_DATUM_GRADIENT_SIGMA``): the kept points' true
    errors, north and east alike and independent, N(0, Σ(c, σ_c, σ_g)) with Σ of :func:`coast_point_covariance`
    (windows of the last level), over all images, on a grid of c (0.70-0.98, steps of 0.005), σ_c (0-60 m, steps
    of 1 m) and σ_g (0-0.6 m per km, steps of 0.025). Returns ``{"overlap_correlation": (c, (low, high)),
    "datum_sigma": (σ_c, (low, high)), "datum_gradient_sigma": (σ_g, (low, high))}``, each with its
    profile-likelihood 90 % interval (a drop of 1.35)."""
    window = DEFAULT_LEVELS[-1].window
    parts = []
    for r in rows:
        overlap = coast_point_covariance(r["sigma"], r["pixel"], r["scan"], r["latitude"], r["longitude"], window,
                                         CoastErrors(1.0, 0.0, 0.0))  # S K S
        offsets = centroid_offsets(r["latitude"], r["longitude"], np.ones(len(r["sigma"]), bool))
        parts.append((np.diag(np.diag(overlap)), overlap, np.column_stack([np.ones(len(offsets)), offsets]),
                      r["error"]))
    correlations, shifts, gradients = np.linspace(0.70, 0.98, 57), np.linspace(0.0, 60.0, 61), np.linspace(0, 6e-4, 25)
    scales = np.stack(np.broadcast_arrays(shifts[:, None], gradients[None], gradients[None]), -1)  # (σ_c, σ_g, σ_g)
    values = np.zeros((correlations.size, shifts.size, gradients.size))
    for i, c in enumerate(correlations):
        for own, overlap, basis, error in parts:
            # Σ = A + U D Uᵀ (U = [1, X], D = diag(σ_c², σ_g², σ_g²)): one Cholesky factor L of A per c, the shared
            # field by Woodbury and the determinant lemma (V = L⁻¹U, z = L⁻¹e, M = I + D½VᵀVD½, b = D½Vᵀz):
            # eᵀΣ⁻¹e = |z|² − bᵀM⁻¹b, log det Σ = log det A + log det M
            factor = np.linalg.cholesky((1.0 - c) * own + c * overlap)
            solved = solve_triangular(factor, np.column_stack([basis, error]), lower=True)
            v, white = solved[:, :3], solved[:, 3:]
            gram, projected = v.T @ v, v.T @ white  # (3, 3), (3, axes)
            middle = np.eye(3) + scales[..., :, None] * gram * scales[..., None, :]
            b = scales[..., :, None] * projected
            quadratic = np.sum(white**2) - np.einsum("...ka,...ka->...", b, np.linalg.solve(middle, b))
            log_det = 2.0 * np.sum(np.log(np.diag(factor))) + np.linalg.slogdet(middle)[1]
            values[i] -= 0.5 * quadratic + 0.5 * error.shape[1] * log_det
    best = np.unravel_index(int(np.argmax(values)), values.shape)

    def profile(grid, axis):
        others = tuple(k for k in range(3) if k != axis)
        inside = grid[values.max(axis=others) >= values.max() - 1.35]
        return float(inside.min()), float(inside.max())

    return {"overlap_correlation": (float(correlations[best[0]]), profile(correlations, 0)),
            "datum_sigma": (float(shifts[best[1]]), profile(shifts, 1)),
            "datum_gradient_sigma": (float(gradients[best[2]]), profile(gradients, 2))}


def shared_error(rows) -> list[str]:
    """Per imaging geometry (pass direction, subtrack on or off the image): the mean over images of the kept
    points' weighted mean error (weights 1/σ², m north and east) with its standard error — a bias the images
    share on the ground whatever the scan direction is an error of where the matched coast lies."""
    groups: dict = {}
    for r in rows:
        weight = 1.0 / r["sigma"] ** 2
        key = (r["direction"], "subtrack on the image" if (r["seed"] // 2) % 2 == 0 else "subtrack off it")
        groups.setdefault(key, []).append((r["error"] * weight[:, None]).sum(axis=0) / weight.sum())
    groups[("all", "")] = [m for values in list(groups.values()) for m in values]
    lines = []
    for (direction, subtrack), values in groups.items():
        values = np.array(values)
        mean, error = values.mean(axis=0), values.std(axis=0, ddof=1) / np.sqrt(len(values))
        label = " ".join(filter(None, (direction, subtrack)))
        lines.append(f"| {label} | {len(values)} | {mean[0]:+.0f} ± {error[0]:.0f} | {mean[1]:+.0f} ± {error[1]:.0f} | "
                     f"{values.std(axis=0, ddof=1).mean():.0f} |")
    return lines


def shared_field(rows) -> list[str]:
    """The kept points' errors per image fitted (weights 1/σ²) by an affine field on the ground — a shift and the
    four gradients about the points' centroid —; per term the mean over images ± its standard error and the
    scatter: a mean beyond its error is a bias all images share (what a random shared field, ``COAST_DATUM_SIGMA``
    and ``COAST_DATUM_GRADIENT_SIGMA``, does not describe)."""
    terms = []
    for r in rows:
        offsets = centroid_offsets(r["latitude"], r["longitude"], np.ones(len(r["sigma"]), bool))
        design = np.column_stack([np.ones(len(offsets)), offsets / 1e5]) / r["sigma"][:, None]
        terms.append(np.linalg.lstsq(design, r["error"] / r["sigma"][:, None], rcond=None)[0])
    terms = np.array(terms)  # (images, term, axis of the error)
    mean, error = terms.mean(axis=0), terms.std(axis=0, ddof=1) / np.sqrt(len(terms))
    scatter = terms.std(axis=0, ddof=1)
    return [f"| {label} | {mean[k, 0]:+.1f} ± {error[k, 0]:.1f} ({scatter[k, 0]:.0f}) | "
            f"{mean[k, 1]:+.1f} ± {error[k, 1]:.1f} ({scatter[k, 1]:.0f}) |"
            for k, label in enumerate(("shift (m)", "per 100 km north (m)", "per 100 km east (m)"))]


def pooled_sigma0(rows) -> float:
    """σ̂0 of all fits together: √(Σ σ̂0² r / Σ r)."""
    return float(np.sqrt(sum(r["sigma0"] ** 2 * r["dof"] for r in rows) / sum(r["dof"] for r in rows)))


def summary(rows, label: str) -> list[str]:
    sigma0 = np.array([r["sigma0"] for r in rows])
    normalised = np.concatenate([r["error"] / r["sigma"][:, None] for r in rows])
    rng = np.random.default_rng(0)
    draws = rng.integers(0, len(rows), (2000, len(rows)))
    weights = np.array([r["sigma0"] ** 2 * r["dof"] for r in rows]), np.array([r["dof"] for r in rows])
    resampled = np.sqrt(weights[0][draws].sum(axis=1) / weights[1][draws].sum(axis=1))
    low, high = np.percentile(resampled, [5, 95])
    return [f"| {label} | {len(rows)} | **{pooled_sigma0(rows):.3f}** ({low:.3f}-{high:.3f}) | "
            f"{np.median(sigma0):.3f} | {sigma0.min():.2f}-{sigma0.max():.2f} | "
            f"{np.sqrt(np.mean(normalised**2)):.2f} | {np.sqrt(np.mean([r['check'] ** 2 for r in rows])):.2f} |"]


LEAN_VARIANTS = {"the package's last level": DEFAULT_LEVELS[-1],
                 "the whole window (no edge band)": dataclasses.replace(DEFAULT_LEVELS[-1], edge=None),
                 "a band of 8 pixels": dataclasses.replace(DEFAULT_LEVELS[-1], edge=8.0)}
"""The last level's matcher as the package has it and two variants, for :func:`lean`."""


def lean(seeds) -> dict:
    """The matcher's bias on the ground: each image of ``seeds`` matched at the last level against the prediction
    of its true model (so every match should be found at its own place), per :data:`LEAN_VARIANTS`; returns per
    variant ``(means (images, 2), errors (matches, 2), landward (images,))``: each image's mean ground error of its
    matches (m north and east), every match's, and each image's mean error along the coast's normal toward the land
    (pixels; the normal from the gradient of the prediction's signed distance, smoothed by 2 pixels, at the
    window's centre)."""
    out: dict = {name: ([], [], []) for name in LEAN_VARIANTS}
    for seed in seeds:
        truth, image, coast, _ = simulated(seed)
        prediction = predicted_land(truth, coast.contains)
        gradient = np.gradient(cv2.GaussianBlur(signed_distance(prediction > 0.5).astype(np.float32), (0, 0), 2.0))
        for name, level in LEAN_VARIANTS.items():
            matches = match_coast(image, prediction, level)
            at = [matches.predicted_scan - 1.0, matches.predicted_pixel - 1.0]  # row, column
            normal = np.stack([map_coordinates(gradient[1], at, order=1), map_coordinates(gradient[0], at, order=1)])
            normal /= np.maximum(np.hypot(*normal), 1e-12)  # (pixel, scan), toward the land
            shift = np.stack([matches.pixel - matches.predicted_pixel, matches.scan - matches.predicted_scan])
            out[name][2].append(float(np.mean(np.sum(shift * normal, axis=0))))
            latitude, longitude = (np.asarray(a) for a in truth.forward(jnp.asarray(matches.pixel),
                                                                        jnp.asarray(matches.scan)))
            centre_lat, centre_lon = (np.asarray(a) for a in truth.forward(jnp.asarray(matches.predicted_pixel),
                                                                           jnp.asarray(matches.predicted_scan)))
            error = MEAN_RADIUS * np.stack([latitude - centre_lat, (longitude - centre_lon) * np.cos(centre_lat)], 1)
            out[name][0].append(error.mean(axis=0))
            out[name][1].append(error)
        print(f"seed {seed}: " + "; ".join(f"{name} {out[name][0][-1][0]:+.0f} N {out[name][0][-1][1]:+.0f} E m"
                                           for name in LEAN_VARIANTS), flush=True)
    return {name: (np.array(means), np.concatenate(errors), np.array(landward))
            for name, (means, errors, landward) in out.items()}


def lean_report(seeds, seconds: float) -> list[str]:
    result = lean(seeds)
    load = os.getloadavg()
    lines = ["# The coastline matcher's lean (experiments/coast_control_calibration.py --lean)", "",
             f"Seeds {seeds[0]}-{seeds[-1]} ({len(seeds)} images, set up as the calibration's), each matched at the "
             "last level against the prediction of its true model: a match's ground error is where the true model "
             "puts the position found less where it puts the window's centre. Mean over images of each image's mean "
             "error, ± its standard error; RMS per coordinate over all matches; toward the land: each image's mean "
             "error along the coast's normal (pixels of about 1.2 km), mean over images ± its standard error.", "",
             "| matcher | matches an image | north (m) | east (m) | RMS north, east (m) | toward the land (pixel) |",
             "|---|---|---|---|---|---|"]
    for name, (means, errors, landward) in result.items():
        mean, error = means.mean(axis=0), means.std(axis=0, ddof=1) / np.sqrt(len(means))
        rms = np.sqrt(np.mean(errors**2, axis=0))
        lines.append(f"| {name} | {len(errors) / len(means):.0f} | {mean[0]:+.1f} ± {error[0]:.1f} | "
                     f"{mean[1]:+.1f} ± {error[1]:.1f} | {rms[0]:.0f}, {rms[1]:.0f} | {landward.mean():+.3f} ± "
                     f"{landward.std(ddof=1) / np.sqrt(len(landward)):.3f} |")
    seconds = time.perf_counter() - seconds
    lines += ["", f"Computed in {seconds:.0f} s (load average {load[0]:.2f} / {load[1]:.2f} / {load[2]:.2f} at the "
              "end, 2 cores).", ""]
    return lines


def crossing(pooled: dict) -> float:
    """The scale where the pooled σ̂0 is 1: linear between the two scales whose σ̂0 are nearest 1 (``pooled``:
    ``{scale: σ̂0}``, two or more)."""
    (a, sigma_a), (b, sigma_b) = sorted(pooled.items(), key=lambda item: abs(item[1] - 1.0))[:2]
    return a + (1.0 - sigma_a) * (b - a) / (sigma_b - sigma_a)


def main():
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--tune", type=int, nargs=2, default=(0, 30), metavar=("FIRST", "END"))
    parser.add_argument("--check", type=int, nargs=2, default=(1000, 1030), metavar=("FIRST", "END"),
                        help="fresh seeds checked at the package's scale (FIRST = END: none)")
    parser.add_argument("--scales", type=float, nargs="+", default=(1.0, MATCH_SIGMA_SCALE),
                        help="match_sigma_scale values the tuning seeds are run with (two or more to tune it; one: "
                             "only κ and the summary; default: 1 and the package's)")
    parser.add_argument("--lean", type=int, nargs=2, metavar=("FIRST", "END"),
                        help="only measure the last level's lean on these seeds (coast_matcher_lean.md)")
    args = parser.parse_args()
    begin = time.perf_counter()
    if args.lean:
        lines = lean_report(list(range(*args.lean)), begin)
        RESULTS.mkdir(exist_ok=True)
        (RESULTS / "coast_matcher_lean.md").write_text("\n".join(lines))
        print("\n".join(lines))
        return
    tuning = {scale: collect(range(*args.tune), scale) for scale in args.scales}
    pooled = {scale: pooled_sigma0(rows) for scale, rows in tuning.items()}
    tuned = crossing(pooled) if len(pooled) > 1 else None
    if tuned is not None:
        print(f"tuned match_sigma_scale: {tuned:.3f}", flush=True)
    kurtosis = {scale: effective_kurtosis(rows) for scale, rows in tuning.items()}
    model = {scale: error_model(rows) for scale, rows in tuning.items()}
    fresh = collect(range(*args.check), MATCH_SIGMA_SCALE)
    seconds = time.perf_counter() - begin
    load = os.getloadavg()
    header = ["| seeds | images | σ̂0 pooled (90 % over images) | median σ̂0 | range | true error / stated σ, RMS per "
              "coordinate | check-point RMS (px) |", "|---|---|---|---|---|---|---|"]
    lines = [
        "# Calibration of the coastline control points' σ (experiments/coast_control_calibration.py)",
        "",
        f"One simulated NOAA-7-like {SIZE} x {SIZE} image of Lancaster Sound per seed (set up as in "
        "experiments/coast_control.py), rectified by `coast_control` from a start 0.5° off in the node and 20 km along "
        "the track; σ̂0 of the final fit (after data snooping), and the kept points' true ground errors against "
        "their stated σ.",
        "",
        f"Run: `.venv/bin/python experiments/coast_control_calibration.py --tune {args.tune[0]} {args.tune[1]} "
        f"--check {args.check[0]} {args.check[1]} --scales {' '.join(f'{s:g}' for s in args.scales)}` "
        f"({seconds:.0f} s of this run, images in the cache cost nothing; load average {load[0]:.2f} / "
        f"{load[1]:.2f} / {load[2]:.2f} at the end, 2 cores).",
        "",
        f"Tuning seeds {args.tune[0]}-{args.tune[1] - 1}: pooled σ̂0 "
        + ", ".join(f"{sigma0:.3f} at match_sigma_scale {scale:g}" for scale, sigma0 in pooled.items())
        + ("" if tuned is None else f"; σ̂0 = 1 at {tuned:.3f}") + f". The package's default: {MATCH_SIGMA_SCALE}.",
        "",
        "Effective kurtosis κ of the tuning fits (the global test's r' = 2r/(κ − 1); 90 % over images): "
        + "; ".join(f"at scale {scale:g}: the global test at its level α = {GLOBAL_ALPHA} (the (1 − α) quantile of "
                    f"each fit's critical κ) {k['level'][0]:.2f} ({k['level'][1][0]:.2f}-{k['level'][1][1]:.2f}), "
                    f"by moments (1 + mean r (σ̂0² − 1)²) {k['moments'][0]:.2f} ({k['moments'][1][0]:.2f}-"
                    f"{k['moments'][1][1]:.2f})" for scale, k in kurtosis.items())
        + ".",
        "",
        "The points' correlated-error model by maximum likelihood (`CoastErrors`; 90 % by the profile likelihood): "
        + "; ".join(f"at scale {scale:g}: overlap correlation c {m['overlap_correlation'][0]:.3f} "
                    f"({m['overlap_correlation'][1][0]:.3f}-{m['overlap_correlation'][1][1]:.3f}; the package's "
                    f"{CoastErrors().overlap_correlation:g}), shared shift σ_c {m['datum_sigma'][0]:.0f} m "
                    f"({m['datum_sigma'][1][0]:.0f}-{m['datum_sigma'][1][1]:.0f} m; the package's "
                    f"{CoastErrors().datum_sigma:g} m), shared gradients σ_g "
                    f"{1e3 * m['datum_gradient_sigma'][0]:.3f} m per km ({1e3 * m['datum_gradient_sigma'][1][0]:.3f}-"
                    f"{1e3 * m['datum_gradient_sigma'][1][1]:.3f}; the package's "
                    f"{1e3 * CoastErrors().datum_gradient_sigma:g})" for scale, m in model.items())
        + ".",
        "",
        "The kept points' weighted mean error per image (m; the tuning seeds):", "",
        "| pass | images | north | east | scatter per image (RMS of the two axes) |", "|---|---|---|---|---|",
        *[line for rows in tuning.values() for line in shared_error(rows)],
        "",
        "The same errors as an affine field per image (weights 1/σ²; mean over images ± its standard error, the "
        "scatter over images in brackets):", "",
        "| term | north error | east error |", "|---|---|---|",
        *[line for rows in tuning.values() for line in shared_field(rows)],
        "",
        *header,
        *[row for scale, rows in tuning.items()
          for row in summary(rows, f"tuning {args.tune[0]}-{args.tune[1] - 1}, scale {scale:g}")],
        *(summary(fresh, f"fresh {args.check[0]}-{args.check[1] - 1}, scale {MATCH_SIGMA_SCALE} (the default)")
          if fresh else []),
        "",
        *(["Per image (fresh seeds):", "",
           "| seed | pass | σ̂0 | degrees of freedom | points kept | removed by the w-test | check-point RMS (px) |",
           "|---|---|---|---|---|---|---|",
           *[f"| {r['seed']} | {r['direction']} | {r['sigma0']:.2f} | {r['dof']} | {r['points']} | {r['removed']} | "
             f"{r['check']:.2f} |" for r in fresh], ""] if fresh else []),
    ]
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "coast_control_calibration.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
