"""Camera files and cameras derived from image metadata (I/O at the edge of the algorithm layer)."""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

import yaml

from livetrack.calibration.report import CameraUncertainty
from livetrack.camera import CameraModel
from livetrack.camera.encoding import canonical
from livetrack.camera.optics import CameraOptics
from livetrack.config import checks as cc

log = logging.getLogger(__name__)

FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)


OPTICS_SECTIONS = ("optics", "response")
"""Optional sections of a camera file next to the intrinsics (``livetrack.camera.optics``)."""

UNCERTAINTY_SECTION = "uncertainty"
"""Optional section of a camera file: 1-sigma of the intrinsics as calibrated (``livetrack calibrate``),
``{fx: px, fy: px, cx: px, cy: px, dist: [k1, k2, p1, p2, k3]}``; checked on load, kept by
:func:`load_camera_uncertainty`."""


def load_camera(file: str | Path) -> CameraModel:
    """A camera YAML file: either a mapping with a ``camera`` key or the camera mapping itself. Its optional
    ``optics``/``response`` sections are checked and dropped (:func:`load_camera_with_optics` returns them)."""
    return load_camera_with_optics(file)[0]


def load_camera_with_optics(file: str | Path) -> tuple[CameraModel, CameraOptics | None]:
    """A camera YAML file and its fitted optics: ``{camera: {...}, optics: {...}, response: {...}}``, or the
    camera mapping itself with ``optics``/``response`` among its keys. The optics are None when the file has no
    ``optics`` section; a ``response`` without ``optics`` is an error. ConfigError messages name the key path."""
    data = cc.load_yaml(file)
    if isinstance(data, dict) and "camera" in data:
        camera_data, sections, base = data["camera"], data, str(file)
    else:
        camera_data = data
        if isinstance(data, dict):
            camera_data = {k: v for k, v in data.items() if k not in (*OPTICS_SECTIONS, UNCERTAINTY_SECTION)}
        sections, base = (data if isinstance(data, dict) else {}), f"{file}: camera"
    camera = CameraModel.from_dict(camera_data, f"{file}: camera")
    if sections.get(UNCERTAINTY_SECTION) is not None:
        _uncertainty_from_dict(sections[UNCERTAINTY_SECTION], cc.join(base, UNCERTAINTY_SECTION))
    if sections.get("optics") is None:
        if sections.get("response") is not None:
            raise cc.ConfigError(cc.join(base, "response"), "needs an optics section (psf_sigma_px)")
        return camera, None
    return camera, CameraOptics.from_sections(sections["optics"], sections.get("response"), base)


def states_bit_depth(file: str | Path) -> bool:
    """Whether a camera file gives ``bit_depth`` (else CameraModel's default, 8, stands in for it)."""
    data = cc.load_yaml(file)
    if isinstance(data, dict) and isinstance(data.get("camera"), dict):
        data = data["camera"]
    return isinstance(data, dict) and "bit_depth" in data


def load_camera_uncertainty(file: str | Path) -> CameraUncertainty | None:
    """The ``uncertainty`` section of a camera file (None when absent); ConfigError naming the key if wrong."""
    data = cc.load_yaml(file)
    if not isinstance(data, dict) or data.get(UNCERTAINTY_SECTION) is None:
        return None
    return _uncertainty_from_dict(data[UNCERTAINTY_SECTION], cc.join(str(file), UNCERTAINTY_SECTION))


def _uncertainty_from_dict(data: Any, path: str) -> CameraUncertainty:
    cc.mapping(data, path, required=["fx", "fy", "cx", "cy"], optional=["dist"])
    values = [cc.number(data, key, path, ge=0) for key in ("fx", "fy", "cx", "cy")]
    dist = cc.number_list(data, "dist", path, length=5, default=[0.0] * 5)
    if any(d < 0 for d in dist):
        raise cc.ConfigError(cc.join(path, "dist"), "standard deviations must be >= 0")
    return CameraUncertainty(fx=values[0], fy=values[1], cx=values[2], cy=values[3],
                             dist=tuple(float(d) for d in dist))  # type: ignore[arg-type]


def load_optics(file: str | Path) -> CameraOptics:
    """Only the ``optics``/``response`` sections of a camera file (the intrinsics may be absent, e.g. a file
    written by ``livetrack model --camera-out`` from a series without them). ConfigError when there are none."""
    data = cc.load_yaml(file)
    if not isinstance(data, dict) or data.get("optics") is None:
        raise cc.ConfigError(cc.join(str(file), "optics"), "missing (a camera file with fitted optics, e.g. from "
                                                           "livetrack model --camera-out)")
    return CameraOptics.from_sections(data["optics"], data.get("response"), str(file))


def camera_file_dict(camera: CameraModel | None, optics: CameraOptics | None,
                     uncertainty: CameraUncertainty | None = None) -> dict[str, Any]:
    """The content of a camera file: ``camera`` (intrinsics, omitted when unknown), its ``uncertainty`` and the
    optics sections."""
    out: dict[str, Any] = {}
    if camera is not None:
        out["camera"] = camera.to_dict()
    if uncertainty is not None:
        out[UNCERTAINTY_SECTION] = uncertainty.to_dict()
    if optics is not None:
        out.update(optics.to_sections())
    return out


def write_camera_file(file: str | Path, camera: CameraModel | None, optics: CameraOptics | None,
                      comment: str = "", uncertainty: CameraUncertainty | None = None) -> None:
    """Write a camera YAML file readable by :func:`load_camera_with_optics` (``comment``: header lines)."""
    file = Path(file)
    file.parent.mkdir(parents=True, exist_ok=True)
    header = "".join(f"# {line}\n" for line in comment.splitlines())
    file.write_text(header + yaml.safe_dump(camera_file_dict(camera, optics, uncertainty), sort_keys=False,
                                            default_flow_style=None), encoding="utf-8")


def image_encoding(image_file: str | Path) -> str | None:
    """How an image file says its values encode light (``camera.encoding``), or None when it says nothing: "srgb"
    for EXIF ColorSpace 1 (phones' and cameras' JPEGs) or a PNG sRGB chunk; "gamma G" for a PNG gAMA chunk of
    1 / G (G rounded to 0.01, within the known range; a gAMA of 1 says linear). Unreadable files say nothing."""
    from PIL import Image  # optional dependency, only for photos

    try:
        with Image.open(image_file) as im:
            info = dict(im.info)
            color_space = im.getexif().get_ifd(0x8769).get(0xA001)
    except (OSError, ValueError):
        return None
    if color_space == 1 or "srgb" in info:
        return "srgb"
    file_gamma = info.get("gamma")
    if isinstance(file_gamma, (int, float)) and file_gamma > 0:
        return canonical(f"gamma {round(1.0 / float(file_gamma), 2):g}") if file_gamma < 1.0 else "linear"
    return None


def camera_from_exif(image_file: str | Path, width: int, height: int, pixel_pitch_um: float | None = None,
                     bit_depth: int = 8) -> CameraModel:
    """An uncalibrated pinhole camera for a photo: principal point at the image centre, no distortion.

    fx = fy = EXIF FocalLength / pixel pitch when ``pixel_pitch_um`` is given (the sensor's datasheet value, the
    better choice); otherwise from FocalLengthIn35mmFilm over the full-frame diagonal (43.27 mm) mapped on the
    image diagonal. ``width``/``height`` are the pixel array as read (sensor order, EXIF orientation NOT
    applied). ``encoding``: the file's own (``image_encoding``), else "linear" (``camera.encoding``).
    Raises ConfigError naming the file when the metadata is missing.
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
    encoding = image_encoding(image_file) or "linear"
    log.debug("%s: camera from EXIF, f = %.1f px, %s", image_file, f_px, encoding)
    return CameraModel(width=width, height=height, fx=f_px, fy=f_px, cx=(width - 1) / 2.0, cy=(height - 1) / 2.0,
                       bit_depth=bit_depth, encoding=encoding)
