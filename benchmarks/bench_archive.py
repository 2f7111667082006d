"""An archive of simulated images remapped in one process (``seaice remap``) and on a local Dask cluster of 1 and 2
workers (``seaice remap --workers N``): wall times and their ratio, the peak memory of the single process and of
each worker, the per-image cost of a task, and the outputs' equality to the single-process run. Writes
benchmarks/RESULTS.md.

The archive: a project of ``--images`` daily entries cycling through the images of a small simulated sequence
(each with its control points: every image's scan model is fitted, then the image remapped into the 150 x 150
grid of 2.5 km). Every run is timed end to end as the user sees it (interpreter and JAX start, the workers' start and
compilations included; no persistent compilation cache).

Run: ``.venv/bin/python benchmarks/bench_archive.py [--quick] [--images 200] [--size 128]``.
"""

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np

os.environ.setdefault("NPROC", "1")  # before JAX starts, here and in the workers: seaice_jax._small_linalg's deadlock
sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import publish  # noqa: E402

from seaice_jax import simulate_sequence  # noqa: E402
from seaice_jax.io.sequence import write_sequence  # noqa: E402
from seaice_jax.timefmt import time_after  # noqa: E402
from seaice_jax.workflows.simulated_sequence import SIMULATED_GRID  # noqa: E402


def archive_project(root: Path, images: int, size: int, distinct: int = 4) -> Path:
    """A project of ``images`` daily entries cycling through ``distinct`` simulated images (``size`` pixels)."""
    source = write_sequence(simulate_sequence(7, n_images=distinct, size=size), root, SIMULATED_GRID)
    document = tomllib.loads(source.read_text())
    lines = [f'epoch = "{document["epoch"]}"', "[grid]",
             *(f"{key} = {json.dumps(value)}" for key, value in document["grid"].items())]
    for k in range(images):
        entry = {**document["image"][k % distinct], "name": f"D{k:05d}",
                 "time": time_after(document["epoch"], 86400.0 * k + 3600.0)}
        lines += ["[[image]]", *(f"{key} = {json.dumps(value)}" for key, value in entry.items())]
    project = root / "archive.toml"
    project.write_text("\n".join(lines) + "\n")
    return project


_PEAK = ("def peak():\n    for line in open('/proc/self/status'):\n        if line.startswith('VmHWM:'):\n"
         "            return int(line.split()[1]) * 1024\n")

_SINGLE = _PEAK + """import json, sys
from seaice_jax.cli import main
code = main(sys.argv[1:])
print(json.dumps({"client": peak()}))
sys.exit(code)
"""

_DASK = _PEAK + """import json, sys
import numpy as np
from seaice_jax.workflows.archive import run_remap_archive
step = run_remap_archive(sys.argv[1], sys.argv[2], progress=False, workers=int(sys.argv[3]))
workers = {}
for image in step.result.images:
    workers[image.worker] = max(workers.get(image.worker, 0), image.peak_memory)
print(json.dumps({"client": peak(), "workers": list(workers.values()),
                  "task": float(np.median([image.seconds for image in step.result.images]))}))
"""


def measured(code: str, *args: str) -> tuple[float, dict]:
    """Wall time (s) of ``code`` run with ``args`` in its own Python process, and what it printed (JSON)."""
    start = time.perf_counter()
    run = subprocess.run([sys.executable, "-c", code, *args], check=True, capture_output=True, text=True)
    return time.perf_counter() - start, json.loads(run.stdout.splitlines()[-1])


def same_outputs(expected: Path, actual: Path) -> tuple[bool, float]:
    """Whether every file matches (GeoTIFFs, CSV and figure byte for byte; ``remapped.npz`` array for array) and the
    largest difference of the remapped values."""
    names = sorted(p.name for p in expected.iterdir())
    if sorted(p.name for p in actual.iterdir()) != names:
        return False, float("nan")
    same, largest = True, 0.0
    for name in names:
        if name != "remapped.npz":
            same &= (expected / name).read_bytes() == (actual / name).read_bytes()
            continue
        with np.load(expected / name) as a, np.load(actual / name) as b:
            for key in a.files:
                same &= a[key].shape == b[key].shape and np.array_equal(a[key], b[key],
                                                                         equal_nan=a[key].dtype.kind == "f")
            finite = np.isfinite(a["values"])
            largest = float(np.max(np.abs(a["values"][finite] - b["values"][finite]), initial=0.0))
    return bool(same), largest


def main():
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="12 images, do not write RESULTS.md")
    parser.add_argument("--images", type=int, default=200, help="images in the archive")
    parser.add_argument("--size", type=int, default=128, help="pixels of a simulated image (square)")
    args = parser.parse_args()
    images = 12 if args.quick else args.images
    load = os.getloadavg()[0]
    root = Path(tempfile.mkdtemp(prefix="bench_archive."))
    try:
        project = archive_project(root / "project", images, args.size)
        single_seconds, single = measured(_SINGLE, "-q", "--no-compile-cache", "remap", str(project), "--out",
                                          str(root / "single"))
        rows = [f"| one process (`seaice remap`) | {single_seconds:.1f} | 1.00 | {single['client'] / 2**20:.0f} | - | "
                "- | reference |"]
        for workers in (1, 2):
            out = root / f"dask{workers}"
            seconds, run = measured(_DASK, str(project), str(out), str(workers))
            same, largest = same_outputs(root / "single", out)
            rows.append(f"| Dask, {workers} local worker{'s' if workers > 1 else ''} (`--workers {workers}`) | "
                        f"{seconds:.1f} | {single_seconds / seconds:.2f} | {run['client'] / 2**20:.0f} | "
                        f"{', '.join(f'{p / 2**20:.0f}' for p in run['workers'])} | {run['task']:.2f} | "
                        f"{'identical' if same else f'DIFFERENT (max |Δ| {largest:.2e})'} |")
        stack = 17 * images * int(np.prod(SIMULATED_GRID["shape"]))
    finally:
        shutil.rmtree(root, ignore_errors=True)
    lines = [f"{images} simulated images ({args.size} x {args.size} pixels, each with its control points: scan model "
             f"fitted, then remapped into the {SIMULATED_GRID['shape'][0]} x {SIMULATED_GRID['shape'][1]} grid), "
             f"on {os.cpu_count()} CPU cores; load average at the start {load:.1f} (other jobs shared the cores).",
             "",
             "| run | wall time (s) | speed-up over one process | peak memory, main process (MiB) | "
             "peak memory per worker (MiB) | median task (s) | files |",
             "|---|---:|---:|---:|---:|---:|---|",
             *rows,
             "",
             f"Wall time end to end (interpreter, JAX and workers started, compilations included). Peak memory: "
             f"`VmHWM` of the main process (the single process, or Dask's client, which streams `remapped.npz` and "
             f"draws `remapped.png`) and of each worker at the end of its last task. The stack's "
             f"pixels (values, validity, σ) are {stack / 2**20:.0f} MiB; a worker holds one image at a time. "
             f"Median task: read, fit, remap, write one image, in a warm worker. Files: every GeoTIFF, "
             f"`rectification.csv` and `remapped.png` byte for byte and every array of `remapped.npz` equal to the "
             f"single-process run's."]
    publish("Archives on Dask (benchmarks/bench_archive.py)", lines, args.quick)


if __name__ == "__main__":
    main()
