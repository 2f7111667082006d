"""What is measured on a satellite image, as the adjustment's input: ground control points (known positions) and
the observations of one image among several (primary control points and secondary points shared with other
images, source 001 section 3.3)."""

from dataclasses import dataclass

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float
from numpy.typing import ArrayLike

from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.scan import Orbit


class ControlPoints(eqx.Module):
    """Ground control points of one image: image position, known position, and its ground σ.

    Attributes:
        pixel, scan: ``(n,)`` fractional 1-based image coordinates.
        latitude, longitude: ``(n,)`` radians (on the model sphere).
        sigma: ``(n,)`` metres, standard deviation of each horizontal coordinate at the ground (map accuracy
            and image pointing combined).
        ids: point identifiers (station numbers or names).
    """

    pixel: Float[Array, " n"]
    scan: Float[Array, " n"]
    latitude: Float[Array, " n"]
    longitude: Float[Array, " n"]
    sigma: Float[Array, " n"]
    ids: tuple[str, ...] = eqx.field(static=True)

    def __init__(self, pixel, scan, latitude, longitude, sigma: ArrayLike = 1000.0, ids=None):
        arrays = [np.atleast_1d(np.asarray(a, float)) for a in (pixel, scan, latitude, longitude)]
        n = arrays[0].size
        ids = tuple(str(i) for i in (range(1, n + 1) if ids is None else ids))
        if any(a.shape != (n,) for a in arrays) or len(ids) != n:
            raise SeaiceError(f"control points: pixel, scan, latitude, longitude and ids must all have {n} entries")
        seen = set()
        for point_id in ids:
            if point_id in seen:
                raise SeaiceError(f"control point {point_id}: duplicate id")
            seen.add(point_id)
        for name, values in zip(("pixel", "scan", "latitude", "longitude"), arrays, strict=True):
            bad = np.nonzero(~np.isfinite(values))[0]
            if bad.size:
                raise SeaiceError(f"control point {ids[bad[0]]}: {name} is not a finite number")
        bad = np.nonzero(np.abs(arrays[2]) > np.pi / 2)[0]
        if bad.size:
            raise SeaiceError(f"control point {ids[bad[0]]}: latitude {np.degrees(arrays[2][bad[0]]):.4f}° is "
                              "outside [-90°, 90°]")
        sigma = np.broadcast_to(np.asarray(sigma, float), (n,))
        bad = np.nonzero(~(sigma > 0))[0]
        if bad.size:
            raise SeaiceError(f"control point {ids[bad[0]]}: sigma must be > 0 metres")
        self.pixel, self.scan, self.latitude, self.longitude = (jnp.asarray(a) for a in arrays)
        self.sigma = jnp.asarray(sigma)
        self.ids = ids

    @classmethod
    def from_degrees(cls, pixel, scan, latitude_deg, longitude_deg, sigma_km: ArrayLike = 1.0, ids=None):
        """Control points with latitude/longitude in degrees and σ in kilometres."""
        return cls(pixel, scan, np.radians(latitude_deg), np.radians(longitude_deg),
                   np.asarray(sigma_km, float) * 1000.0, ids)

    def __len__(self):
        return len(self.ids)

    def joined(self, other: "ControlPoints", prefix: str = "") -> "ControlPoints":
        """These points followed by ``other``'s (their ids with ``prefix``: an id may appear once only)."""
        def both(name):
            return np.concatenate([np.asarray(getattr(self, name)), np.asarray(getattr(other, name))])

        return ControlPoints(both("pixel"), both("scan"), both("latitude"), both("longitude"), both("sigma"),
                             [*self.ids, *(f"{prefix}{i}" for i in other.ids)])

    def subset(self, keep) -> "ControlPoints":
        """The points where ``keep`` ``(n,)`` bool is true, in order."""
        index = np.flatnonzero(np.asarray(keep, bool))

        def kept(name):
            return np.asarray(getattr(self, name))[index]

        return ControlPoints(kept("pixel"), kept("scan"), kept("latitude"), kept("longitude"), kept("sigma"),
                             [self.ids[k] for k in index])


@dataclass(frozen=True)
class ImageObservations:
    """What was measured on one image.

    Attributes:
        name: the image's name (used in messages and parameter names).
        orbit, direction, n_pixels, n_scans: the image's fixed orbit, pass direction and size.
        primary: control points with known positions (may be ``None``).
        secondary_ids: ids of the secondary points measured on this image.
        secondary_pixel, secondary_scan: ``(k,)`` their image coordinates.
        secondary_sigma: metres, ground σ of pointing a secondary point on this image.
    """

    name: str
    orbit: Orbit
    direction: str
    primary: ControlPoints | None
    secondary_ids: tuple[str, ...]
    secondary_pixel: np.ndarray
    secondary_scan: np.ndarray
    secondary_sigma: float = 1000.0
    n_pixels: int = 512
    n_scans: int = 512
