"""The adjustment engine on the NIST StRD nonlinear-regression suite against scipy.optimize.least_squares.

The engine runs as the test does (``tests/test_nist.py``: dense backend, ``strategy="trust-region"``, both starts
vmapped); scipy solves the same residuals (the same JAX model, the jitted autodiff Jacobian, tolerances 1e-15) by
MINPACK's Levenberg-Marquardt (``method="lm"``) and by its trust-region reflective method with Moré's Jacobian
scaling (``method="trf", x_scale="jac"``), from both certified starts. Accuracy is the smallest log relative error
(LRE, digits) over the parameters and over their standard deviations; cost is the engine's steps (each one
Jacobian and one trial evaluation) and scipy's residual evaluations; time is the warm solve (compiled beforehand).

Run: ``.venv/bin/python benchmarks/bench_nist.py [--quick]`` (``--quick``: five problems, nothing written).
"""

import argparse
import os
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

SCIPY_METHODS = {"lm": {"method": "lm"}, "trf": {"method": "trf", "x_scale": "jac"}}


def scipy_fit(problem, start, method):
    """``(estimates, standard deviations, residual evaluations, seconds)`` by scipy (``SCIPY_METHODS[method]``)."""
    model = model_function(problem.expression, problem.parameters, problem.predictors)
    x, y = jnp.asarray(problem.x), jnp.asarray(problem.observed)
    residuals = jax.jit(lambda b: jax.vmap(model, in_axes=(None, 0))(b, x) - y)
    jacobian = jax.jit(jax.jacfwd(residuals))
    residuals(jnp.asarray(start)), jacobian(jnp.asarray(start))  # compile outside the timing
    began = time.perf_counter()
    result = scipy.optimize.least_squares(lambda b: np.asarray(residuals(jnp.asarray(b))), start,
                                          jac=lambda b: np.asarray(jacobian(jnp.asarray(b))),
                                          xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=20000, **SCIPY_METHODS[method])
    seconds = time.perf_counter() - began
    dof = problem.y.size - len(problem.parameters)
    _, singular, vt = np.linalg.svd(result.jac, full_matrices=False)
    cofactor = (vt.T / singular**2) @ vt
    return result.x, np.sqrt(np.diag(cofactor) * 2 * result.cost / dof), result.nfev, seconds


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    names = NAMES[:3] + ("BoxBOD", "MGH10") if args.quick else NAMES
    lines = ["All 27 problems of the NIST StRD nonlinear-regression suite, both certified starts. LRE: the smallest "
             "log relative error (digits) over the parameters (est.) and their standard deviations (σ); "
             "\"refused\": the engine ended where the data do not determine some parameters and names them "
             "instead of returning an answer; steps: the engine's iterations, evaluations: scipy's residual "
             "evaluations; time: warm solve, ms (the engine includes covariance, redundancy numbers and w-tests of "
             "every observation).", "",
             "| problem | start | engine est. | engine σ | engine steps | engine ms | lm est. | lm σ | lm evaluations "
             "| lm ms | trf est. | trf σ | trf evaluations | trf ms |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    load = os.getloadavg()[0]
    solved = {"engine": 0, **dict.fromkeys(SCIPY_METHODS, 0)}
    wrong = []
    for name in names:
        problem, estimates, sigmas, converged, undetermined, steps = fit(name)
        began = time.perf_counter()
        fit(name)
        engine_ms = 1000 * (time.perf_counter() - began) / 2
        floor = 3.0 if name == "Lanczos1" else 4.0  # Lanczos1's float64 floor (tests/test_nist.py)
        for s in range(2):
            if undetermined[s] or not converged[s]:
                engine = ("refused: " + ", ".join(undetermined[s])) if undetermined[s] else "not converged", ""
            else:
                digits = (log_relative_error(estimates[s], problem.certified).min(),
                          log_relative_error(sigmas[s], problem.certified_sigma).min())
                engine = (f"{digits[0]:.1f}", f"{digits[1]:.1f}")
                solved["engine"] += digits[0] >= 6.0 and digits[1] >= floor
                if digits[0] < 1.0:
                    wrong.append(f"engine {name} {s + 1}")
            cells = [name, str(s + 1), *engine, str(int(steps[s])), f"{engine_ms:.1f}"]
            for method in SCIPY_METHODS:
                estimate, sigma, evaluations, seconds = scipy_fit(problem, problem.starts[s], method)
                digits = (log_relative_error(estimate, problem.certified).min(),
                          log_relative_error(sigma, problem.certified_sigma).min())
                solved[method] += digits[0] >= 6.0 and digits[1] >= floor
                if digits[0] < 1.0:
                    wrong.append(f"{method} {name} {s + 1} (LRE {digits[0]:.1f})")
                cells += [f"{digits[0]:.1f}", f"{digits[1]:.1f}", str(evaluations), f"{1000 * seconds:.1f}"]
            lines.append("| " + " | ".join(cells) + " |")
            print(lines[-1], flush=True)
    starts = 2 * len(names)
    lines += ["", "Engine time: half of one warm call that solves both starts (vmapped), statistics included, the "
              "rank check at the solution and the host work of setting the problem up. An LRE of 15 is exact "
              "agreement; a negative LRE is a wrong answer given as a solution.", "",
              f"Certified to est. LRE ≥ 6 and σ LRE ≥ 4 (Lanczos1: 3, its float64 floor): engine {solved['engine']}"
              f"/{starts} starts, " + ", ".join(f"{m} {solved[m]}/{starts}" for m in SCIPY_METHODS) + ". Wrong "
              "answers given as solutions (est. LRE < 1): " + (", ".join(wrong) if wrong else "none") + f". Load "
              f"average at the start: {load:.1f} (times are comparable within this table, not across machines).",
              ""]
    publish("NIST StRD nonlinear regression: engine vs scipy (benchmarks/bench_nist.py)", lines, args.quick)


if __name__ == "__main__":
    main()
