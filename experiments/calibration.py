"""Every σ the package's products state, against Monte Carlo truth on fresh seeds (issue 29, acceptance).

One table, one row per product (each row a function ``row_<name>(seeds, quick) -> list of entries``, run on its
own with ``--rows``):

* **orbit** — :func:`~seaice_jax.adjust.orbit.fit.fit_scan_model` of a NOAA-7-like 512 x 512 image
  (:func:`~seaice_jax.simulate.satellite.noaa_image`, south- and northbound alternately) on 12 simulated control
  points (σ 1 km per coordinate, :func:`~seaice_jax.simulate.satellite.simulate_control_points`); stated: the
  position σ (north, east) of 25 random check pixels by :func:`~seaice_jax.adjust.orbit.fit.position_uncertainty`
  (a posteriori σ̂0²Q, and a priori Q); truth: the fitted minus the true model's position there. Also σ̂0, the
  global test (α = 0.05) and the w-tests (α = 0.001) of the latitude and longitude observations.
* **coast** — :func:`~seaice_jax.imagery.coast_control.coast_control` on the simulated images of
  ``experiments/coast_control_calibration.py`` (its :func:`rectified`): stated: the kept control points' σ against
  their true ground error, and the rectified model's position σ at 25 check pixels against its true error (the fit
  with the points' correlated errors, ``CoastErrors``, in its covariance); σ̂0 and the fit's global test (its
  degrees of freedom for the matches' kurtosis; the plain χ² test in the note) of the final fits (after data
  snooping: the w-test removals are reported, but they remove real mismatches too, so they are not a false-alarm
  rate). The coast model's constants were tuned on seeds 61000-61199.
* **block**, **block_strip** — radar blocks of ``experiments/block_statistics.py`` (its :func:`block_statistics`,
  default ``BlockOptions`` of the flight and the strip navigation scope): stated: the adjusted stations', all
  points' and drift vectors' covariance against the truth; σ̂0, global test, the w-test alarms per testable
  observation by group (as its ``summarize`` counts them).
* **sequence** — image sequences of ``experiments/sequence_block.py`` (its :func:`realization`, without tracking)
  as its fresh-seed run made them (4 images of 256 x 256, seeds :data:`ROW_SEEDS`; ``--sequence-ties`` reads that
  run's matched ties, the adjustments are computed anew): the simultaneous adjustment and the per-image fits, 12
  control points per image; stated: the drift σ due to the models (``displacement_sigma`` (x, y) of the joint
  covariance) against the exact drift error at every pack-ice cell, and the position σ (north, east) at random
  pixels against the model's true error there. Tests of the simultaneous adjustment: the control points' group
  test (the package's ``group_test``, their σ given) as the global test, their w-tests; the whole adjustment's
  σ̂0 and global test (little to test: the ties' variance factors are estimated) and the ties' removals by the
  snooping (real mismatches among them, not a false-alarm rate) in the row's note.
* **sequence_2** — the same sequences adjusted with the first 2 control points of every image (the control-point
  sweep of ``experiments/sequence_block.py``: ties matched through predicted models, which its ties' cache also
  holds): the same lines and tests for that adjustment (the control points' group test then has q = 16).
* **tracking** — image pairs of ``experiments/tracking_calibration.py`` (its :func:`pair_errors`): stated: the
  per-vector σ from the correlation peak with the package's defaults (``CORRELATION_AREA``, ``SIGMA_FLOOR``), its
  variance scaled by the neighbour statistic (``DISAGREEMENT_SCALE``; realizations cached without the statistic:
  the peak's σ alone, said in the row's stated σ), for the vectors the package leaves good (not flagged
  ``MIXED_MOTION``); the flag's rates among the vectors of one motion (false alarms) and across two (detections).
* **deformation** — :func:`~seaice_jax.drift.kinematics.deformation` of 80 floes in a 300 km square moving on a
  known linear velocity field, velocities observed with N(0, σ) noise of their stated σ (0.5-2 x 5 mm/s, per
  component); stated: σ of divergence, shear and vorticity per Delaunay triangle, truth: the field's exact rates.

The ratio of a row is √mean(e²/σ²) over every coordinate of every realization (empirical / stated; pass band
0.9-1.1), its 90 % interval a bootstrap over the seeds (a seed's errors share its fit, its scene or its noise: the
seed, not the point, is the independent unit). Tests, where the product has them: the global test's rejection rate
(target 3-7 %, 95 % Wilson interval) and the worst w-test group's alarm rate per testable observation (redundancy
> 1e-12) in units of α (target ≤ 1.5 α).

Fresh seeds: 50000 + (row's offset) onwards, used for nothing else — no constant of the package was tuned on them
(the tuning seeds of the experiments reused here are 0-29, 1000-1029, 20000-22199, 200-209 and below).

Every realization is cached (``--cache``, default ``experiments/results/.cache/``, ignored by git) per row and seed,
so an interrupted run resumes and ``--table-only`` re-assembles the table from what is there. Writes
experiments/results/calibration.md (``--out``).

Run: ``.venv/bin/python experiments/calibration.py [--rows orbit,coast,tracking,deformation,block,block_strip,
sequence] [--seeds N] [--seed-list A-B,C,...] [--quick] [--minutes M] [--table-only] [--sequence-ties DIR]``
(``--seed-list``: the seeds of every row named, in place of its fresh seeds, e.g. more fresh sequences never used
before, or a pool of cached ones). A full run (the default
seeds per row) took, on 2 cores shared with about six other people's work (load average 18-29 by ``uptime``, this
script at nice 10): orbit 500 fits 5.5 min, coast 30 images 42 min, tracking 30 pairs 9 min, deformation 200 floe
sets 15 s, radar blocks about 10 s each after a compilation of 3-8 min (100 per scope), sequences 6-28 min each (3
images of 256 x 256, ties matched; the first with its compilations; with the ties read through
``--sequence-ties``, 4 images: about 3 min each at load 7) — about 2.5 hours of wall time in all at that load, a
fraction of it on a quiet machine. The results file records each row's compute time and, where recorded, the
load average. ``--quick`` (3 seeds per row) of orbit and deformation: about 15 s of CPU (2 min of wall time at load
20), as the test runs it.
"""

import argparse
import os
import pickle
import sys
import time
from pathlib import Path

import numpy as np

from seaice_jax import SeaiceError

sys.path.insert(0, str(Path(__file__).parent))
from block_statistics import wilson  # noqa: E402  (the experiments' one Wilson interval)

RESULTS = Path(__file__).with_name("results")
CACHE = RESULTS / ".cache"
FIRST_SEED = 50_000
ROW_OFFSET = {"orbit": 0, "coast": 1000, "block": 2000, "block_strip": 2500, "sequence": 3000, "tracking": 4000,
              "deformation": 5000}
DEFAULT_SEEDS = {"orbit": 500, "coast": 60, "block": 100, "block_strip": 100, "sequence": 32, "sequence_2": 32,
                 "tracking": 30, "deformation": 200}
_FRESH_SEQUENCES = (*range(400, 407), *range(410, 416), *range(420, 427), *range(430, 436), *range(440, 446))
ROW_SEEDS = {"sequence": _FRESH_SEQUENCES, "sequence_2": _FRESH_SEQUENCES}
"""Rows whose fresh seeds are a list: the sequences are those of ``experiments/sequence_block.py``'s fresh-seed run
(``experiments/results/sequence_block.md``; seeds from 400 on, none tuned on), whose matched ties are kept
(``--sequence-ties``)."""
QUICK_SEEDS = 3
BAND = (0.9, 1.1)
GLOBAL_BAND = (0.03, 0.07)
W_LIMIT = 1.5
W_ALPHA = 0.001
GLOBAL_ALPHA = 0.05
TESTABLE = 1e-12
RESAMPLES = 2000
CHECK_PIXELS = 25
_cache_dir = CACHE
_revisions: dict = {}
_timing: dict = {}
_failures: dict = {}
"""``{row: [(seed, message)]}``: seeds whose realization raised a package error (left out of the ratios)."""
"""``{row: [(seconds, load average)]}`` of the realizations used in this run, as recorded when computed."""
"""``{row: {revision: [seeds]}}`` of the realizations used in this run."""


# ---------------------------------------------------------------------------------------------------- statistics

def seed_range(row: str, count: int, given: list[int] | None = None):
    """The first ``count`` fresh seeds of ``row``: of ``given`` where that is a list (``--seed-list``), else its
    :data:`ROW_SEEDS` where it has a list (then at most those), else ``FIRST_SEED + ROW_OFFSET[row]`` onwards."""
    if given is not None:
        return given[:count]
    if row in ROW_SEEDS:
        return list(ROW_SEEDS[row][:count])
    first = FIRST_SEED + ROW_OFFSET[row]
    return range(first, first + count)


def parse_seeds(text: str) -> list[int]:
    """The seeds of ``--seed-list``: comma-separated seeds and inclusive ranges ``A-B``, e.g. ``400-406,53200``."""
    seeds = []
    for part in (p.strip() for p in text.split(",") if p.strip()):
        first, _, last = part.partition("-")
        seeds += list(range(int(first), int(last or first) + 1))
    return seeds


def ratio(normalized, resamples: int = RESAMPLES, seed: int = 0) -> tuple[float, tuple[float, float], int]:
    """√mean(z²) of the normalized errors ``z = e/σ`` of every realization (a list of arrays, one per seed), its
    90 % interval from resampling whole seeds, and the number of values."""
    normalized = [np.asarray(z, float).ravel() for z in normalized]
    normalized = [z[np.isfinite(z)] for z in normalized]
    normalized = [z for z in normalized if z.size]
    if not normalized:
        return float("nan"), (float("nan"), float("nan")), 0
    sums = np.array([np.sum(z**2) for z in normalized])
    counts = np.array([z.size for z in normalized], float)
    draws = np.random.default_rng(seed).integers(0, len(sums), (resamples, len(sums)))
    resampled = np.sqrt(sums[draws].sum(axis=1) / counts[draws].sum(axis=1))
    low, high = np.percentile(resampled, [5, 95])
    return float(np.sqrt(sums.sum() / counts.sum())), (float(low), float(high)), int(counts.sum())


def w_alarms(w, redundancy, alpha: float = W_ALPHA) -> tuple[int, int]:
    """``(alarms, testable)``: observations with redundancy > :data:`TESTABLE` and their |w| beyond the critical
    value of ``alpha``."""
    from seaice_jax.adjust.engine.quality import critical_value

    w, redundancy = np.asarray(w, float).ravel(), np.asarray(redundancy, float).ravel()
    testable = redundancy > TESTABLE
    return int(np.sum(np.abs(w[testable]) > float(critical_value(alpha)))), int(testable.sum())


def entry(label: str, stated: str, seeds, normalized, **tests) -> dict:
    """One line of the table: ``label``, what is ``stated``, the seeds, the ratio of ``normalized`` (per seed) and
    optional tests: ``sigma0`` (per seed), ``rejected`` (global test rejections per seed, bools),
    ``groups`` ({group: (alarms, testable)} summed over the seeds), ``note``. σ̂0 is summarized as √mean(σ̂0²)
    (expectation 1 when the stochastic model is right; the mean of σ̂0 itself is below 1 by about 1/(4r))."""
    value, interval, values = ratio(normalized)
    out = {"label": label, "stated": stated, "seeds": (min(seeds), max(seeds)), "count": len(seeds),
           "values": values, "ratio": value, "interval": interval, "note": tests.get("note", "")}
    if tests.get("sigma0") is not None:
        out["sigma0"] = float(np.sqrt(np.mean(np.square(tests["sigma0"]))))  # E σ̂0² = 1
    if tests.get("rejected") is not None:
        k, n = int(np.sum(tests["rejected"])), len(tests["rejected"])
        out["global"] = (k, n, wilson(k, n))
    if tests.get("groups"):
        rates = {g: a / n / W_ALPHA for g, (a, n) in tests["groups"].items() if n}
        worst = max(rates, key=lambda g: rates[g])
        a, n = tests["groups"][worst]
        low, high = wilson(a, n)
        out["w"] = (rates[worst], worst, a, n, (low / W_ALPHA, high / W_ALPHA))
    return out


# --------------------------------------------------------------------------------------------------- the cache

def revision() -> str:
    """The commit of the package's tree (``+ uncommitted changes`` where its package or experiments differ from
    it), or ``SEAICE_REVISION`` where that is set (a snapshot without git)."""
    if os.environ.get("SEAICE_REVISION"):
        return os.environ["SEAICE_REVISION"]
    import subprocess

    import seaice_jax

    root = Path(seaice_jax.__file__).parent.parent
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no", "seaice_jax",
                                "experiments"], capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + (" + uncommitted changes" if dirty else "")


def cached(row: str, seed: int, compute):
    """``compute(seed)`` (a dict), kept in the cache as ``<row>/<seed>.pkl`` (and read from there when present),
    with the :func:`revision` it was computed at, its seconds and the load average (1 min) at its end."""
    path = _cache_dir / row / f"{seed}.pkl"
    if path.exists():
        with open(path, "rb") as file:
            return pickle.load(file)
    begin = time.perf_counter()
    value: dict
    try:
        value = compute(seed)
    except SeaiceError as error:  # the simulation or the product refused this seed: counted, not hidden
        value = {"failed": f"{type(error).__name__}: {str(error)[:300]}"}
    value.update(revision=revision(), seconds=time.perf_counter() - begin, load=os.getloadavg()[0])
    path.parent.mkdir(parents=True, exist_ok=True)
    (_cache_dir / ".gitignore").write_text("*\n")
    temporary = path.with_suffix(".tmp")
    with open(temporary, "wb") as file:
        pickle.dump(value, file)
    temporary.replace(path)
    return value


def realizations(row: str, seeds, compute, deadline: float | None = None) -> list:
    """The cached realizations of ``row`` for ``seeds`` (computed where missing, until ``deadline``, a
    ``time.time()``: later seeds not in the cache are skipped)."""
    out = []
    for seed in seeds:
        if deadline is not None and time.time() > deadline and not (_cache_dir / row / f"{seed}.pkl").exists():
            print(f"{row}: stopped (deadline or --table-only) after {len(out)} seeds", flush=True)
            break
        begin = time.perf_counter()
        value = cached(row, seed, compute)
        if "failed" in value:
            _failures.setdefault(row, []).append((seed, value["failed"]))
            print(f"{row} {seed}: failed: {value['failed']}", flush=True)
            continue
        out.append({**value, "seed": seed})
        _revisions.setdefault(row, {}).setdefault(out[-1].get("revision", "not recorded"), []).append(seed)
        _timing.setdefault(row, []).append((out[-1].get("seconds", np.nan), out[-1].get("load", np.nan)))
        print(f"{row} {seed}: {time.perf_counter() - begin:.1f} s", flush=True)
    return out


# ------------------------------------------------------------------------------------------------------- orbit

def north_east_error(fitted, true, pixel, scan) -> np.ndarray:
    """``(n, 2)`` m: the fitted minus the true model's ground position (north, east) of image points."""
    import jax.numpy as jnp

    from seaice_jax.geometry.earth import wrap_angle

    radius = float(true.orbit.radius)
    lat_f, lon_f = (np.asarray(a) for a in fitted.forward(jnp.asarray(pixel), jnp.asarray(scan)))
    lat_t, lon_t = (np.asarray(a) for a in true.forward(jnp.asarray(pixel), jnp.asarray(scan)))
    return np.stack([(lat_f - lat_t) * radius, np.asarray(wrap_angle(lon_f - lon_t)) * radius * np.cos(lat_t)], 1)


def check_pixels(rng, n_pixels: int, n_scans: int, count: int = CHECK_PIXELS, margin: float = 20.0):
    """``count`` random image points ``(pixel, scan)`` away from the edges."""
    return rng.uniform(1 + margin, n_pixels - margin, count), rng.uniform(1 + margin, n_scans - margin, count)


ORBIT_CONTROL = 12


def orbit_realization(seed: int) -> dict:
    """One image fitted on 12 control points of σ 1 km: the check pixels' errors and stated σ (a posteriori and a
    priori), σ̂0, the global test and the w-tests."""
    from seaice_jax.adjust.orbit.fit import fit_scan_model, position_uncertainty
    from seaice_jax.simulate.satellite import noaa_image, simulate_control_points

    rng = np.random.default_rng([seed, 29])
    direction = "south" if seed % 2 == 0 else "north"
    truth = noaa_image(direction)
    control, _, _ = simulate_control_points(truth, ORBIT_CONTROL, rng, sigma_m=1000.0)
    fit = fit_scan_model(control, truth.orbit, direction=direction, n_pixels=truth.n_pixels, n_scans=truth.n_scans)
    pixel, scan = check_pixels(rng, truth.n_pixels, truth.n_scans)
    error = north_east_error(fit.model, truth, pixel, scan)
    posterior = np.stack([np.asarray(s) for s in position_uncertainty(fit, pixel, scan)], 1)
    prior = np.stack([np.asarray(s) for s in position_uncertainty(fit, pixel, scan, a_priori=True)], 1)
    adjustment = fit.adjustment
    if adjustment is None:  # no redundancy: nothing to test
        raise SeaiceError(f"orbit fit of seed {seed} has no adjustment statistics")
    test = fit.global_test(GLOBAL_ALPHA)
    return {"error": error, "posterior": posterior, "prior": prior, "sigma0": float(adjustment.sigma0),
            "rejected": test is not None and not test[1],
            "alarms": {g: w_alarms(adjustment.standardized_residuals[g], adjustment.redundancy[g])
                       for g in ("latitude", "longitude")}}


def summed_alarms(runs) -> dict:
    groups = dict.fromkeys(g for r in runs for g in r["alarms"])
    return {g: tuple(int(sum(r["alarms"].get(g, (0, 0))[k] for r in runs)) for k in range(2)) for g in groups}


def row_orbit(seeds, quick: bool = False, deadline=None) -> list[dict]:
    runs = realizations("orbit", seeds, orbit_realization, deadline)
    if not runs:
        return []
    done = [r["seed"] for r in runs]
    tests = dict(sigma0=[r["sigma0"] for r in runs], rejected=[r["rejected"] for r in runs],
                 groups=summed_alarms(runs))
    dof = 2 * ORBIT_CONTROL - 5
    note = (f"σ̂0 of {dof} degrees of freedom in the stated σ makes e/σ Student-t: expected ratio "
            f"√({dof}/{dof - 2}) = {np.sqrt(dof / (dof - 2)):.3f}, not 1")
    return [entry("orbit fit: check-pixel position (a posteriori σ̂0²Q)",
                  "position σ north/east at 25 check pixels (`position_uncertainty`)", done,
                  [r["error"] / r["posterior"] for r in runs], **tests, note=note),
            entry("orbit fit: check-pixel position (a priori Q)", "the same with σ of the control points taken as "
                  "right (`a_priori=True`)", done, [r["error"] / r["prior"] for r in runs])]


# ------------------------------------------------------------------------------------------------------- coast

def coast_realization(seed: int) -> dict:
    """One image of ``experiments/coast_control_calibration.py`` rectified by the coastline control (the
    package's ``MATCH_SIGMA_SCALE`` and correlated-error model ``CoastErrors()``), with the rectified model's error
    and stated σ at check pixels and the kept points' image positions (the fit's global test: :func:`coast_rejected`,
    from σ̂0 and the degrees of freedom)."""
    from coast_control_calibration import rectified

    from seaice_jax.adjust.orbit.fit import position_uncertainty
    from seaice_jax.imagery.coast_control import MATCH_SIGMA_SCALE

    r = rectified(seed, MATCH_SIGMA_SCALE)
    fit, truth = r.pop("fit"), r.pop("truth")
    rng = np.random.default_rng([seed, 29])
    pixel, scan = check_pixels(rng, truth.n_pixels, truth.n_scans)
    r["check_error"] = north_east_error(fit.model, truth, pixel, scan)
    r["check_sigma"] = np.stack([np.asarray(s) for s in position_uncertainty(fit, pixel, scan)], 1)
    r["pixel"], r["scan"] = np.asarray(fit.control.pixel), np.asarray(fit.control.scan)
    return r


def coast_rejected(r: dict, kurtosis: float | None = None) -> bool:
    """The fit's global test (``OrbitFit.global_test``) from its cached σ̂0 and degrees of freedom, with the
    package's ``MATCH_ERROR_KURTOSIS`` as it is now (``kurtosis`` 3: as if the errors were normal, χ² with r
    degrees of freedom)."""
    from seaice_jax.adjust.engine.quality import global_test
    from seaice_jax.imagery.coast_control import MATCH_ERROR_KURTOSIS

    kurtosis = MATCH_ERROR_KURTOSIS if kurtosis is None else kurtosis
    return not bool(global_test(r["sigma0"] ** 2, r["dof"], GLOBAL_ALPHA, kurtosis)[2])


def common_error(error, sigma) -> np.ndarray:
    """``(2,)``: the weighted mean of control points' errors ``(n, 2)`` (weights 1/σ², σ ``(n,)``) over its σ if
    the errors were independent — N(0, 1) per coordinate then."""
    weight = 1.0 / np.asarray(sigma, float) ** 2
    return (np.asarray(error) * weight[:, None]).sum(axis=0) / np.sqrt(weight.sum())


def row_coast(seeds, quick: bool = False, deadline=None) -> list[dict]:
    runs = realizations("coast", seeds, coast_realization, deadline)
    if not runs:
        return []
    done = [r["seed"] for r in runs]
    removed, kept = sum(r["removed"] for r in runs), sum(r["points"] for r in runs)
    note = (f"w-test removals (data snooping, α = 0.001, mismatches included): {removed} of {removed + kept} points "
            f"= {removed / max(removed + kept, 1) / W_ALPHA:.0f} α — not a false-alarm rate")
    common = np.array([common_error(r["error"], r["sigma"]) for r in runs])
    note += (f"; the kept points' weighted mean error per image over its σ if the points were independent: RMS "
             f"{np.sqrt(np.mean(common**2)):.2f} (1 if independent), mean north {common[:, 0].mean():+.2f}, east "
             f"{common[:, 1].mean():+.2f} (± {1 / np.sqrt(len(runs)):.2f}): errors shared by an image's points "
             "(in the fit's covariance since issue 29: CoastErrors)")
    plain = sum(coast_rejected(r, 3.0) for r in runs)
    note += (f"; the global test as if the errors were normal (χ² with r degrees of freedom, not the fit's "
             f"r' = 2r/(κ − 1)): {plain}/{len(runs)} rejected")
    tests = dict(sigma0=[r["sigma0"] for r in runs], rejected=[coast_rejected(r) for r in runs], note=note)
    return [entry("coast control: control points kept", "each point's σ (MATCH_SIGMA_SCALE x the correlation "
                  "peak's), true ground error north/east", done,
                  [r["error"] / r["sigma"][:, None] for r in runs], **tests),
            entry("coast control: rectified model at check pixels", "position σ (a posteriori; the points' "
                  "correlated errors in the fit's covariance) at 25 check pixels",
                  done, [r["check_error"] / r["check_sigma"] for r in runs])]


# ------------------------------------------------------------------------------------------------------- block

def block_realization(seed: int, scope: str = "flight") -> dict:
    """One blunder-free block of ``experiments/block_statistics.py`` with the default ``BlockOptions`` of the
    navigation ``scope``."""
    from block_statistics import block_statistics

    from seaice_jax.adjust.radar.options import BlockOptions

    return block_statistics(seed, BlockOptions(navigation_scope=scope))


def _diagonal_normalized(errors, covariances) -> np.ndarray:
    e = np.asarray(errors).reshape(-1, 2)
    sigma = np.sqrt(np.diagonal(np.asarray(covariances).reshape(-1, 2, 2), axis1=1, axis2=2))
    return e / sigma


def row_block(seeds, quick: bool = False, deadline=None, scope: str = "flight") -> list[dict]:
    name = "block" if scope == "flight" else f"block_{scope}"
    runs = realizations(name, seeds, lambda seed: block_realization(seed, scope), deadline)
    if not runs:
        return []
    done = [r["seed"] for r in runs]
    tests = dict(sigma0=[float(r["sigma0"]) for r in runs], rejected=[not r["accepted"] for r in runs],
                 groups=summed_alarms(runs))
    labels = {"stations": "stations", "points": "all points", "drift": "drift vectors"}
    return [entry(f"radar block ({scope} scope): {label}", "adjusted position covariance (x along, y across track)"
                  if key != "drift" else "drift vector covariance", done,
                  [_diagonal_normalized(r["errors"][key], r["covariances"][key]) for r in runs],
                  **(tests if key == "stations" else {}),
                  note="plain ratio (not conditioned on the stations' fixes; see block_statistics.md)"
                  if key == "stations" else "")
            for key, label in labels.items()]


# ---------------------------------------------------------------------------------------------------- sequence

SEQUENCE_IMAGES = 4
SEQUENCE_SIZE = 256
SEQUENCE_METHOD = "simultaneous, 12 control points"
SEQUENCE_PER_IMAGE = "per image, 12 control points"
SEQUENCE_TWO = "simultaneous, 2 control points"
_sequence_ties: Path | None = None
"""``--sequence-ties``: the folder of ``experiments/sequence_block.py``'s matched ties per seed (``ties_<seed>.pkl``),
read where present and written where not (``None``: match every seed anew, about 150 s a sequence)."""


def sequence_realization(seed: int) -> dict:
    """One sequence of ``experiments/sequence_block.py`` as its fresh-seed run was made (``--images 4 --size 256
    --counts 2 --no-planted``; the 2-point sweep is not computed here, it changes no draw of the 12-point case), no
    tracking: per method (the simultaneous adjustment and the per-image fits, 12 control points each) the exact
    drift errors and their stated σ ``(n, 2)`` m and the model errors (north, east) and their stated σ at random
    pixels ``(1600, 2)`` m; ``quality``: the simultaneous adjustment's own statistics
    (:func:`sequence_block.adjustment_quality`)."""
    from sequence_block import realization

    keep = (SEQUENCE_METHOD, SEQUENCE_PER_IMAGE)
    out = realization(seed, SEQUENCE_IMAGES, False, SEQUENCE_SIZE, counts=(), planting=False, cache=_sequence_ties,
                      drift_labels=keep)
    result = {label: {k: np.asarray(v) for k, v in out[label].items()} for label in keep if label in out}
    return {**result, "quality": out["quality"], "ties": int(out["ties"][0])}


def sequence_two_realization(seed: int) -> dict:
    """One sequence as :func:`sequence_realization`, adjusted with the first 2 control points of every image (the
    sweep's ties, matched through predicted models): the drift and model errors and their stated σ of that
    adjustment, ``quality`` its own statistics."""
    from sequence_block import realization

    out = realization(seed, SEQUENCE_IMAGES, False, SEQUENCE_SIZE, counts=(2,), planting=False, cache=_sequence_ties,
                      drift_labels=(SEQUENCE_TWO,))
    return {SEQUENCE_TWO: {k: np.asarray(v) for k, v in out[SEQUENCE_TWO].items()}, "quality": out["quality_sweep"][2],
            "ties": int(out["ties"][1])}


def control_tests(quality: dict) -> dict:
    """The control points' group tests of one adjustment, recomputed from its cached inputs (``quality["control"]``)
    by the package's ``group_test`` as it is now (realizations cached before it took C's rank tested T against
    χ² of all q coordinates, one too many): ``plain`` (the adjustment's weights, C = R) and ``stated`` (C = R + J S
    Jᵀ), each ``(T, q, two-sided p)``."""
    from sequence_block import two_sided_p

    from seaice_jax.adjust.engine.quality import group_test

    c = quality["control"]
    out = {}
    for name, systematic in (("plain", None), ("stated", c["systematic"])):
        statistic, count = (float(v) for v in group_test(c["whitened"], c["jacobian"], c["cofactor"], systematic)[:2])
        out[name] = (statistic, int(count), two_sided_p(statistic, int(count)))
    return out


def sequence_tests(runs) -> dict:
    """The simultaneous adjustment's tests over ``runs`` for :func:`entry`: ``sigma0`` √(T/q) and ``rejected`` of
    the control points' group test under the stochastic model the product states (the ties' correlated and
    systematic errors included: the package's ``group_test`` with ``systematic``; α = :data:`GLOBAL_ALPHA`),
    ``groups`` the control points' w-test alarms per testable observation (the engine's w, of the adjustment's
    weights; the ties' w-tests are the snooping's: see :func:`sequence_note`)."""
    quality = [r["quality"] for r in runs]
    tests = [control_tests(q)["stated"] for q in quality]
    return dict(sigma0=[np.sqrt(t / q) for t, q, _ in tests], rejected=[p < GLOBAL_ALPHA for _, _, p in tests],
                groups={"control": tuple(int(sum(w_alarms(*q["w"]["control"])[k] for q in quality))
                                         for k in range(2))})


def sequence_note(runs) -> str:
    """What the sequence adjustment's tests in the table are, and those not in its columns: the whole adjustment's
    σ̂0 and global test (its tie σ rescaled by the estimated variance factors), the tie groups' removals (real
    mismatches among them: not a false-alarm rate), the estimated variance factors."""
    quality = [r["quality"] for r in runs]
    whole = np.array([q["sigma0"] for q in quality])
    rejected = sum(q["global_p"] < GLOBAL_ALPHA for q in quality)
    low, high = wilson(rejected, len(quality))
    tests = [control_tests(q)["plain"] for q in quality]
    plain = sum(p < GLOBAL_ALPHA for _, _, p in tests)
    plain_low, plain_high = wilson(plain, len(quality))
    plain_ratio = np.mean([t / q for t, q, _ in tests])
    removed, rows = sum(q["removed_rows"] for q in quality), sum(q["tie_rows"] for q in quality)
    tie_alarms, tie_testable = (sum(w_alarms(*q["w"]["ties"])[k] for q in quality) for k in range(2))
    factors = np.array([v for q in quality for v in q["variance_factors"].values()])
    dof = np.median([q for _, q, _ in tests])
    coordinates = np.median([np.size(q["control"]["whitened"]) for q in quality])
    return (f"σ̂0 and global test of this line: the control points' group test against the rest of the "
            f"adjustment with their σ given, T = ṽᵀC⁺ṽ ~ χ²(q), q = {dof:.0f} a sequence (C's rank: its "
            f"{coordinates:.0f} coordinates less the directions only the control points fix) (column: "
            f"√mean(T/q)), C = R + J S Jᵀ their residuals' covariance under the stated model (R the redundancy "
            f"block, S the ties' correlated and systematic part of the covariance); with the adjustment's weights "
            f"alone (C = R: the ties' errors independent) mean T/q {plain_ratio:.3f}, rejected {plain}/"
            f"{len(quality)} ({100 * plain_low:.1f}-{100 * plain_high:.1f} %). w-test: the control points' (the "
            f"engine's w; the simulation's points are blunder-free). The whole adjustment "
            f"(tie σ rescaled by the estimated variance factors, median {np.median(factors):.3f}, range "
            f"{factors.min():.3f}-{factors.max():.3f}): √mean σ̂0² {np.sqrt(np.mean(whole**2)):.3f}, its global test "
            f"rejected {rejected}/{len(quality)} ({100 * low:.1f}-{100 * high:.1f} %) — but the estimated factors "
            f"make the ties' Σ(v/σ)² equal their redundancy, so it tests little beyond the control points. Ties: "
            f"the snooping removed {removed} of {rows} tie observations = {removed / max(rows, 1) / W_ALPHA:.1f} α "
            f"(whole ties: the matcher's real mismatches among them; not a false-alarm rate); in the final "
            f"adjustment {tie_alarms}/{tie_testable} testable tie observations flagged (0 by construction)")


def sequence_entries(runs, methods, tested: str) -> list[dict]:
    """The drift and model-error lines of ``methods`` (labels of the realizations ``runs``), with the tests of the
    adjustment ``tested``."""
    if not runs:
        return []
    done = [r["seed"] for r in runs]
    shape = f"{SEQUENCE_IMAGES} images of {SEQUENCE_SIZE} x {SEQUENCE_SIZE}"
    out = []
    for method in methods:
        if method not in runs[0]:
            continue
        tests = dict(**sequence_tests(runs), note=sequence_note(runs)) if method == tested else {}
        out.append(entry(f"sequence ({method}): drift due to the models",
                         f"`displacement_sigma` (x, y) of the joint covariance, {shape}, every pack-ice cell", done,
                         [r[method]["drift"] / r[method]["drift_sigma"] for r in runs], **tests))
        out.append(entry(f"sequence ({method}): model error", "position σ (north, east) at 400 random pixels an "
                         "image", done,
                         [r[method]["model_north_east"] / r[method]["model_sigma_north_east"] for r in runs]))
    return out


def row_sequence(seeds, quick: bool = False, deadline=None) -> list[dict]:
    runs = realizations("sequence", seeds, sequence_realization, deadline)
    return sequence_entries(runs, (SEQUENCE_METHOD, SEQUENCE_PER_IMAGE), SEQUENCE_METHOD)


def row_sequence_2(seeds, quick: bool = False, deadline=None) -> list[dict]:
    runs = realizations("sequence_2", seeds, sequence_two_realization, deadline)
    return sequence_entries(runs, (SEQUENCE_TWO,), SEQUENCE_TWO)


# ---------------------------------------------------------------------------------------------------- tracking

def tracking_realization(seed: int) -> dict:
    from tracking_calibration import pair_errors

    return pair_errors(seed)


def row_tracking(seeds, quick: bool = False, deadline=None) -> list[dict]:
    from tracking_calibration import flag_rates, stated_sigma

    from seaice_jax.imagery.tracking import CORRELATION_AREA, DISAGREEMENT_SCALE, SIGMA_FLOOR

    runs = realizations("tracking", seeds, tracking_realization, deadline)
    if not runs:
        return []
    done = [r["seed"] for r in runs]
    scaled = all("disagreement" in r for r in runs)  # realizations cached before the scale lack the statistic

    def normalized(r, select):
        sigma = stated_sigma(r, CORRELATION_AREA, SIGMA_FLOOR, DISAGREEMENT_SCALE if scaled else None)
        return (r["error"] / sigma)[select]

    before, _, _ = ratio([normalized(r, np.ones(len(r["uniform"]), bool)) for r in runs])
    edge, _, _ = ratio([normalized(r, ~r["uniform"]) for r in runs])
    scale = f"({DISAGREEMENT_SCALE[0]} + {DISAGREEMENT_SCALE[1]} χ²_ν/m) per axis, m the pair's median χ²_ν"
    stated = (f"σ² = ({SIGMA_FLOOR}² + {CORRELATION_AREA} C₁){scale} (the package's defaults)" if scaled
              else f"σ² = {SIGMA_FLOOR}² + {CORRELATION_AREA} C₁ per axis (the peak alone: realizations without the "
              "neighbour statistic)")
    return [entry("tracking: good vectors of one motion", stated, done,
                  [normalized(r, r["uniform"] & ~r["mixed"]) for r in runs]),
            entry("tracking: good vectors across two motions (patch on the fast-ice edge or a coast, not flagged)",
                  stated, done, [normalized(r, ~r["uniform"] & ~r["mixed"]) for r in runs],
                  note="a patch across two motions sees a mix: its peak's σ describes neither; the vectors the "
                  f"mixed-motion flag does not take (before the flag all such vectors gave {edge:.2f})"),
            entry("tracking: all good vectors (after the mixed-motion flag)", stated, done,
                  [normalized(r, ~r["mixed"]) for r in runs],
                  note=f"{flag_rates(runs)} Before the flag all these vectors gave {before:.2f} (see "
                  "tracking_calibration.md)")]


# ------------------------------------------------------------------------------------------------- deformation

FLOES = 80
AREA = 300_000.0  # m, side of the square
VELOCITY_SIGMA = 0.005  # m/s
GRADIENT_SCALE = 2e-7  # 1/s (about 1.7 % a day)


def deformation_realization(seed: int) -> dict:
    """Floes on a random linear velocity field, velocities with N(0, σ) noise of their stated σ: per triangle the
    errors and stated σ of divergence, shear, vorticity, and the true shear."""
    from seaice_jax.drift.kinematics import deformation

    rng = np.random.default_rng([seed, 29])
    points = rng.uniform(0.0, AREA, (FLOES, 2))
    gradient = rng.normal(0.0, GRADIENT_SCALE, (2, 2))
    velocity = rng.normal(0.0, 0.1, 2) + (points - AREA / 2) @ gradient.T
    sigma = VELOCITY_SIGMA * rng.uniform(0.5, 2.0, (FLOES, 2))
    d = deformation(points, velocity + rng.normal(0.0, 1.0, (FLOES, 2)) * sigma, sigma)
    (ux, uy), (vx, vy) = gradient
    truth = np.array([ux + vy, np.hypot(ux - vy, uy + vx), vx - uy])
    rates = np.stack([d.divergence, d.shear, d.vorticity], 1)
    stated = np.stack([d.sigma_divergence, d.sigma_shear, d.sigma_vorticity], 1)
    return {"error": rates - truth, "sigma": stated, "true_shear": np.full(len(rates), truth[1])}


def row_deformation(seeds, quick: bool = False, deadline=None) -> list[dict]:
    runs = realizations("deformation", seeds, deformation_realization, deadline)
    if not runs:
        return []
    done = [r["seed"] for r in runs]
    out = []
    for k, name in enumerate(("divergence", "shear", "vorticity")):
        out.append(entry(f"deformation: {name} per triangle", f"σ of the {name} from the velocities' σ (first "
                         "order)", done, [r["error"][:, k] / r["sigma"][:, k] for r in runs],
                         note="the shear is the length of a vector of two rates: biased upward where the true "
                         "shear is not large against its σ" if name == "shear" else ""))
    out.append(entry("deformation: shear, triangles with true shear > 3σ",
                     "as above (where the absolute value is nearly linear)", done,
                     [(r["error"][:, 1] / r["sigma"][:, 1])[r["true_shear"] > 3 * r["sigma"][:, 1]] for r in runs]))
    return out


def row_block_strip(seeds, quick: bool = False, deadline=None) -> list[dict]:
    return row_block(seeds, quick, deadline, scope="strip")


ROWS = {"orbit": row_orbit, "coast": row_coast, "block": row_block, "block_strip": row_block_strip,
        "sequence": row_sequence, "sequence_2": row_sequence_2, "tracking": row_tracking,
        "deformation": row_deformation}


# ------------------------------------------------------------------------------------------------------- table

def verdict(e: dict) -> str:
    """``pass``, or what is outside its target: ``FAIL (...)`` where the interval excludes the ideal value (ratio
    1, global test 5 %, w-test α), ``outside band, not significant (...)`` where it does not."""
    failed, chance = [], []
    if not BAND[0] <= e["ratio"] <= BAND[1]:
        (chance if e["interval"][0] <= 1.0 <= e["interval"][1] else failed).append("ratio")
    if "global" in e and not GLOBAL_BAND[0] <= e["global"][0] / e["global"][1] <= GLOBAL_BAND[1]:
        (chance if e["global"][2][0] <= GLOBAL_ALPHA <= e["global"][2][1] else failed).append("global test")
    if "w" in e and e["w"][0] > W_LIMIT:
        (chance if e["w"][4][0] <= 1.0 else failed).append("w-test")
    text = []
    if failed:
        text.append("FAIL (" + ", ".join(failed) + ")")
    if chance:
        text.append("outside band, not significant (" + ", ".join(chance) + ")")
    return "; ".join(text) or "pass"


def table(entries: list[dict]) -> list[str]:
    lines = ["| product | stated | seeds (realizations; values) | empirical / stated σ (90 %) | band | √mean σ̂0² | "
             "global test rejected (95 %) | worst w-test group ÷ α (95 %) | verdict |",
             "|---|---|---|---|---|---|---|---|---|"]
    for e in entries:
        glob = "–" if "global" not in e else (f"{e['global'][0]}/{e['global'][1]} = "
                                              f"{100 * e['global'][0] / e['global'][1]:.1f} % "
                                              f"({100 * e['global'][2][0]:.1f}-{100 * e['global'][2][1]:.1f} %)")
        w = "–" if "w" not in e else (f"{e['w'][0]:.2f} ({e['w'][1]}: {e['w'][2]}/{e['w'][3]}; "
                                      f"{e['w'][4][0]:.2f}-{e['w'][4][1]:.2f})")
        sigma0 = f"{e['sigma0']:.3f}" if "sigma0" in e else "–"
        lines.append(f"| {e['label']} | {e['stated']} | {e['seeds'][0]}-{e['seeds'][1]} ({e['count']}; "
                     f"{e['values']}) | **{e['ratio']:.3f}** ({e['interval'][0]:.3f}-{e['interval'][1]:.3f}) | "
                     f"{BAND[0]}-{BAND[1]} | {sigma0} | {glob} | {w} | {verdict(e)} |")
    notes = [f"- {e['label']}: {e['note']}" for e in entries if e["note"]]
    return lines + ([""] + notes if notes else [])


def timing_text(row: str, times) -> str:
    """``row: N min for k (median s each; load average a-b)`` of ``times``, a list of (seconds, load average)."""
    seconds, load = np.array([t for t, _ in times], float), np.array([a for _, a in times], float)
    text = f"{row}: {np.nansum(seconds) / 60:.1f} min for {len(times)}"
    if np.isfinite(seconds).any():
        text += f" (median {np.nanmedian(seconds):.1f} s each"
        text += (f"; load average {np.nanmin(load):.0f}-{np.nanmax(load):.0f})" if np.isfinite(load).any()
                 else "; load average not recorded)")
    return text


def main(argv=None):
    global _cache_dir, _sequence_ties
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--rows", default="orbit,coast,tracking,deformation,block,block_strip,sequence",
                        help="comma-separated: " + ", ".join(ROWS))
    parser.add_argument("--seeds", type=int, default=None, help="seeds per row (default: per row, "
                        + ", ".join(f"{k} {v}" for k, v in DEFAULT_SEEDS.items()) + ")")
    parser.add_argument("--seed-list", default=None,
                        help="the seeds of every row named, in place of its fresh seeds: comma-separated seeds and "
                        "inclusive ranges A-B (with --seeds: the first that many)")
    parser.add_argument("--quick", action="store_true", help=f"a smoke run: {QUICK_SEEDS} seeds per row")
    parser.add_argument("--minutes", type=float, default=None,
                        help="per row: stop computing new seeds after this many minutes (cached ones still count)")
    parser.add_argument("--table-only", action="store_true",
                        help="compute nothing: the table of the cached seeds (all from each row's first on, unless "
                        "--seeds)")
    parser.add_argument("--cache", type=Path, default=CACHE)
    parser.add_argument("--sequence-ties", type=Path, default=None,
                        help="the sequence row: a folder of experiments/sequence_block.py's matched ties per seed "
                        "(its --cache: ties_<seed>.pkl), read where present, written where not (default: match anew)")
    parser.add_argument("--out", type=Path, default=RESULTS / "calibration.md")
    args = parser.parse_args(argv)
    _cache_dir = args.cache
    _sequence_ties = args.sequence_ties
    given = None if args.seed_list is None else parse_seeds(args.seed_list)
    names = [n.strip() for n in args.rows.split(",") if n.strip()]
    unknown = [n for n in names if n not in ROWS]
    if unknown:
        parser.error(f"unknown rows {unknown}; known: {', '.join(ROWS)}")
    entries, timing = [], []
    load_start = os.getloadavg()
    for name in names:
        count = QUICK_SEEDS if args.quick else (args.seeds or DEFAULT_SEEDS[name])
        if (args.table_only or given is not None and not args.quick) and not args.seeds:
            count = 1_000_000  # every cached seed from the row's first to the first missing; or the whole list
        begin = time.perf_counter()
        deadline = None if args.minutes is None else time.time() + 60 * args.minutes
        if args.table_only:
            deadline = time.time() - 1.0
        entries += ROWS[name](list(seed_range(name, count, given)), args.quick, deadline)
        timing.append(f"{name} {time.perf_counter() - begin:.0f} s")
        print(f"{name}: done ({timing[-1]})", flush=True)
    load_end = os.getloadavg()
    lines = ["# Stated σ against Monte Carlo truth (experiments/calibration.py, issue 29)", "",
             f"`python experiments/calibration.py --rows {','.join(names)}"
             + (" --quick" if args.quick else "") + (f" --seeds {args.seeds}" if args.seeds else "")
             + (f" --seed-list {args.seed_list}" if given is not None else "")
             + (" --table-only" if args.table_only else "") + "`; "
             f"fresh seeds from {FIRST_SEED} (row offsets {ROW_OFFSET}), used for tuning nowhere"
             + ("" if args.table_only else f"; this run's time (cached realizations cost nothing): "
                f"{', '.join(timing)}, load average {load_start[0]:.1f} at the start, {load_end[0]:.1f} at the end, "
                "on 2 cores shared with other work") + ".", "",
             "Empirical / stated: √mean(e²/σ²) over every coordinate of every realization; 90 % interval by "
             "resampling whole seeds. Global test: χ², two-sided, α = 0.05, target 3-7 %. w-test: α = 0.001, alarms "
             "per testable observation (redundancy > 1e-12), worst group, target ≤ 1.5 α.", "",
             *(["**Smoke run** (--quick, 3 seeds a row): the verdicts below mean nothing.", ""] if args.quick else []),
             *table(entries), "",
             "Code the realizations were computed with (the package and experiments/): " + "; ".join(
                 f"{row}: " + ", ".join(f"{rev} ({len(seeds)} seeds)" for rev, seeds in revs.items())
                 for row, revs in _revisions.items()) + ".", "",
             "Compute time of the realizations used (as recorded when each was computed, on the shared 2 cores): "
             + "; ".join(timing_text(row, times) for row, times in _timing.items()) + ".", "",
             *(["Seeds that failed (a package error; left out of the row): " + "; ".join(
                 f"{row} {seed}: {message}" for row, fails in _failures.items() for seed, message in fails), ""]
               if _failures else [])]
    text = "\n".join(lines)
    print(text)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    return entries


if __name__ == "__main__":
    main()
