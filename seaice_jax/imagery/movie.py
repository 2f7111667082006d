"""Time-lapse films of a remapped image sequence (source 001, the MOVIE module).

As in 1985: grey scales stretched to show the ice, areas without data white, an optional filled overlay of the
land (so changing views of the coast do not distract), a date label on every frame, and optionally the tracked
points; and an optional map overlay (an RGBA image: the coastline, a labelled graticule and a scale bar, as the
workflow draws them with :func:`seaice_jax.report.maps.map_overlay`). Written as an animated GIF (Pillow) or an MP4
(OpenCV's ``mp4v`` encoder).
"""

import os
from pathlib import Path

import cv2
import numpy as np

from seaice_jax.errors import SeaiceError
from seaice_jax.files import atomic_path

LAND_COLOUR = (150, 120, 90)
POINT_COLOUR = (220, 30, 30)


def stretch(images, low: float = 1.0, high: float = 99.0):
    """Grey values 0-255 stretched between the ``low`` and ``high`` percentiles of all valid pixels of the
    sequence (one stretch for every frame, so brightness changes are real)."""
    images = np.asarray(images, float)
    finite = images[np.isfinite(images)]
    if finite.size == 0:
        raise SeaiceError("the sequence has no valid pixels to film")
    lo, hi = np.percentile(finite, [low, high])
    return np.clip((images - lo) / max(hi - lo, 1e-12), 0.0, 1.0) * 255.0


def composite(frame, overlay):
    """``overlay`` (RGBA uint8, the frame's size) laid over the RGB uint8 ``frame`` ("over" with straight alpha)."""
    overlay = np.asarray(overlay)
    if overlay.shape[:2] != frame.shape[:2] or overlay.shape[2] != 4:
        raise SeaiceError(f"the map overlay is {overlay.shape}, the frames {frame.shape[:2]} (+ 4 channels)")
    alpha = overlay[..., 3:4].astype(float) / 255.0
    return np.round(overlay[..., :3] * alpha + frame * (1.0 - alpha)).astype(np.uint8)


def render_frames(images, labels, land=None, points=None, scale: int = 2, overlay=None):
    """RGB frames ``(k, rows·scale, columns·scale, 3)`` uint8 of a remapped sequence.

    Args:
        images: ``(k, rows, columns)`` (NaN: no data, drawn white).
        labels: ``k`` strings (dates) printed in the top-left corner.
        land: ``(rows, columns)`` bool, filled with a land colour.
        points: per frame an ``(n, 2)`` array of (row, column) positions to mark, or ``None``.
        scale: pixel replication factor (nearest neighbour, so pixels stay visible).
        overlay: ``(rows·scale, columns·scale, 4)`` uint8 RGBA laid over every frame (under the points and the
            date), e.g. the coastline, graticule and scale bar.
    """
    images = np.asarray(images, float)
    if len(labels) != len(images):
        raise SeaiceError(f"{len(images)} images but {len(labels)} labels")
    grey = stretch(images)
    frames = []
    for k in range(len(images)):
        frame = np.repeat(np.nan_to_num(grey[k], nan=255.0)[..., None], 3, axis=2).astype(np.uint8)
        if land is not None:
            frame[np.asarray(land, bool)] = LAND_COLOUR
        frame = np.repeat(np.repeat(frame, scale, axis=0), scale, axis=1)
        frame = np.ascontiguousarray(frame if overlay is None else composite(frame, overlay))
        if points is not None and points[k] is not None:
            for row, column in np.asarray(points[k], float).reshape(-1, 2):
                if np.isfinite(row) and np.isfinite(column):
                    centre = (int(round((column + 0.5) * scale)), int(round((row + 0.5) * scale)))
                    cv2.circle(frame, centre, max(2, scale + 1), POINT_COLOUR, 1, cv2.LINE_AA)
        size = 0.35 + 0.1 * scale
        (width, height), baseline = cv2.getTextSize(labels[k], cv2.FONT_HERSHEY_SIMPLEX, size, 1)
        cv2.rectangle(frame, (0, 0), (width + 10, height + baseline + 8), (0, 0, 0), -1)  # a banner under the date
        cv2.putText(frame, labels[k], (5, height + 4), cv2.FONT_HERSHEY_SIMPLEX, size, (255, 255, 255), 1,
                    cv2.LINE_AA)
        frames.append(frame)
    return np.stack(frames)


def write_movie(path: str | os.PathLike, frames, fps: float = 2.0) -> Path:
    """Write RGB ``frames`` as ``.gif`` or ``.mp4`` (by the file's suffix), atomically."""
    from PIL import Image

    path = Path(path)
    frames = np.asarray(frames, np.uint8)
    if frames.ndim != 4 or frames.shape[-1] != 3 or len(frames) == 0:
        raise SeaiceError(f"{path}: frames must be (k, rows, columns, 3), got {frames.shape}")
    suffix = path.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise SeaiceError(f"{path}: a film is written as .gif or .mp4, not {suffix or 'no suffix'!r}")
    with atomic_path(path) as temporary:
        if suffix == ".gif":
            pictures = [Image.fromarray(f) for f in frames]
            pictures[0].save(temporary, format="GIF", save_all=True, append_images=pictures[1:],
                             duration=int(1000 / fps), loop=0)
        else:
            height, width = frames.shape[1:3]
            video = cv2.VideoWriter(str(temporary) + ".mp4", cv2.VideoWriter.fourcc(*"mp4v"), fps, (width, height))
            if not video.isOpened():
                raise SeaiceError(f"{path}: OpenCV cannot write MP4 here (no mp4v encoder); write a .gif instead")
            for frame in frames:
                video.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
            video.release()
            os.replace(str(temporary) + ".mp4", temporary)
    return path
