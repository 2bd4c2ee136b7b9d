"""Camera files and cameras derived from image metadata (I/O at the edge of the algorithm layer)."""

from __future__ import annotations

import logging
import math
from pathlib import Path

from livetrack import config_checks as cc
from livetrack.camera import CameraModel

log = logging.getLogger(__name__)

FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)


def load_camera(file: str | Path) -> CameraModel:
    """A camera YAML file: either a mapping with a ``camera`` key or the camera mapping itself."""
    data = cc.load_yaml(file)
    if isinstance(data, dict) and "camera" in data:
        return CameraModel.from_dict(data["camera"], f"{file}: camera")
    return CameraModel.from_dict(data, f"{file}: camera")


def camera_from_exif(image_file: str | Path, width: int, height: int, pixel_pitch_um: float | None = None,
                     bit_depth: int = 8) -> CameraModel:
    """An uncalibrated pinhole camera for a photo: principal point at the image centre, no distortion.

    fx = fy = EXIF FocalLength / pixel pitch when ``pixel_pitch_um`` is given (the sensor's datasheet value, the
    better choice); otherwise from FocalLengthIn35mmFilm over the full-frame diagonal (43.27 mm) mapped on the
    image diagonal. ``width``/``height`` are the pixel array as read (sensor order, EXIF orientation NOT
    applied). Raises ConfigError naming the file when the metadata is missing.
    """
    from PIL import Image  # optional dependency, only for photos

    try:
        with Image.open(image_file) as im:
            exif = im.getexif().get_ifd(0x8769)
    except OSError as exc:
        raise cc.ConfigError(str(image_file), f"cannot read EXIF: {exc}") from exc
    focal_mm = exif.get(0x920A)  # FocalLength
    focal_35mm = exif.get(0xA405)  # FocalLengthIn35mmFilm
    if pixel_pitch_um is not None and focal_mm:
        f_px = float(focal_mm) / (pixel_pitch_um * 1e-3)
    elif focal_35mm:
        f_px = float(focal_35mm) / FULL_FRAME_DIAGONAL_MM * math.hypot(width, height)
    else:
        raise cc.ConfigError(str(image_file), "no EXIF focal length: give a camera file (--camera)")
    log.debug("%s: camera from EXIF, f = %.1f px", image_file, f_px)
    return CameraModel(width=width, height=height, fx=f_px, fy=f_px, cx=(width - 1) / 2.0, cy=(height - 1) / 2.0,
                       bit_depth=bit_depth)
