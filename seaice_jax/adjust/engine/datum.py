"""Datum diagnosis of a block: which free motions (shift, rotation, stretch) nothing fixes, and which unknowns
they involve.

The reduced normal matrix S of the global unknowns (points eliminated, :mod:`.schur`) is column-scaled and its
null space found by eigen-decomposition; each null vector is carried back to the points (Δp = −V⁻¹ Bᵀ Δθ) and the
points' motion fitted, coverage by coverage, by a shift and a 2 × 2 matrix: a shift, a rotation, a stretch or a
deformation of the whole block, named in the error.
"""

import jax
import numpy as np

from seaice_jax.adjust.engine.problem import linearize_all
from seaice_jax.adjust.engine.schur import reduced_system
from seaice_jax.errors import RankDeficiencyError

NULL_TOLERANCE = 1e-8
"""Eigenvalue of the column-scaled reduced normal matrix (relative to the largest) below which a combination of
unknowns counts as free: exactly singular, or held only by second-order effects such as the Earth's curvature (a
block with one control point can turn about it: its rotation is then "determined" at the 1e-9 level)."""


@jax.jit
def _system_at_start(problem, layout):
    linear = linearize_all(problem, problem.start, problem.points)
    reduced, _, point_inverse, _, couple = reduced_system(problem, linear, layout)
    return reduced, point_inverse, couple.matrix, couple.index, couple.point


def check_datum(problem, layout, names, point_coverage, start_points):
    """Raise :class:`RankDeficiencyError` if the reduced normal matrix is singular at the start, saying which free
    motions of the block nothing fixes and which unknowns they involve.

    Args:
        problem, layout: the engine's problem and its Schur tables.
        names: names of the global unknowns. point_coverage: ``(p,)`` coverage of each real point.
        start_points: ``(p, 2)`` their start positions (map metres).
    """
    normal, point_inverse, coupling, index, point = (np.asarray(a) for a in _system_at_start(problem, layout))
    scale = np.sqrt(np.diag(normal))
    dead = scale <= 0
    scaled = normal / np.outer(np.where(dead, 1.0, scale), np.where(dead, 1.0, scale))
    values, vectors = np.linalg.eigh(scaled)
    null = vectors[:, values <= NULL_TOLERANCE * values[-1]]
    if null.shape[1] == 0 and not dead.any():
        return
    n_real = len(point_coverage)
    motions = set()
    for z in null.T:
        z = z / np.where(dead, 1.0, scale)
        moved = np.zeros((point_inverse.shape[0], 2))
        np.add.at(moved, point, np.einsum("mka,mk->ma", coupling, z[index]))
        moved = -np.einsum("pab,pb->pa", point_inverse, moved)[:n_real]
        if np.linalg.norm(moved) <= 1e-9 * np.linalg.norm(z):
            motions.add("separation of unknowns that act alike (no point moves)")
            continue
        motions |= _motions(moved, point_coverage, start_points)
    involved = sorted(set(np.nonzero(dead)[0].tolist()) | set(np.nonzero(np.any(np.abs(null) > 0.1, axis=1))[0]
                                                                .tolist()))
    named = [names[k] for k in involved]
    shown = ", ".join(named[:8]) + (f" and {len(named) - 8} more" if len(named) > 8 else "")
    raise RankDeficiencyError(
        f"datum defect: nothing fixes the block's {' and '.join(sorted(motions)) or 'unknowns'} ({null.shape[1]} free "
        f"combination(s) of the unknowns {shown}); add control points (one fixes a shift, two also the rotation) or "
        "priors on the navigation errors", named)


def _motions(moved, coverage, where):
    """The kinds of motion (shift, rotation, stretch, deformation) of each coverage's points."""
    motions = set()
    for c in np.unique(coverage):
        on = coverage == c
        if np.linalg.norm(moved[on]) <= 1e-6 * np.linalg.norm(moved):
            continue
        centred = where[on] - where[on].mean(axis=0)
        design = np.concatenate([np.ones((int(on.sum()), 1)), centred], axis=1)
        fit, *_ = np.linalg.lstsq(design, moved[on], rcond=None)  # rows: shift, then the 2 x 2 matrix
        if np.linalg.norm(design @ fit - moved[on]) > 0.1 * np.linalg.norm(moved[on]):
            motions.add("deformation")
            continue
        extent = np.sqrt(np.mean(np.sum(centred**2, axis=1)))
        matrix = fit[1:].T
        parts = {"shift": np.hypot(*fit[0]), "rotation": abs(matrix[1, 0] - matrix[0, 1]) / 2 * extent,
                 "stretch": np.linalg.norm((matrix + matrix.T) / 2) * extent}
        motions.update(k for k, v in parts.items() if v > 0.3 * max(parts.values()))
    return motions
