"""Observation model of a sequence of satellite images adjusted together: every image's scan-model unknowns, every
tie point's ground position, control points and per-image priors, as residual functions for a dense or a
Schur-complement least-squares backend (issue 13, «the simultaneous method»).

Unknowns:
  * θ ``(n_images, 5)``: per image the five unknowns of :class:`~seaice_jax.geometry.scan.ScanModel` in the order
    of :data:`~seaice_jax.geometry.scan.SCAN_UNKNOWNS` (as :mod:`seaice_jax.adjust.orbit.fit` fits them; radians
    and one pixel); flattened row-major, image ``i``'s unknown ``j`` is θ_flat[5 i + j] (:func:`global_index`);
  * points ``(n_ties, 2)``: per tie, ``(north, east)`` metres from the tie's reference position (φ0, λ0) on the
    model sphere: φ = φ0 + north/R, λ = λ0 + east/(R cos φ0) (:func:`tie_ground`). The chart is exact (an
    equirectangular chart about each tie), the unknowns are metres of similar size, start at 0 and never wrap.

Observations, in groups of rows sharing one residual function ``function(theta (5,), point (d,), row) ->
(c,)`` = computed − observed in observation units (the signature of the engine's residual blocks; ``row`` is the
group's ``data`` at one row):
  * **ties** (``"ties <direction> <n_pixels>x<n_scans>"``): the ``(pixel, scan)`` of tie ``t`` measured in image
    ``i``; computed by the inverse scan model of the tie's ground position, σ the pointing σ in pixels. The
    residual lives in image space because the inverse is closed form (up to the Earth-rotation fixed point, which
    contracts by T_s/T_e ≈ 0.07 a step: 8 steps are exact to 1e-9 and so are their derivatives), so unlike the
    radar block (:mod:`seaice_jax.adjust.radar.block`, whose inverse needs a zero-Doppler search and whose residuals are
    therefore formed on the ground and whitened by the image Jacobian) nothing is approximated: the whitened
    residuals are the image residuals in units of their σ, and a w-test names the pixel or the scan line at fault;
  * **control** (``"control <direction> <n_pixels>x<n_scans>"``): a control point measured at ``(pixel, scan)``
    with known position and ground σ (:class:`~seaice_jax.sensors.control.ControlPoints`: map accuracy and
    pointing combined, metres); computed − known position as ``(north, east)`` metres on the sphere, exactly the
    observation :func:`~seaice_jax.adjust.orbit.fit.fit_scan_model` fits, so the simultaneous adjustment and the
    per-image baseline weigh control points alike; no point unknowns;
  * **prior** (``"prior"``): per image, L⁻¹ (θ_i − θ̄_i) with L the Cholesky factor of the prior covariance (σ = 1:
    already whitened); the node difference is wrapped to (−π, π].

Images differ in pass direction and size, which are static in :class:`ScanModel`: rows are grouped by
(direction, n_pixels, n_scans), one function per group (cached, so two sequences of one layout share their
compiled code).
"""

import functools
from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from seaice_jax.adjust.engine import ResidualBlock
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.earth import wrap_angle
from seaice_jax.geometry.scan import SCAN_UNKNOWNS, ScanModel, scan_unknowns, with_scan_unknowns
from seaice_jax.sensors.control import ControlPoints

UNKNOWNS_PER_IMAGE = len(SCAN_UNKNOWNS)
_NODE = SCAN_UNKNOWNS.index("ascending_node")


def global_index(image) -> Int[Array, "m 5"]:
    """``(m, 5)`` indices into the flattened θ of the unknowns of each row's image ``(m,)``."""
    return UNKNOWNS_PER_IMAGE * jnp.asarray(image, int)[:, None] + jnp.arange(UNKNOWNS_PER_IMAGE)[None, :]


def tie_ground(reference, point, radius):
    """Latitude and longitude (radians) of a tie at ``point = (north, east)`` m from ``reference = (φ0, λ0)``."""
    return reference[0] + point[0] / radius, reference[1] + point[1] / (radius * jnp.cos(reference[0]))


def _model(theta, orbit, direction, n_pixels, n_scans) -> ScanModel:
    return ScanModel(theta[0], theta[1], theta[2], theta[3], theta[4], orbit, direction, n_pixels, n_scans)


def _tie_residual(direction, n_pixels, n_scans, theta, point, row):
    """Inverse scan model of the tie's ground position minus the measured ``(pixel, scan)``, pixels."""
    model = _model(theta, row["orbit"], direction, n_pixels, n_scans)
    latitude, longitude = tie_ground(row["reference"], point, row["orbit"].radius)
    pixel, scan = model.inverse(latitude, longitude)
    return jnp.stack([pixel - row["pixel"], scan - row["scan"]])


def _control_residual(direction, n_pixels, n_scans, theta, point, row):
    """Forward scan model at the measured ``(pixel, scan)`` minus the known position, ``(north, east)`` m."""
    del point
    model = _model(theta, row["orbit"], direction, n_pixels, n_scans)
    latitude, longitude = model.forward_unchecked(row["pixel"], row["scan"])
    radius = row["orbit"].radius
    return jnp.stack([radius * (latitude - row["latitude"]),
                      radius * jnp.cos(row["latitude"]) * wrap_angle(longitude - row["longitude"])])


def _prior_residual(theta, point, row):
    """Whitened difference of the unknowns from their prior mean (σ = 1)."""
    del point
    difference = theta - row["mean"]
    difference = difference.at[_NODE].set(wrap_angle(difference[_NODE]))
    return row["whitening"] @ difference


@functools.cache
def tie_function(direction: str, n_pixels: int, n_scans: int) -> Callable:
    """The tie residual ``(theta (5,), point (2,), row) -> (2,)`` pixels for images of one direction and size."""
    return functools.partial(_tie_residual, direction, n_pixels, n_scans)


@functools.cache
def control_function(direction: str, n_pixels: int, n_scans: int) -> Callable:
    """The control residual ``(theta (5,), point (0,), row) -> (2,)`` metres for images of one direction and
    size."""
    return functools.partial(_control_residual, direction, n_pixels, n_scans)


class SequenceObservations(eqx.Module):
    """Everything observed on a sequence, with the starting values of the unknowns.

    Attributes:
        groups: ``{name: ResidualBlock}`` (the engine's residual blocks, rows not padded; image ``i``'s unknowns are
            θ_flat[5 i: 5 i + 5], tie ``t`` is point ``t``).
        start: ``(n_images, 5)`` starting θ (the current models). models: the current :class:`ScanModel` per
            image (their orbits, directions and sizes are fixed; :meth:`models_at` puts θ into them).
        reference: ``(n_ties, 2)`` φ0, λ0 radians of each tie's chart (:func:`tie_ground`); the tie unknowns start
            at 0.
        reference_image: ``(n_ties,)`` the image whose observation of each tie the others were matched against
            (the table's ``reference`` observation; without that field, the tie's first observation).
    """

    groups: dict
    start: Float[Array, "n 5"]
    models: tuple
    reference: Float[Array, "t 2"]
    reference_image: Int[Array, " t"]

    @property
    def n_images(self) -> int:
        return len(self.models)

    @property
    def n_ties(self) -> int:
        return int(self.reference.shape[0])

    def models_at(self, theta) -> list[ScanModel]:
        """The scan models with unknowns ``theta (n_images, 5)``."""
        return [with_scan_unknowns(model, theta[i]) for i, model in enumerate(self.models)]

    def ground_at(self, points):
        """Latitude and longitude (radians), each ``(n_ties,)``, of the ties at ``points (n_ties, 2)``."""
        radius = self.models[0].orbit.radius
        return tie_ground(self.reference.T, jnp.asarray(points).T, radius)


def _row_orbits(models, image):
    stacked = jax.tree_util.tree_map(lambda *leaves: jnp.stack(leaves), *[m.orbit for m in models])
    return jax.tree_util.tree_map(lambda leaf: leaf[jnp.asarray(image, int)], stacked)


def _layouts(models):
    """``{(direction, n_pixels, n_scans): image indices}``."""
    layouts: dict[tuple, list[int]] = {}
    for i, model in enumerate(models):
        layouts.setdefault((model.direction, model.n_pixels, model.n_scans), []).append(i)
    return layouts


def sequence_observations(models: Sequence[ScanModel], ties=None, controls: Sequence[ControlPoints | None] = (),
                          prior_mean=None, prior_covariance=None) -> SequenceObservations:
    """The observation groups of a sequence.

    Args:
        models: the current scan model of every image (starting values; orbits, directions, sizes fixed).
        ties: a :class:`~seaice_jax.imagery.ties.TiePoints`-like object with ``image, tie, pixel, scan,
            sigma_pixel, sigma_scan`` ``(m,)`` per observation and ``latitude, longitude`` ``(n_ties,)`` radians
            (the charts' reference positions); ``None``: no ties.
        controls: per image its :class:`ControlPoints` (or ``None``); shorter than ``models``: the rest have none.
        prior_mean: ``(n_images, 5)`` (default: the current models' unknowns) and prior_covariance: ``(n_images,
            5, 5)`` or per-unknown σ ``(n_images, 5)``; ``None``: no priors.

    Raises:
        SeaiceError: naming the image or tie whose indices or σ are invalid.
    """
    models = tuple(models)
    n_images = len(models)
    if n_images == 0:
        raise SeaiceError("a sequence needs at least one image")
    start = jnp.stack([scan_unknowns(m) for m in models])
    groups: dict[str, ResidualBlock] = {}
    layouts = _layouts(models)
    reference = jnp.zeros((0, 2))
    reference_image = np.zeros(0, int)
    if ties is not None:
        image, tie = np.asarray(ties.image, int), np.asarray(ties.tie, int)
        reference = jnp.stack([jnp.asarray(ties.latitude, float), jnp.asarray(ties.longitude, float)], 1)
        if image.size and (image.min() < 0 or image.max() >= n_images):
            raise SeaiceError(f"tie observations: image index out of range 0..{n_images - 1}")
        if tie.size and (tie.min() < 0 or tie.max() >= reference.shape[0]):
            raise SeaiceError(f"tie observations: tie index out of range 0..{reference.shape[0] - 1}")
        reference_image = _reference_images(ties, image, tie, reference.shape[0])
        sigma = np.stack([np.asarray(ties.sigma_pixel, float), np.asarray(ties.sigma_scan, float)], 1)
        bad = np.nonzero(~(sigma > 0).all(axis=1))[0]
        if bad.size:
            raise SeaiceError(f"tie {tie[bad[0]]} in image {image[bad[0]]}: σ must be > 0 pixels")
        for (direction, n_pixels, n_scans), members in layouts.items():
            rows = np.nonzero(np.isin(image, members))[0]
            if rows.size == 0:
                continue
            data = {"pixel": jnp.asarray(np.asarray(ties.pixel, float)[rows]),
                    "scan": jnp.asarray(np.asarray(ties.scan, float)[rows]),
                    "orbit": _row_orbits(models, image[rows]), "reference": reference[tie[rows]]}
            groups[f"ties {direction} {n_pixels}x{n_scans}"] = ResidualBlock(
                tie_function(direction, n_pixels, n_scans), data, jnp.asarray(sigma[rows]),
                global_index(image[rows]), jnp.asarray(tie[rows]))
    controls = list(controls)
    if len(controls) > n_images:
        raise SeaiceError(f"{len(controls)} control-point sets for {n_images} images")
    for (direction, n_pixels, n_scans), members in layouts.items():
        present: list[tuple[int, ControlPoints]] = [
            (i, c) for i in members if i < len(controls) and (c := controls[i]) is not None and len(c) > 0]
        if not present:
            continue
        image = np.concatenate([np.full(len(c), i) for i, c in present])
        data = {key: jnp.concatenate([getattr(c, key) for _, c in present])
                for key in ("pixel", "scan", "latitude", "longitude")}
        data["orbit"] = _row_orbits(models, image)
        sigma = jnp.concatenate([c.sigma for _, c in present])
        groups[f"control {direction} {n_pixels}x{n_scans}"] = ResidualBlock(
            control_function(direction, n_pixels, n_scans), data, jnp.stack([sigma, sigma], 1), global_index(image))
    if prior_covariance is not None:
        groups["prior"] = _prior_group(start if prior_mean is None else jnp.asarray(prior_mean, float),
                                       jnp.asarray(prior_covariance, float), n_images)
    return SequenceObservations(groups, start, models, reference, jnp.asarray(reference_image))


def _reference_images(ties, image, tie, n_ties) -> np.ndarray:
    """``(n_ties,)`` the image of each tie's reference observation (``ties.reference`` if the table has it, else
    the tie's first observation; −1 for a tie without observations)."""
    flags = getattr(ties, "reference", None)
    if flags is None:
        first = np.zeros(tie.size, bool)
        first[np.unique(tie, return_index=True)[1]] = True
        flags = first
    out = np.full(n_ties, -1)
    chosen = np.nonzero(np.asarray(flags, bool))[0]
    out[tie[chosen]] = image[chosen]
    return out


def _prior_group(mean, covariance, n_images) -> ResidualBlock:
    if covariance.shape == (n_images, UNKNOWNS_PER_IMAGE):
        covariance = jax.vmap(jnp.diag)(covariance**2)
    size = UNKNOWNS_PER_IMAGE
    if covariance.shape != (n_images, size, size) or mean.shape != (n_images, size):
        raise SeaiceError(f"prior: mean must be ({n_images}, 5) and covariance ({n_images}, 5, 5) or σ "
                          f"({n_images}, 5), got {mean.shape} and {covariance.shape}")
    whitening = []
    for i, matrix in enumerate(np.asarray(covariance)):
        try:
            whitening.append(np.linalg.inv(np.linalg.cholesky(matrix)))
        except np.linalg.LinAlgError:
            raise SeaiceError(f"prior of image {i}: covariance is not positive definite") from None
    whitening = jnp.asarray(np.stack(whitening))
    data = {"mean": mean, "whitening": whitening}
    return ResidualBlock(_prior_residual, data, jnp.ones((n_images, UNKNOWNS_PER_IMAGE)),
                         global_index(np.arange(n_images)))


def unknown_names(observations: SequenceObservations, names: Sequence[str] | None = None) -> list[str]:
    """Names of the flattened θ: ``"<image name>.<unknown>"`` (image names default to ``"image<i>"``)."""
    names = [f"image{i}" for i in range(observations.n_images)] if names is None else list(names)
    return [f"{image}.{unknown}" for image in names for unknown in SCAN_UNKNOWNS]
