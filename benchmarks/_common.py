"""Timing helpers shared by the benchmarks (best of several runs, compile time reported separately)."""

import time
from pathlib import Path

import jax

RESULTS = Path(__file__).with_name("RESULTS.md")


def best_time(function, *args, repeats=5):
    """Best wall time (s) of ``function(*args)`` over ``repeats`` runs; JAX results are waited for."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(function(*args))
        best = min(best, time.perf_counter() - start)
    return best


def first_call_time(function, *args):
    """Wall time of the first call of ``function(*args)`` (trace + compile + run)."""
    start = time.perf_counter()
    jax.block_until_ready(function(*args))
    return time.perf_counter() - start


def update_results(section: str, body: str):
    """Replace (or append) ``## section`` in benchmarks/RESULTS.md with ``body``."""
    text = RESULTS.read_text() if RESULTS.exists() else "# Benchmark results\n\nWritten by benchmarks/*.py.\n"
    header = f"## {section}\n"
    if header in text:
        start = text.index(header)
        end = text.find("\n## ", start + len(header))
        text = text[:start] + header + body + ("" if end < 0 else text[end:])
    else:
        text = text.rstrip("\n") + "\n\n" + header + body
    RESULTS.write_text(text.rstrip("\n") + "\n")


def publish(section: str, lines, quick: bool):
    """Print the section; unless ``quick`` (a smoke run), also write it into RESULTS.md."""
    body = "\n".join(lines)
    print(body)
    if not quick:
        update_results(section, body)
