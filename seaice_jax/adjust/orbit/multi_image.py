"""Several satellite images adjusted at once (source 001, section 3.3, "multiple image rectification").

Images share *secondary* control points — features seen on two or more images whose ground position is unknown —
and have *primary* control points with known positions. The 1985 program solved one image, then used the
secondary points' positions from that solution as fixed controls for the next (:func:`sequential_fit`). The
rigorous alternative estimates all images' five unknowns and all secondary points' positions in one weighted
least-squares adjustment (:func:`joint_fit`), so the uncertainty of the first image is carried into the others.
"""

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from seaice_jax.adjust.engine.lsq import Adjustment, Observations, least_squares, make_solver
from seaice_jax.adjust.engine.sharding import sharded_vmap
from seaice_jax.adjust.orbit.fit import (
    FREE_PARAMETERS,
    fit_scan_model,
    free_mask,
    orbit_solver,
    propagate_position_sigma,
)
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.earth import wrap_angle as _wrap
from seaice_jax.geometry.scan import ScanModel
from seaice_jax.sensors.control import ControlPoints, ImageObservations


@dataclass(frozen=True)
class JointFit:
    """All images and secondary points from one adjustment.

    Attributes:
        models: the fitted scan model of each image.
        point_ids: ids of the secondary points, in the order of ``point_latitude``/``point_longitude``.
        point_latitude, point_longitude: ``(k,)`` radians.
        adjustment: the engine's result (covariance of everything, residuals, w-tests).
    """

    models: tuple[ScanModel, ...]
    point_ids: tuple[str, ...]
    point_latitude: np.ndarray
    point_longitude: np.ndarray
    adjustment: Adjustment


def _secondary_as_control(image: ImageObservations, positions: dict) -> ControlPoints | None:
    """The image's secondary points with known (previously solved) positions, as control points."""
    keep = [k for k, i in enumerate(image.secondary_ids) if i in positions]
    if not keep:
        return None
    return ControlPoints(np.asarray(image.secondary_pixel)[keep], np.asarray(image.secondary_scan)[keep],
                         [positions[image.secondary_ids[k]][0] for k in keep],
                         [positions[image.secondary_ids[k]][1] for k in keep],
                         image.secondary_sigma, [f"{image.secondary_ids[k]}" for k in keep])


def _merge(a: ControlPoints | None, b: ControlPoints | None) -> ControlPoints | None:
    if a is None or b is None:
        return a if b is None else b
    return a.joined(b, "secondary ")


def sequential_fit(images: list[ImageObservations]):
    """The 1985 practice: solve images one after another, each solved image's secondary points becoming fixed
    controls of the next.

    Returns:
        ``(fits, positions)``: an :class:`OrbitFit` per image and ``{secondary id: (latitude, longitude)}`` from
        the first image that solved it.

    Raises:
        SeaiceError: naming the images that never get three control points.
    """
    fits, positions = {}, {}
    while len(fits) < len(images):
        progress = False
        for j, image in enumerate(images):
            if j in fits:
                continue
            control = _merge(image.primary, _secondary_as_control(image, positions))
            if control is None or len(control) < 3:
                continue
            fits[j] = fit_scan_model(control, image.orbit, direction=image.direction, n_pixels=image.n_pixels,
                                     n_scans=image.n_scans)
            lat, lon = fits[j].model.forward(jnp.asarray(image.secondary_pixel), jnp.asarray(image.secondary_scan))
            for k, point in enumerate(image.secondary_ids):
                positions.setdefault(point, (float(lat[k]), float(lon[k])))
            progress = True
        if not progress:
            stuck = [images[j].name for j in range(len(images)) if j not in fits]
            raise SeaiceError(f"images {', '.join(stuck)} never reach three control points (primary, or secondary "
                              "points seen on an already solved image)")
    return [fits[j] for j in range(len(images))], positions


def joint_problem(images: list[ImageObservations], models, positions):
    """The joint adjustment's ``(model, parameters, observations, free, args)`` for :mod:`seaice_jax.adjust.engine.lsq`.

    Parameters: ``{"images": (ScanModel, ...), "points": (k, 2) latitude/longitude}``. Observation groups per
    image ``j``: ``"j:primary latitude"``/``"j:primary longitude"`` (known positions) and
    ``"j:secondary north"``/``"j:secondary east"`` (image position minus point position, observed as zero).
    """
    point_ids = tuple(sorted(positions))
    index = {p: k for k, p in enumerate(point_ids)}
    points = jnp.asarray([positions[p] for p in point_ids], float)
    radius = float(images[0].orbit.radius)
    observations, layout = {}, []
    for j, image in enumerate(images):
        primary = image.primary
        if primary is not None:
            observations[f"{j}:primary latitude"] = Observations(primary.latitude, primary.sigma / radius)
            observations[f"{j}:primary longitude"] = Observations(
                primary.longitude, primary.sigma / (radius * jnp.cos(primary.latitude)))
        k = len(image.secondary_ids)
        if k:
            zeros = jnp.zeros(k)
            observations[f"{j}:secondary north"] = Observations(zeros, image.secondary_sigma / radius)
            observations[f"{j}:secondary east"] = Observations(zeros, image.secondary_sigma / radius)
        layout.append((primary, jnp.asarray([index[p] for p in image.secondary_ids], int),
                       jnp.asarray(image.secondary_pixel, float), jnp.asarray(image.secondary_scan, float)))

    def model(parameters, _):
        predicted = {}
        for j, (primary, point_index, pixel, scan) in enumerate(layout):
            image_model = parameters["images"][j]
            if primary is not None:
                lat, lon = image_model.forward(primary.pixel, primary.scan)
                predicted[f"{j}:primary latitude"] = lat
                reference = jnp.mean(primary.longitude)
                predicted[f"{j}:primary longitude"] = reference + _wrap(lon - reference)
            if point_index.size:
                lat, lon = image_model.forward(pixel, scan)
                point = parameters["points"][point_index]
                predicted[f"{j}:secondary north"] = lat - point[:, 0]
                predicted[f"{j}:secondary east"] = jnp.cos(point[:, 0]) * _wrap(lon - point[:, 1])
        return predicted

    parameters = {"images": tuple(models), "points": points}
    free = {"images": tuple(free_mask(m) for m in models), "points": True}
    return model, parameters, observations, free, point_ids


def joint_fit(images: list[ImageObservations]) -> JointFit:
    """All images' unknowns and all secondary points in one adjustment, started from :func:`sequential_fit`."""
    fits, positions = sequential_fit(images)
    model, parameters, observations, free, point_ids = joint_problem(images, [f.model for f in fits], positions)
    adjustment = least_squares(model, parameters, observations, free=free)
    points = np.asarray(adjustment.parameters["points"])
    return JointFit(tuple(adjustment.parameters["images"]), point_ids, points[:, 0], points[:, 1], adjustment)


@dataclass(frozen=True)
class MonteCarloComparison:
    """Joint adjustment against the 1985 sequential practice for the second image (Monte Carlo, same noise).

    All arrays are ``(points,)`` over the evaluation grid, metres (horizontal position).

    Attributes:
        joint_predicted: σ from the joint adjustment's covariance.
        joint_scatter: RMS error of the joint estimates over the realizations.
        sequential_claimed: σ the sequential fit of the second image reports (secondary points taken as exact).
        sequential_scatter: RMS error of the sequential estimates.
        runs: number of realizations.
    """

    joint_predicted: np.ndarray
    joint_scatter: np.ndarray
    sequential_claimed: np.ndarray
    sequential_scatter: np.ndarray
    runs: int


_BATCH = 100
"""Realizations per vmapped batch of the Monte Carlo."""


def _in_batches(function, realizations):
    """``vmap(function)`` over the leading axis of ``realizations`` (a pytree of arrays), ``_BATCH`` at a time
    under one compilation, each batch split over the local devices (:func:`~..engine.sharding.sharded_vmap`):
    a 400-lane vmap of the solver's while_loop is many times slower per lane than four of 100 on the CPU."""
    solve = sharded_vmap(function)
    runs = jax.tree_util.tree_leaves(realizations)[0].shape[0]
    parts = [solve(jax.tree_util.tree_map(lambda a, k=k: jnp.asarray(a[k:k + _BATCH]), realizations))
             for k in range(0, runs, _BATCH)]
    return jax.tree_util.tree_map(lambda *pieces: np.concatenate([np.asarray(p) for p in pieces]), *parts)


def monte_carlo_comparison(images, truths, runs, rng, pixel, scan) -> MonteCarloComparison:
    """Vmapped Monte Carlo of :func:`joint_fit` and :func:`sequential_fit` for a pair of images (first solved
    first), with noise on the known positions (their σ) and on the pointing at secondary points (their σ).

    Both adjustments are linearised at the truth (``truths``) and solved by Gauss-Newton per realization.
    ``pixel``, ``scan``: ``(n,)`` evaluation points on the second image.
    """
    first, second = images
    radius = float(first.orbit.radius)
    lat0, lon0 = truths[0].forward(jnp.asarray(first.secondary_pixel), jnp.asarray(first.secondary_scan))
    positions = {p: (float(a), float(b)) for p, a, b in zip(first.secondary_ids, lat0, lon0, strict=True)}
    model, parameters, observations, free, _ = joint_problem(images, list(truths), positions)
    solver = make_solver(model, parameters, observations, free=free)
    noise = {g: rng.normal(0.0, 1.0, (runs,) + o.values.shape) * np.asarray(o.sigma)
             for g, o in observations.items()}
    observed = {g: np.asarray(o.values)[None] + noise[g] for g, o in observations.items()}
    joint = _in_batches(solver, observed)
    block = [solver.parameter_names.index(f"images[1].{n}") for n in FREE_PARAMETERS]
    cofactor = np.asarray(joint.cofactor[0])[np.ix_(block, block)]
    joint_predicted = np.hypot(*(np.asarray(a) for a in propagate_position_sigma(truths[1], cofactor, pixel, scan)))
    truth_lat, truth_lon = (np.asarray(a) for a in truths[1].forward(pixel, scan))

    def scatter(models):
        lat, lon = jax.vmap(lambda m: m.forward(pixel, scan))(models)
        north = (np.asarray(lat) - truth_lat) * radius
        east = np.asarray(_wrap(np.asarray(lon) - truth_lon[None, :])) * radius * np.cos(truth_lat)
        return np.sqrt(np.mean(north**2 + east**2, axis=0))

    # 1985: the first image from its primaries; the secondary points' positions from it (with its pointing
    # noise) become fixed controls of the second (with the second's pointing noise on top)
    solve_a = orbit_solver(first.primary, truths[0])
    args_a = (first.primary.pixel, first.primary.scan, jnp.mean(first.primary.longitude))
    fit_a = _in_batches(lambda x: solve_a({"latitude": x[0], "longitude": x[1]}, args_a),
                        (observed["0:primary latitude"], observed["0:primary longitude"]))
    sec_lat, sec_lon = jax.vmap(lambda m: m.forward(first.secondary_pixel, first.secondary_scan))(fit_a.parameters)
    sec_lat = np.asarray(sec_lat) - noise["0:secondary north"] + noise["1:secondary north"]
    sec_lon = np.asarray(sec_lon) - (noise["0:secondary east"] - noise["1:secondary east"]) / np.cos(sec_lat)
    k = len(second.secondary_ids)
    control = ControlPoints(np.concatenate([second.primary.pixel, second.secondary_pixel]),
                            np.concatenate([second.primary.scan, second.secondary_scan]),
                            np.concatenate([second.primary.latitude, sec_lat[0]]),
                            np.concatenate([second.primary.longitude, sec_lon[0]]),
                            np.concatenate([np.asarray(second.primary.sigma), np.full(k, second.secondary_sigma)]))
    solve_b = orbit_solver(control, truths[1])
    args_b = (control.pixel, control.scan, jnp.mean(control.longitude))
    fit_b = _in_batches(lambda x: solve_b({"latitude": x[0], "longitude": x[1]}, args_b),
                        (np.concatenate([observed["1:primary latitude"], sec_lat], 1),
                         np.concatenate([observed["1:primary longitude"], sec_lon], 1)))
    claimed = np.hypot(*(np.asarray(a) for a in propagate_position_sigma(
        truths[1], np.asarray(fit_b.cofactor[0]), pixel, scan)))
    return MonteCarloComparison(joint_predicted, scatter(joint.parameters["images"][1]), claimed,
                                scatter(fit_b.parameters), runs)
