"""Per image (1985) and chained (1985 multi-image practice) against simultaneous adjustment of simulated
Lancaster-Sound-like sequences (issues 13 and 29).

Each realization simulates a sequence of NOAA-7-like images (as ``experiments/lancaster_like.py``: 12 land control
points per image, pointing σ 0.5 / 1.0 pixel, map σ 500 m) and finds the scan models these ways:

* **per image, 12 control points** (the 1985 practice, ``seaice adjust --method per-image``): one Gauss-Newton
  fit per image;
* **chained, 12 control points** (the 1985 multi-image practice, source 001 section 3.3,
  :func:`~seaice_jax.adjust.orbit.multi_image.sequential_fit`): image 0 on its control points, every later image on its
  own control points plus the ties it shares with an image already solved, their ground positions taken from that
  image's model as fixed control points (σ: the ties' median matching σ on the ground). The ties are those the
  simultaneous adjustment kept (a 1985 operator's secondary points carried no mismatches); stated σ: each fit's own
  covariance, as the 1985 fits reported it;
* **simultaneous, 12 control points**: ties found automatically on land and fast ice (``find_ties`` through the
  per-image fits, windows sized by their covariances), one adjustment of all images (``adjust_sequence``),
  mismatched ties removed by the w-tests;
* **simultaneous, 4 / 2 / 0 control points** (the control-point sweep): the first 4 / 2 / no control points of every
  image; the ties are matched through predicted models (the truth plus N(0, σ) of about one pixel in every
  unknown, as an orbit prediction would give: no per-image fit is possible on two points). With none, the
  predicted models are the adjustment's priors (σ of the prediction); with 2 and 4 nothing else is known.

For every control count also the stated σ without the affine pair fields that issue 29 added beside the
phase-dependent bias (``SequenceOptions.tie_offset_factor``, ``tie_gradient_factor``;
:func:`~seaice_jax.adjust.sequence.adjustment.systematic_tie_covariance`), «phase term alone (before issue 29)».
For the 12-point case also: the stated σ without the ties' systematic error terms
(``SequenceAdjustment.systematic``, «independent tie errors»); the matcher's error against the truth, and the part
of it common to each image pair (an affine field per pair and axis fitted to the true tie errors: the measurement
behind ``SequenceOptions``' ``tie_offset_factor`` and ``tie_gradient_factor``); 5 % of the ties planted as
mismatches (one observation moved 5-20 pixels) and the adjustment repeated.

Scores against the simulation's truth: the true model error over the image (ground distance between the adjusted and
the true model's positions of random pixels) and its stated σ there; the drift error due to the models, exact for
every pack-ice cell of the map grid (the feature at true position P appears in the remapped image k at P + e_k(P),
with e_k the model's position error there, so the tracked displacement is off by e_{k+1}(P') − e_k(P)); with
``--track`` also the drift actually tracked (remap + NCC, as ``seaice track``) for the 12-point methods, and its
stated σ (``displacement_sigma`` with the pair's joint covariance and 0.2 pixel of tracking) against the empirical
error.

Seeds: the stochastic model's defaults were measured on seeds 100-109 (``tie_phase_sigma``) and 300-304, 326-329
(the affine pair fields); the default run starts at seed 400, never tuned on. ``--cache DIR`` keeps each seed's
matched ties (``DIR/ties_<seed>.pkl``, the two tie sets) so that a rerun of the adjustments and the covariances does
not match again, and each finished realization (``DIR/run_<seed>.pkl``: several processes can share the seeds of one
run, ``--cached-only`` then summarizes the seeds done; the cache holds what the code that wrote it computed: empty it
after changing the code); ``--counts`` chooses the control-point sweep (2 is always run: the summary's 2-point
lines) and ``--no-planted`` skips the planted-mismatch adjustment, to keep long runs within a shared machine's time.

Writes experiments/results/sequence_block.md (``--out`` another file).
Run: ``.venv/bin/python experiments/sequence_block.py [--realizations 30] [--first-seed 400] [--images 4]
[--size 512] [--counts 4,2,0] [--no-planted] [--cache DIR [--cached-only]] [--track]``.
"""

import argparse
import pickle
import time
from dataclasses import replace
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from scipy.linalg import block_diag

from seaice_jax import (
    MEAN_RADIUS,
    ControlPoints,
    ImageObservations,
    MapGrid,
    SequenceOptions,
    adjust_sequence,
    find_ties,
    fit_scan_model,
    remap,
    simulate_sequence,
    track,
    wrap_angle,
)
from seaice_jax.adjust.engine.quality import global_test, group_test
from seaice_jax.adjust.orbit.fit import position_jacobian
from seaice_jax.adjust.orbit.multi_image import sequential_fit
from seaice_jax.adjust.sequence.adjustment import sequence_problem, systematic_tie_covariance
from seaice_jax.adjust.sequence.control_test import control_rows
from seaice_jax.adjust.sequence.model import scan_unknowns, with_scan_unknowns
from seaice_jax.imagery.ties import transfer
from seaice_jax.simulate.satellite import true_displacement
from seaice_jax.workflows.track import displacement_sigma

RESULTS = Path(__file__).with_name("results")
POINTING = (0.5, 1.0)
PREDICTION_SIGMA = np.array([2e-4, 0.5, 2e-4, 2e-4, 3e-4])
"""σ of the predicted models' unknowns (radians, pixel) for the 2-control-point case: about one pixel."""
STATIC_MARGIN = 3000.0
TRACKING_SIGMA = 0.2  # pixels of the map grid


def static_surface(scene):
    """Land and fast ice, ``STATIC_MARGIN`` inside the pack-ice edge (the scene's coastline)."""

    @jax.jit
    def static(latitude, longitude):
        xy = jnp.stack(scene.projection.forward(latitude, longitude), axis=-1)
        return scene.coast_offset(xy) > -scene.fast_ice_width + STATIC_MARGIN

    return lambda latitude, longitude: np.asarray(static(jnp.asarray(latitude), jnp.asarray(longitude)))


def model_error(fitted, true, covariance, rng, size, count=400):
    """At ``count`` random pixels: the ground distance (m) between the fitted and the true model's positions and
    its stated σ there (√ of the trace of the position covariance from the model's ``(5, 5)`` covariance), each
    ``(count,)``; and the same per coordinate: the error (north, east) and its stated σ, ``(count, 2)`` m each."""
    pixel, scan = rng.uniform(1, size, count), rng.uniform(1, size, count)
    lat_f, lon_f = (np.asarray(a) for a in fitted.forward(pixel, scan))
    lat_t, lon_t = (np.asarray(a) for a in true.forward(pixel, scan))
    jacobian = np.asarray(position_jacobian(fitted, pixel, scan))
    variance = np.einsum("nij,jk,nik->ni", jacobian, covariance, jacobian)  # (count, 2) north, east
    north_east = MEAN_RADIUS * np.stack([lat_f - lat_t, np.asarray(wrap_angle(lon_f - lon_t)) * np.cos(lat_t)], 1)
    return np.hypot(north_east[:, 0], north_east[:, 1]), np.sqrt(variance.sum(1)), north_east, np.sqrt(variance)


def apparent(scene, fitted, true, xy, size):
    """Where a feature at scene positions ``xy (n, 2)`` appears when the image of ``true`` is mapped through
    ``fitted``; NaN outside the image."""
    lat, lon = scene.projection.inverse(xy[:, 0], xy[:, 1])
    pixel, scan = (np.asarray(a) for a in true.inverse(lat, lon))
    inside = (pixel >= 1) & (pixel <= size) & (scan >= 1) & (scan <= size)
    lat_f, lon_f = fitted.forward(pixel, scan)
    out = np.stack([np.asarray(a) for a in scene.projection.forward(lat_f, lon_f)], 1)
    return np.where(inside[:, None], out, np.nan)


def phase_only_covariance(result, size):
    """``result``'s covariance without the affine pair fields (``SequenceOptions`` ``tie_offset_factor``,
    ``tie_gradient_factor``): the phase-dependent bias alone, as before issue 29."""
    problem, adjustment, observations = sequence_problem(result.observations), result.adjustment, result.observations
    options = SequenceOptions()
    sizes = np.full((observations.n_images, 2), size)
    return result.covariance - systematic_tie_covariance(problem, adjustment, observations.reference_image, sizes,
                                                         np.asarray(result.cofactor), options.tie_offset_factor,
                                                         options.tie_gradient_factor)


def matched_ties(cache, seed, match):
    """``match()`` (the two tie sets of a seed), or what ``cache`` holds for ``seed`` (``None``: no cache)."""
    path = None if cache is None else Path(cache) / f"ties_{seed}.pkl"
    if path is not None and path.exists():
        stored = pickle.loads(path.read_bytes())
        return stored["ties"], stored["predicted_ties"]
    ties, predicted_ties = match()
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(pickle.dumps({"ties": ties, "predicted_ties": predicted_ties}))
    return ties, predicted_ties


def first_controls(control: ControlPoints, count: int) -> ControlPoints:
    return ControlPoints(control.pixel[:count], control.scan[:count], control.latitude[:count],
                         control.longitude[:count], control.sigma[:count], control.ids[:count])


def tie_errors(ties, truth):
    """Per matched (non-reference) observation: its (pixel, scan) minus the true correspondent of its tie's
    reference observation (true models), and the stated σ of that difference; ``(m, 2)`` each, pixels; and the rows
    of those observations and of their reference observations in ``ties``."""
    reference = {int(t): k for k, t in enumerate(ties.tie) if ties.reference[k]}
    matched = np.nonzero(~ties.reference)[0]
    rows = np.array([reference[int(t)] for t in ties.tie[matched]], int)
    errors = np.zeros((matched.size, 2))
    for a in np.unique(ties.image[rows]):
        for b in np.unique(ties.image[matched]):
            pick = (ties.image[rows] == a) & (ties.image[matched] == b)
            if pick.any():
                p, s = transfer(truth[a], truth[b], ties.pixel[rows[pick]], ties.scan[rows[pick]])
                errors[pick] = np.stack([ties.pixel[matched[pick]] - p, ties.scan[matched[pick]] - s], 1)
    sigma = np.stack([np.hypot(ties.sigma_pixel[matched], ties.sigma_pixel[rows]),
                      np.hypot(ties.sigma_scan[matched], ties.sigma_scan[rows])], 1)
    return errors, sigma, matched, rows


def pair_fields(ties, errors, matched, rows, result, size, correlation, minimum=30):
    """The part of the true tie errors common to each image pair, as ``SequenceOptions``' pair fields model it
    (:func:`~seaice_jax.adjust.sequence.adjustment.systematic_tie_covariance`): per pair (reference image a, matched
    image b) with at least ``minimum`` ties kept by ``result`` and per axis of b, the affine field (offset;
    gradients along pixel and scan about the matches' centroid, pixels per image width) fitted by least squares to
    the errors. Returns ``(k, 3)`` each: the coefficients², their variance due to the matches' own noise
    (``correlation`` times the fit's residual variance), and the model's unit (Xᵀ W X)⁻¹ with W of the final σ of
    b's observations (a priori σ times the group's estimated variance factor)."""
    keep = ~np.isin(ties.tie[matched], np.asarray(result.removed_ties, int))
    pairs = np.stack([ties.image[rows], ties.image[matched]], 1)
    squares, noise, unit = [], [], []
    for a, b in sorted({(int(x), int(y)) for x, y in pairs[keep]}):
        pick = np.nonzero(keep & (pairs[:, 0] == a) & (pairs[:, 1] == b))[0]
        if pick.size < minimum:
            continue
        model = result.models[b]
        factor = result.variance_factors.get(f"ties {model.direction} {model.n_pixels}x{model.n_scans}", 1.0)
        pixel, scan = ties.pixel[matched[pick]], ties.scan[matched[pick]]
        design = np.stack([np.ones(pick.size), (pixel - pixel.mean()) / size, (scan - scan.mean()) / size], 1)
        inverse = np.linalg.inv(design.T @ design)
        for axis, sigma in enumerate((ties.sigma_pixel, ties.sigma_scan)):
            fitted = inverse @ design.T @ errors[pick, axis]
            residual = errors[pick, axis] - design @ fitted
            whitened = design / (sigma[matched[pick]] * np.sqrt(factor))[:, None]
            squares.append(fitted**2)
            noise.append(correlation * float(residual @ residual) / (pick.size - 3) * np.diag(inverse))
            unit.append(np.diag(np.linalg.inv(whitened.T @ whitened)))
    return tuple(np.array(v).reshape(-1, 3) for v in (squares, noise, unit))


def chained_fit(sequence, ties, removed, controls, size):
    """The 1985 multi-image practice (module docstring): the models and the block-diagonal covariance of the fits."""
    kept = ~np.isin(ties.tie, np.asarray(sorted(removed), int))
    centre = 0.5 * (1 + size)
    model = sequence.images[0].model
    lat, lon = (np.asarray(a) for a in model.forward(np.array([centre, centre + 1]), np.array([centre, centre])))
    pixel_size = MEAN_RADIUS * np.hypot(np.diff(lat), np.diff(lon) * np.cos(lat[0]))[0]
    sigma = float(np.median(np.hypot(ties.sigma_pixel[kept], ties.sigma_scan[kept]))) / np.sqrt(2) * pixel_size
    observations = []
    for k, image in enumerate(sequence.images):
        rows = kept & (ties.image == k)
        observations.append(ImageObservations(f"image{k}", image.model.orbit, image.model.direction, controls[k],
                                              tuple(str(t) for t in ties.tie[rows]), ties.pixel[rows],
                                              ties.scan[rows], sigma, size, size))
    fits, _ = sequential_fit(observations)
    return [f.model for f in fits], block_diag(*[np.asarray(f.adjustment.covariance) for f in fits])


def group_factors(result):
    """``{group kind: Σ(v/σ)² / Σ r}`` of the final adjustment with its final σ (≈ 1 where a group's σ is right)."""
    adjustment, sums = result.adjustment, {}
    for name, group in result.observations.groups.items():
        sigma = np.asarray(group.sigma)
        finite = np.isfinite(sigma)
        v = np.asarray(adjustment.residuals[name])[:group.rows]
        square = float(np.sum(np.where(finite, v / np.where(finite, sigma, 1.0), 0.0) ** 2))
        redundancy = float(np.sum(np.asarray(adjustment.redundancy[name])[:group.rows][finite]))
        kind = name.split()[0]
        total = sums.get(kind, (0.0, 0.0))
        sums[kind] = (total[0] + square, total[1] + redundancy)
    return {kind: square / redundancy for kind, (square, redundancy) in sums.items() if redundancy > 0}


def two_sided_p(statistic: float, degrees_of_freedom: float) -> float:
    """Two-sided p-value of a χ² statistic (the package's global test of statistic / degrees of freedom)."""
    return float(global_test(statistic / degrees_of_freedom, degrees_of_freedom)[1])


def adjustment_quality(result):
    """The sequence adjustment's own statistics, for ``experiments/calibration.py``: ``sigma0`` and
    ``degrees_of_freedom`` of the final adjustment (its tie σ rescaled by the estimated ``variance_factors``),
    ``global_p`` its χ² test's two-sided p-value; ``control_test`` ``(T, q)`` of :func:`group_test` (q: C's
    rank) with the adjustment's weights and ``control_p`` its p-value, ``control_test_stated``,
    ``control_p_stated`` the same with the ties' correlated and systematic errors the product states
    (``result.systematic``); ``control`` the inputs (whitened residuals, Jacobian, cofactor, systematic part);
    ``w`` ``{"control" | "ties": (w (m,), redundancy (m,))}`` of the final adjustment's real rows (removed ties:
    σ = ∞, redundancy 0); ``tie_rows``: the tie observations (coordinates) before the removals, ``removed_rows``
    those of the removed ties, ``removed_ties`` their number."""
    adjustment = result.adjustment
    w = {}
    for name, group in result.observations.groups.items():
        kind = name.split()[0]
        values = np.asarray(adjustment.standardized_residuals[name])[:group.rows].reshape(-1)
        redundancy = np.asarray(adjustment.redundancy[name])[:group.rows].reshape(-1)
        old = w.get(kind, (np.zeros(0), np.zeros(0)))
        w[kind] = (np.concatenate([old[0], values]), np.concatenate([old[1], redundancy]))
    tie_sigma = [np.asarray(g.sigma) for n, g in result.observations.groups.items() if n.startswith("ties")]
    tie_rows = int(sum(s.size for s in tie_sigma))
    removed_rows = int(sum(np.sum(~np.isfinite(s)) for s in tie_sigma))
    whitened, jacobian = control_rows(result)
    cofactor, systematic = np.asarray(result.cofactor), np.asarray(result.systematic)
    statistic, count = (float(v) for v in group_test(whitened, jacobian, cofactor)[:2])
    stated, stated_count = (float(v) for v in group_test(whitened, jacobian, cofactor, systematic)[:2])
    count, stated_count = int(count), int(stated_count)
    dof = int(result.degrees_of_freedom)
    return {"sigma0": float(result.sigma0), "degrees_of_freedom": dof,
            "global_p": two_sided_p(float(result.sigma0) ** 2 * dof, dof),
            "variance_factors": dict(result.variance_factors), "control_test": (statistic, count),
            "control_p": two_sided_p(statistic, count), "control_test_stated": (stated, stated_count),
            "control_p_stated": two_sided_p(stated, stated_count),
            "control": {"whitened": whitened, "jacobian": jacobian, "cofactor": cofactor, "systematic": systematic},
            "w": w,
            "tie_rows": tie_rows, "removed_rows": removed_rows, "removed_ties": result.n_removed}


def plant_mismatches(ties, rng, fraction=0.05):
    """``ties`` with one matched observation of ``fraction`` of the ties moved 5-20 pixels in a random direction,
    and the set of those ties."""
    matched = np.nonzero(~ties.reference)[0]
    chosen = rng.choice(np.unique(ties.tie[matched]), max(1, int(round(fraction * ties.n_ties))), replace=False)
    pixel, scan = ties.pixel.copy(), ties.scan.copy()
    for t in chosen:
        row = rng.choice(matched[ties.tie[matched] == t])
        length, angle = rng.uniform(5, 20), rng.uniform(0, 2 * np.pi)
        pixel[row] += length * np.cos(angle)
        scan[row] += length * np.sin(angle)
    return replace(ties, pixel=pixel, scan=scan), {int(t) for t in chosen}


def realization(seed, images, tracked, size, counts=(4, 2, 0), planting=True, cache=None, drift_labels=None):
    """One simulated sequence of ``images`` images of ``size`` x ``size`` pixels (module docstring), ``seed`` its
    seed: per method (label) the model errors and their stated σ at random pixels (``model``, ``model_sigma``
    distances; ``model_north_east``, ``model_sigma_north_east`` per coordinate, m) and the exact drift errors
    and their stated σ (``drift``, ``drift_sigma`` ``(n, 2)`` m; only for the labels in ``drift_labels``, default
    all), the ties' stochastic-model measurements, and ``quality``, the 12-point simultaneous adjustment's own
    statistics (:func:`adjustment_quality`; ``quality_sweep``: per control count > 0 of the sweep, the same of its
    adjustment). ``counts``: the control-point sweep (``()``: none; the summary needs 2); ``cache``: the folder of
    the matched ties (:func:`matched_ties`)."""
    rng = np.random.default_rng(20_000 + seed)
    sequence = simulate_sequence(seed, n_images=images, size=size, pointing_sigma=POINTING)
    scene = sequence.scene
    truth = [im.model for im in sequence.images]
    static = static_surface(scene)
    data = [im.data for im in sequence.images]
    lat0, lon0 = scene.projection.inverse(*scene.centre)
    grid = MapGrid.centred(scene.projection, lat0, lon0, 1200.0, 1200.0, 320, 320)
    fits = [fit_scan_model(im.control, im.model.orbit, direction=im.model.direction, n_pixels=size, n_scans=size)
            for im in sequence.images]
    per_image = [f.model for f in fits]
    blocks = [np.asarray(f.adjustment.covariance) for f in fits if f.adjustment is not None]
    rng_matching = np.random.default_rng(20_000 + seed)  # the draws of plant_mismatches, then the prediction

    def match():
        found = find_ties(data, per_image, static, blocks)
        plant_mismatches(found, rng_matching)
        guess = [with_scan_unknowns(m, scan_unknowns(m) + rng_matching.normal(0, PREDICTION_SIGMA)) for m in truth]
        return found, find_ties(data, guess, static, [np.diag(PREDICTION_SIGMA**2)] * images)

    started = time.time()
    ties, predicted_ties = matched_ties(cache, seed, match)
    tie_time = time.time() - started
    started = time.time()
    controls = [im.control for im in sequence.images]
    block12 = adjust_sequence(per_image, ties, controls)
    adjust_time = time.time() - started
    chained = chained_fit(sequence, ties, set(block12.removed_ties), controls, size)
    bad, planted = plant_mismatches(ties, rng)
    planted_run = adjust_sequence(per_image, bad, controls) if planting else None
    theta_sigma = np.sqrt(np.diag(block12.covariance)).reshape(-1, 5)
    tie_error, tie_sigma, matched, rows = tie_errors(ties, truth)
    field = pair_fields(ties, tie_error, matched, rows, block12, size, SequenceOptions().tie_correlation)
    predicted = [with_scan_unknowns(m, scan_unknowns(m) + rng.normal(0, PREDICTION_SIGMA)) for m in truth]
    sweep = {count: adjust_sequence(predicted, predicted_ties, [first_controls(im.control, count)
                                                                for im in sequence.images])
             for count in counts if count > 0}
    if 0 in counts:
        sweep[0] = adjust_sequence(predicted, predicted_ties, [None] * images,
                                   prior_covariance=np.tile(PREDICTION_SIGMA, (images, 1)))
    methods = {"per image, 12 control points": (per_image, block_diag(*blocks)),
               "chained, 12 control points": chained,
               "simultaneous, 12 control points, independent tie errors": (
                   list(block12.models), block12.covariance - block12.systematic),
               "simultaneous, 12 control points": (list(block12.models), block12.covariance)}
    methods.update({f"simultaneous, {count} control points": (list(result.models), result.covariance)
                    for count, result in sweep.items()})
    methods.update({f"simultaneous, {count} control points, phase term alone (before issue 29)": (
        list(result.models), phase_only_covariance(result, size)) for count, result in [(12, block12), *sweep.items()]})
    cells = np.stack([np.asarray(a) for a in grid.xy()], -1).reshape(-1, 2)
    pack = cells[np.asarray(scene.is_pack(cells))]
    two = sweep.get(2)  # the summary's 2-point lines (None without the sweep)
    out = {"ties": [ties.n_ties, predicted_ties.n_ties],
           "removed": [block12.n_removed, np.nan if two is None else two.n_removed],
           "tie_time": tie_time, "adjust_time": adjust_time, "tie_error": tie_error, "tie_sigma": tie_sigma,
           "field": field,
           "factors": [block12.variance_factors, {} if two is None else two.variance_factors],
           "group_factors": [group_factors(block12), {} if two is None else group_factors(two)],
           "planted": len(planted), "quality": adjustment_quality(block12),
           "quality_sweep": {count: adjustment_quality(result) for count, result in sweep.items() if count > 0}}
    if planted_run is not None:
        out.update({"planted_found": len(planted & set(planted_run.removed_ties)),
                    "false_removed": len(set(planted_run.removed_ties) - planted - set(block12.removed_ties)),
                    "planted_shift": float(np.max(np.abs(planted_run.theta - block12.theta) / theta_sigma))})
    drift_errors = {}  # the methods of one set of models share their exact drift errors
    for label, (models, covariance) in methods.items():
        errors, model_sigma, north_east, north_east_sigma = zip(*[
            model_error(m, t, covariance[5 * k:5 * k + 5, 5 * k:5 * k + 5], rng, size)
            for k, (m, t) in enumerate(zip(models, truth, strict=True))], strict=True)
        out[label] = {"model": np.concatenate(errors), "model_sigma": np.concatenate(model_sigma),
                      "model_north_east": np.concatenate(north_east),
                      "model_sigma_north_east": np.concatenate(north_east_sigma)}
        if drift_labels is not None and label not in drift_labels:
            continue
        drift, predicted_sigma = [], []
        for k in range(images - 1):
            a, b = sequence.images[k], sequence.images[k + 1]
            end = pack + true_displacement(scene, pack, a.time, b.time)
            key = (id(models[k]), id(models[k + 1]))
            if key not in drift_errors:
                drift_errors[key] = ((apparent(scene, models[k + 1], truth[k + 1], end, size) - end)
                                     - (apparent(scene, models[k], truth[k], pack, size) - pack))
            error = drift_errors[key]
            keep = np.all(np.isfinite(error), axis=1)
            drift.append(error[keep])
            pair = covariance[5 * k:5 * k + 10, 5 * k:5 * k + 10]
            moved = end[keep] - pack[keep]
            predicted_sigma.append(displacement_sigma(models[k:k + 2], pair, grid, pack[keep, 0], pack[keep, 1],
                                                      moved[:, 0], moved[:, 1], 0.0))
        out[label].update(drift=np.concatenate(drift), drift_sigma=np.concatenate(predicted_sigma))
    if tracked:
        for label in [k for k in methods if "12" in k]:
            models, covariance = methods[label]
            maps, _ = remap(data, models, grid)
            errors, sigmas = [], []
            for k in range(images - 1):
                a, b = sequence.images[k], sequence.images[k + 1]
                d = track(maps[k], maps[k + 1])
                vectors = d.in_map(grid)
                xy = np.stack([vectors["x"], vectors["y"]], 1)
                good = np.asarray(scene.is_pack(xy)) & d.good
                measured = np.stack([vectors["dx"], vectors["dy"]], 1)[good]
                errors.append(measured - true_displacement(scene, xy[good], a.time, b.time))
                sigmas.append(displacement_sigma(models[k:k + 2], covariance[5 * k:5 * k + 10, 5 * k:5 * k + 10],
                                                 grid, xy[good, 0], xy[good, 1], measured[:, 0], measured[:, 1],
                                                 TRACKING_SIGMA * 1200.0))
            out[label]["tracked"] = np.concatenate(errors)
            out[label]["tracked_sigma"] = np.concatenate(sigmas)
    return out


def seed_ranges(seeds) -> str:
    """``400-409, 412`` of sorted integers."""
    seeds, parts = sorted(seeds), []
    for seed in seeds:
        if parts and seed == parts[-1][1] + 1:
            parts[-1][1] = seed
        else:
            parts.append([seed, seed])
    return ", ".join(f"{a}-{b}" if b > a else f"{a}" for a, b in parts)


def rms(values):
    return float(np.sqrt(np.mean(np.asarray(values) ** 2)))


def summary(runs, args, elapsed):
    """The results file's lines for the realizations run so far."""
    labels = [k for k in runs[0] if isinstance(runs[0][k], dict) and "drift" in runs[0][k]]
    tie_error = np.concatenate([r["tie_error"] for r in runs])
    tie_sigma = np.concatenate([r["tie_sigma"] for r in runs])
    factors = [np.array([v for r in runs for v in r["factors"][i].values()]) for i in range(2)]
    control = [np.array([r["group_factors"][i].get("control", np.nan) for r in runs]) for i in range(2)]
    squares, noise, unit = (np.concatenate([r["field"][k] for r in runs]) for k in range(3))
    factor = [float(np.sum(squares[:, c] - noise[:, c]) / np.sum(unit[:, c])) for c in ([0], [1, 2])]
    options = SequenceOptions()
    partial = "" if len(runs) == args.realizations else f" (of {args.realizations} planned: stopped for time)"
    lines = ["# Simultaneous adjustment of image sequences against the per-image and the chained fit", "",
             f"Generated by `experiments/sequence_block.py --realizations {args.realizations} --first-seed "
             f"{args.first_seed} --images {args.images} --size {args.size} --counts {args.counts}"
             f"{'' if args.planted else ' --no-planted'}`: {len(runs)} simulated Lancaster-like "
             f"sequences{partial} (seeds {seed_ranges([r['seed'] for r in runs])}) of {args.images} "
             f"NOAA-7-like {args.size} x {args.size} images; {elapsed:.0f} s. Ties per sequence (12 / 2 control "
             f"points): median {np.median([r['ties'][0] for r in runs]):.0f} / "
             f"{np.median([r['ties'][1] for r in runs]):.0f}; ties removed as mismatches: "
             f"{sum(r['removed'][0] for r in runs)} / {sum(r['removed'][1] for r in runs)} in all; tie finding "
             f"median {np.median([r['tie_time'] for r in runs]):.1f} s, adjustment (variance components included) "
             f"median {np.median([r['adjust_time'] for r in runs]):.1f} s per sequence.", "",
             "Drift error due to the models: every pack-ice cell of the 1.2 km map grid, exact (module docstring); "
             "the tracking adds about 0.35 / 0.20 km (experiments/results/lancaster_like.md, true models). "
             "Stated σ: `displacement_sigma` of the models' joint covariance without the tracking term: Q with the "
             "ties' variance factor estimated plus the ties' correlated and systematic error terms (the defaults: "
             "`SequenceOptions.tie_correlation`, `tie_phase_sigma`, the affine pair fields `tie_offset_factor`, "
             "`tie_gradient_factor`; «phase term alone (before issue 29)»: without the affine pair fields), the "
             "same without all those terms («independent "
             "tie errors»); the chained and per-image fits: their own covariances. One sequence's drift errors are "
             "a few smooth error fields, not independent draws: the ratio varies from sequence to sequence and only "
             "the pooled one is a test; its 90 % interval is a bootstrap over the sequences.", "",
             "| method | true model error RMS (km) | its stated σ RMS (km) | drift error RMS x / y (km) | "
             "stated drift σ RMS (km) | stated / empirical drift |", "|---|---|---|---|---|---|"]
    resample = np.random.default_rng(0).integers(0, len(runs), (2000, len(runs)))
    for label in labels:
        model = np.concatenate([r[label]["model"] for r in runs]) / 1000
        model_sigma = np.concatenate([r[label]["model_sigma"] for r in runs]) / 1000
        drift = np.concatenate([r[label]["drift"] for r in runs]) / 1000
        sigma = np.concatenate([r[label]["drift_sigma"] for r in runs]) / 1000
        ratios = [rms(r[label]["drift_sigma"]) / rms(r[label]["drift"].ravel()) for r in runs]
        sums = np.array([[np.sum(r[label]["drift_sigma"] ** 2), np.sum(r[label]["drift"] ** 2)] for r in runs])
        pooled = np.sqrt(sums[resample, 0].sum(1) / sums[resample, 1].sum(1))
        lines.append(f"| {label} | {rms(model):.2f} | {rms(model_sigma):.2f} | {rms(drift[:, 0]):.2f} / "
                     f"{rms(drift[:, 1]):.2f} | {rms(sigma):.2f} | {rms(sigma) / rms(drift.ravel()):.2f} (90 %: "
                     f"{np.quantile(pooled, 0.05):.2f}-{np.quantile(pooled, 0.95):.2f}; per sequence "
                     f"{min(ratios):.2f}-{max(ratios):.2f}) |")
    lines += ["", "Stochastic model of the ties (12 control points): the matcher's error against the truth (each "
              "matched observation minus the true correspondent of its tie's reference observation) "
              f"{rms(tie_error[:, 0]):.3f} / {rms(tie_error[:, 1]):.3f} pixel RMS (pixel / scan) against a stated σ "
              f"of that difference of {rms(tie_sigma[:, 0]):.3f} / {rms(tie_sigma[:, 1]):.3f}: error / σ "
              f"{rms(tie_error[:, 0] / tie_sigma[:, 0]):.2f} / {rms(tie_error[:, 1] / tie_sigma[:, 1]):.2f}. "
              "Estimated variance factors of the tie groups (σ̂² relative to the a priori σ²): median "
              f"{np.median(factors[0]):.3f} (range {factors[0].min():.3f}-{factors[0].max():.3f}) with 12 control "
              f"points, {np.median(factors[1]):.3f} with 2. The control points' Σ(v/σ)²/Σr with their given σ "
              f"after the fix: median {np.nanmedian(control[0]):.2f} (12 points), {np.nanmedian(control[1]):.2f} "
              "(2 points).", "",
              "The part of the tie errors common to an image pair (affine field per pair and axis fitted to the true "
              f"errors, {len(squares)} pair axes of ≥ 30 kept ties; pixels, gradients per image width): RMS of the "
              f"fitted offset {np.sqrt(np.mean(squares[:, 0])):.4f}, gradients {np.sqrt(np.mean(squares[:, 1:])):.3f}"
              "; of which the matches' own noise (residual variance x tie_correlation) "
              f"{np.sqrt(np.mean(noise[:, 0])):.4f} / {np.sqrt(np.mean(noise[:, 1:])):.3f}; the rest in units of "
              "the pair's own (Xᵀ W X)⁻¹ (Σ(c² − noise) / Σ unit, the estimate of `SequenceOptions."
              f"tie_offset_factor`, `tie_gradient_factor` were the phase term not there): {factor[0]:.1f} / "
              f"{factor[1]:.1f} (the defaults, measured beside the phase term: {options.tie_offset_factor:g} / "
              f"{options.tie_gradient_factor:g})."]
    if "planted_found" in runs[0]:
        lines += ["", f"Planted mismatches (5 % of the ties of the 12-point case, one observation each moved 5-20 "
                  f"pixels): {sum(r['planted_found'] for r in runs)} of {sum(r['planted'] for r in runs)} removed; "
                  f"other ties removed besides those of the clean run: {sum(r['false_removed'] for r in runs)}; "
                  f"largest change of an unknown against the clean adjustment: "
                  f"{max(r['planted_shift'] for r in runs):.2f} σ."]
    if args.track:
        lines += ["", "Drift tracked on the remapped images (NCC, as `seaice track`) against the truth; stated σ "
                  "with 0.2 pixel of tracking:", "", "| method | vectors | RMS x / y (km) | stated σ RMS (km) | "
                  "stated / empirical |", "|---|---|---|---|---|"]
        for label in labels:
            if "tracked" not in runs[0][label]:
                continue
            tracked = np.concatenate([r[label]["tracked"] for r in runs]) / 1000
            sigma = np.concatenate([r[label]["tracked_sigma"] for r in runs]) / 1000
            lines.append(f"| {label} | {len(tracked)} | {rms(tracked[:, 0]):.2f} / {rms(tracked[:, 1]):.2f} | "
                         f"{rms(sigma):.2f} | {rms(sigma) / rms(tracked.ravel()):.2f} |")
    return lines


def main():
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--realizations", type=int, default=30, help="simulated sequences (a pooled drift ratio "
                        "over 10 is decided only to ±15-20 %%)")
    parser.add_argument("--first-seed", type=int, default=400,
                        help="seed of the first simulated sequence (400 on: seeds no default was measured on)")
    parser.add_argument("--images", type=int, default=4, help="images per simulated sequence")
    parser.add_argument("--out", type=Path, default=RESULTS / "sequence_block.md", help="results file")
    parser.add_argument("--size", type=int, default=512, help="pixels and scan lines per image")
    parser.add_argument("--track", action="store_true", help="also remap and track (12-point methods)")
    parser.add_argument("--counts", default="4,2,0", help="control points per image of the sweep (2 always run)")
    parser.add_argument("--no-planted", dest="planted", action="store_false", help="skip the planted mismatches")
    parser.add_argument("--cache", type=Path, help="folder keeping each seed's matched ties and realization "
                        "(module docstring)")
    parser.add_argument("--cached-only", action="store_true", help="summarize the seeds in --cache, compute none")
    args = parser.parse_args()
    counts = tuple(sorted({int(c) for c in args.counts.split(",")} | {2}, reverse=True))
    started = time.time()
    runs = []
    args.out.parent.mkdir(parents=True, exist_ok=True)
    for seed in range(args.first_seed, args.first_seed + args.realizations):
        stored = None if args.cache is None else args.cache / f"run_{seed}.pkl"
        if stored is not None and stored.exists():
            runs.append(pickle.loads(stored.read_bytes()))
        elif args.cached_only:
            continue
        else:
            runs.append({**realization(seed, args.images, args.track, args.size, counts, args.planted, args.cache),
                         "seed": seed})
            if stored is not None:
                stored.write_bytes(pickle.dumps(runs[-1]))
        print(f"realization {len(runs)}/{args.realizations} ({time.time() - started:.0f} s)", flush=True)
        lines = summary(runs, args, time.time() - started)  # rewritten after every realization
        args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
