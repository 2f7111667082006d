"""Drift of features between two coverages and the transformation that best explains it (source 000, section 4).

Positions are planar map coordinates (x east, y north, metres; e.g. a tangent plane). A fit maps the earlier
positions onto the later ones about the earlier centroid c:

* rigid: p' = c + shift + R(θ)(p − c) — the general drift (shift of the centroid) and rotation;
* similarity: p' = c + shift + s R(θ)(p − c);
* affine: p' = c + shift + A (p − c), A a full 2 × 2 matrix (source 000 found a 10 % affinity over 16 days).

The residuals of the rigid fit are the relative motion after removing the general drift. The fits go through the
least-squares engine, so their parameters come with standard deviations.
"""

import functools
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from seaice_jax.adjust.lsq import Adjustment, Observations, Solver, checked_solve, make_solver
from seaice_jax.errors import SeaiceError

TRANSFORMS = ("rigid", "similarity", "affine")


def _rotation(angle):
    c, s = jnp.cos(angle), jnp.sin(angle)
    return jnp.array([[c, -s], [s, c]])


def _matrix(kind, parameters):
    if kind == "rigid":
        return _rotation(parameters["rotation"])
    if kind == "similarity":
        return parameters["scale"] * _rotation(parameters["rotation"])
    return parameters["matrix"]


def _start_parameters(kind):
    start = {"shift": jnp.zeros(2)}
    if kind in ("rigid", "similarity"):
        start["rotation"] = jnp.asarray(0.0)
    if kind == "similarity":
        start["scale"] = jnp.asarray(1.0)
    if kind == "affine":
        start["matrix"] = jnp.eye(2)
    return start


@functools.lru_cache(maxsize=32)
def _transform_solver(kind: str, count: int, sigma: float) -> Solver:
    """One compiled solver per transformation kind, number of points and σ (the points are model arguments)."""

    def model(parameters, args):
        centre, relative = args
        offset = (centre + parameters["shift"])[None, :]
        return {"later": offset + relative @ _matrix(kind, parameters).T}

    return make_solver(model, _start_parameters(kind), {"later": Observations(jnp.zeros((count, 2)), sigma)})


@dataclass(frozen=True)
class TransformFit:
    """A fitted transformation between two point sets.

    Attributes:
        kind: ``"rigid"``, ``"similarity"`` or ``"affine"``.
        centre: ``(2,)`` centroid of the earlier points (the point the rotation/scale act about).
        parameters: ``{"shift": (2,), "rotation": rad, "scale": ...}`` or ``{"shift", "matrix": (2, 2)}``.
        sigma: standard deviation of each scalar parameter, by engine name (``shift[0]``, ``rotation``, ...).
        residuals: ``(n, 2)`` later positions minus transformed earlier positions, metres.
        adjustment: the engine's result (covariance, redundancy, w-tests).
    """

    kind: str
    centre: np.ndarray
    parameters: dict
    sigma: dict
    residuals: np.ndarray
    adjustment: Adjustment

    @property
    def rms(self) -> float:
        """RMS length of the residual vectors, metres."""
        return float(np.sqrt(np.mean(np.sum(self.residuals**2, axis=1))))

    def __call__(self, points):
        """Transform ``(n, 2)`` earlier positions."""
        points = np.asarray(points, float)
        matrix = np.asarray(_matrix(self.kind, self.parameters))
        return self.centre + np.asarray(self.parameters["shift"]) + (points - self.centre) @ matrix.T


def fit_transform(earlier, later, kind: str = "rigid", sigma: float = 1.0) -> TransformFit:
    """Least-squares ``kind`` transformation taking ``earlier`` (n, 2) positions onto ``later`` (n, 2).

    Args:
        sigma: σ of each later coordinate (metres); the earlier positions are taken as exact.

    Raises:
        SeaiceError: too few points or unequal shapes; RankDeficiencyError: collinear points for an affine fit.
    """
    if kind not in TRANSFORMS:
        raise SeaiceError(f"transformation must be one of {', '.join(TRANSFORMS)}, got {kind!r}")
    earlier, later = np.asarray(earlier, float), np.asarray(later, float)
    if earlier.shape != later.shape or earlier.ndim != 2 or earlier.shape[1] != 2:
        raise SeaiceError(f"point sets must both be (n, 2), got {earlier.shape} and {later.shape}")
    bad = np.nonzero(~(np.isfinite(earlier).all(axis=1) & np.isfinite(later).all(axis=1)))[0]
    if bad.size:
        raise SeaiceError(f"point {int(bad[0])}: position is not finite ({bad.size} such points); drop them first")
    needed = {"rigid": 2, "similarity": 2, "affine": 3}[kind]
    if earlier.shape[0] < needed:
        raise SeaiceError(f"a {kind} fit needs at least {needed} points, got {earlier.shape[0]}")
    centre = earlier.mean(axis=0)
    solver = _transform_solver(kind, earlier.shape[0], float(sigma))
    start = dict(_start_parameters(kind), shift=jnp.asarray(later.mean(axis=0) - centre))
    adjustment = checked_solve(solver, {"later": later}, (jnp.asarray(centre), jnp.asarray(earlier - centre)), start)
    parameters = {k: np.asarray(v) for k, v in adjustment.parameters.items()}
    sigma_by_name = {k: float(v) for k, v in adjustment.standard_deviations(a_priori=True).items()}
    return TransformFit(kind, centre, parameters, sigma_by_name, -np.asarray(adjustment.residuals["later"]),
                        adjustment)


@dataclass(frozen=True)
class DriftVectors:
    """Displacements of features between two times.

    Attributes:
        displacement: ``(n, 2)`` metres (x east, y north).
        speed: ``(n,)`` m/s. direction: ``(n,)`` degrees clockwise from north, the direction of motion.
    """

    displacement: np.ndarray
    speed: np.ndarray
    direction: np.ndarray


def drift_vectors(earlier, later, interval_seconds: float) -> DriftVectors:
    """Drift of each feature from ``earlier`` to ``later`` positions ``(n, 2)`` over ``interval_seconds``."""
    if not interval_seconds > 0:
        raise SeaiceError(f"the interval between the coverages must be > 0 s, got {interval_seconds}")
    displacement = np.asarray(later, float) - np.asarray(earlier, float)
    speed = np.hypot(displacement[:, 0], displacement[:, 1]) / interval_seconds
    direction = np.degrees(np.arctan2(displacement[:, 0], displacement[:, 1])) % 360.0
    return DriftVectors(displacement, speed, direction)
