import jax
import jax.numpy as jnp
import numpy as np
import pytest

from seaice_jax.adjust.lsq import make_solver
from seaice_jax.adjust.multi_image import joint_fit, joint_problem, sequential_fit
from seaice_jax.adjust.orbit_fit import FREE_PARAMETERS, ControlPoints, orbit_solver, propagate_position_sigma
from seaice_jax.errors import SeaiceError
from seaice_jax.simulate.satellite import overlapping_pair

RADIUS = 6_371_000.0


def exact_images(images, truths):
    """The same measurements with the known positions set to the truth."""
    from dataclasses import replace

    out = []
    for image, truth in zip(images, truths, strict=True):
        lat, lon = truth.forward(image.primary.pixel, image.primary.scan)
        primary = ControlPoints(image.primary.pixel, image.primary.scan, lat, lon, image.primary.sigma,
                                image.primary.ids)
        out.append(replace(image, primary=primary))
    return out


def test_noise_free_joint_and_sequential_fits_recover_both_images():
    images, truths = overlapping_pair(np.random.default_rng(4))
    images = exact_images(images, truths)
    joint = joint_fit(images)
    for model, truth in zip(joint.models, truths, strict=True):
        assert float(model.subtrack_pixel) == pytest.approx(float(truth.subtrack_pixel), abs=1e-5)
        assert float(model.ascending_node) == pytest.approx(float(truth.ascending_node), abs=1e-9)
    fits, _ = sequential_fit(images)
    assert fits[1].rms_km < 1e-6
    assert joint.point_ids == tuple(f"S{k}" for k in range(1, 7))


def test_an_image_without_enough_control_is_named():
    images, _ = overlapping_pair(np.random.default_rng(4), primary_first=2, primary_second=1)
    with pytest.raises(SeaiceError, match="images A, B never reach three control points"):
        sequential_fit(images)


def test_joint_sigma_matches_monte_carlo_and_the_1985_practice_is_overconfident():
    """Vmapped Monte Carlo of both methods with the same noise: known positions (500 m) and pointing (300 m)."""
    runs = 400
    rng = np.random.default_rng(12)
    images, truths = overlapping_pair(rng)
    images = exact_images(images, truths)
    grid_p, grid_s = (a.ravel() for a in np.meshgrid(np.linspace(50, 460, 3), np.linspace(50, 460, 3)))

    # the joint adjustment, linearised at the truth
    positions = {i: tuple(float(x) for x in a) for i, a in zip(
        images[0].secondary_ids, np.stack([np.asarray(v) for v in truths[0].forward(
            images[0].secondary_pixel, images[0].secondary_scan)], 1), strict=True)}
    model, parameters, observations, free, _ = joint_problem(images, list(truths), positions)
    solver = make_solver(model, parameters, observations, free=free)
    noise = {g: rng.normal(0.0, 1.0, (runs,) + o.values.shape) * np.asarray(o.sigma)
             for g, o in observations.items()}
    observed = {g: np.asarray(o.values)[None] + noise[g] for g, o in observations.items()}
    joint = jax.jit(jax.vmap(lambda obs: solver(obs)))(observed)
    assert bool(jnp.all(joint.converged))
    block = [solver.parameter_names.index(f"images[1].{n}") for n in FREE_PARAMETERS]
    cofactor_b = np.asarray(joint.cofactor[0])[np.ix_(block, block)]
    predicted = np.hypot(*propagate_position_sigma(truths[1], cofactor_b, grid_p, grid_s))
    lat, lon = jax.vmap(lambda m: m.forward(grid_p, grid_s))(joint.parameters["images"][1])
    truth_lat, truth_lon = (np.asarray(a) for a in truths[1].forward(grid_p, grid_s))

    def scatter(lat, lon):
        north = (np.asarray(lat) - truth_lat) * RADIUS
        east = (np.asarray(lon) - truth_lon) * RADIUS * np.cos(truth_lat)
        return np.sqrt(np.mean(north**2 + east**2, axis=0))

    joint_scatter = scatter(lat, lon)
    np.testing.assert_allclose(joint_scatter / predicted, 1.0, atol=0.10)

    # the 1985 practice with the same random numbers: A from its primaries; the secondary points' positions from
    # A (with A's pointing noise) become fixed controls of B, with B's pointing noise on top
    a, b = images
    solve_a = orbit_solver(a.primary, truths[0])
    args_a = (a.primary.pixel, a.primary.scan, jnp.mean(a.primary.longitude))
    fit_a = jax.vmap(lambda la, lo: solve_a({"latitude": la, "longitude": lo}, args_a))(
        jnp.asarray(observed["0:primary latitude"]), jnp.asarray(observed["0:primary longitude"]))
    sec_lat, sec_lon = jax.vmap(lambda m: m.forward(a.secondary_pixel, a.secondary_scan))(fit_a.parameters)
    sec_lat = np.asarray(sec_lat) - noise["0:secondary north"] + noise["1:secondary north"]
    sec_lon = np.asarray(sec_lon) - (noise["0:secondary east"] - noise["1:secondary east"]) / np.cos(sec_lat)
    control_b = ControlPoints(np.concatenate([b.primary.pixel, b.secondary_pixel]),
                              np.concatenate([b.primary.scan, b.secondary_scan]),
                              np.concatenate([b.primary.latitude, sec_lat[0]]),
                              np.concatenate([b.primary.longitude, sec_lon[0]]),
                              np.concatenate([np.asarray(b.primary.sigma), np.full(6, b.secondary_sigma)]))
    solve_b = orbit_solver(control_b, truths[1])
    args_b = (control_b.pixel, control_b.scan, jnp.mean(control_b.longitude))
    lat_b = np.concatenate([observed["1:primary latitude"], sec_lat], 1)
    lon_b = np.concatenate([observed["1:primary longitude"], sec_lon], 1)
    fit_b = jax.jit(jax.vmap(lambda la, lo: solve_b({"latitude": la, "longitude": lo}, args_b)))(
        jnp.asarray(lat_b), jnp.asarray(lon_b))
    claimed = np.hypot(*propagate_position_sigma(truths[1], np.asarray(fit_b.cofactor[0]), grid_p, grid_s))
    lat, lon = jax.vmap(lambda m: m.forward(grid_p, grid_s))(fit_b.parameters)
    sequential_scatter = scatter(lat, lon)
    assert np.all(sequential_scatter > 1.3 * claimed)  # treating A's positions as exact hides A's errors
    assert np.mean(joint_scatter) < np.mean(sequential_scatter)
