"""Simultaneous block adjustment: solve time and memory against block size, dense vs Schur complement, and
scipy.optimize.least_squares (trf with a sparse Jacobian) on the same residuals.

Run: ``.venv/bin/python benchmarks/bench_block.py [--quick]`` (``--quick``: small sizes, nothing written).
BLAS runs on one thread (``OPENBLAS_NUM_THREADS=1`` unless set), as in the ``seaice`` command: the datum check's
eigenvalues and the reduced system's Cholesky factor go to OpenBLAS, whose threads spin against XLA's on a busy
machine (the 50-strip warm call: 6.3 s with OpenBLAS's default threads, 1.4 s with one, at a load of 3 on 2 cores).
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy and jax load OpenBLAS (module docstring)

import argparse  # noqa: E402
import platform  # noqa: E402
import resource  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402

import jax
import jax.numpy as jnp
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import scipy.optimize  # noqa: E402
import scipy.sparse  # noqa: E402
from _common import RESULTS, publish  # noqa: E402

from seaice_jax import MEAN_RADIUS  # noqa: E402
from seaice_jax.adjust.engine.problem import block_residuals  # noqa: E402
from seaice_jax.adjust.radar import block  # noqa: E402
from seaice_jax.simulate.aircraft import FlightPlan, aidjex_scenario  # noqa: E402


def one_coverage(strips, features, seed=0):
    scenario = aidjex_scenario(seed, plan=FlightPlan(strips=strips), features=features)
    return replace(scenario, coverages=scenario.coverages[:1])


def timed(function, *args, **kwargs):
    start = time.perf_counter()
    result = function(*args, **kwargs)
    return result, time.perf_counter() - start


def peak_memory_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def scipy_solve(scenario, options):
    """scipy.optimize.least_squares (trf, sparse finite-difference Jacobian from the block's structure) on the
    whitened residuals of the simultaneous model; returns (seconds, function evaluations, final cost)."""
    n = len(scenario.kinds)
    layout = block.layout_block(scenario.coverages, n, scenario.plane, options, MEAN_RADIUS)
    problem = block.block_problem(layout, options, scenario.plane, MEAN_RADIUS, padded=False)
    size, points = problem.start.shape[0], problem.points.shape

    @jax.jit
    def residuals(x):
        theta, where = x[:size], x[size:].reshape(points)
        return jnp.concatenate([block_residuals(b, theta, where).ravel() for b in problem.blocks.values()])

    rows, columns, offset = [], [], 0
    for b in problem.blocks.values():
        m, c = b.sigma.shape
        touched = np.asarray(b.global_index)
        if b.point_index is not None:
            touched = np.concatenate([touched, size + 2 * np.asarray(b.point_index)[:, None] + np.arange(2)], axis=1)
        for component in range(c):
            rows.append(np.repeat(offset + np.arange(m) * c + component, touched.shape[1]))
            columns.append(touched.ravel())
        offset += m * c
    rows, columns = np.concatenate(rows), np.concatenate(columns)
    sparsity = scipy.sparse.coo_matrix((np.ones(rows.size), (rows, columns)),
                                       shape=(offset, size + points[0] * points[1])).tocsr()
    start = np.concatenate([np.asarray(problem.start), np.asarray(problem.points).ravel()])  # the block's own start
    np.asarray(residuals(jnp.asarray(start)))  # compile outside the timing
    fit, seconds = timed(scipy.optimize.least_squares, lambda x: np.asarray(residuals(jnp.asarray(x))), start,
                         jac_sparsity=sparsity, method="trf", x_scale="jac")
    return seconds, fit.nfev, fit.cost


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    sizes = [(2, 250), (4, 1000)] if args.quick else [(4, 1000), (10, 2500), (20, 5000), (50, 10500), (100, 21000)]
    options = block.BlockOptions(solver="schur")
    lines = [f"Machine: {platform.machine()}, {jax.device_count()} {jax.default_backend()} device(s); float64. "
             "One coverage of an AIDJEX-like block (Schuler navigation-error model per flight), navigation-only "
             "start.", "",
             "### Schur-complement solve against block size", "",
             "| strips | points | image observations | unknowns | iterations | first call (s) | warm solve (s) "
             "| warm ms per point | peak RSS (MB) |", "|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    scaling = []
    for strips, features in sizes:
        scenario = one_coverage(strips, features)
        n = len(scenario.kinds)
        result, first = timed(block.simultaneous_block, scenario.coverages, scenario.plane, n, options)
        _, warm = timed(block.simultaneous_block, scenario.coverages, scenario.plane, n, options)
        points = int(np.isfinite(result.positions[0]).all(axis=1).sum())
        unknowns = 2 * points + len(result.parameter_names)
        scaling.append((points, warm, peak_memory_mb()))
        lines.append(f"| {strips} | {points:,} | {result.point_of.size:,} | {unknowns:,} | {result.iterations} | "
                     f"{first:.1f} | {warm:.2f} | {1000 * warm / points:.2f} | {peak_memory_mb():.0f} |")
        print(lines[-1], flush=True)
    lines += ["", "First call = trace + compile + solve; warm = the same block again (end to end, host set-up "
              "included). Time per point roughly constant = linear scaling. Peak RSS is the process's high-water "
              "mark, so with the sizes increasing it is each size's peak (JAX and its compiled code included).", ""]

    lines += ["### Dense backend (QR and SVD of the whole Jacobian) vs Schur-complement backend", "",
              "| strips | points | unknowns | dense second call (s) | Schur warm (s) | dense / Schur | max position "
              "difference (m) |", "|---:|---:|---:|---:|---:|---:|---:|"]
    for strips, features in [(2, 100), (3, 250), (4, 400)]:
        scenario = one_coverage(strips, features, seed=1)
        n = len(scenario.kinds)
        timings = {}
        for solver in ("dense", "schur"):
            chosen = replace(options, solver=solver)
            block.simultaneous_block(scenario.coverages, scenario.plane, n, chosen)
            timings[solver] = timed(block.simultaneous_block, scenario.coverages, scenario.plane, n, chosen)
        (dense, dense_time), (schur, schur_time) = timings["dense"], timings["schur"]
        points = int(np.isfinite(schur.positions[0]).all(axis=1).sum())
        difference = float(np.nanmax(np.abs(dense.positions[0] - schur.positions[0])))
        unknowns = 2 * points + len(schur.parameter_names)
        lines.append(f"| {strips} | {points} | {unknowns} | {dense_time:.2f} | {schur_time:.2f} | "
                     f"{dense_time / schur_time:.1f} | {difference:.1e} |")
        print(lines[-1], flush=True)
    lines += ["", "Both backends are compiled once per block structure (the second call compiles nothing). The dense "
              "backend serves small blocks and checks the Schur backend (same estimates and covariances).", ""]

    lines += ["### scipy.optimize.least_squares (trf, sparse finite-difference Jacobian) on the same residuals",
              "", "| strips | points | scipy (s) | function evaluations | Schur warm (s) | scipy / Schur |",
              "|---:|---:|---:|---:|---:|---:|"]
    for strips, features in ([(2, 250)] if args.quick else [(4, 1000), (10, 2500)]):
        scenario = one_coverage(strips, features, seed=2)
        n = len(scenario.kinds)
        block.simultaneous_block(scenario.coverages, scenario.plane, n, options)
        result, schur_time = timed(block.simultaneous_block, scenario.coverages, scenario.plane, n, options)
        points = int(np.isfinite(result.positions[0]).all(axis=1).sum())
        try:
            seconds, evaluations, _ = scipy_solve(scenario, options)
        except ValueError as error:  # a trial step off the film: NaN residuals, which trf cannot take
            lines.append(f"| {strips} | {points:,} | failed: {error} | | {schur_time:.2f} | |")
        else:
            lines.append(f"| {strips} | {points:,} | {seconds:.1f} | {evaluations} | {schur_time:.2f} | "
                         f"{seconds / schur_time:.0f} |")
        print(lines[-1], flush=True)
    lines += ["", "scipy gets the jitted residual function, the Jacobian's sparsity pattern and `x_scale='jac'`; it "
              "has no covariance, redundancy numbers or w-tests (the Schur timing includes them).", ""]

    if not args.quick:
        figure, (axis, memory_axis) = plt.subplots(1, 2, figsize=(9.5, 3.8))
        points, seconds, memory = np.array(scaling).T
        axis.loglog(points, seconds, "o-", label="Schur complement, warm")
        axis.loglog(points, seconds[0] * points / points[0], "k--", lw=0.8, label="linear")
        axis.set_xlabel("points")
        axis.set_ylabel("solve time (s)")
        axis.grid(alpha=0.3, which="both")
        axis.legend()
        memory_axis.plot(points, memory, "o-")
        memory_axis.set_xlabel("points")
        memory_axis.set_ylabel("peak resident memory (MB)")
        memory_axis.grid(alpha=0.3)
        figure.tight_layout()
        figure.savefig(RESULTS.with_name("block_scaling.png"), dpi=120)
        lines += ["![scaling](block_scaling.png)", ""]
    publish("Simultaneous block adjustment (benchmarks/bench_block.py)", lines, args.quick)


if __name__ == "__main__":
    main()
