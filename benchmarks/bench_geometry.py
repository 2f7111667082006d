"""Points per second of the geometric models: jit + vmap JAX against the same formula in NumPy and against a
generic root solve of the defining equations (scipy.optimize), in one process. Writes benchmarks/RESULTS.md.

Run: ``.venv/bin/python benchmarks/bench_geometry.py [--quick]``.
"""

import argparse
import platform
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import least_squares

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import best_time, first_call_time, publish  # noqa: E402

import seaice_jax  # noqa: E402,F401
from seaice_jax import (
    MEAN_RADIUS,  # noqa: E402
    ground_point,  # noqa: E402
)
from seaice_jax.simulate.scenarios import figure_3_3_image  # noqa: E402

R = MEAN_RADIUS


def numpy_ground_point(s, v, r, radius):
    """Source 000 eq. A5 (zero Doppler, right-looking) in plain NumPy: the reference implementation."""
    s_len = np.linalg.norm(s, axis=-1)
    s_hat = s / s_len[:, None]
    a = (radius**2 + s_len**2 - r**2) / (2 * s_len)
    w = np.cross(v, s)
    w /= np.linalg.norm(w, axis=-1)[:, None]
    u = np.cross(s, w)
    u /= np.linalg.norm(u, axis=-1)[:, None]
    below = s_len - a
    b = below * np.sum(s_hat * v, -1) / np.sum(u * v, -1)
    c = np.sqrt(r**2 - b**2 - below**2)
    return a[:, None] * s_hat + b[:, None] * u + c[:, None] * w


def scipy_ground_point(s, v, r, radius):
    """Generic root solve of |p| = R, |p - s| = r, (p - s)·v = 0 per point (scipy least_squares)."""
    out = np.empty_like(s)
    for k in range(s.shape[0]):
        up = s[k] / np.linalg.norm(s[k])
        right = np.cross(v[k], s[k])
        right /= np.linalg.norm(right)
        h = np.linalg.norm(s[k]) - radius
        start = radius * up + np.sqrt(r[k] ** 2 - h**2) * right

        def equations(p, k=k):
            d = p - s[k]
            return [np.linalg.norm(p) - radius, np.linalg.norm(d) - r[k], d @ v[k] / np.linalg.norm(v[k])]

        out[k] = least_squares(equations, start, xtol=1e-12, ftol=1e-12).x
    return out


def radar_inputs(n, rng):
    lat = np.radians(rng.uniform(70, 80, n))
    lon = np.radians(rng.uniform(-180, 180, n))
    up = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], -1)
    east = np.stack([-np.sin(lon), np.cos(lon), np.zeros(n)], -1)
    s = (R + 10_000.0) * up
    v = 170.0 * east
    r = rng.uniform(11_000.0, 40_000.0, n)
    return s, v, r


def numpy_scan_forward(model, pixel, scan):
    """The scan model's forward formula in NumPy (H = 0)."""
    beta = float(model.scanner_angle_span) * (float(model.subtrack_pixel) - pixel) / (model.n_pixels - 1)
    eta = float(model.orbital_angle_first) + float(model.orbital_angle_span) * (scan - 1) / (model.n_scans - 1)
    inc = float(model.orbit.inclination)
    gx = np.cos(beta) * np.cos(eta)
    gy = np.cos(beta) * np.sin(eta) * np.cos(inc) + np.sin(beta) * np.sin(inc)
    gz = np.cos(beta) * np.sin(eta) * np.sin(inc) - np.sin(beta) * np.cos(inc)
    lon = float(model.ascending_node) + np.arctan2(gy, gx) - float(model.orbit.rotation_ratio) * eta
    return np.arctan2(gz, np.hypot(gx, gy)), lon


def scipy_scan_inverse(model, lat, lon):
    """Inverse by a generic root solve of forward(p, s) = (lat, lon), per point."""
    out = np.empty((lat.size, 2))
    for k in range(lat.size):
        def equations(x, k=k):
            la, lo = numpy_scan_forward(model, x[0], x[1])
            return [la - lat[k], np.angle(np.exp(1j * (lo - lon[k])))]

        out[k] = least_squares(equations, [256.0, 256.0], xtol=1e-12, ftol=1e-12).x
    return out


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="small sizes only (smoke run)")
    args = parser.parse_args()
    sizes = [1_000, 10_000] if args.quick else [1_000, 10_000, 100_000, 1_000_000]
    scipy_points = 100 if args.quick else 300
    rng = np.random.default_rng(0)

    forward_rd = jax.jit(lambda s, v, r: ground_point(s, v, r, R, "right", on_failure="nan"))
    rows = []
    s, v, r = radar_inputs(scipy_points, rng)
    scipy_rate = scipy_points / best_time(scipy_ground_point, s, v, r, R, repeats=1)
    for n in sizes:
        s, v, r = radar_inputs(n, rng)
        sj, vj, rj = jnp.asarray(s), jnp.asarray(v), jnp.asarray(r)
        compile_s = f"{first_call_time(forward_rd, sj, vj, rj):.2f}" if n == sizes[0] else "-"
        jax_rate = n / best_time(forward_rd, sj, vj, rj)
        numpy_rate = n / best_time(numpy_ground_point, s, v, r, R)
        difference = np.max(np.linalg.norm(np.asarray(forward_rd(sj, vj, rj)) - numpy_ground_point(s, v, r, R),
                                           axis=-1))
        rows.append((n, jax_rate, numpy_rate, jax_rate / numpy_rate, jax_rate / scipy_rate, difference, compile_s))

    model = figure_3_3_image()
    forward_scan = jax.jit(lambda m, p, q: m.forward(p, q))
    inverse_scan = jax.jit(lambda m, la, lo: m.inverse(la, lo))
    scan_rows = []
    p0, q0 = rng.uniform(1, 512, scipy_points), rng.uniform(1, 512, scipy_points)
    la0, lo0 = numpy_scan_forward(model, p0, q0)
    scipy_inverse_rate = scipy_points / best_time(scipy_scan_inverse, model, la0, lo0, repeats=1)
    for n in sizes:
        p, q = rng.uniform(1, 512, n), rng.uniform(1, 512, n)
        pj, qj = jnp.asarray(p), jnp.asarray(q)
        la, lo = (jnp.asarray(a) for a in numpy_scan_forward(model, p, q))
        fwd = n / best_time(forward_scan, model, pj, qj)
        fwd_np = n / best_time(numpy_scan_forward, model, p, q)
        inv = n / best_time(inverse_scan, model, la, lo)
        scan_rows.append((n, fwd, fwd_np, fwd / fwd_np, inv, inv / scipy_inverse_rate))

    machine = f"{platform.processor() or platform.machine()}, {jax.device_count()} {jax.default_backend()} device(s)"
    lines = [
        f"Machine: {machine}; float64; best of 5 runs, jit compile time excluded (shown separately).",
        "",
        "### Range-Doppler forward (source 000 eq. A5), points per second",
        "",
        "| points | JAX jit | NumPy | JAX / NumPy | JAX / scipy root solve | max JAX-NumPy (m) | first call (s) |",
        "|---:|---:|---:|---:|---:|---:|---:|",
        *[f"| {n:,} | {a:,.0f} | {b:,.0f} | {c:.2f} | {d:,.0f} | {e:.1e} | {f} |" for n, a, b, c, d, e, f in rows],
        "",
        f"scipy.optimize.least_squares on the three defining equations, one point at a time: {scipy_rate:,.0f} "
        f"points/s ({scipy_points} points).",
        "",
        "### Great-circle scan model (source 001 section 3.3), points per second",
        "",
        "| points | forward JAX jit | forward NumPy | JAX / NumPy | inverse JAX jit | inverse JAX / scipy root solve |",
        "|---:|---:|---:|---:|---:|---:|",
        *[f"| {n:,} | {a:,.0f} | {b:,.0f} | {c:.2f} | {d:,.0f} | {e:,.0f} |" for n, a, b, c, d, e in scan_rows],
        "",
        f"scipy.optimize.least_squares inverse (forward(p, s) = (lat, lon)), one point at a time: "
        f"{scipy_inverse_rate:,.0f} points/s ({scipy_points} points).",
        "",
    ]
    publish("Geometry (benchmarks/bench_geometry.py)", lines, args.quick)


if __name__ == "__main__":
    main()
