"""Whole ``seaice`` commands as a person at the terminal runs them: wall and CPU time, peak memory, first run with
an empty compilation cache and second run reusing it. Writes the CLI section of benchmarks/RESULTS.md.

Run: ``.venv/bin/python benchmarks/bench_cli.py [--quick]`` (quick: print, do not write RESULTS.md).
"""

import argparse
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import publish  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SEAICE = Path(sys.executable).with_name("seaice")
TIME = "/usr/bin/time"
RECTIFY = ["rectify", str(ROOT / "examples" / "figure_3_3.csv"), "--satellite", "NOAA-7", "--altitude", "0",
           "--earth-day", "1440"]
DEMO_PROJECT = ["simulate", "aidjex", "--strips", "3", "--features", "200", "--seed", "0"]
"""The radar project ``seaice demo`` writes into ``seaice-demo/aidjex/`` (same scenario, seed and size)."""


@dataclass(frozen=True)
class Run:
    """One command: wall and CPU (user + system) seconds, peak resident memory (MB)."""

    wall: float
    cpu: float
    peak_mb: float


def timed(arguments: list[str], cache: Path | None, folder: Path) -> Run:
    """Run ``seaice arguments`` under ``/usr/bin/time`` with its compilation cache in ``cache`` (None: no cache)."""
    report = folder / "time.txt"
    environment = {**os.environ, "JAX_PLATFORMS": "cpu", "SEAICE_JAX_CACHE_DIR": "" if cache is None else str(cache)}
    command = [TIME, "-o", str(report), "-f", "%e %U %S %M", str(SEAICE), *arguments]
    result = subprocess.run(command, capture_output=True, text=True, env=environment, cwd=folder)
    if result.returncode != 0:
        raise RuntimeError(f"seaice {' '.join(arguments)} failed:\n{result.stderr[-3000:]}")
    wall, user, system, peak_kb = (float(v) for v in report.read_text().split()[-4:])
    return Run(wall, user + system, peak_kb / 1024.0)


def row(name: str, run: Run, target: float | None, runs: list[Run] | None = None) -> str:
    verdict = "" if target is None else (f"≤ {target:g} s: " + ("met" if run.wall <= target else "**not met**"))
    spread = "" if runs is None else " (" + ", ".join(f"{r.wall:.2f}" for r in runs) + ")"
    return f"| {name} | {run.wall:.2f}{spread} | {run.cpu:.2f} | {run.peak_mb:.0f} | {verdict} |"


def median(runs: list[Run]) -> Run:
    """The run of median wall time."""
    return sorted(runs, key=lambda r: r.wall)[len(runs) // 2]


def load() -> str:
    return " / ".join(f"{v:.1f}" for v in os.getloadavg())


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="print only (RESULTS.md untouched)")
    parser.add_argument("--repeats", type=int, default=5, help="rectify runs of each kind (median reported)")
    args = parser.parse_args()
    load_before = load()
    with tempfile.TemporaryDirectory() as temporary:
        folder = Path(temporary)
        help_run = min((timed(["--help"], None, folder) for _ in range(3)), key=lambda r: r.wall)
        version_run = min((timed(["--version"], None, folder) for _ in range(3)), key=lambda r: r.wall)
        no_cache = timed(RECTIFY, None, folder)
        rectify_loads = []
        firsts, seconds = [], []
        for k in range(args.repeats):  # alternating, so that both kinds see the same load
            rectify_loads.append(os.getloadavg()[0])
            firsts.append(timed(RECTIFY, folder / f"cache_{k}", folder))
            seconds.append(timed(RECTIFY, folder / f"cache_{k}", folder))
        rectify_loads.append(os.getloadavg()[0])
        rectify_first, rectify_second = median(firsts), median(seconds)
        cache = folder / "cache_0"
        cache_mb = sum(p.stat().st_size for p in cache.iterdir()) / 2**20
        entries = len(list(cache.iterdir()))
        timed([*DEMO_PROJECT, "--out", str(folder / "aidjex")], None, folder)
        block = ["block", str(folder / "aidjex" / "project.toml"), "--out"]
        block_first = timed([*block, str(folder / "block_1")], cache, folder)
        block_second = timed([*block, str(folder / "block_2")], cache, folder)
    lines = [
        f"`seaice` commands run as a new user would (subprocess under `/usr/bin/time`, CPU backend; machine: "
        f"{os.cpu_count()} cores, load average (1/5/15 min) {load_before} before and {load()} after: other jobs "
        "share the cores, so wall times are upper bounds). First run: empty compilation cache; second run: the "
        "first run's cache (JAX's persistent compilation cache, `~/.cache/seaice_jax/jax` by default).",
        "",
        "| command | wall (s) | CPU (s) | peak memory (MB) | target |",
        "|---|---:|---:|---:|---|",
        row("`seaice --help` (best of 3)", help_run, None),
        row("`seaice --version` (best of 3)", version_run, None),
        row("`seaice rectify examples/figure_3_3.csv …`, `--no-compile-cache`", no_cache, None),
        row(f"`seaice rectify examples/figure_3_3.csv …`, first run (empty cache), median of {args.repeats}",
            rectify_first, 10.0, firsts),
        row(f"`seaice rectify examples/figure_3_3.csv …`, second run, median of {args.repeats}", rectify_second, 3.0,
            seconds),
        row("`seaice block` on the demo's project (3 strips, 200 features), first run", block_first, None),
        row("`seaice block` on the demo's project, second run", block_second, 10.0),
        "",
        "Rectify: first and second runs alternate (each pair with its own empty cache), all walls in brackets; "
        "the 1-minute load average during them went " + " → ".join(f"{v:.1f}" for v in rectify_loads) + ". "
        f"The rectify run left {entries} compiled functions ({cache_mb:.1f} MB) in the cache. A second run still "
        "imports JAX (about 1 s of it on a quiet machine) and traces and lowers every function (the cache is keyed "
        "by the lowered program); only XLA's compilation is skipped. Both pass directions share one compiled solve "
        "(`--direction auto` fits both), and the fit's host-side arithmetic runs in NumPy, not as one compiled "
        "function per JAX operation.",
        "",
    ]
    publish("Command line (benchmarks/bench_cli.py)", lines, args.quick)


if __name__ == "__main__":
    main()
