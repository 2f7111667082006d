"""Remapping throughput (output megapixels per second) for 1, 10 and 100 images: the approximate transformer +
``cv2.remap`` (the default path) against OpenCV ``cv2.remap`` with exact maps (their computation included, and
excluded), the vmapped exact JAX path and pyresample; the largest map error against the exact inverse; tracking
time per image pair. Writes benchmarks/RESULTS.md.

Run: ``.venv/bin/python benchmarks/bench_remap.py [--quick]``.
"""

import argparse
import math
import os
import platform
import sys
import time
from pathlib import Path

import cv2
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import best_time, publish  # noqa: E402

import seaice_jax  # noqa: E402,F401
from seaice_jax import (  # noqa: E402
    MapGrid,
    nsidc_polar_stereographic,
    remap,  # noqa: E402
    track,  # noqa: E402
)
from seaice_jax.imagery.remap import remap_exact, scan_maps, stack_models  # noqa: E402
from seaice_jax.simulate.satellite import ice_scene, noaa_pass, render  # noqa: E402

try:
    import pyresample.geometry
    import pyresample.kd_tree
except ImportError:  # the optional `bench` extra
    pyresample = None


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
    grid = MapGrid.centred(nsidc_polar_stereographic("north"), math.radians(74.0), math.radians(-85.0),
                           1200.0 * 512 / size, 1200.0 * 512 / size, size, size)
    latitude, longitude = grid.latitude_longitude()
    megapixels = size * size / 1e6
    load = os.getloadavg()[0]
    started = time.perf_counter()
    rows, errors = [], []
    for count in counts:
        models, images = models_and_images(count, size, rng)
        start = time.perf_counter()
        remap(images, models, grid)
        first = time.perf_counter() - start
        repeats = 1 if count >= 100 else 3
        stacked = stack_models(models)
        exact = _exact_maps(stacked, latitude, longitude)
        approximate = scan_maps(models, grid)
        inside = (exact[1] >= -0.5) & (exact[1] <= size - 0.5) & (exact[0] >= -0.5) & (exact[0] <= size - 0.5)
        error = np.hypot(approximate.column - exact[0], approximate.row - exact[1])
        errors.append((np.max(error[inside]), np.max(error), approximate.exact_points / (count * size * size)))
        maps = [(exact[0][k], exact[1][k]) for k in range(count)]
        timings = {
            "approximate": _best(repeats, remap, images, models, grid),
            "cv2 incl. maps": _best(repeats, _opencv_with_maps, images, stacked, latitude, longitude),
            "cv2": _best(repeats, _opencv, images, maps),
            "exact JAX": _best(repeats, remap_exact, images, models, grid),
        }
        if pyresample is not None:  # one image at a time: timed on at most 10 of them, scaled
            timed = min(count, 10)
            timings["pyresample"] = _pyresample(images[:timed], models[:timed], latitude, longitude) * count / timed
        rate = {k: count * megapixels / t for k, t in timings.items()}
        rows.append((count, first, rate))
    elapsed = time.perf_counter() - started
    lines = [f"Machine: {platform.processor() or platform.machine()}, {jax.devices()[0].platform.upper()}, "
             f"JAX {jax.__version__}, OpenCV {cv2.__version__}"
             + (f", pyresample {pyresample.__version__}" if pyresample is not None else ", pyresample not installed")
             + f". {size} x {size} NOAA-7-like float64 images remapped into a {size} x {size} EPSG:3413 grid at "
             f"{1.2 * 512 / size:.1f} km; output megapixels per second (images x grid pixels / wall time), best of 3 "
             f"(1 for 100 images) after a warm-up call, all columns measured side by side in one run "
             f"({elapsed:.0f} s; load average {load:.1f} at the start, {os.getloadavg()[0]:.1f} at the end, on 2 "
             "cores shared with other work).", "",
             "| images | approximate + cv2.remap (default) | first call | cv2.remap incl. exact maps | "
             "cv2.remap, maps precomputed | exact JAX, vmapped | pyresample (nearest, kd-tree) | "
             "approximate ÷ cv2 incl. maps | approximate ÷ cv2 precomputed | largest map error (pixels) |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for (count, first, rate), (inside_error, _, _) in zip(rows, errors, strict=True):
        lines.append(f"| {count} | {rate['approximate']:.1f} | {first:.2f} s | {rate['cv2 incl. maps']:.1f} | "
                     f"{rate['cv2']:.0f} | {rate['exact JAX']:.1f} | "
                     f"{rate.get('pyresample', math.nan):.2f} | {rate['approximate'] / rate['cv2 incl. maps']:.1f} | "
                     f"{rate['approximate'] / rate['cv2']:.2f} | {inside_error:.4f} |")
    worst = max(e[1] for e in errors)
    fraction = max(e[2] for e in errors)
    loop_rate = python_loop_rate(models[0], images[0], grid, 200 if args.quick else 2000)
    lines += ["", "Approximate: `remap` with its default `max_error_pixels=0.05` — the exact inverse scan model on "
              "a lattice every 16 output pixels (the corners of 32 x 32 tiles, their centres and edge midpoints), "
              "bilinear maps in between, a tile split where a checkpoint misses by more than half the threshold, "
              "the exact inverse again for pixels within the threshold of an image edge (so the masks equal the "
              "exact path's), then `cv2.remap` (bilinear). The exact inverse ran at "
              f"{fraction:.2%} of the output pixels at most. Largest map error: over the pixels inside an image "
              f"(as tabled) and {worst:.4f} over the whole grid, against the exact float64 inverse of every pixel. "
              "First call: the first `remap` of that many images in the process (the exact transform compiles in "
              "the first row; the later rows reuse it).",
              "cv2.remap incl. exact maps: the exact inverse of every output pixel, all images in one jitted vmapped "
              "call (float64, to float32 maps), then `cv2.remap`; maps precomputed: `cv2.remap` alone. "
              "Exact JAX: `remap_exact` (the exact inverse and a JAX gather, the differentiable path; "
              "`max_error_pixels=0`).",
              "pyresample: the same job from the other side — every source pixel geolocated by the forward scan "
              "model (jitted), then `kd_tree.resample_nearest` (radius 2 km) from that swath to the grid's "
              "latitudes and longitudes, one image at a time, one call timed (for 100 images: 10 of them, "
              "scaled).",
              f"Per-pixel Python loop (the same inverse model and bilinear sampling in `math`): "
              f"{loop_rate / 1e6:.4f} megapixels per second."]
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
def _inverse(models, latitude, longitude):
    """The exact inverse of every grid pixel for a batch of models: 0-based (column, row) maps."""
    pixel, scan = jax.vmap(lambda model: model.inverse(latitude, longitude))(models)
    return pixel - 1.0, scan - 1.0


def _exact_maps(stacked, latitude, longitude):
    column, row = _inverse(stacked, latitude, longitude)
    return np.asarray(column), np.asarray(row)


def _opencv_with_maps(images, stacked, latitude, longitude):
    """The exact maps of every image (one jitted vmapped call), then ``cv2.remap``."""
    column, row = _exact_maps(stacked, latitude, longitude)
    return _opencv(images, [(column[k], row[k]) for k in range(len(images))])


def _opencv(images, maps):
    return [cv2.remap(image, column.astype(np.float32), row.astype(np.float32), cv2.INTER_LINEAR,
                      borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
            for image, (column, row) in zip(images, maps, strict=True)]


@eqx.filter_jit
def _forward(model, pixel, scan):
    return model.forward_unchecked(pixel, scan)


def _pyresample(images, models, latitude, longitude):
    """Seconds for the pyresample job (geolocation of every source pixel included), one call."""
    target = pyresample.geometry.SwathDefinition(lons=np.degrees(np.asarray(longitude)),
                                                 lats=np.degrees(np.asarray(latitude)))
    scans, pixels = np.meshgrid(np.arange(1.0, images[0].shape[0] + 1), np.arange(1.0, images[0].shape[1] + 1),
                                indexing="ij")
    pixel, scan = jnp.asarray(pixels), jnp.asarray(scans)
    jax.block_until_ready(_forward(models[0], pixel, scan))  # compile outside the timing
    start = time.perf_counter()
    for image, model in zip(images, models, strict=True):
        lat, lon = (np.degrees(np.asarray(a)) for a in _forward(model, pixel, scan))
        source = pyresample.geometry.SwathDefinition(lons=lon, lats=lat)
        pyresample.kd_tree.resample_nearest(source, image, target, radius_of_influence=2000.0, fill_value=np.nan)
    return time.perf_counter() - start


def _best(repeats, function, *args):
    """Best wall time over ``repeats`` calls after one warm-up call."""
    jax.block_until_ready(function(*args))
    return best_time(function, *args, repeats=repeats)


if __name__ == "__main__":
    main()
