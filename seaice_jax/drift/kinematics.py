"""Drift of features between two coverages and the transformation that best explains it (source 000, section 4).

Positions are planar map coordinates (x east, y north, metres; e.g. a tangent plane). A fit maps the earlier
positions onto the later ones about the earlier centroid c:

* rigid: p' = c + shift + R(θ)(p − c) — the general drift (shift of the centroid) and rotation;
* similarity: p' = c + shift + s R(θ)(p − c);
* affine: p' = c + shift + A (p − c), A a full 2 × 2 matrix (source 000 found a 10 % affinity over 16 days).

The residuals of the rigid fit are the relative motion after removing the general drift. The fits go through the
least-squares engine, so their parameters come with standard deviations.
"""

import functools
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from seaice_jax._shapes import padded_to_bucket
from seaice_jax.adjust.engine.lsq import Adjustment, Observations, Solver, checked_solve, make_solver
from seaice_jax.errors import SeaiceError
from seaice_jax.timefmt import time_after

TRANSFORMS = ("rigid", "similarity", "affine")


def _rotation(angle):
    c, s = jnp.cos(angle), jnp.sin(angle)
    return jnp.array([[c, -s], [s, c]])


def _matrix(kind, parameters):
    if kind == "rigid":
        return _rotation(parameters["rotation"])
    if kind == "similarity":
        return parameters["scale"] * _rotation(parameters["rotation"])
    return parameters["matrix"]


def _start_parameters(kind):
    start = {"shift": jnp.zeros(2)}
    if kind in ("rigid", "similarity"):
        start["rotation"] = jnp.asarray(0.0)
    if kind == "similarity":
        start["scale"] = jnp.asarray(1.0)
    if kind == "affine":
        start["matrix"] = jnp.eye(2)
    return start


@functools.lru_cache(maxsize=32)
def _transform_solver(kind: str, count: int, sigma: float) -> Solver:
    """One compiled solver per transformation kind, number of points and σ (the points are model arguments)."""

    def model(parameters, args):
        centre, relative = args
        offset = (centre + parameters["shift"])[None, :]
        return {"later": offset + relative @ _matrix(kind, parameters).T}

    return make_solver(model, _start_parameters(kind), {"later": Observations(jnp.zeros((count, 2)), sigma)})


@dataclass(frozen=True)
class TransformFit:
    """A fitted transformation between two point sets.

    Attributes:
        kind: ``"rigid"``, ``"similarity"`` or ``"affine"``.
        centre: ``(2,)`` centroid of the earlier points (the point the rotation/scale act about).
        parameters: ``{"shift": (2,), "rotation": rad, "scale": ...}`` or ``{"shift", "matrix": (2, 2)}``.
        sigma: standard deviation of each scalar parameter, by engine name (``shift[0]``, ``rotation``, ...).
        residuals: ``(n, 2)`` later positions minus transformed earlier positions, metres.
        adjustment: the engine's result (covariance, redundancy, w-tests).
    """

    kind: str
    centre: np.ndarray
    parameters: dict
    sigma: dict
    residuals: np.ndarray
    adjustment: Adjustment

    @property
    def rms(self) -> float:
        """RMS length of the residual vectors, metres."""
        return float(np.sqrt(np.mean(np.sum(self.residuals**2, axis=1))))

    def __call__(self, points):
        """Transform ``(n, 2)`` earlier positions."""
        points = np.asarray(points, float)
        matrix = np.asarray(_matrix(self.kind, self.parameters))
        return self.centre + np.asarray(self.parameters["shift"]) + (points - self.centre) @ matrix.T


def fit_transform(earlier, later, kind: str = "rigid", sigma: float = 1.0) -> TransformFit:
    """Least-squares ``kind`` transformation taking ``earlier`` (n, 2) positions onto ``later`` (n, 2).

    Args:
        sigma: σ of each later coordinate (metres); the earlier positions are taken as exact.

    Raises:
        SeaiceError: too few points or unequal shapes; RankDeficiencyError: collinear points for an affine fit.
    """
    if kind not in TRANSFORMS:
        raise SeaiceError(f"transformation must be one of {', '.join(TRANSFORMS)}, got {kind!r}")
    earlier, later = np.asarray(earlier, float), np.asarray(later, float)
    if earlier.shape != later.shape or earlier.ndim != 2 or earlier.shape[1] != 2:
        raise SeaiceError(f"point sets must both be (n, 2), got {earlier.shape} and {later.shape}")
    bad = np.nonzero(~(np.isfinite(earlier).all(axis=1) & np.isfinite(later).all(axis=1)))[0]
    if bad.size:
        raise SeaiceError(f"point {int(bad[0])}: position is not finite ({bad.size} such points); drop them first")
    needed = {"rigid": 2, "similarity": 2, "affine": 3}[kind]
    if earlier.shape[0] < needed:
        raise SeaiceError(f"a {kind} fit needs at least {needed} points, got {earlier.shape[0]}")
    centre = earlier.mean(axis=0)
    solver = _transform_solver(kind, earlier.shape[0], float(sigma))
    start = dict(_start_parameters(kind), shift=jnp.asarray(later.mean(axis=0) - centre))
    adjustment = checked_solve(solver, {"later": later}, (jnp.asarray(centre), jnp.asarray(earlier - centre)), start)
    parameters = {k: np.asarray(v) for k, v in adjustment.parameters.items()}
    sigma_by_name = {k: float(v) for k, v in adjustment.standard_deviations(a_priori=True).items()}
    return TransformFit(kind, centre, parameters, sigma_by_name, -np.asarray(adjustment.residuals["later"]),
                        adjustment)


@dataclass(frozen=True)
class DriftVectors:
    """Displacements of features between two times.

    Attributes:
        displacement: ``(n, 2)`` metres (x east, y north).
        speed: ``(n,)`` m/s. direction: ``(n,)`` degrees clockwise from north, the direction of motion.
    """

    displacement: np.ndarray
    speed: np.ndarray
    direction: np.ndarray


def drift_vectors(earlier, later, interval_seconds: float) -> DriftVectors:
    """Drift of each feature from ``earlier`` to ``later`` positions ``(n, 2)`` over ``interval_seconds``."""
    if not interval_seconds > 0:
        raise SeaiceError(f"the interval between the coverages must be > 0 s, got {interval_seconds}")
    displacement = np.asarray(later, float) - np.asarray(earlier, float)
    speed = np.hypot(displacement[:, 0], displacement[:, 1]) / interval_seconds
    direction = np.degrees(np.arctan2(displacement[:, 0], displacement[:, 1])) % 360.0
    return DriftVectors(displacement, speed, direction)


# ---------------------------------------------------------------------------------------------------------------
# Velocities, box averages, time series and deformation (source 001, section 4 and Figures 4-3 to 4-7)
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Velocities:
    """Velocities between consecutive fixes of floes.

    Attributes:
        floe: ``(n,)`` ids. time: ``(n,)`` s, the middle of each interval; interval: ``(n,)`` s.
        x, y: ``(n,)`` m, map position at the middle of the interval.
        u_grid, v_grid: ``(n,)`` m/s along the map grid's x and y axes (grid-relative).
        u_east, v_north: ``(n,)`` m/s toward geographic east and north.
    """

    floe: np.ndarray
    time: np.ndarray
    interval: np.ndarray
    x: np.ndarray
    y: np.ndarray
    u_grid: np.ndarray
    v_grid: np.ndarray
    u_east: np.ndarray
    v_north: np.ndarray

    @property
    def speed(self) -> np.ndarray:
        return np.hypot(self.u_grid, self.v_grid)


MAX_ICE_SPEED = 2.0
"""m/s (173 km/day): faster than any sea-ice drift measured (storms drive pack ice at up to about 1 m/s). A speed
beyond it comes from a wrong time or a wrong match, not from the ice."""


SUBPIXEL = 0.1
"""Pixels: about the smallest displacement a correlation peak resolves (sub-pixel peak fitting)."""


def check_tracking_interval(names, times, pixel_size: float, limit: float = MAX_ICE_SPEED,
                            resolution: float = SUBPIXEL) -> None:
    """Refuse consecutive images too close in time to measure ice drift: where the smallest displacement the
    tracking resolves (``resolution`` pixels of ``pixel_size`` m) over their interval is already a speed beyond
    ``limit`` m/s, every vector between them would be noise read as an implausible speed.

    Raises:
        SeaiceError: naming the two images, their interval and the speed a resolved step would be.
    """
    step = resolution * pixel_size
    for k, interval in enumerate(np.diff(np.asarray(times, float))):
        speed = step / interval if interval > 0 else np.inf
        if speed > limit:
            raise SeaiceError(
                f"images {names[k]} and {names[k + 1]} are {interval:.6g} s apart: the smallest displacement the "
                f"tracking resolves ({resolution:g} px of {pixel_size:g} m) would already be {speed * 86.4:.3g} "
                f"km/day, beyond the fastest sea-ice drift ({limit * 86.4:.0f} km/day); check the images' times "
                f"(ice drift needs images at least {step / limit:.0f} s apart on this grid)")


def plausible_velocities(v: Velocities, limit: float = MAX_ICE_SPEED,
                         epoch: str | None = None) -> tuple[Velocities, str | None]:
    """``v`` without the velocities faster than ``limit`` m/s (a wrong time or a wrong match, not ice), and a note
    saying how many were left out and naming the fastest, with its fixes' times (ISO 8601 with ``epoch``, else s)
    (None when every velocity is plausible).

    Raises:
        SeaiceError: every velocity beyond ``limit``, naming the fastest floe and its fixes' interval.
    """
    speed = v.speed
    implausible = ~(speed <= limit)
    if not implausible.any():
        return v, None
    k = int(np.nanargmax(np.where(implausible, speed, -np.inf)))
    ends = (v.time[k] - v.interval[k] / 2, v.time[k] + v.interval[k] / 2)
    when = (" and ".join(time_after(epoch, t) for t in ends) if epoch is not None
            else " and ".join(f"{t:.6g} s" for t in ends))
    worst = f"floe {v.floe[k]}: {speed[k] * 86.4:.3g} km/day over {v.interval[k]:.6g} s between its fixes at {when}"
    if implausible.all():
        raise SeaiceError(f"all {speed.size} velocities are beyond the fastest sea-ice drift ({limit * 86.4:.0f} "
                          f"km/day), e.g. {worst}; check the fixes' times and positions")
    kept = Velocities(*(np.asarray(getattr(v, name))[~implausible] for name in Velocities.__dataclass_fields__))
    return kept, (f"{int(implausible.sum())} of {speed.size} velocities beyond the fastest sea-ice drift "
                  f"({limit * 86.4:.0f} km/day) left out (a wrong time or position); the fastest: {worst}")


def east_north_axes(projection, x, y):
    """Unit vectors ``(n, 2)`` of geographic east and north in map-grid components at map points ``(x, y)`` (from
    the projection's Jacobian: the grid's convergence)."""
    lat, lon = (np.atleast_1d(np.asarray(a)) for a in projection.inverse(np.asarray(x, float),
                                                                          np.asarray(y, float)))

    def forward(point):
        return jnp.stack(projection.forward(point[0], point[1]))

    jac = np.asarray(jax.vmap(jax.jacfwd(forward))(jnp.stack([jnp.asarray(lat), jnp.asarray(lon)], -1)))
    north = jac[:, :, 0] / np.linalg.norm(jac[:, :, 0], axis=1, keepdims=True)
    east = jac[:, :, 1] / np.linalg.norm(jac[:, :, 1], axis=1, keepdims=True)
    return east, north


def grid_to_east_north(projection, x, y, u, v):
    """Rotate map-grid vector components ``(u, v)`` at map points ``(x, y)`` into geographic east and north
    (:func:`east_north_axes`).

    Returns:
        ``(east, north)`` in the vector's units, measured on the ground (a grid metre is one ground metre at
        the point only where the scale factor is 1; the ground vector keeps the map vector's length here, only
        its direction is rotated).
    """
    east_dir, north_dir = east_north_axes(projection, x, y)
    vectors = np.stack([np.broadcast_to(u, east_dir.shape[:1]), np.broadcast_to(v, east_dir.shape[:1])], -1)
    return np.sum(vectors * east_dir, axis=1), np.sum(vectors * north_dir, axis=1)


def velocities(floe, time, x, y, projection) -> Velocities:
    """Velocities of each floe between its consecutive fixes (finite differences of its trajectory).

    Args:
        floe: ``(n,)`` ids; time: ``(n,)`` s; x, y: ``(n,)`` map metres of the fixes (any order).
        projection: the map projection of ``x, y`` (for east/north components).
    """
    floe, time, x, y = (np.asarray(a) for a in (floe, time, x, y))
    rows = {k: [] for k in ("floe", "time", "interval", "x", "y", "u", "v")}
    for f in dict.fromkeys(floe.tolist()):
        k = np.nonzero(floe == f)[0]
        k = k[np.argsort(time[k])]
        dt = np.diff(time[k])
        if np.any(dt <= 0):
            raise SeaiceError(f"floe {f}: two fixes at the same time {time[k][np.argmin(dt)]} s")
        rows["floe"] += [f] * dt.size
        rows["time"].append(0.5 * (time[k][1:] + time[k][:-1]))
        rows["interval"].append(dt)
        rows["x"].append(0.5 * (x[k][1:] + x[k][:-1]))
        rows["y"].append(0.5 * (y[k][1:] + y[k][:-1]))
        rows["u"].append(np.diff(x[k]) / dt)
        rows["v"].append(np.diff(y[k]) / dt)
    arrays = {k: (np.concatenate(v) if v and k != "floe" else np.asarray(v, dtype=floe.dtype if k == "floe"
                                                                          else float)) for k, v in rows.items()}
    if arrays["x"].size == 0:
        raise SeaiceError("no floe has two fixes: no velocities")
    east, north = grid_to_east_north(projection, arrays["x"], arrays["y"], arrays["u"], arrays["v"])
    return Velocities(arrays["floe"], arrays["time"], arrays["interval"], arrays["x"], arrays["y"], arrays["u"],
                      arrays["v"], east, north)


@dataclass(frozen=True)
class BoxAverages:
    """Velocity vectors averaged in square boxes, with their standard deviations (the rectangles of source 001,
    Figure 4-7).

    Attributes:
        x, y: ``(b,)`` m, box centres. u, v: ``(b,)`` mean velocity (m/s, grid axes). sigma_u, sigma_v: ``(b,)``
        sample standard deviations of the velocities in each box. count: ``(b,)`` vectors in the box.
    """

    x: np.ndarray
    y: np.ndarray
    u: np.ndarray
    v: np.ndarray
    sigma_u: np.ndarray
    sigma_v: np.ndarray
    count: np.ndarray


def _box_index(x, y, box_size, origin):
    return (np.floor((np.asarray(x) - origin[0]) / box_size).astype(int),
            np.floor((np.asarray(y) - origin[1]) / box_size).astype(int))


def box_averages(x, y, u, v, box_size: float, origin=(0.0, 0.0), min_count: int = 2) -> BoxAverages:
    """Mean and standard deviation of the velocity vectors in each ``box_size`` m square box (boxes aligned
    at ``origin``) with at least ``min_count`` vectors."""
    if not box_size > 0:
        raise SeaiceError(f"box_size must be > 0 m, got {box_size}")
    i, j = _box_index(x, y, box_size, origin)
    u, v = np.asarray(u, float), np.asarray(v, float)
    out = {k: [] for k in ("x", "y", "u", "v", "sigma_u", "sigma_v", "count")}
    for key in sorted(set(zip(i.tolist(), j.tolist(), strict=True))):
        members = (i == key[0]) & (j == key[1])
        if members.sum() < min_count:
            continue
        out["x"].append(origin[0] + (key[0] + 0.5) * box_size)
        out["y"].append(origin[1] + (key[1] + 0.5) * box_size)
        out["u"].append(u[members].mean())
        out["v"].append(v[members].mean())
        out["sigma_u"].append(u[members].std(ddof=1))
        out["sigma_v"].append(v[members].std(ddof=1))
        out["count"].append(int(members.sum()))
    return BoxAverages(**{k: np.asarray(val) for k, val in out.items()})


def box_time_series(velocity: Velocities, box_size: float, origin=(0.0, 0.0), period: float = 86400.0):
    """Box-averaged velocity per ``period`` s (daily by default; source 001, Figure 4-5).

    Returns:
        dict ``{(i, j) box index: {"time": (d,) s (period middles), "u", "v", "sigma_u", "sigma_v", "count"}}``.
    """
    i, j = _box_index(velocity.x, velocity.y, box_size, origin)
    day = np.floor(velocity.time / period).astype(int)
    series = {}
    for key in sorted(set(zip(i.tolist(), j.tolist(), strict=True))):
        in_box = (i == key[0]) & (j == key[1])
        entry = {k: [] for k in ("time", "u", "v", "sigma_u", "sigma_v", "count")}
        for d in np.unique(day[in_box]):
            members = in_box & (day == d)
            entry["time"].append((d + 0.5) * period)
            entry["u"].append(velocity.u_grid[members].mean())
            entry["v"].append(velocity.v_grid[members].mean())
            entry["sigma_u"].append(velocity.u_grid[members].std(ddof=1) if members.sum() > 1 else np.nan)
            entry["sigma_v"].append(velocity.v_grid[members].std(ddof=1) if members.sum() > 1 else np.nan)
            entry["count"].append(int(members.sum()))
        series[key] = {k: np.asarray(val) for k, val in entry.items()}
    return series


@dataclass(frozen=True)
class Deformation:
    """Strain rates of triangles of points (1/s), by line integrals around each triangle, with first-order σ.

    Attributes:
        triangles: ``(t, 3)`` point indices. area: ``(t,)`` m². gradient: ``(t, 2, 2)`` ∂(u, v)/∂(x, y).
        divergence, shear, vorticity: ``(t,)``; sigma_divergence, sigma_shear, sigma_vorticity: ``(t,)``.
        note: what was left out and why (points on one line, degenerate triangles), empty when nothing was.
    """

    triangles: np.ndarray
    area: np.ndarray
    gradient: np.ndarray
    divergence: np.ndarray
    shear: np.ndarray
    vorticity: np.ndarray
    sigma_divergence: np.ndarray
    sigma_shear: np.ndarray
    sigma_vorticity: np.ndarray
    note: str = ""


DEGENERATE = 1e-6
"""A triangle whose height is below this fraction of its longest edge has its corners on one line (to the rounding of
their coordinates): its strain rates are 0/0, and it is left out of a Delaunay triangulation's deformation."""


def _no_triangles(note: str) -> Deformation:
    empty = np.zeros(0)
    return Deformation(np.zeros((0, 3), int), empty, np.zeros((0, 2, 2)), empty, empty, empty, empty, empty, empty,
                       note)


def _strain_rates(corners, velocity):
    """Divergence, maximum shear and vorticity of one triangle: ``corners (3, 2)`` m, ``velocity (3, 2)`` m/s.

    Green's theorem with the trapezoidal rule along the edges (exact for a linear field): ∂u/∂x = (1/A)∮u dy,
    ∂u/∂y = −(1/A)∮u dx, and the same for v."""
    nxt = jnp.roll(jnp.arange(3), -1)
    dx = corners[nxt, 0] - corners[:, 0]
    dy = corners[nxt, 1] - corners[:, 1]
    area = 0.5 * jnp.sum(corners[:, 0] * corners[nxt, 1] - corners[nxt, 0] * corners[:, 1])
    mean = 0.5 * (velocity + velocity[nxt])  # (3, 2) edge means
    ux, uy = jnp.sum(mean[:, 0] * dy) / area, -jnp.sum(mean[:, 0] * dx) / area
    vx, vy = jnp.sum(mean[:, 1] * dy) / area, -jnp.sum(mean[:, 1] * dx) / area
    rates = jnp.stack([ux + vy, jnp.hypot(ux - vy, uy + vx), vx - uy])
    return rates, jnp.array([[ux, uy], [vx, vy]]), area


@jax.jit
def _triangle_rates(corners, velocity):
    rates, gradient, area = jax.vmap(_strain_rates)(corners, velocity)
    jacobian = jax.vmap(jax.jacfwd(lambda c, v: _strain_rates(c, v)[0], argnums=1))(corners, velocity)
    return rates, gradient, area, jacobian


def deformation(points, velocity, velocity_sigma, triangles=None) -> Deformation:
    """Divergence, shear and vorticity of triangles of points and their σ, propagated to first order from
    independent velocity errors (positions taken as exact).

    Args:
        points: ``(n, 2)`` m. velocity: ``(n, 2)`` m/s. velocity_sigma: σ per velocity component, scalar or
            ``(n,)`` or ``(n, 2)`` m/s.
        triangles: ``(t, 3)`` indices; default the Delaunay triangulation of ``points`` without its degenerate
            triangles (:data:`DEGENERATE`; the result's ``note`` says how many were left out), or no triangles when
            the points lie on one line (``note`` says so).
    """
    points, velocity = np.asarray(points, float), np.asarray(velocity, float)
    if points.shape != velocity.shape or points.ndim != 2 or points.shape[1] != 2:
        raise SeaiceError(f"points and velocities must both be (n, 2), got {points.shape} and {velocity.shape}")
    if points.shape[0] < 3:
        raise SeaiceError(f"deformation needs at least 3 points, got {points.shape[0]}")
    note = ""
    if triangles is None:
        from matplotlib.tri import Triangulation  # Delaunay; imported here so that the package loads without it

        on_line = f"the {points.shape[0]} points lie on one line (or coincide): no triangles"
        try:
            triangles = Triangulation(points[:, 0], points[:, 1]).triangles
        except (RuntimeError, ValueError):
            return _no_triangles(on_line)
        corners = points[triangles]
        edges = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
        a, b = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
        doubled_area = np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
        degenerate = ~(doubled_area > DEGENERATE * edges**2)
        if degenerate.all():
            return _no_triangles(on_line)
        if degenerate.any():
            note = (f"{int(degenerate.sum())} of {degenerate.size} triangles left out: their corners lie on one "
                    "line")
            triangles = triangles[~degenerate]
    triangles = np.asarray(triangles)
    sigma = np.broadcast_to(np.asarray(velocity_sigma, float).reshape(
        (-1, 1) if np.ndim(velocity_sigma) == 1 else np.shape(velocity_sigma)), points.shape)
    # padded to a bucket of triangles (copies of the first): one compiled function for every pair of a sequence
    count = triangles.shape[0]
    padded = padded_to_bucket(triangles)
    rates, gradient, area, jacobian = (np.asarray(a)[:count] for a in _triangle_rates(
        jnp.asarray(points[padded]), jnp.asarray(velocity[padded])))
    variance = np.einsum("trkc,tkc->tr", jacobian ** 2, sigma[triangles] ** 2)
    std = np.sqrt(variance)
    return Deformation(triangles, np.abs(area), gradient, rates[:, 0], rates[:, 1], rates[:, 2], std[:, 0],
                       std[:, 1], std[:, 2], note)


def error_ellipses(covariances, confidence: float = 0.95):
    """Semi-axes ``(n,)``, ``(n,)`` (same units as √covariance) and orientation ``(n,)`` (radians from x toward
    y, of the major axis) of the ``confidence`` error ellipses of 2 × 2 ``covariances`` ``(n, 2, 2)``."""
    covariances = np.asarray(covariances, float)
    scale = np.sqrt(-2.0 * np.log(1.0 - confidence))  # χ² with 2 degrees of freedom
    values, vectors = np.linalg.eigh(np.nan_to_num(covariances))
    major, minor = np.sqrt(np.maximum(values[:, 1], 0)) * scale, np.sqrt(np.maximum(values[:, 0], 0)) * scale
    bad = ~np.isfinite(covariances).all(axis=(1, 2))
    major[bad] = minor[bad] = np.nan
    return major, minor, np.arctan2(vectors[:, 1, 1], vectors[:, 0, 1])
