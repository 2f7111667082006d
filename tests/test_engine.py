"""The adjustment engine against closed forms, between its two backends, and by Monte Carlo."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from seaice_jax.adjust.engine import dense, gauss_newton, trust_region
from seaice_jax.adjust.engine.gauss_newton import INSEPARABLE, EngineOptions, solve
from seaice_jax.adjust.engine.lsq import Observations, make_solver
from seaice_jax.adjust.engine.problem import Problem, ResidualBlock
from seaice_jax.adjust.engine.quality import critical_value
from seaice_jax.adjust.engine.variance import robust_adjustment, variance_components
from seaice_jax.errors import NotConvergedError, SeaiceError


def _image_point(theta, point, row):
    """A 2-D similarity per image (shift x, y, rotation, log scale): computed image position − observed."""
    shift, angle, scale = theta[:2], theta[2], jnp.exp(theta[3])
    rotation = jnp.array([[jnp.cos(angle), -jnp.sin(angle)], [jnp.sin(angle), jnp.cos(angle)]])
    return scale * rotation @ point + shift - row["observed"]


def _control(_, point, row):
    return point - row["known"]


def _prior(theta, _, row):
    return theta - row["value"]


def small_block(rng, images=3, points=12, noise=1.0, control_error=0.0):
    """Images of 2-D points with similarity distortions; five control points; a prior on image 0.

    Point p is seen on images p mod 3 and the next, and odd points also on the one after (point 6: images 0 and 1
    only).
    """
    truth_theta = np.concatenate([[rng.normal(0, 5, 2).tolist() + [rng.normal(0, 0.05), rng.normal(0, 0.01)]]
                                  for _ in range(images)]).reshape(-1)
    truth_points = rng.uniform(-500, 500, (points, 2))
    rows, point_index, image_index = [], [], []
    for p in range(points):
        first = p % images
        seen = [first, (first + 1) % images] + ([(first + 2) % images] if p % 2 else [])
        for i in seen:
            t = truth_theta[4 * i:4 * i + 4]
            clean = np.asarray(_image_point(jnp.asarray(t), jnp.asarray(truth_points[p]), {"observed": jnp.zeros(2)}))
            rows.append(clean + rng.normal(0, noise, 2))
            point_index.append(p)
            image_index.append(i)
    index = np.array([[4 * i + k for k in range(4)] for i in image_index])
    known = truth_points[:5] + rng.normal(0, noise, (5, 2))
    known[2, 0] += control_error
    blocks = {
        "image": ResidualBlock(_image_point, {"observed": jnp.asarray(np.array(rows))},
                               jnp.full((len(rows), 2), noise), jnp.asarray(index), jnp.asarray(point_index)),
        "control": ResidualBlock(_control, {"known": jnp.asarray(known)}, jnp.full((5, 2), noise),
                                 jnp.zeros((5, 0), int), jnp.arange(5)),
        "prior": ResidualBlock(_prior, {"value": jnp.zeros(4)}, jnp.full((4, 1), 10.0), jnp.arange(4)[:, None]),
    }
    start_points = truth_points + rng.normal(0, 20, truth_points.shape)
    return Problem(blocks, jnp.zeros(4 * images), jnp.asarray(start_points)), truth_theta, truth_points


CROSS = [(3, 4), (5, 9)]
"""Point pairs whose cross-cofactors the small block's solves return: the same in every test of the small block, so
that one compiled solve per backend serves them all (a request of none, padded to one pair, compiled again)."""


def test_schur_and_dense_backends_agree(rng):
    problem, _, _ = small_block(rng)
    dense = solve(problem, EngineOptions("dense"), cross_points=CROSS)
    schur = solve(problem, EngineOptions("schur"), cross_points=CROSS)
    assert bool(dense.converged) and bool(schur.converged)
    assert dense.degrees_of_freedom == schur.degrees_of_freedom > 0

    def close(a, b):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-8, atol=1e-8 * float(np.max(np.abs(b))))

    close(schur.parameters["theta"], dense.parameters["theta"])
    close(schur.parameters["points"], dense.parameters["points"])
    close(schur.cofactor, dense.cofactor)
    close(schur.point_cofactor, dense.point_cofactor)
    close(schur.point_pair_cofactor, dense.point_pair_cofactor)
    close(schur.sigma0, dense.sigma0)
    for group in ("image", "control", "prior"):
        close(schur.redundancy[group], dense.redundancy[group])
        close(schur.standardized_residuals[group], dense.standardized_residuals[group])
    total = sum(float(np.sum(r)) for r in dense.redundancy.values())
    assert total == pytest.approx(dense.degrees_of_freedom, rel=1e-9)


def test_point_cofactors_match_the_inverse_normal_matrix(rng):
    """Independent truth: the full (JᵀJ)⁻¹ from a finite-difference Jacobian, solved by numpy."""
    problem, _, _ = small_block(rng)
    result = solve(problem, EngineOptions("schur"), cross_points=CROSS)
    theta, points = np.asarray(result.parameters["theta"]), np.asarray(result.parameters["points"])

    @jax.jit  # one compilation for the 72 evaluations
    def whitened_residuals(x):
        t, p = x[:theta.size], x[theta.size:].reshape(points.shape)
        out = []
        for block in problem.blocks.values():
            pts = p[block.point_index] if block.point_index is not None else jnp.zeros((block.rows, 0))
            out.append((jax.vmap(block.function)(t[block.global_index], pts, block.data) / block.sigma).reshape(-1))
        return jnp.concatenate(out)

    def whitened(x):
        return np.asarray(whitened_residuals(jnp.asarray(x)))

    x = np.concatenate([theta, points.reshape(-1)])
    step = 1e-6 * np.maximum(np.abs(x), 1.0)
    jacobian = np.stack([(whitened(x + h) - whitened(x - h)) / (2 * h[k]) for k, h in enumerate(np.diag(step))], 1)
    inverse = np.linalg.inv(jacobian.T @ jacobian)
    tolerance = {"rtol": 1e-5, "atol": 1e-7 * np.abs(inverse).max()}
    np.testing.assert_allclose(result.cofactor, inverse[:theta.size, :theta.size], **tolerance)
    blocks = inverse[theta.size:, theta.size:].reshape(points.shape[0], 2, points.shape[0], 2)
    diagonal = np.arange(points.shape[0])
    np.testing.assert_allclose(result.point_cofactor, blocks[diagonal, :, diagonal], **tolerance)


@pytest.mark.parametrize("backend", ["dense", "schur"])
def test_a_control_point_blunder_is_flagged_named_and_signed(rng, backend):
    problem, _, _ = small_block(rng, control_error=30.0)  # 30 σ on control point 2's x
    result = solve(problem, EngineOptions(backend), cross_points=CROSS)
    flags = result.flagged()
    assert flags and (flags[0].group, flags[0].row, flags[0].component) == ("control", 2, 0)
    # computed − observed residual; the estimated error has the sign of the planted one (observed − true)
    assert float(result.residuals["control"][2, 0]) < 0
    redundancy = float(result.redundancy["control"][2, 0])
    assert flags[0].estimated_error == pytest.approx(30.0, abs=4.0 / np.sqrt(redundancy))
    assert flags[0].minimal_detectable_bias < 30.0


@pytest.mark.parametrize("backend", ["dense", "schur"])
def test_a_blunder_on_a_point_seen_twice_is_named_inseparable(rng, backend):
    problem, _, _ = small_block(rng)
    image = problem.blocks["image"]
    rows = np.nonzero(np.asarray(image.point_index) == 6)[0]  # seen on two images only
    observed = image.data["observed"].at[rows[0], 0].add(12.0)
    bad = Problem({**problem.blocks, "image": ResidualBlock(image.function, {"observed": observed}, image.sigma,
                                                            image.global_index, image.point_index)},
                  problem.start, problem.points)
    result = solve(bad, EngineOptions(backend), cross_points=CROSS)
    flags = [f for f in result.flagged() if f.group == "image" and f.row in rows]
    assert len(flags) == 2 and not any(f.separable for f in flags)
    assert abs(abs(flags[0].w) - abs(flags[1].w)) < 0.05 * abs(flags[0].w)
    assert {flags[0].confounded_with[1], flags[1].confounded_with[1]} == set(rows.tolist())
    assert float(np.max(result.w_correlation["image"][rows])) > INSEPARABLE
    clean = solve(problem, EngineOptions(backend), cross_points=CROSS)
    other = image.data["observed"].at[rows[0] + 2, 0].add(12.0)  # a point seen on three images
    single = Problem({**problem.blocks, "image": ResidualBlock(image.function, {"observed": other}, image.sigma,
                                                               image.global_index, image.point_index)},
                     problem.start, problem.points)
    separable = [f for f in solve(single, EngineOptions(backend), cross_points=CROSS).flagged() if f.row == rows[0] + 2]
    assert separable and separable[0].separable and not clean.flagged()


def test_variance_components_recover_a_planted_sigma_ratio():
    """Two groups measuring a line; group "b" has twice the σ it is given. 30 realizations: the estimated variance
    factors average to 4 and 1, and their reported σ matches their scatter."""
    t = np.linspace(0, 1, 60)

    def line(theta, _, row):
        return jnp.atleast_1d(theta[0] + theta[1] * row["t"] - row["y"])

    rng = np.random.default_rng(8)
    factors, sigmas = [], []
    for _ in range(30):
        blocks = {g: ResidualBlock(line, {"t": jnp.asarray(t), "y": jnp.asarray(1 + 2 * t + rng.normal(0, s, t.size))},
                                   jnp.full((t.size, 1), 0.1), jnp.broadcast_to(jnp.arange(2), (t.size, 2)))
                  for g, s in (("a", 0.1), ("b", 0.2))}
        result = variance_components(Problem(blocks, jnp.zeros(2)))
        factors.append([result.variance_components[g].value for g in "ab"])
        sigmas.append([result.variance_components[g].sigma for g in "ab"])
    factors, sigmas = np.array(factors), np.array(sigmas)
    np.testing.assert_allclose(factors.mean(axis=0), [1.0, 4.0], atol=3 * sigmas.mean(axis=0)[1] / np.sqrt(30))
    np.testing.assert_allclose(factors.std(axis=0, ddof=1) / sigmas.mean(axis=0), 1.0, atol=0.35)
    assert result.variance_components["b"].p_value < 1e-3


@pytest.mark.parametrize("kind", ["huber", "danish"])
def test_robust_reweighting_removes_a_blunder(rng, kind):
    t = np.linspace(0, 1, 40)
    y = 1 + 2 * t + rng.normal(0, 0.1, t.size)

    def line(theta, _, row):
        return jnp.atleast_1d(theta[0] + theta[1] * row["t"] - row["y"])

    def problem(values):
        return Problem({"y": ResidualBlock(line, {"t": jnp.asarray(t), "y": jnp.asarray(values)},
                                           jnp.full((t.size, 1), 0.1), jnp.broadcast_to(jnp.arange(2), (t.size, 2)))},
                       jnp.zeros(2))

    clean = solve(problem(y))
    bad = y.copy()
    bad[5] += 3.0  # 30 σ
    plain = solve(problem(bad))
    robust = robust_adjustment(problem(bad), kind)
    sigma = np.sqrt(np.diag(np.asarray(clean.cofactor)))
    shift = np.abs(np.asarray(plain.parameters["theta"]) - np.asarray(clean.parameters["theta"])) / sigma
    remaining = np.abs(np.asarray(robust.parameters["theta"]) - np.asarray(clean.parameters["theta"])) / sigma
    assert shift.max() > 3.0 and remaining.max() < (0.3 if kind == "danish" else 1.0)
    weights = np.asarray(robust.robust_weights["y"])[:, 0]
    assert weights[5] < (1e-3 if kind == "danish" else 0.1) and np.delete(weights, 5).min() > 0.3
    # the down-weighted observation keeps its whole error as residual (computed − observed = −3); the w-tests of
    # the final weights pass for the others
    assert float(robust.residuals["y"][5, 0]) == pytest.approx(-3.0, abs=0.2)
    assert np.all(np.abs(np.delete(np.asarray(robust.standardized_residuals["y"])[:, 0], 5)) < float(critical_value()))


def test_a_second_solver_of_the_same_shape_compiles_nothing(rng):

    def decay(p, _):
        return {"y": p["a"] * jnp.exp(-p["b"] * jnp.linspace(0, 2, 9))}

    def fit(a):
        solver = make_solver(decay, {"a": jnp.asarray(a), "b": jnp.asarray(1.0)},
                             {"y": Observations(jnp.zeros(9), 0.1)})
        return solver({"y": np.asarray(decay({"a": 2.0, "b": 1.3}, None)["y"]) + rng.normal(0, 0.1, 9)})

    fit(1.0)
    before = gauss_newton._solve._cache_size()
    result = fit(1.5)
    assert gauss_newton._solve._cache_size() == before and bool(result.converged)


def test_under_vmap_each_lane_stops_on_its_own():
    """A lane that needs damping does not make an easy lane take more steps than it takes alone."""
    x = jnp.linspace(0.0, 4.0, 12)

    def model(p, _):
        return {"y": p["a"] * jnp.exp(-p["b"] * x)}

    truth = {"a": jnp.asarray(2.0), "b": jnp.asarray(0.7)}
    solver = make_solver(model, truth, {"y": Observations(jnp.zeros(12), 0.01)})
    observed = np.asarray(model(truth, None)["y"]) + np.random.default_rng(3).normal(0, 0.01, 12)
    starts = {"a": jnp.array([2.1, 40.0]), "b": jnp.array([0.72, 9.0])}
    both = jax.vmap(lambda s: solver({"y": observed}, start=s))(starts)
    alone = solver({"y": observed}, start={"a": jnp.asarray(2.1), "b": jnp.asarray(0.72)})
    assert bool(jnp.all(both.converged))
    assert int(both.steps[0]) == int(alone.steps) < int(both.steps[1])
    np.testing.assert_allclose(both.parameters["b"], float(alone.parameters["b"]), rtol=1e-9)


@pytest.mark.parametrize("fraction", [0.3, 1e-4, 2.0])
def test_the_trust_region_step_has_the_radius_and_solves_the_damped_problem(rng, fraction):
    """Independent truth: numpy's least squares on the augmented system [J; √λ D] Δ = −[e; 0] (the damped problem),
    at the λ the secular equation gives; the step's scaled norm is the radius (or, for a radius beyond the
    Gauss-Newton step, λ = 0 and the step is Gauss-Newton's)."""
    jacobian = rng.normal(size=(40, 5)) * np.array([1e-3, 1.0, 1e2, 1e4, 3.0])
    jacobian[:, 4] += 1e-4 * jacobian[:, 1]  # a nearly dependent pair
    residuals = rng.normal(size=40) * 10.0
    scale = np.linalg.norm(jacobian, axis=0) * rng.uniform(1.0, 2.0, 5)  # a running maximum: ≥ the column norms
    factors = dense.Factors(jnp.asarray(jacobian), jnp.asarray(scale))
    projected = factors.left.T @ jnp.asarray(residuals)
    newton = np.linalg.lstsq(jacobian, -residuals, rcond=None)[0]
    radius = fraction * np.linalg.norm(scale * newton)
    damping = float(trust_region.damping_for_radius(factors.singular, projected, factors.kept, radius))
    step = np.asarray(factors.step(jnp.asarray(residuals), damping))
    if fraction >= 1.0:
        assert damping == 0.0
        np.testing.assert_allclose(step, newton, rtol=1e-9)
        return
    assert damping > 0
    assert np.linalg.norm(scale * step) == pytest.approx(radius, rel=1e-10)
    assert float(trust_region.step_norm(factors.singular, projected, factors.kept, damping)) == pytest.approx(
        radius, rel=1e-10)
    augmented = np.vstack([jacobian, np.sqrt(damping) * np.diag(scale)])
    expected = np.linalg.lstsq(augmented, -np.concatenate([residuals, np.zeros(5)]), rcond=None)[0]
    np.testing.assert_allclose(step, expected, rtol=1e-8, atol=1e-12 * np.abs(expected).max())


def _saturating(theta, _, row):
    """b1 (1 − exp(−b2 x)) − y: rises with x for every b1 > 0, b2 > 0."""
    return jnp.atleast_1d(theta[0] * (1.0 - jnp.exp(-theta[1] * row["x"])) - row["y"])


@pytest.mark.parametrize("strategy", ["damped", "trust-region"])
def test_a_minimum_at_infinity_is_refused_naming_the_parameter(strategy):
    """Falling data under a model that can only rise: the best fit is the constant b1 = mean(y), reached only as
    b2 → ∞ (ill posed, whatever the start). The engine must name b2, not return a finite b2 as an answer."""
    x = np.arange(1.0, 11.0)
    block = ResidualBlock(_saturating, {"x": jnp.asarray(x), "y": jnp.asarray(200.0 - x)}, jnp.ones((10, 1)),
                          jnp.broadcast_to(jnp.arange(2), (10, 2)))
    result = solve(Problem({"y": block}, jnp.array([1.0, 1.0])),
                   EngineOptions("dense", max_steps=500, strategy=strategy), ("b1", "b2"))
    assert result.undetermined_parameters() == ["b2"]
    assert float(result.parameters["theta"][0]) == pytest.approx(np.mean(200.0 - x), rel=1e-9)


def test_the_result_code_says_how_a_solve_ended_and_an_unconverged_solve_raises():
    """Converged, stopped at max_steps, or a residual that is not finite: the result code tells them apart (also per
    lane under vmap); an eager solve that did not converge raises unless the caller passes throw=False."""
    x = np.arange(1.0, 11.0)

    def problem(y):
        block = ResidualBlock(_saturating, {"x": jnp.asarray(x), "y": jnp.asarray(y)}, jnp.ones((10, 1)),
                              jnp.broadcast_to(jnp.arange(2), (10, 2)))
        return Problem({"y": block}, jnp.array([1.0, 0.1]))

    rising = 50.0 * (1.0 - np.exp(-0.3 * x))
    done = solve(problem(rising), EngineOptions("dense"), ("b1", "b2"))
    assert bool(done.converged) and done.result_name == "successful"
    with pytest.raises(NotConvergedError, match="max_steps_reached"):
        solve(problem(rising), EngineOptions("dense", max_steps=1), ("b1", "b2"))
    stopped = solve(problem(rising), EngineOptions("dense", max_steps=1), ("b1", "b2"), throw=False)
    assert not bool(stopped.converged) and stopped.result_name == "max_steps_reached"
    broken = solve(problem(np.where(x == 3, np.nan, rising)), EngineOptions("dense"), ("b1", "b2"), throw=False)
    assert broken.result_name == "nonfinite"
    lanes = jax.vmap(lambda y: solve(problem(y), EngineOptions("dense"), ("b1", "b2"), dof=8))(
        jnp.stack([rising, np.where(x == 3, np.nan, rising)]))
    assert np.asarray(lanes.result).tolist() == [0, 2]


def test_the_trust_region_reaches_the_damped_loops_minimum_in_as_few_steps(rng):
    problem, _, _ = small_block(rng)
    damped = solve(problem, EngineOptions("dense"), cross_points=CROSS)
    region = solve(problem, EngineOptions("dense", strategy="trust-region"), cross_points=CROSS)
    assert bool(region.converged) and int(region.steps) <= int(damped.steps)
    np.testing.assert_allclose(region.parameters["points"], damped.parameters["points"], rtol=0, atol=1e-6)
    # entries that are zero but for roundoff (1e-17 next to a diagonal of 0.4) agree to the matrix's scale
    scale = float(np.max(np.abs(damped.cofactor)))
    np.testing.assert_allclose(region.cofactor, damped.cofactor, rtol=1e-8, atol=1e-12 * scale)


@pytest.mark.parametrize("settings", [{"backend": "schur", "strategy": "trust-region"},
                                      {"monotone": False, "strategy": "trust-region"},
                                      {"strategy": "dogleg"}, {"backend": "sparse"},
                                      {"strategy": "trust-region", "initial_radius": 0.0}])
def test_engine_options_refuse_what_they_cannot_do(settings):
    with pytest.raises(SeaiceError, match="EngineOptions"):
        EngineOptions(**settings)


@pytest.mark.parametrize("d", [2, 3])
def test_the_point_blocks_inverse_matches_numpy_and_refuses_what_is_not_positive_definite(d):
    """Plane points (d = 2) are inverted in closed form, others by Cholesky: both against numpy's inverse, over a
    wide range of conditioning; a block that is not positive definite gives NaN (the solve then breaks down by
    name), an unobserved (all-zero, padding) block the identity."""
    from seaice_jax.adjust.engine.schur import _point_inverse

    rng = np.random.default_rng(3)
    factors = rng.normal(size=(200, d, d + 3))
    blocks = factors @ np.swapaxes(factors, 1, 2) * rng.uniform(1e-3, 1e6, (200, 1, 1))
    blocks[0] = 0.0
    blocks[1] = np.diag([1.0] * (d - 1) + [-1.0])
    inverse = np.asarray(_point_inverse(jnp.asarray(blocks), 0.0))
    expected = np.linalg.inv(blocks[2:])
    scale = np.abs(expected).max(axis=(1, 2))[:, None, None]
    np.testing.assert_allclose(inverse[2:] / scale, expected / scale, atol=1e-12)
    np.testing.assert_array_equal(inverse[0], np.eye(d))
    assert np.isnan(inverse[1]).all()
