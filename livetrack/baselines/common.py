"""The interface every baseline implements: ``estimate(image) -> list[PoseEstimate]``, one call per frame.

A frame in which nothing is found gives an empty list, never an exception.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from livetrack.camera import CameraModel
from livetrack.geometry import Pose


@dataclass(frozen=True)
class PoseEstimate:
    """One target or marker found in one frame.

    ``target_id``: target or marker id; ``pose``: target-to-camera pose in livetrack's target frame;
    ``delta_px``: estimated exposure edge shift in pixels (None when the method has no exposure model);
    ``quality``: method-specific figure of merit (documented by each method; NaN if none);
    ``extra``: method-specific diagnostics (e.g. both IPPE solutions' reprojection errors).
    """

    target_id: int
    pose: Pose
    delta_px: float | None = None
    quality: float = math.nan
    extra: dict[str, Any] = field(default_factory=dict)


class PoseMethod(Protocol):
    """A pose estimator: ``name`` for tables and plots, ``estimate`` once per frame."""

    name: str

    def estimate(self, image: npt.NDArray[np.generic]) -> list[PoseEstimate]: ...


def full_scale(image: npt.NDArray[np.generic], camera: CameraModel, saturation: float | None = None) -> float:
    """Image value that reads as full scale (the sensor's clip level): ``saturation`` if given, else 255 for
    uint8 images and the camera's top code (2^bit_depth - 1) for any other dtype (uint16 or float DN). Pass
    ``saturation=1.0`` for float images in [0, 1]."""
    if saturation is not None:
        return float(saturation)
    if np.asarray(image).dtype == np.uint8:
        return 255.0
    return float(camera.saturation_level)


def to_uint8(image: npt.NDArray[np.generic], full_scale_value: float) -> npt.NDArray[np.uint8]:
    """(H, W) uint8 copy for the 8-bit detectors: ``full_scale_value`` maps to 255, NaN to 0, C-contiguous."""
    image = np.asarray(image)
    if image.dtype == np.uint8 and full_scale_value == 255.0:
        return np.ascontiguousarray(image)
    scaled = np.nan_to_num(image.astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0) * (255.0 / full_scale_value)
    return np.ascontiguousarray(np.clip(np.rint(scaled), 0, 255).astype(np.uint8))


def is_usable_image(image: npt.NDArray[np.generic], min_side_px: int = 16) -> bool:
    """True for a 2-D real-valued image at least ``min_side_px`` on each side with some finite contrast."""
    image = np.asarray(image)
    if image.ndim != 2 or min(image.shape) < min_side_px:
        return False
    if image.dtype == np.bool_ or not (np.issubdtype(image.dtype, np.integer)
                                       or np.issubdtype(image.dtype, np.floating)):
        return False
    finite = image[np.isfinite(image)] if np.issubdtype(image.dtype, np.floating) else image
    return finite.size > 0 and float(finite.max()) > float(finite.min())
