"""``seaice adjust``: the scan models of an image sequence, per image (the 1985 practice: each image on its own
control points) or simultaneously (all images, tie points found automatically on the static surface, and the control
points in one adjustment: :func:`~seaice_jax.adjust.sequence.adjustment.adjust_sequence`), written with their joint
covariance to ``models.npz``, which ``seaice remap --models`` adopts (``seaice track`` then states drift σ with the
correlation of the two images' geolocation errors).

Compute (:func:`adjust_project` -> :class:`AdjustedSequence`), then write (:func:`write_adjusted`): ``models.npz``,
``ties.csv`` (every tie observation, ``removed`` for those taken out as mismatches) and ``models.csv`` (each
image's unknowns and their σ).
"""

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seaice_jax.adjust.sequence.adjustment import SequenceAdjustment, SequenceOptions, adjust_sequence
from seaice_jax.adjust.sequence.control_test import ControlTest, control_test
from seaice_jax.errors import SeaiceError
from seaice_jax.files import write_csv
from seaice_jax.geometry.scan import SCAN_UNKNOWNS
from seaice_jax.imagery.ties import TieOptions, TiePoints, find_ties, grid_mask
from seaice_jax.io.coastline import land_mask_of_grid
from seaice_jax.io.remapped import save_models
from seaice_jax.io.sequence import MODEL_KEYS, SequenceProject, read_sequence
from seaice_jax.outputs import output_folder
from seaice_jax.workflows.remap import rectify_images
from seaice_jax.workflows.step import Step
from seaice_jax.workflows.track import land_of_grid

METHODS = ("simultaneous", "per-image")


@dataclass(frozen=True)
class AdjustedSequence:
    """The scan models of a sequence and how they were found.

    Attributes:
        names: the images. models: their scan models. covariance: ``(5·images, 5·images)`` joint covariance of
            their unknowns (block diagonal for ``per-image``). sigma0: σ̂0 (per image: the RMS of the fits' σ̂0).
        method: ``"simultaneous"`` or ``"per-image"``. start: the per-image fits (the simultaneous adjustment's
            starting models). ties: the tie points (``None`` per image). adjustment: the
            :class:`SequenceAdjustment` (``None`` per image). control: the control points' test against the ties
            (:func:`~seaice_jax.adjust.sequence.control_test.control_test`; ``None`` per image or without
            redundancy among them).
    """

    names: tuple[str, ...]
    models: tuple
    covariance: np.ndarray
    sigma0: float
    method: str
    start: tuple
    ties: TiePoints | None = None
    adjustment: SequenceAdjustment | None = None
    control: ControlTest | None = None


def static_surface_interior(mask: np.ndarray) -> np.ndarray:
    """``mask`` with every cell whose four neighbours are not all in it removed (a binary erosion by the 3 x 3 cross,
    cells beyond the edge counted out), so that a tie's patch never straddles the static surface's edge."""
    padded = np.pad(mask, 1, constant_values=False)
    return (padded[1:-1, 1:-1] & padded[:-2, 1:-1] & padded[2:, 1:-1] & padded[1:-1, :-2] & padded[1:-1, 2:])


def static_mask_path(project: SequenceProject, static: str | os.PathLike | None) -> Path | None:
    """The static-surface mask: ``static``, else ``static_mask.npy`` or ``land_mask.npy`` beside the project (as
    ``seaice simulate lancaster`` writes them), else ``None``: the coastline's land is then the static surface
    (:func:`~seaice_jax.io.coastline.land_mask_of_grid`)."""
    beside = [project.path.parent / name for name in ("static_mask.npy", "land_mask.npy")]
    if static is None:
        return next((p for p in beside if p.exists()), None)
    path = Path(static)
    if not path.exists():
        raise SeaiceError(f"{path}: no static-surface mask (a .npy bool array on the project's grid: land and fast "
                          "ice); give one with --static")
    return path


def adjust_project(project: SequenceProject, method: str = "simultaneous", static_mask=None,
                   tie_options: TieOptions | None = None, options: SequenceOptions | None = None,
                   progress: bool = False) -> AdjustedSequence:
    """Find the scan models of every image of ``project``.

    Args:
        method: ``"per-image"`` (each image fitted to its control points) or ``"simultaneous"`` (those fits are the
            starting models; ties matched through them on ``static_mask``; all adjusted at once).
        static_mask: ``(n_rows, n_columns)`` bool on the project's grid, True on land and fast ice (eroded by one
            cell before use, so that a tie's patch stays on it); needed by ``"simultaneous"``.
    """
    if method not in METHODS:
        raise SeaiceError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    rectifications, covariance = rectify_images(project, progress)
    names = tuple(r.name for r in rectifications)
    start = tuple(r.model for r in rectifications)
    fitted = [r.sigma0 for r in rectifications if np.isfinite(r.sigma0)]
    if method == "per-image":
        sigma0 = float(np.sqrt(np.mean(np.square(fitted)))) if fitted else float("nan")
        return AdjustedSequence(names, start, covariance, sigma0, method, start)
    if static_mask is None:
        raise SeaiceError("the simultaneous method needs a static-surface mask")
    mask = static_surface_interior(np.asarray(static_mask, bool))
    given = [im.name for im in project.images if im.model is not None]
    if given:
        raise SeaiceError(f"the simultaneous method adjusts every image's scan model from control points and ties: "
                          f"image {given[0]!r} gives its model instead (use --method per-image)")
    blocks = [covariance[5 * k:5 * k + 5, 5 * k:5 * k + 5] for k in range(len(start))]
    ties = find_ties([im.data for im in project.images], start, grid_mask(project.grid, mask), blocks,
                      tie_options or TieOptions())
    adjusted = adjust_sequence(start, ties, [im.control for im in project.images], options=options or SequenceOptions(),
                               image_names=names)
    return AdjustedSequence(names, adjusted.models, adjusted.covariance, adjusted.sigma0, method, start, ties,
                            adjusted, control_test(adjusted))


def adjust_report(result: AdjustedSequence) -> str:
    lines = [f"{result.method} adjustment of {len(result.names)} images, σ̂0 {result.sigma0:.2f}"]
    if result.ties is not None and result.adjustment is not None:
        ties, adjusted = result.ties, result.adjustment
        pairs = ties.pair_counts()
        lines.append(f"  {ties.n_ties} ties, {ties.n_observations} observations, {len(pairs)} overlapping pairs "
                     f"({min(pairs.values()) if pairs else 0}-{max(pairs.values()) if pairs else 0} ties each)")
        lines.append(f"  {adjusted.n_removed} ties removed as mismatches (w-tests at α = {adjusted.alpha}), "
                     f"{adjusted.rounds} adjustments, {adjusted.degrees_of_freedom} degrees of freedom")
        for group, factor in adjusted.variance_factors.items():
            lines.append(f"  {group}: σ estimated {np.sqrt(factor):.2f} times the a priori (variance factor "
                         f"{factor:.3g}); the covariance uses it")
        tested = result.control
        if tested is not None:
            verdict = ("accepted" if tested.accepted else
                       "rejected: the control points and the ties disagree beyond their stated σ"
                       if tested.statistic > tested.degrees_of_freedom else
                       "rejected: the control points agree better than their stated σ (σ too large)")
            lines.append(f"  control points against the ties and the other images (their σ as given, the ties' "
                         f"correlated errors as stated): T {tested.statistic:.1f} on {tested.degrees_of_freedom} "
                         f"degrees of freedom, two-sided p {tested.p_value:.3f} at α = {tested.alpha}: {verdict}")
        for flag in adjusted.flagged()[:5]:
            lines.append(f"  still flagged: {flag.group} row {flag.row} component {flag.component}, w {flag.w:.1f}")
    sigma = np.sqrt(np.diag(result.covariance)).reshape(-1, len(SCAN_UNKNOWNS))
    for name, row in zip(result.names, sigma, strict=True):
        lines.append(f"  {name}: σ " + ", ".join(f"{unknown} {value:.3g}" for unknown, value in
                                                  zip(SCAN_UNKNOWNS, row, strict=True)))
    return "\n".join(lines)


def write_adjusted(result: AdjustedSequence, out_dir: str | os.PathLike) -> tuple[Path, ...]:
    """``models.npz`` (:func:`~seaice_jax.io.remapped.save_models`), ``models.csv`` (each unknown and
    its σ, angles in degrees: the keys of a given model, :data:`~seaice_jax.io.sequence.MODEL_KEYS`) and, for the
    simultaneous method, ``ties.csv``."""
    out = Path(out_dir)
    files = [save_models(out / "models.npz", result.names, result.models, result.covariance, result.sigma0,
                         result.method)]
    sigma = np.sqrt(np.diag(result.covariance)).reshape(-1, len(SCAN_UNKNOWNS))
    columns: dict = {"image": np.array(result.names)}
    for j, (unknown, key) in enumerate(zip(SCAN_UNKNOWNS, MODEL_KEYS, strict=True)):
        scale = 1.0 if key == unknown else np.degrees(1.0)  # subtrack_pixel in pixels, the angles in degrees
        columns[key] = np.array([float(getattr(m, unknown)) for m in result.models]) * scale
        columns[f"sigma_{key}"] = sigma[:, j] * scale
    files.append(write_csv(out / "models.csv", columns, float_format="%.12g"))
    if result.ties is not None and result.adjustment is not None:
        ties = result.ties
        removed = np.isin(ties.tie, np.array(result.adjustment.removed_ties, int))
        files.append(write_csv(out / "ties.csv", {
            "tie": ties.tie, "image": np.array(result.names)[ties.image], "pixel": ties.pixel, "scan": ties.scan,
            "sigma_pixel": ties.sigma_pixel, "sigma_scan": ties.sigma_scan, "reference": ties.reference.astype(int),
            "removed": removed.astype(int)}))
    return tuple(files)


def run_adjust(project_path: str | os.PathLike, out_dir: str | os.PathLike, method: str = "simultaneous",
               static: str | os.PathLike | None = None, progress: bool = True,
               overwrite: bool = False) -> Step[AdjustedSequence]:
    """Adjust a sequence project (:func:`adjust_project`) and write it (:func:`write_adjusted`) as one run."""
    project = read_sequence(project_path)
    inputs: tuple = (project_path,)
    mask = None
    if method == "simultaneous":
        mask_path = static_mask_path(project, static)
        if mask_path is None:
            mask = land_mask_of_grid(project.grid)
        else:
            inputs += (mask_path,)
            mask = land_of_grid(mask_path, project.grid, "static-surface mask")
    with output_folder(out_dir, overwrite, inputs=inputs) as folder:
        result = adjust_project(project, method, mask, progress=progress)
        files = folder.final(write_adjusted(result, folder.path))
    return Step(files, adjust_report(result), result)
