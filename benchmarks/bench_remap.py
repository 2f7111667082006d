"""Remapping throughput (output megapixels per second) of the vmapped JAX path against OpenCV ``cv2.remap`` with
precomputed maps and against a per-pixel Python loop, for 1 to 100 images; tracking time per image pair.
Writes benchmarks/RESULTS.md.

Run: ``.venv/bin/python benchmarks/bench_remap.py [--quick]``.
"""

import argparse
import math
import platform
import sys
import time
from pathlib import Path

import cv2
import equinox as eqx
import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import best_time, publish  # noqa: E402

import seaice_jax  # noqa: E402,F401
from seaice_jax.geometry.projections import MapGrid, nsidc_polar_stereographic  # noqa: E402
from seaice_jax.imagery.remap import remap  # noqa: E402
from seaice_jax.imagery.tracking import track  # noqa: E402
from seaice_jax.simulate.satellite import ice_scene, noaa_pass, render  # noqa: E402


def models_and_images(count, size, rng):
    """``count`` southbound passes with their own nodes and a texture (the speed does not depend on content)."""
    base = noaa_pass("south", size, math.radians(74.0), math.radians(-85.0))
    models = [eqx.tree_at(lambda m: (m.ascending_node, m.orbital_angle_first), base,
                          replace=(base.ascending_node + rng.normal(0, 0.01), base.orbital_angle_first
                                   + rng.normal(0, 0.005))) for _ in range(count)]
    texture = cv2.GaussianBlur(rng.random((size, size)), (0, 0), 2.0)
    return models, [np.roll(texture, k, axis=1) for k in range(count)]


def python_loop_rate(model, image, grid, pixels=400):
    """Output pixels per second of a per-pixel loop: inverse model by the same closed form in ``math`` calls."""
    lat, lon = (np.asarray(a) for a in grid.latitude_longitude())
    inc, node = float(model.orbit.inclination), float(model.ascending_node)
    ratio = float(model.orbit.rotation_ratio)
    eta_ref = float(model.orbital_angle(0.5 * (1 + model.n_scans)))
    span, subtrack = float(model.scanner_angle_span), float(model.subtrack_pixel)
    eta1, eta_span = float(model.orbital_angle_first), float(model.orbital_angle_span)
    flat_lat, flat_lon = lat.ravel()[:pixels], lon.ravel()[:pixels]
    start = time.perf_counter()
    for phi, lam in zip(flat_lat, flat_lon, strict=True):
        eta = eta_ref
        for _ in range(8):
            dl = lam + ratio * eta - node
            g = (math.cos(phi) * math.cos(dl), math.cos(phi) * math.sin(dl), math.sin(phi))
            gy = g[1] * math.cos(inc) + g[2] * math.sin(inc)
            eta_new = math.atan2(gy, g[0])
            eta = eta_new + 2 * math.pi * round((eta - eta_new) / (2 * math.pi))
        beta = -math.asin(-g[1] * math.sin(inc) + g[2] * math.cos(inc))
        p = subtrack - beta * (model.n_pixels - 1) / span
        s = 1.0 + (eta - eta1) * (model.n_scans - 1) / eta_span
        r, c = s - 1.0, p - 1.0
        if 0 <= r < image.shape[0] - 1 and 0 <= c < image.shape[1] - 1:
            i, j = int(r), int(c)
            fr, fc = r - i, c - j
            _ = ((1 - fr) * ((1 - fc) * image[i, j] + fc * image[i, j + 1])
                 + fr * ((1 - fc) * image[i + 1, j] + fc * image[i + 1, j + 1]))
    return pixels / (time.perf_counter() - start)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes, do not write RESULTS.md")
    args = parser.parse_args()
    size, counts = (128, (1, 4)) if args.quick else (512, (1, 10, 100))
    rng = np.random.default_rng(0)
    grid = MapGrid.centred(nsidc_polar_stereographic("north"), math.radians(74.0), math.radians(-85.0), 1200.0,
                           1200.0, size, size)
    megapixels = size * size / 1e6
    lines = [f"Machine: {platform.processor() or platform.machine()}, {jax.devices()[0].platform.upper()}, "
             f"JAX {jax.__version__}, OpenCV {cv2.__version__}. {size} x {size} NOAA-7-like images remapped "
             f"(bilinear) into a {size} x {size} EPSG:3413 grid at 1.2 km; output megapixels per second "
             "(images x grid pixels / wall time), best of 3.", "",
             "| images | JAX vmapped (first call) | JAX vmapped | JAX one by one | cv2.remap, maps precomputed | "
             "cv2.remap incl. maps (JAX inverse) | vmapped ÷ cv2 incl. maps |", "|---|---|---|---|---|---|---|"]
    for count in counts:
        models, images = models_and_images(count, size, rng)
        start = time.perf_counter()
        remap(images, models, grid)
        first = time.perf_counter() - start
        timings = {"vmapped": _best(remap, images, models, grid), "loop": _best(_one_by_one, images, models, grid)}
        latitude, longitude = grid.latitude_longitude()
        _opencv_maps(models[0], latitude, longitude)  # compile once
        start = time.perf_counter()
        maps = [_opencv_maps(model, latitude, longitude) for model in models]
        map_time = time.perf_counter() - start
        timings["cv2"] = _best(_opencv, [i.astype(np.float32) for i in images], maps)
        rate = {k: count * megapixels / t for k, t in timings.items()}
        with_maps = count * megapixels / (timings["cv2"] + map_time)
        lines.append(f"| {count} | {count * megapixels / first:.2f} | {rate['vmapped']:.1f} | {rate['loop']:.1f} | "
                     f"{rate['cv2']:.0f} | {with_maps:.1f} | {rate['vmapped'] / with_maps:.2f} |")
    loop_rate = python_loop_rate(models[0], images[0], grid, 200 if args.quick else 2000)
    lines += ["", f"Per-pixel Python loop (the same inverse model and bilinear sampling in `math`): "
              f"{loop_rate / 1e6:.4f} megapixels per second, {rate['vmapped'] * 1e6 / loop_rate:.0f} times slower "
              "than the vmapped path.", "",
              "cv2.remap with precomputed maps only resamples (float32, positions quantised to 1/32 pixel); the "
              "geometry — the inverse scan model of every output pixel, which changes with every image — is the "
              "expensive part, and JAX computes it in float64 for the whole batch in one call. With identical "
              "geometry for many images (a fixed grid and one model) the maps are computed once and OpenCV's "
              "resampling is the fastest choice."]
    # tracking: one pair of remapped images
    scene = ice_scene(np.random.default_rng(1))
    model = noaa_pass("south", size, math.radians(74.0), math.radians(-85.0))
    pair = [np.asarray(render(scene, model, t)) for t in (0.0, 86400.0)]
    (first_map, second_map), _ = remap(pair, [model, model], grid)
    start = time.perf_counter()
    result = track(first_map, second_map)
    elapsed = time.perf_counter() - start
    lines += ["", f"Tracking one {size} x {size} pair (normalised cross-correlation, 15-pixel patches, ±6 pixels, "
              f"every 8th pixel): {result.row.size} points in {elapsed:.2f} s ({elapsed / result.row.size * 1e3:.2f} "
              "ms per point)."]
    publish("Remapping and tracking (benchmarks/bench_remap.py)", lines, args.quick)


@eqx.filter_jit
def _inverse(model, latitude, longitude):
    return model.inverse(latitude, longitude)


def _opencv_maps(model, latitude, longitude):
    """OpenCV's float32 maps (0-based column, row) of one image: the jitted inverse model per output pixel."""
    pixel, scan = _inverse(model, latitude, longitude)
    return (np.asarray(pixel) - 1).astype(np.float32), (np.asarray(scan) - 1).astype(np.float32)


def _one_by_one(images, models, grid):
    return [remap([i], [m], grid) for i, m in zip(images, models, strict=True)]


def _opencv(images, maps):
    return [cv2.remap(i, mx, my, cv2.INTER_LINEAR, borderValue=np.nan) for i, (mx, my) in zip(images, maps,
                                                                                               strict=True)]


def _best(function, *args):
    """Best wall time over 3 calls after one warm-up call."""
    jax.block_until_ready(function(*args))
    return best_time(function, *args, repeats=3)


if __name__ == "__main__":
    main()
