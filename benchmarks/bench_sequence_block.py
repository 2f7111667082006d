"""Simultaneous adjustment of an image sequence (``adjust_sequence``, engine Schur backend): time per tie for 10, 50
and 200 images, and the first call's compile time. Writes its section of benchmarks/RESULTS.md.

The sequences are synthetic (no imagery): NOAA-like 256 x 256 passes on a lattice of latitude bands and longitude
columns about 200 km apart (alternating directions); ``ties_per_image`` ground points drawn in every image are
observed in it and the later images that see them (exact pixel and scan by the true models plus N(0, 0.3 pixel)),
and, as :func:`~seaice_jax.imagery.ties.find_ties` does, a point seen by more than ``TieOptions.max_images`` (6)
images gives several ties over consecutive runs of them sharing one image
(:func:`~seaice_jax.imagery.ties.image_runs`; the shared image's two observations with their own noise); four control
points per image at σ 500 m; the adjustment starts about one pixel off.

The lattice's interior is seen by more images than its edges, so larger sequences have more observations per tie
(3.5 at 10 images, 4.4 at 200, at most 6); the Schur backend's work per tie is that of its pairs of observations
(Σ k² over the ties, k the tie's observations: 14, 19 and 21 per tie), so the table gives the time per pair too.
The engine's solves (w-test rounds and the variance factor's iterations) and their Gauss-Newton steps are counted
by a wrapper around ``engine.solve``, which also times them.

Measured (benchmarks/RESULTS.md, load 6-11 on 2 cores): the time per tie and solve is nearly constant (CPU 102, 83
and 93 µs at 10, 50 and 200 images; the pairs per tie grow by half, and the reduced system of 5 unknowns per image
is dense); the time per tie grows from 10 to 50 images with the number of solves (4 to 9: at a fixed α the w-tests
flag a number of ties that grows with the observations, removed over 4 rounds instead of 2, each followed by the
variance factor's re-estimation) and not from 50 to 200 (9 solves both). Every round starts from the previous
round's estimates: 23 Gauss-Newton steps instead of 29 over the same 9 solves at 50 images (CPU 6.3 s instead of
6.9, back to back), as about half of a solve is its statistics (cofactors, redundancy numbers and w correlations
of every observation), computed once per solve. The compile times are inflated by other work (tests compiling on
the same cores) and by ``phase_tie_covariance``, whose first call evaluates the scan models eagerly image by image
(12 s at 10 images, 51 s at 50, measured apart; 0.13 and 0.9 s when called again).

BLAS runs on one thread (``OPENBLAS_NUM_THREADS=1`` unless set): the reduced system's Cholesky factor goes to
scipy's OpenBLAS, whose threads, on cores busy with other work, spin against XLA's: a 250 x 250 factor took 0.25 s
instead of 0.7 ms (load 4 on 2 cores), 4 to 5 of them per solve, and the 50- and 200-image runs were dominated by it.

Run: ``.venv/bin/python benchmarks/bench_sequence_block.py [--sizes 10 50 200] [--ties-per-image 130]``.
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy and jax load OpenBLAS (module docstring)

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import update_results  # noqa: E402

import seaice_jax  # noqa: E402,F401
from seaice_jax import (  # noqa: E402
    ControlPoints,  # noqa: E402
    SequenceOptions,
    TiePoints,  # noqa: E402
    adjust_sequence,
)
from seaice_jax.adjust import engine  # noqa: E402
from seaice_jax.adjust.sequence.adjustment import (  # noqa: E402
    correlated_tie_covariance,
    phase_tie_covariance,
    sequence_problem,
    systematic_tie_covariance,
)
from seaice_jax.adjust.sequence.model import scan_unknowns, with_scan_unknowns  # noqa: E402
from seaice_jax.imagery.ties import TieOptions, image_runs  # noqa: E402
from seaice_jax.simulate.satellite import noaa_pass  # noqa: E402

SIZE = 256
START_SIGMA = np.array([2e-4, 0.5, 2e-4, 2e-4, 3e-4])


def synthetic_sequence(n_images: int, ties_per_image: int, rng):
    columns = int(np.ceil(np.sqrt(2 * n_images)))
    models = []
    for k in range(n_images):
        band, column = divmod(k, columns)
        latitude = np.radians(66.0 + 1.8 * band)
        longitude = np.radians(-150.0 + 200.0 / (111.0 * np.cos(latitude)) * column)
        models.append(noaa_pass("south" if k % 2 == 0 else "north", SIZE, latitude, longitude))
    rows, points = [], []
    centres = np.array([[float(m.forward(SIZE / 2, SIZE / 2)[0]), float(m.forward(SIZE / 2, SIZE / 2)[1])]
                        for m in models])
    for k, model in enumerate(models):
        pixel, scan = rng.uniform(20, SIZE - 20, (2, ties_per_image))
        lat, lon = (np.asarray(a) for a in model.forward(pixel, scan))
        near = np.nonzero(np.hypot(centres[:, 0] - centres[k, 0],
                                   (centres[:, 1] - centres[k, 1]) * np.cos(centres[k, 0])) < np.radians(8.0))[0]
        seen = {}
        for o in near:
            p, s = (np.asarray(a) for a in models[o].inverse(lat, lon))
            seen[o] = (p, s, (p > 1) & (p < SIZE) & (s > 1) & (s < SIZE))
        # a point belongs to the image that drew it and to later ones only; its ties are runs of those images
        for t in range(ties_per_image):
            images = [o for o, v in seen.items() if o >= k and v[2][t]]
            if len(images) < 2:
                continue
            for run in image_runs(images, TieOptions().max_images):
                tie = len(points)
                points.append((lat[t], lon[t]))
                rows += [(o, tie, seen[o][0][t], seen[o][1][t]) for o in run]
    table = np.array(rows)
    noise = rng.normal(0, 0.3, (len(table), 2))
    sigma = np.full(len(table), 0.3)
    points = np.array(points)
    ties = TiePoints.measured(table[:, 0].astype(int), table[:, 1].astype(int), table[:, 2] + noise[:, 0],
                              table[:, 3] + noise[:, 1], sigma, sigma, points[:, 0], points[:, 1])
    controls = []
    for model in models:
        pixel, scan = rng.uniform(10, SIZE - 10, (2, 4))
        lat, lon = (np.asarray(a) for a in model.forward(pixel, scan))
        north, east = rng.normal(0, 500.0, (2, 4)) / 6_371_000.0
        controls.append(ControlPoints(pixel, scan, lat + north, lon + east / np.cos(lat), 500.0))
    start = [with_scan_unknowns(m, scan_unknowns(m) + rng.normal(0, START_SIGMA)) for m in models]
    return models, start, ties, controls


def tie_terms_time(result) -> float:
    """Wall time (s) of the covariance's tie error terms on ``result``'s final problem (after one call to compile
    the linearization)."""
    options = SequenceOptions()
    problem = sequence_problem(result.observations)
    sizes = np.array([(m.n_pixels, m.n_scans) for m in result.models])
    cofactor = np.asarray(result.adjustment.cofactor)

    def terms():
        return (correlated_tie_covariance(problem, result.adjustment, cofactor, 1.0, options.tie_correlation)
                + systematic_tie_covariance(problem, result.adjustment, result.observations.reference_image, sizes,
                                            cofactor, options.tie_offset_factor, options.tie_gradient_factor)
                + phase_tie_covariance(problem, result.adjustment, result.observations, cofactor,
                                       options.tie_phase_sigma))

    terms()
    began = time.perf_counter()
    terms()
    return time.perf_counter() - began


class EngineSolves:
    """Within ``with``: every ``engine.solve`` (called through the module by ``adjust_sequence`` and the variance
    components) counted, its Gauss-Newton steps summed and its wall time (result waited for) added up."""

    def __enter__(self):
        self.solves, self.steps, self.seconds = 0, 0, 0.0
        self.original = engine.solve

        def solve(*args, **kwargs):
            began = time.perf_counter()
            result = self.original(*args, **kwargs)
            self.steps += int(result.steps)
            self.seconds += time.perf_counter() - began
            self.solves += 1
            return result

        engine.solve = solve
        return self

    def __exit__(self, *exc):
        engine.solve = self.original


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--sizes", type=int, nargs="+", default=[10, 50, 200])
    parser.add_argument("--ties-per-image", type=int, default=130)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    load = os.getloadavg()[0]
    lines = ["Synthetic sequences (module docstring of `benchmarks/bench_sequence_block.py`), "
             f"{args.ties_per_image} ground points drawn per image, at most {TieOptions().max_images} images per tie "
             "(`TieOptions.max_images`); `adjust_sequence` with its defaults (Schur backend, w-test rounds each "
             "started from the previous round's estimates, the ties' variance factor, the correlated and systematic "
             "tie error terms of the covariance). First call: trace + compile + solve; compile: first call − warm "
             "call; warm: the same call again (compiled), wall and process CPU time (CPU: the work, less the waits "
             "for cores that other processes hold); of it, the engine's solves (w-test rounds and variance "
             "iterations; their Gauss-Newton steps) and the tie error terms (`correlated_tie_covariance`, "
             "`systematic_tie_covariance`, `phase_tie_covariance`, timed apart on the final problem).", "",
             "| images | ties | observations per tie | observation pairs (Σ k²) | rounds | solves (steps) "
             "| first call (s) | compile (s) | warm call (s) | warm CPU (s) | of it solves (s) | tie error terms (s) "
             "| warm µs per tie | warm µs per tie per solve (wall / CPU) | warm µs per pair | σ̂0 |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for n_images in args.sizes:
        models, start, ties, controls = synthetic_sequence(n_images, args.ties_per_image, rng)
        began = time.perf_counter()
        adjust_sequence(start, ties, controls)
        first = time.perf_counter() - began
        with EngineSolves() as solves:
            began, cpu = time.perf_counter(), time.process_time()
            result = adjust_sequence(start, ties, controls)
            warm, cpu = time.perf_counter() - began, time.process_time() - cpu
        terms = tie_terms_time(result)
        n_ties = ties.latitude.size
        pairs = int(np.sum(np.bincount(ties.tie) ** 2))
        lines.append(f"| {n_images} | {n_ties} | {ties.image.size / n_ties:.2f} | {pairs} | {result.rounds} | "
                     f"{solves.solves} ({solves.steps}) | {first:.1f} | {first - warm:.1f} | {warm:.2f} | {cpu:.2f} | "
                     f"{solves.seconds:.2f} | {terms:.2f} | {1e6 * warm / n_ties:.0f} | "
                     f"{1e6 * warm / n_ties / solves.solves:.0f} / {1e6 * cpu / n_ties / solves.solves:.0f} | "
                     f"{1e6 * warm / pairs:.0f} | {result.sigma0:.2f} |")
        print(lines[-1], flush=True)
    lines += ["", f"Machine: {os.cpu_count()} cores, load average {load:.1f} at the start and "
              f"{os.getloadavg()[0]:.1f} at the end (other work sharing the cores slows every column alike); "
              f"OPENBLAS_NUM_THREADS={os.environ['OPENBLAS_NUM_THREADS']} (module docstring).",
              "Per tie and solve the time is about constant; per tie and call it grows with the number of solves: "
              "at a fixed α the w-tests flag a number of good ties that grows with the observations, removed over "
              "more rounds, each followed by the variance factor's re-estimation."]
    update_results("Simultaneous adjustment of image sequences (bench_sequence_block.py)", "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
