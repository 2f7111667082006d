"""Simulated satellite images with known truth: single images with control points for the orbit fit, and
sequences of AVHRR-like images of moving pack ice (:func:`simulate_sequence`) for remapping, tracking and films."""

from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from seaice_jax.geometry.earth import MEAN_RADIUS
from seaice_jax.geometry.projections import MapGrid, Projection
from seaice_jax.geometry.scan import Direction, ScanModel, satellite_orbit
from seaice_jax.imagery.coast_control import signed_distance
from seaice_jax.sensors.control import ControlPoints, ImageObservations


def noaa_image(direction: Direction = "south", altitude: float = 0.0, earth_day=None) -> ScanModel:
    """A NOAA-7-like 512 x 512 blow-up image over Baffin Bay / Lancaster Sound (like source 001's).

    Southbound: orbital angle 99° to 104.6°, node 66°; northbound: the mirrored geometry (η from 81° down to
    75.4°, node chosen so the image covers the same area).
    """
    options = {} if earth_day is None else {"earth_day": earth_day}
    orbit = satellite_orbit("NOAA-7", altitude=altitude, **options)
    if direction == "south":
        return ScanModel(np.radians(7.0), 110.0, np.radians(99.0), np.radians(5.6), np.radians(66.0), orbit, "south")
    return ScanModel(np.radians(7.0), 400.0, np.radians(81.0), np.radians(5.6), np.radians(-126.0), orbit, "north")


def simulate_control_points(model: ScanModel, count: int, rng: np.random.Generator, sigma_m: float = 1000.0,
                            margin: float = 20.0):
    """Control points spread over the image with known positions perturbed by N(0, σ) metres per coordinate.

    Returns:
        ``(control, truth_latitude, truth_longitude)``: the noisy control points and the true positions.
    """
    pixel = rng.uniform(1.0 + margin, model.n_pixels - margin, count)
    scan = rng.uniform(1.0 + margin, model.n_scans - margin, count)
    latitude, longitude = (np.asarray(a) for a in model.forward(jnp.asarray(pixel), jnp.asarray(scan)))
    radius = float(model.orbit.radius)
    noisy_lat = latitude + rng.normal(0.0, sigma_m, count) / radius
    noisy_lon = longitude + rng.normal(0.0, sigma_m, count) / (radius * np.cos(latitude))
    control = ControlPoints(pixel, scan, noisy_lat, noisy_lon, sigma_m, [f"P{i + 1}" for i in range(count)])
    return control, latitude, longitude


def perturb_known_positions(latitude, longitude, sigma_m, rng, runs, radius=MEAN_RADIUS):
    """``runs`` Monte Carlo realizations of known positions: arrays ``(runs, n)`` of latitude and longitude."""
    latitude, longitude = np.asarray(latitude), np.asarray(longitude)
    noise = rng.normal(0.0, 1.0, (2, runs, latitude.size)) * np.asarray(sigma_m)
    return latitude + noise[0] / radius, longitude + noise[1] / (radius * np.cos(latitude))


def overlapping_pair(rng: np.random.Generator, primary_first: int = 6, primary_second: int = 1,
                     secondary: int = 6, sigma_m: float = 500.0, pointing_m: float = 300.0):
    """Two overlapping southbound NOAA-7 images (the second's node 2° east, 0.8° earlier in the orbit).

    The first has ``primary_first`` control points, the second only ``primary_second`` (too few on its own);
    ``secondary`` points inside the overlap are measured on both. Known positions carry N(0, σ) noise; pointing
    at the secondary points is exact (add noise to the adjustment's observations to simulate it).

    Returns:
        ``(images, truths)``: two :class:`ImageObservations` and the two true :class:`ScanModel`.
    """
    first = noaa_image("south")
    second = eqx.tree_at(lambda m: (m.ascending_node, m.orbital_angle_first), first,
                         replace=(first.ascending_node + np.radians(2.0), first.orbital_angle_first - np.radians(0.8)))
    primary_a, _, _ = simulate_control_points(first, primary_first, rng, sigma_m)
    primary_b, _, _ = simulate_control_points(second, primary_second, rng, sigma_m)
    pixel = rng.uniform(150.0, 400.0, secondary)
    scan = rng.uniform(150.0, 400.0, secondary)
    pixel_b, scan_b = (np.asarray(a) for a in second.inverse(*first.forward(pixel, scan)))
    ids = tuple(f"S{k + 1}" for k in range(secondary))
    images = [ImageObservations("A", first.orbit, "south", primary_a, ids, pixel, scan, pointing_m),
              ImageObservations("B", second.orbit, "south", primary_b, ids, pixel_b, scan_b, pointing_m)]
    return images, (first, second)


# ---------------------------------------------------------------------------------------------------------------
# Image sequences: a region of land, fast ice and moving pack ice seen by successive passes
# ---------------------------------------------------------------------------------------------------------------

DAY = 86400.0


def _waves(rng, count, shortest, longest):
    """Random plane waves: wave vectors ``(count, 2)`` rad/m, phases and amplitudes (normalised to unit RMS)."""
    wavelength = np.exp(rng.uniform(np.log(shortest), np.log(longest), count))
    angle = rng.uniform(0.0, np.pi, count)
    vectors = (2 * np.pi / wavelength)[:, None] * np.stack([np.cos(angle), np.sin(angle)], 1)
    amplitude = np.sqrt(wavelength / longest)  # more energy in the long waves (floes larger than their cracks)
    return jnp.asarray(vectors), jnp.asarray(rng.uniform(0, 2 * np.pi, count)), jnp.asarray(
        amplitude * np.sqrt(2.0 / np.sum(amplitude**2)))


@jax.jit
def _field(waves, xi):
    """Sum of plane waves at points ``xi (..., 2)`` m: a smooth random field of unit RMS."""
    vectors, phases, amplitudes = waves
    angle = xi @ vectors.T
    return jnp.cos(angle + jnp.broadcast_to(phases, angle.shape)) @ amplitudes


def _relief_octaves(rng, shortest, octaves=4, count=24):
    """Wave sets of :func:`_relief`: ``octaves`` bands of ``count`` waves, wavelengths ``shortest`` · [2^o, 2^(o+1)]
    m."""
    return tuple(_waves(rng, count, shortest * 2.0**o, shortest * 2.0 ** (o + 1)) for o in range(octaves))


def _relief(octaves, xi):
    """Ridged multi-octave noise at ``xi (..., 2)`` m: the mean over octaves of 0.8 − |f_o| (f_o a unit-RMS
    field of one octave, E|f_o| ≈ 0.8): sharp crests and valley lines at every scale, as eroded terrain shows in
    the shading of an AVHRR image; mean ≈ 0, RMS ≈ 0.6 / √octaves."""
    return sum(0.8 - jnp.abs(_field(waves, xi)) for waves in octaves) / len(octaves)


class IceScene(eqx.Module):
    """The ground truth of a region: land behind the real (GSHHG) coastline, a band of fast ice along it, pack ice
    moving with an affine velocity field, all as brightness (0-1) in a local map projection.

    The land is the signed distance to the coast (m, > 0 on land) on a fine raster (``land``, a map grid in the
    scene's projection; land where :func:`~seaice_jax.io.coastline.land_mask_of_grid` says so), interpolated
    bilinearly: a pure, differentiable function of position whose coast is the GSHHG shoreline to within half a
    raster cell, with a smooth edge (no aliasing when sampled by coarser pixels).

    Pack ice is a material texture: the floe that is at ``X`` at time 0 is at ``X + t (v + G (X − X0))`` at time
    ``t`` s (velocity ``v`` m/s at the scene's centre ``X0``, velocity gradient ``G`` 1/s), so its velocity is
    constant and the field is exactly affine. Floes are bright, leads dark. Land and fast ice do not move.

    Attributes:
        projection: the metric map projection (x, y in metres) the scene is defined in.
        centre: ``(2,)`` m, map coordinates of the scene's centre.
        land: the :class:`~seaice_jax.geometry.projections.MapGrid` of the coast-distance raster.
        coast_distance: ``(land.n_rows, land.n_columns)`` m, signed distance from the coast (> 0 on land) at the
            raster's cell centres. fast_ice_width: m.
        velocity: ``(2,)`` m/s at the centre (map x, y). velocity_gradient: ``(2, 2)`` 1/s, ∂(u, v)/∂(x, y).
    """

    projection: Projection
    centre: Float[Array, " 2"]
    land: MapGrid
    coast_distance: Float[Array, "rows columns"]
    fast_ice_width: Float[Array, ""]
    velocity: Float[Array, " 2"]
    velocity_gradient: Float[Array, "2 2"]
    ice_waves: tuple
    detail_waves: tuple
    land_waves: tuple
    relief_waves: tuple

    def displacement(self, xy, time):
        """Displacement (m) by ``time`` s of the pack ice that is at ``xy (..., 2)`` m at time 0 (zero on land
        and fast ice is not applied here: see :meth:`is_pack`)."""
        relative = jnp.asarray(xy) - jnp.broadcast_to(self.centre, jnp.shape(xy))
        return time * (jnp.broadcast_to(self.velocity, relative.shape) + relative @ self.velocity_gradient.T)

    def material_position(self, xy, time):
        """Where the pack ice at ``xy (..., 2)`` at ``time`` s was at time 0 (the inverse of the motion)."""
        matrix = jnp.eye(2) + time * self.velocity_gradient
        xy = jnp.asarray(xy)
        shifted = xy - jnp.broadcast_to(self.centre + time * self.velocity, xy.shape)
        material = jnp.linalg.solve(matrix, shifted.reshape(-1, 2).T).T.reshape(xy.shape)
        return material + jnp.broadcast_to(self.centre, xy.shape)

    def coast_offset(self, xy):
        """Signed distance (m) from the coastline toward land (> 0 on land) at ``xy (..., 2)`` m: the raster
        interpolated bilinearly (beyond the raster, its edge value)."""
        xy = jnp.asarray(xy, float)
        row, column = self.land.to_pixel(xy[..., 0], xy[..., 1])
        return jax.scipy.ndimage.map_coordinates(self.coast_distance, [row, column], order=1, mode="nearest")

    def is_pack(self, xy):
        """True where ``xy`` is seaward of the fast ice."""
        return self.coast_offset(xy) < -self.fast_ice_width

    def brightness(self, xy, time, clouds=None):
        """Brightness 0-1 at map positions ``xy (..., 2)`` m at ``time`` s; ``clouds``: ``(centres (c, 2) m,
        radii (c,) m)`` of cloud patches (flat, bright, opaque at their centres)."""
        xy = jnp.asarray(xy, float)
        material = self.material_position(xy, time)
        floes = jax.nn.sigmoid((_field(self.ice_waves, material) - 0.3) / 0.12)
        pack = 0.12 + 0.68 * floes + 0.06 * _field(self.detail_waves, material)
        land = 0.5 + 0.06 * _field(self.land_waves, xy) + 0.3 * _relief(self.relief_waves, xy)
        fast = 0.86 + 0.03 * _field(self.detail_waves, xy)
        offset = self.coast_offset(xy)
        on_land = jax.nn.sigmoid(offset / 500.0)
        on_fast = jax.nn.sigmoid((offset + self.fast_ice_width) / 500.0)
        value = on_land * land + (1 - on_land) * (on_fast * fast + (1 - on_fast) * pack)
        if clouds is not None:
            centres, radii = (jnp.asarray(a, float) for a in clouds)
            difference = xy[..., None, :] - jnp.broadcast_to(centres, (*xy.shape[:-1], *centres.shape))
            distance2 = jnp.sum(difference**2, axis=-1) / jnp.broadcast_to(radii**2, difference.shape[:-1])
            opacity = jnp.clip(jnp.max(jnp.exp(-0.5 * distance2**2) * 1.6, axis=-1), 0.0, 1.0)
            value = (1 - opacity) * value + opacity * 0.93
        return value


_COAST_DISTANCE: dict[tuple, np.ndarray] = {}
"""Coast-distance rasters already made in this process, by grid (rasterizing takes seconds, a lookup nothing)."""


def coast_distance_raster(grid: MapGrid) -> np.ndarray:
    """``(n_rows, n_columns)`` m: signed distance from the GSHHG coast (> 0 on land) at a map grid's cell centres.

    Land and sea are the coastline's :meth:`~seaice_jax.io.coastline.Coastline.contains` at the cell centres; each
    cell's distance is that to the nearest cell of the other kind (exact Euclidean distance transform) less half a
    cell, so the zero line runs midway between a land and a sea cell. Cells are assumed square
    (``pixel_width``)."""
    from seaice_jax.io.coastline import land_mask_of_grid

    key = (grid.projection.proj_string(), float(grid.x_first), float(grid.y_first), float(grid.pixel_width),
           float(grid.pixel_height), grid.n_rows, grid.n_columns)
    if key not in _COAST_DISTANCE:
        distance = signed_distance(land_mask_of_grid(grid)) * float(grid.pixel_width)
        if len(_COAST_DISTANCE) >= 8:
            _COAST_DISTANCE.pop(next(iter(_COAST_DISTANCE)))
        _COAST_DISTANCE[key] = distance.astype(float)
    return _COAST_DISTANCE[key]


def ice_scene(rng: np.random.Generator, latitude=74.2, longitude=-78.0, velocity=(0.06, -0.03),
              velocity_gradient=((2e-7, 1e-7), (-1e-7, -1e-7)), feature_size=12_000.0,
              projection=None, fast_ice_width=12_000.0, extent=1_100_000.0, land_spacing=1000.0) -> IceScene:
    """A scene of Lancaster Sound and its mouth into Baffin Bay (by default; any region by its centre): the real
    GSHHG land — Devon Island to the north, Bylot and Baffin Islands to the south —, ``fast_ice_width`` of fast
    ice along every coast, pack ice moving ~6 km/day. The Figure 3-3 stations (``examples/AGRID.STN``) are
    coastal features of this scene.

    The land has relief texture (:func:`_relief`, wavelengths feature_size/2 to 8 feature_size, static, drawn from
    a generator spawned from ``rng``, so the other draws of ``rng`` do not change with it): what image matching
    between passes (tie points) and control-point identification rely on.

    Args:
        latitude, longitude: degrees of the centre. velocity: m/s (map x, y) at the centre.
        velocity_gradient: 1/s. feature_size: m, the smallest floe and lead widths (keep above two pixels of the
            images and maps the scene is seen in). projection: metric map projection (default NSIDC EPSG:3413).
        fast_ice_width: m. extent: m, the side of the square coast raster around the centre (beyond it the land
            or sea of its edge continues). land_spacing: m, its cell size (the coast's resolution).
    """
    from seaice_jax.geometry.projections import nsidc_polar_stereographic

    projection = projection or nsidc_polar_stereographic("north")
    centre = jnp.stack(projection.forward(np.radians(latitude), np.radians(longitude)))
    rng.uniform(size=12)  # the draws of the former invented coastline: a seed keeps its pack ice and passes
    cells = int(np.ceil(extent / land_spacing))
    land = MapGrid.centred(projection, np.radians(latitude), np.radians(longitude), land_spacing, land_spacing,
                           cells, cells)
    return IceScene(projection, centre, land, jnp.asarray(coast_distance_raster(land)),
                    jnp.asarray(float(fast_ice_width)), jnp.asarray(velocity, float),
                    jnp.asarray(velocity_gradient, float), _waves(rng, 40, 2 * feature_size, 12 * feature_size),
                    _waves(rng, 20, feature_size, 3 * feature_size), _waves(rng, 30, feature_size, 10 * feature_size),
                    _relief_octaves(rng.spawn(1)[0], 0.5 * feature_size))


def place_pass(template: ScanModel, latitude, longitude, iterations: int = 8) -> ScanModel:
    """The template's pass moved (ascending node and orbital angle) so that its image centre falls on
    ``(latitude, longitude)`` radians: Newton on the two unknowns, autodiff Jacobian."""
    centre_pixel, centre_scan = 0.5 * (1 + template.n_pixels), 0.5 * (1 + template.n_scans)
    target = jnp.array([latitude, longitude], float)

    def misfit(unknowns):
        model = eqx.tree_at(lambda m: (m.ascending_node, m.orbital_angle_first), template,
                            replace=(unknowns[0], unknowns[1]))
        lat, lon = model.forward_unchecked(centre_pixel, centre_scan)
        return jnp.array([lat - target[0], jnp.angle(jnp.exp(1j * (lon - target[1])))])

    unknowns = jnp.array([template.ascending_node, template.orbital_angle_first])
    for _ in range(iterations):
        unknowns = unknowns - jnp.linalg.solve(jax.jacfwd(misfit)(unknowns), misfit(unknowns))
    return eqx.tree_at(lambda m: (m.ascending_node, m.orbital_angle_first), template,
                       replace=(unknowns[0], unknowns[1]))


def noaa_pass(direction: Direction, size: int, latitude, longitude, subtrack_pixel=None) -> ScanModel:
    """A NOAA-7-like ``size`` x ``size`` image (the swath of :func:`noaa_image`, sampled at ``size``) centred on
    ``(latitude, longitude)`` radians; ``subtrack_pixel`` default: the image's middle column."""
    template = noaa_image(direction)
    subtrack = 0.5 * (1 + size) if subtrack_pixel is None else subtrack_pixel
    template = ScanModel(template.scanner_angle_span, subtrack, template.orbital_angle_first,
                         template.orbital_angle_span, template.ascending_node, template.orbit, direction, size, size)
    return place_pass(template, latitude, longitude)


class CameraDistortion(eqx.Module):
    """The re-digitizing video camera of source 001 (section 3.3): radial lens distortion and a non-square frame.

    A digitized pixel ``(u, v)`` (1-based column, row of the camera frame) shows the hardcopy image's point
    ``(pixel, scan)`` = centre + (1 + k r²) ((u − u_c) / aspect, v − v_c), r² in units of the frame's half
    height squared. ``aspect`` 4/3: the camera's 4:3 frame spreads the square image over 4/3 as many columns.
    """

    radial: Float[Array, ""] = eqx.field(converter=lambda x: jnp.asarray(x, float), default=0.04)
    aspect: Float[Array, ""] = eqx.field(converter=lambda x: jnp.asarray(x, float), default=4.0 / 3.0)
    frame_rows: int = eqx.field(static=True, default=512)
    frame_columns: int = eqx.field(static=True, default=683)
    image_pixels: int = eqx.field(static=True, default=512)
    image_scans: int = eqx.field(static=True, default=512)

    @classmethod
    def for_image(cls, n_pixels: int, n_scans: int, radial=0.04, aspect=4.0 / 3.0, margin: float = 0.25):
        """The camera framing an ``n_pixels`` x ``n_scans`` image with ``margin`` (a fraction of the image) of
        the sheet around it, in a frame of ``aspect``."""
        rows = int(round(n_scans * (1 + margin)))
        return cls(radial, aspect, rows, int(round(n_pixels * (1 + margin) * aspect)), n_pixels, n_scans)

    @jax.jit
    def to_image(self, u, v):
        """Image ``(pixel, scan)`` (1-based) seen at frame ``(u, v)`` (1-based column, row)."""
        uc, vc = 0.5 * (1 + self.frame_columns), 0.5 * (1 + self.frame_rows)
        du, dv = (jnp.asarray(u, float) - uc) / self.aspect, jnp.asarray(v, float) - vc
        half = 0.5 * self.frame_rows
        scale = 1.0 + self.radial * (du**2 + dv**2) / half**2
        return 0.5 * (1 + self.image_pixels) + scale * du, 0.5 * (1 + self.image_scans) + scale * dv


@dataclass(frozen=True)
class SatelliteImage:
    """One simulated image: what a researcher has (pixels, time, control points) and the truth.

    Attributes:
        name: image id. time: s since the sequence's epoch. data: ``(n_scans, n_pixels)`` brightness 0-1
            (row = scan line − 1, column = pixel − 1). model: the true :class:`ScanModel`.
        control: measured control points (pointing noise in pixel and scan; known positions with their σ).
        clouds: the cloud patches drawn on it (``None``: clear).
        frame: with a camera, the re-digitized frame ``(frame_rows, frame_columns)`` of the hardcopy (what
            :func:`~seaice_jax.imagery.optical.correct_image` turns back into ``data``).
    """

    name: str
    time: float
    data: np.ndarray
    model: ScanModel
    control: ControlPoints
    clouds: tuple | None = None
    frame: np.ndarray | None = None


@dataclass(frozen=True)
class ImageSequence:
    """A simulated sequence of images of one :class:`IceScene` (``epoch``: ISO 8601 UTC of time 0)."""

    scene: IceScene
    images: tuple[SatelliteImage, ...]
    epoch: str = "1983-03-08T00:00:00Z"


def render(scene: IceScene, model: ScanModel, time: float, clouds=None, distortion: CameraDistortion | None = None):
    """The image ``(n_scans, n_pixels)`` (or the camera frame ``(frame_rows, frame_columns)`` with
    ``distortion``) of ``scene`` at ``time`` s through the scan model: each pixel samples the ground brightness
    at its centre."""
    if distortion is None:
        scan, pixel = jnp.meshgrid(jnp.arange(1.0, model.n_scans + 1), jnp.arange(1.0, model.n_pixels + 1),
                                   indexing="ij")
    else:
        v, u = jnp.meshgrid(jnp.arange(1.0, distortion.frame_rows + 1),
                            jnp.arange(1.0, distortion.frame_columns + 1), indexing="ij")
        pixel, scan = distortion.to_image(u, v)
    return _render(scene, model, jnp.asarray(time, float), pixel, scan, clouds)  # an array: a float would be static


@eqx.filter_jit
def _render(scene, model, time, pixel, scan, clouds):
    latitude, longitude = model.forward_unchecked(pixel, scan)
    xy = jnp.stack(scene.projection.forward(latitude, longitude), axis=-1)
    inside = (pixel >= 0.5) & (pixel <= model.n_pixels + 0.5) & (scan >= 0.5) & (scan <= model.n_scans + 0.5)
    return jnp.where(inside, scene.brightness(xy, time, clouds), 0.0)


def simulate_sequence(seed: int = 0, n_images: int = 4, size: int = 128, interval_days: float = 1.0,
                      clouds: bool = False, control_points: int = 12, pointing_sigma=(0.3, 0.6),
                      control_sigma: float = 500.0, scene: IceScene | None = None,
                      camera: CameraDistortion | None = None) -> ImageSequence:
    """A sequence of NOAA-7-like images of a Lancaster-Sound-like scene, passes alternating south- and
    northbound with their own nodes, ``interval_days`` apart (plus a few hours of pass time).

    Args:
        size: pixels and scan lines per image (the swath is the NOAA blow-up's ~620 km whatever the size).
        clouds: draw one to three cloud patches on every image but the first.
        control_points: per image, on land (fixed, known features such as capes and lakes).
        pointing_sigma: ``(pixel, scan)`` σ of the operator's pointing, in pixels (the video camera's vertical
            resolution was half its horizontal: source 001 section 4).
        control_sigma: m, σ of the known positions (map accuracy); each point's σ adds its pointing σ.
        camera: the re-digitizing camera (distortion, 4:3 frame): each image also gets its ``frame``.
    """
    rng = np.random.default_rng(seed)
    scene = scene or ice_scene(rng)
    lat0, lon0 = (float(a) for a in scene.projection.inverse(*scene.centre))
    images = []
    for k in range(n_images):
        direction = "south" if k % 2 == 0 else "north"
        offset = rng.normal(0.0, 60_000.0, 2) / MEAN_RADIUS  # the pass's centre wanders ±60 km
        model = noaa_pass(direction, size, lat0 + offset[0], lon0 + offset[1] / np.cos(lat0),
                          0.5 * (1 + size) + rng.normal(0, 0.1 * size))
        time = k * interval_days * DAY + rng.uniform(-3, 3) * 3600.0
        cloud = None
        if clouds and k > 0:
            count = rng.integers(1, 4)
            cloud = (np.asarray(scene.centre) + rng.normal(0, 120_000.0, (count, 2)),
                     rng.uniform(30_000.0, 70_000.0, count))
        data = np.asarray(render(scene, model, time, cloud))
        control = _land_control(scene, model, rng, control_points, pointing_sigma, control_sigma)
        frame = None if camera is None else np.asarray(render(scene, model, time, cloud, camera))
        images.append(SatelliteImage(f"IMG{k + 1:02d}", float(time), data, model, control, cloud, frame))
    return ImageSequence(scene, tuple(images))


def _land_control(scene, model, rng, count, pointing_sigma, control_sigma):
    """``count`` control points on land inside the image, pointed with noise, positions known to σ."""
    pixels, scans, lats, lons = [], [], [], []
    while len(pixels) < count:
        pixel, scan = rng.uniform(8, model.n_pixels - 8, 64), rng.uniform(8, model.n_scans - 8, 64)
        lat, lon = (np.asarray(a) for a in model.forward_unchecked(pixel, scan))
        on_land = np.asarray(scene.coast_offset(jnp.stack(scene.projection.forward(lat, lon), -1))) > 5000.0
        for p, s, a, b in zip(pixel[on_land], scan[on_land], lat[on_land], lon[on_land], strict=True):
            if len(pixels) < count:
                pixels.append(p)
                scans.append(s)
                lats.append(a)
                lons.append(b)
    # the ground σ of each point: map accuracy and pointing (pixels times the ground size of a pixel there)
    lat_p, lon_p = (np.asarray(a) for a in model.forward_unchecked(np.array(pixels) + 1.0, np.array(scans)))
    lat_s, lon_s = (np.asarray(a) for a in model.forward_unchecked(np.array(pixels), np.array(scans) + 1.0))
    lat0, lon0 = np.array(lats), np.array(lons)
    size_p = MEAN_RADIUS * np.hypot(lat_p - lat0, (lon_p - lon0) * np.cos(lat0))
    size_s = MEAN_RADIUS * np.hypot(lat_s - lat0, (lon_s - lon0) * np.cos(lat0))
    sigma = np.sqrt(control_sigma**2 + 0.5 * ((pointing_sigma[0] * size_p) ** 2 + (pointing_sigma[1] * size_s) ** 2))
    pixels = np.array(pixels) + rng.normal(0, pointing_sigma[0], count)
    scans = np.array(scans) + rng.normal(0, pointing_sigma[1], count)
    lats = np.array(lats) + rng.normal(0, control_sigma, count) / MEAN_RADIUS
    lons = np.array(lons) + rng.normal(0, control_sigma, count) / (MEAN_RADIUS * np.cos(lats))
    return ControlPoints(pixels, scans, lats, lons, sigma, [f"L{i + 1}" for i in range(count)])


def render_grid_target(distortion: CameraDistortion, spacing: float = 24.0, dot_sigma: float = 2.0):
    """The camera frame ``(frame_rows, frame_columns)`` of a calibration sheet: bright Gaussian dots of σ
    ``dot_sigma`` pixels on a dark ground every ``spacing`` image pixels, one dot at the image's centre, the
    sheet larger than the image (source 001, OPT: a regular grid photographed like the hardcopy)."""
    v, u = jnp.meshgrid(jnp.arange(1.0, distortion.frame_rows + 1), jnp.arange(1.0, distortion.frame_columns + 1),
                        indexing="ij")
    pixel, scan = distortion.to_image(u, v)
    centre_p, centre_s = 0.5 * (1 + distortion.image_pixels), 0.5 * (1 + distortion.image_scans)
    dp = pixel - centre_p - spacing * jnp.round((pixel - centre_p) / spacing)
    ds = scan - centre_s - spacing * jnp.round((scan - centre_s) / spacing)
    return np.asarray(0.1 + 0.8 * jnp.exp(-0.5 * (dp**2 + ds**2) / dot_sigma**2))


def scene_xy(scene: IceScene, grid) -> jnp.ndarray:
    """Scene map coordinates ``(n_rows, n_columns, 2)`` of the pixel centres of a :class:`MapGrid`."""
    latitude, longitude = grid.latitude_longitude()
    return jnp.stack(scene.projection.forward(latitude, longitude), axis=-1)


def land_mask(scene: IceScene, grid) -> np.ndarray:
    """``(n_rows, n_columns)`` bool: land in the grid (the coastal-map overlay of the 1985 films)."""
    return np.asarray(scene.coast_offset(scene_xy(scene, grid))) > 0


def true_displacement(scene: IceScene, xy, start: float, end: float) -> np.ndarray:
    """Where the surface at scene positions ``xy (n, 2)`` at time ``start`` is at ``end`` (s): pack ice moves,
    land and fast ice stay; returns the displacement ``(n, 2)`` m."""
    xy = jnp.asarray(xy, float)
    material = scene.material_position(xy, start)
    moved = material + scene.displacement(material, end)
    return np.asarray(jnp.where(scene.is_pack(xy)[:, None], moved - xy, 0.0))
