"""Memory guards against the real peaks: for each guarded job (``seaice remap``, ``simulate``, ``movie``, ``track``,
``block``), the largest one its guard accepts under the budget (found by inverting the estimate of
:mod:`seaice_jax.memory`) is run as a ``seaice`` command with an empty compilation cache, under ``/usr/bin/time``,
and its peak resident memory is compared with the estimate: within 1.5x either way, or the estimate is wrong.

The alternative compared against: the estimates the guards used before (8 bytes per grid cell per image, 3 bytes
per film pixel, none for simulate, track and block), printed beside the new ones.

Run: ``.venv/bin/python benchmarks/bench_memory.py [--quick] [--budget GIB]`` (quick: print, do not write
RESULTS.md; ``--budget``: another budget, e.g. 2 for a quicker run; the sizes follow it).
"""

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import publish  # noqa: E402

from seaice_jax.adjust.radar.block import BlockOptions  # noqa: E402
from seaice_jax.io.project import read_project  # noqa: E402
from seaice_jax.memory import BUDGET_VARIABLE, GIB, block_peak, film_peak, remap_peak, simulate_peak, track_peak  # noqa: E402
from seaice_jax.workflows.radar_block import block_unknowns  # noqa: E402

SEAICE = Path(sys.executable).with_name("seaice")
TIME = "/usr/bin/time"
AREA = 375_000.0
"""m: the side of the simulated sequences' grid (150 cells of 2.5 km), kept when the grid is made finer."""
MARGIN = 13
"""Grid cells at each edge without a tracking point at the default patch (15) and search (6)."""


def seaice(arguments, folder: Path, budget: float) -> tuple[float, float, int]:
    """Run ``seaice arguments`` with an empty compilation cache: ``(wall s, peak GiB, exit code)``."""
    report = folder / "time.txt"
    cache = tempfile.mkdtemp(prefix="cache", dir=folder)
    environment = {**os.environ, "JAX_PLATFORMS": "cpu", "SEAICE_JAX_CACHE_DIR": cache,
                   BUDGET_VARIABLE: f"{budget:g}"}
    start = time.perf_counter()
    run = subprocess.run([TIME, "-o", str(report), "-f", "%M", str(SEAICE), "-q", *map(str, arguments)],
                         capture_output=True, text=True, env=environment, cwd=folder)
    wall = time.perf_counter() - start
    if run.returncode not in (0, 1):  # 1: a block that does not converge has still reached its peak
        raise RuntimeError(f"seaice {' '.join(map(str, arguments))} failed:\n{run.stderr[-3000:]}")
    return wall, int(report.read_text().split()[-1]) * 1024 / GIB, run.returncode


def finer_grid(project: Path, n: int, images: int | None = None) -> Path:
    """A copy of a simulated sequence project on an ``n`` x ``n`` grid over the same area (first ``images``)."""
    text = project.read_text()
    head, *entries = text.split("[[image]]")
    head = re.sub(r"pixel_m = \[.*\]", f"pixel_m = [{AREA / n!r}, {AREA / n!r}]", head)
    head = re.sub(r"shape = \[.*\]", f"shape = [{n}, {n}]", head)
    path = project.with_name(f"grid_{n}.toml")
    path.write_text(head + "".join("[[image]]" + e for e in entries[:images]))
    return path


def largest(estimate, low: int, high: int, budget: float) -> int:
    """The largest integer size in [low, high] whose ``estimate(size)`` fits ``budget`` bytes (bisection)."""
    while low < high:
        middle = (low + high + 1) // 2
        low, high = (middle, high) if estimate(middle) <= budget else (low, middle - 1)
    return low


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="print only (RESULTS.md untouched)")
    parser.add_argument("--budget", type=float, default=4.0, help="GiB (default: the guards' default budget)")
    parser.add_argument("--jobs", default="remap,simulate,movie,track,block", help="which jobs, comma-separated")
    args = parser.parse_args()
    jobs = set(args.jobs.split(","))
    budget = args.budget * GIB
    rows = []
    loads = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory() as temporary:
        folder = Path(temporary)
        seaice(["simulate", "lancaster", "--images", "3", "--size", "64", "--out", folder / "sequence"], folder,
               args.budget)
        project = folder / "sequence" / "sequence.toml"
        pixels = 64 * 64

        if "remap" in jobs:
            n = largest(lambda k: remap_peak(k * k, 1, pixels), 150, 20_000, budget)
            wall, peak, _ = seaice(["remap", finer_grid(project, n, 1), "--out", folder / "remap"], folder,
                                   args.budget)
            rows.append((f"`remap`, 1 image on a {n} x {n} grid", remap_peak(n * n, 1, pixels), 8.0 * n * n, peak,
                         wall))

        if "simulate" in jobs:
            size = largest(lambda k: simulate_peak(k, 2), 16, 4096, budget)
            wall, peak, _ = seaice(["simulate", "lancaster", "--images", "2", "--size", size, "--out",
                                    folder / "simulated"], folder, args.budget)
            rows.append((f"`simulate lancaster`, 2 images of {size} x {size}", simulate_peak(size, 2), 0.0, peak, wall))

        if "movie" in jobs:
            seaice(["remap", project, "--out", folder / "remapped"], folder, args.budget)
            scale = largest(lambda s: film_peak(3, 150 * 150 * s * s), 1, 64, budget)
            wall, peak, _ = seaice(["movie", folder / "remapped", "--out", folder / "film.gif", "--scale", scale],
                                   folder, args.budget)
            rows.append((f"`movie --scale {scale}`, 3 frames of {150 * scale} x {150 * scale}",
                         film_peak(3, 150 * 150 * scale * scale), 3.0 * 3 * 150 * 150 * scale * scale, peak, wall))

        if "track" in jobs:
            # every vector good is the estimate's case: images with texture at the grid's resolution, no land mask
            n = largest(lambda k: track_peak((k - 2 * MARGIN) ** 2, k * k, 2), 2 * MARGIN + 1, 5000, budget)
            seaice(["simulate", "lancaster", "--images", "2", "--size", 768, "--out", folder / "textured"], folder,
                   args.budget)
            seaice(["remap", finer_grid(folder / "textured" / "sequence.toml", n), "--out", folder / f"remapped_{n}"],
                   folder, args.budget)
            points = (n - 2 * MARGIN) ** 2
            wall, peak, _ = seaice(["track", folder / f"remapped_{n}", "--out", folder / "drift", "--spacing", "1",
                                    "--land", "none"], folder, args.budget)
            rows.append((f"`track --spacing 1 --land none`, 2 images of {n} x {n} ({points} points)",
                         track_peak(points, n * n, 2), 0.0, peak, wall))

        if "block" in jobs:
            seaice(["simulate", "aidjex", "--strips", "2", "--features", "60", "--out", folder / "aidjex"], folder,
                   args.budget)
            block = read_project(folder / "aidjex" / "project.toml")
            duration = max(s.end_time - s.start_time for c in block.coverages for s in c.strips)

            def unknowns(pieces: int) -> int:  # knots making each strip's spline ``pieces`` long
                options = BlockOptions(navigation_model="spline", navigation_scope="strip",
                                       knot_spacing=duration / pieces * (1 + 1e-9))
                return block_unknowns(block.coverages, options)

            pieces = largest(lambda k: block_peak(unknowns(k)), 1, 100_000, budget)
            spacing = duration / pieces * (1 + 1e-9)
            wall, peak, code = seaice(["block", folder / "aidjex" / "project.toml", "--out", folder / "block",
                                       "--navigation-model", "spline", "--navigation-scope", "strip", "--knot-spacing",
                                       f"{spacing!r}"], folder, args.budget)
            rows.append((f"`block`, spline knots every {spacing:.2f} s ({unknowns(pieces)} unknowns)"
                         + (", not converged" if code else ""), block_peak(unknowns(pieces)), 0.0, peak, wall))
        loads.append(os.getloadavg()[0])
    ratios = np.array([estimate / GIB / peak for _, estimate, _, peak, _ in rows])
    lines = [
        f"The largest job each memory guard accepts under a {args.budget:g} GiB budget, run as a `seaice` command "
        "with an empty compilation cache (subprocess under `/usr/bin/time`, CPU backend, "
        f"{os.cpu_count()} cores; 1-minute load average {loads[0]:.1f} before, {loads[-1]:.1f} after), its peak "
        "resident memory against the estimate (`seaice_jax/memory.py`) and the old guard's figure (the stack or the "
        "film alone; none: no guard).",
        "",
        "| job | estimate (GiB) | old figure (GiB) | peak (GiB) | estimate / peak | wall (s) |",
        "|---|---:|---:|---:|---:|---:|",
        *(f"| {name} | {estimate / GIB:.2f} | {old / GIB:.2f} | {peak:.2f} | {estimate / GIB / peak:.2f} | "
          f"{wall:.0f} |" for name, estimate, old, peak, wall in rows),
        "",
        f"Estimate / peak from {ratios.min():.2f} to {ratios.max():.2f}: "
        + ("every estimate within 1.5x of its peak." if np.all((ratios >= 1 / 1.5) & (ratios <= 1.5)) else
           "**an estimate is off by more than 1.5x**."),
        "",
    ]
    publish("Memory guards (benchmarks/bench_memory.py)", lines, args.quick)


if __name__ == "__main__":
    main()
