"""Orbit fit speed: the engine's damped Gauss-Newton (jitted) against the 1985 Appendix C search and against
scipy.optimize.least_squares on the same residuals; a vmapped batch of image fits against a Python loop.
Writes benchmarks/RESULTS.md.

Run: ``.venv/bin/python benchmarks/bench_orbit_fit.py [--quick]``.
"""

import argparse
import os
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import least_squares as scipy_least_squares

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import best_time, first_call_time, publish  # noqa: E402

import seaice_jax  # noqa: E402,F401
from seaice_jax import OrbitFit, fit_scan_model  # noqa: E402
from seaice_jax.adjust.orbit.appendix_c import appendix_c_search  # noqa: E402
from seaice_jax.adjust.orbit.fit import control_args, initial_guess, orbit_solver  # noqa: E402
from seaice_jax.simulate.satellite import noaa_image, perturb_known_positions, simulate_control_points  # noqa: E402


def wall_and_cpu(function, *args, repeats=5):
    """Best wall time and best process CPU time (s) of ``function(*args)`` over ``repeats`` runs (on a shared
    machine the CPU time is what the run itself cost; the wall time adds waiting for a core)."""
    wall, cpu = float("inf"), float("inf")
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        jax.block_until_ready(function(*args))
        wall, cpu = min(wall, time.perf_counter() - start), min(cpu, time.process_time() - start_cpu)
    return wall, cpu


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    load_before = " / ".join(f"{v:.1f}" for v in os.getloadavg())
    rng = np.random.default_rng(0)
    truth = noaa_image("south")
    control, lat, lon = simulate_control_points(truth, 7, rng, 1000.0)
    observed = {"latitude": control.latitude, "longitude": control.longitude}
    fit_args = control_args(control)

    # Gauss-Newton: the whole public call (initial guess + compile + solve + rank checks), then the warm solver
    start = time.perf_counter()
    public = fit_scan_model(control, truth.orbit, direction="south", n_pixels=truth.n_pixels, n_scans=truth.n_scans)
    public_seconds = time.perf_counter() - start
    start = time.perf_counter()
    fit_scan_model(control, truth.orbit, direction="south", n_pixels=truth.n_pixels, n_scans=truth.n_scans)
    public_warm_seconds = time.perf_counter() - start
    guess = initial_guess(control, truth.orbit, "south", truth.n_pixels, truth.n_scans)
    solver = orbit_solver(control, guess, factorization="lapack")  # the fastest for one image at a time
    solve = jax.jit(lambda obs: solver(obs, fit_args))
    gn_compile = first_call_time(solve, observed)
    gn_seconds = best_time(solve, observed, repeats=20)
    gn = solve(observed)
    gn_rms = OrbitFit(gn.parameters, control, "gauss-newton", int(gn.steps)).rms_km

    # scipy least_squares (trf) on the same whitened residuals, with the same autodiff Jacobian, same start
    whitened = jax.jit(lambda x: solver.residuals(x, observed, fit_args))
    jacobian = jax.jit(lambda x: solver.jacobian_at(x, observed, fit_args))
    x0 = np.asarray(solver.start)
    jax.block_until_ready((whitened(x0), jacobian(x0)))

    def run_scipy():
        return scipy_least_squares(lambda x: np.asarray(whitened(x)), x0,
                                   jac=lambda x: np.asarray(jacobian(x)),  # pyright: ignore[reportArgumentType]
                                   method="trf", xtol=1e-10, ftol=1e-10, gtol=1e-10)

    reference = run_scipy()
    scipy_seconds = best_time(run_scipy, repeats=5)
    difference = float(np.max(np.abs(reference.x - np.asarray(solver.flatten(gn.parameters)))))

    # Appendix C, as the manual tells the operator (two starts), compile included (one per search)
    start = time.perf_counter()
    model, evaluations = appendix_c_search(control, truth.orbit, "south", truth.n_pixels, truth.n_scans)
    appendix_seconds = time.perf_counter() - start
    appendix_rms = OrbitFit(model, control, "appendix_c", evaluations).rms_km

    lines = [
        "Simulated NOAA-7 image, 7 control points (σ 1 km), southbound, best of repeated runs.",
        "",
        "| method | time per fit | RMS at points (km) | iterations / evaluations | notes |",
        "|---|---:|---:|---:|---|",
        f"| Gauss-Newton, jitted solver (warm) | {gn_seconds * 1e3:.2f} ms | {gn_rms:.4f} | {int(gn.steps)} | "
        f"first call (compile) {gn_compile:.2f} s |",
        f"| `fit_scan_model` (public call: initial guess, compile, rank checks) | {public_seconds:.2f} s | "
        f"{public.rms_km:.4f} | {public.iterations} | one-off per number of control points |",
        f"| `fit_scan_model` again (same number of points: compiles nothing) | {public_warm_seconds * 1e3:.1f} ms | "
        f"{public.rms_km:.4f} | {public.iterations} | initial guess, solve, rank check at the solution |",
        f"| scipy.optimize.least_squares (trf), same residuals and autodiff Jacobian | {scipy_seconds * 1e3:.2f} ms "
        f"| {gn_rms:.4f} | {reference.nfev} evaluations | max parameter difference to GN {difference:.1e} |",
        f"| Appendix C search (1985), compiled loops | {appendix_seconds:.2f} s | {appendix_rms:.4f} | "
        f"{evaluations:,} position evaluations | compile included |",
        "",
        f"Gauss-Newton / scipy: {scipy_seconds / gn_seconds:.1f}x faster; Gauss-Newton / Appendix C: "
        f"{appendix_seconds / gn_seconds:,.0f}x faster (warm GN) and {appendix_seconds / public_seconds:.1f}x "
        "(GN public call, compile included).",
        "",
    ]

    # a batch of image fits: vmap against a Python loop over the same jitted single fit
    sizes = [10, 100] if args.quick else [10, 100, 1000]
    loop_count = 50 if args.quick else 200
    lines += ["### Batch of image fits (same control layout, independent noisy control positions)", "",
              "| images | vmapped (s) | per image (ms) | Python loop per image (ms) | speed-up | "
              "speed-up in CPU time | vmapped compile (s) | iterations, median / slowest image | all converged | "
              "largest difference to the single fit (σ) |",
              "|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|"]
    batch_solver = orbit_solver(control, guess)  # Jacobi rotations: vectorized across the images
    batch = jax.jit(jax.vmap(lambda a, b: batch_solver({"latitude": a, "longitude": b}, fit_args)))
    lats, lons = perturb_known_positions(lat, lon, 1000.0, rng, loop_count)
    loop_per_image, loop_cpu_per_image = float("inf"), float("inf")
    for _ in range(5):  # best of five passes, as the batches are best of five
        start, start_cpu = time.perf_counter(), time.process_time()
        for k in range(loop_count):
            jax.block_until_ready(solve({"latitude": jnp.asarray(lats[k]), "longitude": jnp.asarray(lons[k])}))
        loop_per_image = min(loop_per_image, (time.perf_counter() - start) / loop_count)
        loop_cpu_per_image = min(loop_cpu_per_image, (time.process_time() - start_cpu) / loop_count)
    for n in sizes:
        lats, lons = (jnp.asarray(a) for a in perturb_known_positions(lat, lon, 1000.0, rng, n))
        compile_seconds = first_call_time(batch, lats, lons)
        seconds, cpu_seconds = wall_and_cpu(batch, lats, lons, repeats=5)
        result = batch(lats, lons)
        steps = np.asarray(result.steps)
        difference = 0.0  # the first ten images solved one at a time (LAPACK): the same estimates?
        for k in range(10):
            one = solve({"latitude": lats[k], "longitude": lons[k]})
            sigma = np.sqrt(np.diag(np.asarray(one.covariance)))
            batched = np.array([float(getattr(result.parameters, name)[k]) for name in solver.parameter_names])
            single = np.array([float(getattr(one.parameters, name)) for name in solver.parameter_names])
            difference = max(difference, float(np.max(np.abs(batched - single) / sigma)))
        lines.append(f"| {n:,} | {seconds:.3f} | {seconds / n * 1e3:.3f} | {loop_per_image * 1e3:.2f} | "
                     f"{loop_per_image * n / seconds:.1f}x | {loop_cpu_per_image * n / cpu_seconds:.1f}x | "
                     f"{compile_seconds:.2f} | {np.median(steps):.0f} / "
                     f"{steps.max()} | {bool(jnp.all(result.converged))} | {difference:.1e} |")
    load_after = " / ".join(f"{v:.1f}" for v in os.getloadavg())
    lines += ["", f"The Python loop calls the warm jitted single-image solver {loop_count} times, best of five passes "
              "(same start for every image, as in the batch), with LAPACK's factorization, the faster for one image "
              "at a time (the Jacobi rotations run as a chain of small kernels there); the last column compares the "
              "batch with these single fits. The batches are best of five runs. Wall-clock speed-up as the issue "
              "asks; the CPU-time speed-up (process CPU time, both sides) is what the work itself costs on a shared "
              "machine, where the single-thread Python loop waits for a core more than the batch. The engine's "
              "damped Gauss-Newton is one `lax.while_loop`; under `vmap` a converged image keeps its state but the "
              "loop runs until the slowest image has converged (median against slowest above). An iteration "
              "linearizes once, at the trial point (its square sum decides the step; an accepted step keeps the "
              "linearization for the next iteration and for the statistics). The batch's solver factors by one-sided"
              " Jacobi rotations in elementwise operations (`orbit_solver`'s default, "
              "`EngineOptions.factorization=\"jacobi\"`), which vectorize across the lanes (LAPACK's QR and SVD, "
              "which XLA on CPU runs matrix by matrix under `vmap`, took about half of an iteration before), an "
              "iteration's rotations starting from the previous iteration's and stopping at 1e-6 orthogonality, the "
              "statistics' rotating to roundoff. The first iteration (the start's linearization, the factorization "
              "of its Jacobian and the first trial) runs before the loop: the images of a batch share the start and "
              "the control layout (only the known positions differ), so under `vmap` that factorization is computed "
              "once for all of them (from the identity in every lane, each rotated for several sweeps). The fits "
              "stop when the Gauss-Newton step left is below 1e-6 of the estimates' σ "
              "(`orbit_fit.DECREASE_TOLERANCE`: the estimates then lie within ~1e-9 σ of the minimum, tested); at "
              "1e-10 σ a few per cent of the images took a fifth iteration, which under `vmap` all of them paid. The"
              " scan model's Jacobian comes from closed-form partials of the great-circle geometry (a custom JVP, "
              "checked against autodiff in tests/test_small_factorization.py) instead of autodiff through every "
              "operation.",
              f"Load average (1/5/15 min) {load_before} at the start, {load_after} at the end, on 2 cores shared "
              "with other work.", ""]
    publish("Orbit fit (benchmarks/bench_orbit_fit.py)", lines, args.quick)


if __name__ == "__main__":
    main()
