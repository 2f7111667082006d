"""Memory estimates of the large jobs, from their measured peaks, and the budget they are refused beyond.

Each estimate is the peak resident memory of the whole ``seaice`` process (Python, JAX, XLA's compilations with an
empty compilation cache, the arrays and their temporaries), a straight line through peaks measured on this project's
machine class (2 cores, float64) with the sizes that drive it; ``benchmarks/bench_memory.py`` runs the largest job
each guard accepts and compares its peak with the estimate. A job over the budget is refused before it starts, with
the estimate and what drives it; the budget is :data:`DEFAULT_BUDGET` unless ``$SEAICE_MEMORY_GIB`` says otherwise
(a machine with more memory may allow more).

The straight lines (bytes; measured in December 2026, ``benchmarks/RESULTS.md``, «Memory guards»):

* remap: 0.8 GiB + grid cells × (240 + 50 per image) + image pixels × 16 (a 2000² grid: 1.8 GiB for one image,
  2.2 GiB for three; 4000², one image: 5.0 GiB);
* simulate (lancaster): 0.7 GiB + 1 500 per pixel of one image + 2 per pixel of every image (the scene is rendered
  one image at a time; 1024²: 2.1 GiB, 2048²: 6.4 GiB);
* film: 0.3 GiB + 6 per film pixel of every frame + 70 per pixel of one frame (its decorations; 12 frames of
  2400²: 0.95 GiB);
* track: 1.1 GiB + 15 kB per lattice point (its match, its vector, triangles and ellipse in the files and the
  figure: the case of every vector good) + 20 per grid cell of every image (the stack) (97 000 points, 82 % of
  them good: 2.3 GiB; 27 % good: 1.5 GiB);
* block (simultaneous): 0.8 GiB + 800 × (global unknowns)² (the reduced system of the strips' unknowns, its
  factors and their temporaries; a spline navigation model with knots every 3 s on 4 strips of 900 s, 2 432
  unknowns: 5.1 GiB).
"""

import os

from seaice_jax.errors import SeaiceError

GIB = 2**30
DEFAULT_BUDGET = 4 * GIB
"""Bytes a job may need at its peak (estimated) unless ``$SEAICE_MEMORY_GIB`` sets another budget."""
BUDGET_VARIABLE = "SEAICE_MEMORY_GIB"


def memory_budget() -> int:
    """The budget in bytes: ``$SEAICE_MEMORY_GIB`` GiB when set, else :data:`DEFAULT_BUDGET`.

    Raises:
        SeaiceError: naming the variable, when it is not a positive number.
    """
    text = os.environ.get(BUDGET_VARIABLE, "").strip()
    if not text:
        return DEFAULT_BUDGET
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not value > 0 or value == float("inf"):
        raise SeaiceError(f"${BUDGET_VARIABLE}: the memory budget must be a positive number of GiB, got {text!r}")
    return int(value * GIB)


def check_memory(estimate: float, what: str) -> None:
    """Refuse a job whose estimated peak exceeds :func:`memory_budget`.

    Raises:
        SeaiceError: ``what`` (the file, key or option that sizes the job), the estimate and the budget.
    """
    budget = memory_budget()
    if estimate > budget:
        raise SeaiceError(f"{what} needs about {estimate / GIB:.1f} GiB of memory at its peak, more than the "
                          f"{budget / GIB:g} GiB budget (${BUDGET_VARIABLE} sets another)")


def check_disk(needed: float, folder, what: str) -> None:
    """Refuse a job whose output needs more disk than is free where ``folder`` (or its nearest existing parent)
    lies.

    Raises:
        SeaiceError: ``what``, the bytes needed and free.
    """
    import shutil
    from pathlib import Path

    place = Path(folder).absolute()
    while not place.exists() and place != place.parent:
        place = place.parent
    free = shutil.disk_usage(place).free
    if needed > free:
        raise SeaiceError(f"{what} needs about {needed / GIB:.1f} GiB of disk, {free / GIB:.1f} GiB free in {place}")


def remap_peak(cells: int, images: int, image_pixels: int = 0) -> float:
    """Bytes: ``seaice remap`` of ``images`` images (``image_pixels`` pixels in all) onto a grid of ``cells``."""
    return 0.8 * GIB + cells * (240.0 + 50.0 * images) + 16.0 * image_pixels


def simulate_peak(size: int, images: int) -> float:
    """Bytes: ``seaice simulate lancaster`` of ``images`` images of ``size`` x ``size`` pixels."""
    return 0.7 * GIB + size * size * (1500.0 + 2.0 * images)


def simulate_disk(size: int, images: int, grid_cells: int) -> float:
    """Bytes on disk of a simulated sequence: the images (float64) and the truth (seven float64 fields per grid
    cell for every pair of consecutive images)."""
    return 8.0 * images * size * size + 56.0 * max(images - 1, 0) * grid_cells


def film_peak(frames: int, frame_pixels: int) -> float:
    """Bytes: ``seaice movie`` of ``frames`` frames of ``frame_pixels`` pixels each."""
    return 0.3 * GIB + frame_pixels * (6.0 * frames + 70.0)


def track_peak(points: int, cells: int, images: int) -> float:
    """Bytes: ``seaice track`` of ``images`` images of ``cells`` grid cells on a lattice of ``points``."""
    return 1.1 * GIB + 15_000.0 * points + 20.0 * cells * images


def block_peak(unknowns: int) -> float:
    """Bytes: the simultaneous block adjustment of ``unknowns`` global unknowns (strips' navigation and radar)."""
    return 0.8 * GIB + 800.0 * unknowns * unknowns
