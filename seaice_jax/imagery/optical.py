"""Camera-distortion calibration and correction (source 001, the OPT module).

Hardcopy images were re-digitized with a video camera whose lens distorts and whose 4:3 frame stretches the
image. OPT photographed a regular grid, measured the offset of every lattice point from where it belongs and
corrected every image with offsets interpolated between the lattice points. Here:

1. :func:`detect_dots` finds the grid's dots in the frame (OpenCV threshold and connected components, then the
   intensity-weighted centroid of each dot, sub-pixel);
2. :func:`calibrate_camera` assigns each dot its lattice index (growing from the dot nearest the frame's centre,
   which is the sheet's reference dot at the image's centre) and interpolates the frame position of every image
   pixel from the lattice (bicubic, OpenCV ``remap``): the dense offset fields;
3. :func:`correct_image` samples any frame taken with the same camera settings at those positions.

Image coordinates are 1-based (pixel, scan) of the hardcopy image; frame coordinates 1-based (u, v) = (column,
row) of the camera frame.
"""

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from seaice_jax.errors import SeaiceError
from seaice_jax.files import atomic_path


def detect_dots(frame, min_area: int = 4, max_area: int = 2000):
    """Centres ``(n, 2)`` (u, v), 1-based, of the bright dots of a calibration frame."""
    frame = np.asarray(frame, float)
    low, high = np.percentile(frame, [1, 99.9])
    scaled = np.clip((frame - low) / max(high - low, 1e-12), 0, 1)
    image8 = (scaled * 255).astype(np.uint8)
    _, binary = cv2.threshold(image8, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(binary, connectivity=8)
    centres = []
    for k in range(1, count):
        x, y, w, h, area = stats[k]
        if not min_area <= area <= max_area or x == 0 or y == 0 or x + w >= frame.shape[1] or y + h >= \
                frame.shape[0]:
            continue  # too small/large, or cut by the frame's edge (its centroid would be biased)
        pad = max(w, h) // 2 + 2
        r0, r1 = max(y - pad, 0), min(y + h + pad, frame.shape[0])
        c0, c1 = max(x - pad, 0), min(x + w + pad, frame.shape[1])
        patch = np.clip(scaled[r0:r1, c0:c1] - np.median(scaled), 0, None)
        moments = cv2.moments(patch.astype(np.float64))
        if moments["m00"] <= 0:
            continue
        centres.append((c0 + moments["m10"] / moments["m00"] + 1.0, r0 + moments["m01"] / moments["m00"] + 1.0))
    return np.array(centres, float).reshape(-1, 2)


@dataclass(frozen=True)
class CameraCalibration:
    """The dense offset fields of one camera setting: where each image pixel lies in the frame.

    Attributes:
        frame_u, frame_v: ``(n_scans, n_pixels)`` 1-based frame column and row of image pixel (p, s) at
            ``[s − 1, p − 1]``.
        lattice_residual: RMS (frame pixels) of the detected dots about the smooth lattice model (detection
            noise). settings: the camera settings it belongs to (lens, zoom, distance, frame size, ...).
    """

    frame_u: np.ndarray
    frame_v: np.ndarray
    lattice_residual: float
    settings: dict = field(default_factory=dict)

    @property
    def image_shape(self) -> tuple[int, int]:
        return self.frame_u.shape

    def save(self, path: str | os.PathLike) -> Path:
        """Write the calibration (``.npz`` with the settings as JSON), atomically."""
        path = Path(path)
        with atomic_path(path) as temporary, open(temporary, "wb") as stream:
            np.savez_compressed(stream, frame_u=self.frame_u, frame_v=self.frame_v,
                                lattice_residual=self.lattice_residual, settings=json.dumps(self.settings))
        return path


def load_calibration(path: str | os.PathLike) -> CameraCalibration:
    """Read a calibration written by :meth:`CameraCalibration.save`."""
    try:
        with np.load(path) as data:
            return CameraCalibration(data["frame_u"], data["frame_v"], float(data["lattice_residual"]),
                                     json.loads(str(data["settings"])))
    except (OSError, KeyError, ValueError) as error:
        raise SeaiceError(f"{path}: not a camera calibration ({error})") from None


def _polynomial_terms(i, j, degree):
    return np.stack([i**a * j**b for a in range(degree + 1) for b in range(degree + 1 - a)], axis=-1)


def calibrate_camera(frame, image_shape, spacing: float, settings: dict | None = None,
                     degree: int = 5) -> CameraCalibration:
    """Calibrate the camera from a frame of the dot grid.

    Args:
        frame: ``(rows, columns)`` the camera's picture of the grid sheet.
        image_shape: ``(n_scans, n_pixels)`` of the hardcopy images to correct.
        spacing: image pixels between the grid's dots; the sheet has a dot at the image's centre.
        settings: camera settings stored with the calibration.
        degree: of the smooth polynomial used only to assign lattice indices and measure detection noise (the
            offset fields interpolate the measured dots themselves).

    Raises:
        SeaiceError: too few dots, or the lattice does not cover the image.
    """
    dots = detect_dots(frame)
    if len(dots) < 16:
        raise SeaiceError(f"only {len(dots)} grid dots found in the calibration frame (need at least 16)")
    rows, columns = np.asarray(frame).shape
    centre = np.array([0.5 * (1 + columns), 0.5 * (1 + rows)])
    distance = np.linalg.norm(dots - centre, axis=1)
    origin = dots[np.argmin(distance)]
    # nominal lattice steps from the nearest neighbours of the central dot: along u and along v
    near = dots[np.argsort(np.linalg.norm(dots - origin, axis=1))[1:9]] - origin
    step_u = np.median(np.abs(near[np.abs(near[:, 0]) > np.abs(near[:, 1]), 0]))
    step_v = np.median(np.abs(near[np.abs(near[:, 1]) > np.abs(near[:, 0]), 1]))
    index = np.round((dots - origin) / [step_u, step_v])
    for radius in np.linspace(0.3, 1.0, 6) * distance.max():
        # grow outward: fit the smooth lattice model to the dots assigned so far, re-assign the rest by it
        inner = np.linalg.norm(dots - origin, axis=1) <= radius
        d = min(degree, max(1, int(np.sqrt(inner.sum())) // 3))
        design = _polynomial_terms(index[inner, 0], index[inner, 1], d)
        coefficients, *_ = np.linalg.lstsq(design, dots[inner], rcond=None)
        for _ in range(3):
            guess = np.round(index)
            predicted = _polynomial_terms(guess[:, 0], guess[:, 1], d) @ coefficients
            index = guess + np.round((dots - predicted) / [step_u, step_v])
    unique, counts = np.unique(index, axis=0, return_counts=True)
    if (counts > 1).any():
        raise SeaiceError(f"calibration frame: {int((counts > 1).sum())} lattice points got two dots; is the "
                          "spacing right and the grid complete near the centre?")
    design = _polynomial_terms(index[:, 0], index[:, 1], degree)
    coefficients, *_ = np.linalg.lstsq(design, dots, rcond=None)
    residual = float(np.sqrt(np.mean(np.sum((design @ coefficients - dots) ** 2, axis=1))))
    # the lattice as two arrays over (j, i), NaN where no dot was found
    i0, j0 = index.min(axis=0).astype(int)
    i1, j1 = index.max(axis=0).astype(int)
    lattice = np.full((j1 - j0 + 1, i1 - i0 + 1, 2), np.nan)
    lattice[index[:, 1].astype(int) - j0, index[:, 0].astype(int) - i0] = dots
    n_scans, n_pixels = image_shape
    centre_p, centre_s = 0.5 * (1 + n_pixels), 0.5 * (1 + n_scans)
    s, p = np.meshgrid(np.arange(1.0, n_scans + 1), np.arange(1.0, n_pixels + 1), indexing="ij")
    li, lj = (p - centre_p) / spacing - i0, (s - centre_s) / spacing - j0  # fractional lattice indices
    if li.min() < 1 or lj.min() < 1 or li.max() > lattice.shape[1] - 2 or lj.max() > lattice.shape[0] - 2:
        raise SeaiceError("calibration frame: the grid's dots do not surround the whole image (bicubic "
                          "interpolation needs one lattice point beyond every edge)")
    corners = lattice[int(np.floor(lj.min())) - 1:int(np.ceil(lj.max())) + 2,
                      int(np.floor(li.min())) - 1:int(np.ceil(li.max())) + 2]
    if np.isnan(corners).any():
        raise SeaiceError(f"calibration frame: {int(np.isnan(corners).any(axis=-1).sum())} lattice points around "
                          "the image have no dot (hidden or too faint)")
    # Bicubic interpolation of the dots' departures from the smooth model, plus the smooth model evaluated
    # exactly: OpenCV's remap quantises its sampling positions to 1/32 of a lattice cell, harmless for the small
    # departures but not for the positions themselves.
    li_grid, lj_grid = np.meshgrid(np.arange(i0, i1 + 1.0), np.arange(j0, j1 + 1.0))
    departure = lattice - _polynomial_terms(li_grid, lj_grid, degree) @ coefficients
    maps = li.astype(np.float32), lj.astype(np.float32)
    interpolated = np.stack([cv2.remap(departure[..., k].astype(np.float32), *maps, cv2.INTER_CUBIC)
                             for k in range(2)], -1)
    dense = interpolated.astype(float) + _polynomial_terms(li + i0, lj + j0, degree) @ coefficients
    return CameraCalibration(dense[..., 0], dense[..., 1], residual, dict(settings or {}, spacing=spacing,
                                                                          frame_shape=[rows, columns]))


def correct_image(frame, calibration: CameraCalibration, interpolation: int = cv2.INTER_CUBIC):
    """The image ``(n_scans, n_pixels)`` of a frame taken with the calibrated camera settings (NaN where the
    frame does not reach)."""
    frame = np.asarray(frame, np.float32)
    expected = calibration.settings.get("frame_shape")
    if expected is not None and list(frame.shape) != list(expected):
        raise SeaiceError(f"frame shape {frame.shape} differs from the calibration's {tuple(expected)} (other "
                          "camera settings?)")
    u, v = (calibration.frame_u - 1.0).astype(np.float32), (calibration.frame_v - 1.0).astype(np.float32)
    corrected = cv2.remap(frame, u, v, interpolation, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    inside = (u >= 0) & (v >= 0) & (u <= frame.shape[1] - 1) & (v <= frame.shape[0] - 1)
    return np.where(inside, corrected.astype(float), np.nan)
