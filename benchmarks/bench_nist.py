"""The adjustment engine on the NIST StRD nonlinear-regression suite against scipy.optimize.least_squares.

Both solve the same residuals (the same JAX model, scipy with the jitted autodiff Jacobian, method "lm", tolerances
1e-15) from both certified starts; accuracy is the smallest log relative error (LRE, digits) over the parameters
and over their standard deviations; time is the warm solve (compiled beforehand).

Run: ``.venv/bin/python benchmarks/bench_nist.py [--quick]`` (``--quick``: five problems, nothing written).
"""

import argparse
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize
from _common import publish

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from nist_strd import NAMES, log_relative_error, model_function  # noqa: E402
from test_nist import fit  # noqa: E402


def scipy_fit(problem, start):
    """``(estimates, standard deviations, seconds)`` by scipy's Levenberg-Marquardt (MINPACK)."""
    model = model_function(problem.expression, problem.parameters, problem.predictors)
    x, y = jnp.asarray(problem.x), jnp.asarray(problem.observed)
    residuals = jax.jit(lambda b: jax.vmap(model, in_axes=(None, 0))(b, x) - y)
    jacobian = jax.jit(jax.jacfwd(residuals))
    residuals(jnp.asarray(start)), jacobian(jnp.asarray(start))  # compile outside the timing
    began = time.perf_counter()
    result = scipy.optimize.least_squares(lambda b: np.asarray(residuals(jnp.asarray(b))), start,
                                          jac=lambda b: np.asarray(jacobian(jnp.asarray(b))), method="lm",
                                          xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=20000)
    seconds = time.perf_counter() - began
    dof = problem.y.size - len(problem.parameters)
    _, singular, vt = np.linalg.svd(result.jac, full_matrices=False)
    cofactor = (vt.T / singular**2) @ vt
    return result.x, np.sqrt(np.diag(cofactor) * 2 * result.cost / dof), seconds


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    names = NAMES[:3] + ("MGH09", "Bennett5") if args.quick else NAMES
    lines = ["All 27 problems of the NIST StRD nonlinear-regression suite, both certified starts. LRE: the smallest "
             "log relative error (digits) over the parameters (est.) and their standard deviations (σ); "
             "\"refused\": the engine ended where the data do not determine some parameters and names them "
             "instead of returning an answer; time: warm solve, ms (the engine includes covariance, redundancy "
             "numbers and w-tests of every observation).", "",
             "| problem | start | engine est. | engine σ | engine ms | scipy est. | scipy σ | scipy ms |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for name in names:
        problem, estimates, sigmas, converged, undetermined = fit(name)
        began = time.perf_counter()
        fit(name)
        engine_ms = 1000 * (time.perf_counter() - began) / 2
        for s in range(2):
            if undetermined[s] or not converged[s]:
                engine = ("refused: " + ", ".join(undetermined[s])) if undetermined[s] else "not converged", ""
            else:
                engine = (f"{log_relative_error(estimates[s], problem.certified).min():.1f}",
                          f"{log_relative_error(sigmas[s], problem.certified_sigma).min():.1f}")
            estimate, sigma, seconds = scipy_fit(problem, problem.starts[s])
            lines.append(f"| {name} | {s + 1} | {engine[0]} | {engine[1]} | {engine_ms:.1f} | "
                         f"{log_relative_error(estimate, problem.certified).min():.1f} | "
                         f"{log_relative_error(sigma, problem.certified_sigma).min():.1f} | {1000 * seconds:.1f} |")
            print(lines[-1], flush=True)
    lines += ["", "Engine time: half of one warm call that solves both starts (vmapped), statistics included, the "
              "rank check at the solution and the host work of setting the problem up. An LRE of 15 is exact "
              "agreement; a negative LRE is a wrong answer given as a solution.", ""]
    publish("NIST StRD nonlinear regression: engine vs scipy (benchmarks/bench_nist.py)", lines, args.quick)


if __name__ == "__main__":
    main()
