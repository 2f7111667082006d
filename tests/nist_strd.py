"""Reader of the NIST StRD nonlinear-regression files (tests/data/nist_strd/*.dat) and their models in JAX."""

import functools
import re
from dataclasses import dataclass
from pathlib import Path

import jax.numpy as jnp
import numpy as np

DATA = Path(__file__).with_name("data") / "nist_strd"
NAMES = ("Misra1a", "Chwirut2", "Chwirut1", "Lanczos3", "Gauss1", "Gauss2", "DanWood", "Misra1b", "Kirby2", "Hahn1",
         "Nelson", "MGH17", "Lanczos1", "Lanczos2", "Gauss3", "Misra1c", "Misra1d", "Roszman1", "ENSO", "MGH09",
         "Thurber", "BoxBOD", "Rat42", "MGH10", "Eckerle4", "Rat43", "Bennett5")
"""The 27 problems, in NIST's order of difficulty (lower, average, higher)."""


@dataclass(frozen=True)
class NistProblem:
    """One certified problem.

    Attributes:
        name: e.g. ``"MGH09"``. expression: the model's right-hand side in Python syntax. response: ``"y"`` or
            ``"log(y)"`` (Nelson). parameters: ``("b1", …)``.
        starts: ``(2, p)`` the certified starting points. certified, certified_sigma: ``(p,)``.
        residual_sum_of_squares: certified. y: ``(n,)``. x: ``(n, k)`` predictors (``x`` or ``x1, x2``).
    """

    name: str
    expression: str
    response: str
    parameters: tuple[str, ...]
    predictors: tuple[str, ...]
    starts: np.ndarray
    certified: np.ndarray
    certified_sigma: np.ndarray
    residual_sum_of_squares: float
    y: np.ndarray
    x: np.ndarray

    @property
    def observed(self):
        """The response the model predicts (log y for Nelson)."""
        return np.log(self.y) if self.response == "log(y)" else self.y


def _python(text: str) -> str:
    return re.sub(r"\s+", " ", text.replace("[", "(").replace("]", ")")).strip()


def read(name: str) -> NistProblem:
    """Parse ``tests/data/nist_strd/{name}.dat``."""
    lines = (DATA / f"{name}.dat").read_text().splitlines()
    model_at = next(i for i, line in enumerate(lines) if line.startswith("Model:"))
    starts_at = next(i for i, line in enumerate(lines) if i > model_at and "starting values" in line.lower())
    text = " ".join(line.strip() for line in lines[model_at + 1:starts_at] if "=" in line or line.strip().startswith(
        ("+", "-", "(")))
    text = re.sub(r"pi = [0-9.E]+", "", text).strip()
    response, expression = text.split("=", 1)
    expression = re.sub(r"\+\s*e\s*$", "", expression.strip()).strip()
    parameters, starts, certified, sigma = [], [], [], []
    for line in lines[starts_at:]:
        match = re.match(r"\s*(b\d+)\s*=\s*(\S+)\s+(\S+)\s+(\S+)\s+(\S+)", line)
        if match:
            parameters.append(match.group(1))
            starts.append((float(match.group(2)), float(match.group(3))))
            certified.append(float(match.group(4)))
            sigma.append(float(match.group(5)))
    rss = float(next(line.split(":")[1] for line in lines if line.startswith("Residual Sum of Squares")))
    data_at = [i for i, line in enumerate(lines) if line.startswith("Data:")][-1]
    columns = lines[data_at].split()[1:]
    table = np.array([[float(v) for v in line.split()] for line in lines[data_at + 1:] if line.strip()])
    return NistProblem(name, _python(expression), "log(y)" if "log" in response else "y", tuple(parameters),
                       tuple(columns[1:]), np.array(starts).T, np.array(certified), np.array(sigma), rss, table[:, 0],
                       table[:, 1:])


_FUNCTIONS = {"exp": jnp.exp, "cos": jnp.cos, "sin": jnp.sin, "arctan": jnp.arctan, "log": jnp.log, "pi": jnp.pi}


@functools.cache
def model_function(expression: str, parameters: tuple[str, ...], predictors: tuple[str, ...]):
    """``f(b (p,), x (k,)) -> ()`` the model at one observation; one function object per expression (so problems
    sharing a model share the engine's compiled solve)."""
    code = compile(expression, "<nist model>", "eval")

    def f(b, x):
        names = dict(zip(parameters, b, strict=True)) | dict(zip(predictors, x, strict=True))
        return eval(code, {"__builtins__": {}}, _FUNCTIONS | names)

    return f


def log_relative_error(estimate, certified):
    """LRE = −log10(|estimate − certified| / |certified|), capped at 15 digits (exact agreement)."""
    estimate, certified = np.asarray(estimate, float), np.asarray(certified, float)
    error = np.abs(estimate - certified) / np.abs(certified)
    return np.where(error > 0, -np.log10(np.maximum(error, 1e-15)), 15.0)
