"""The output encoding of a camera's pixel values, and its inverse: the linear light the estimator's edge model needs.

Machine-vision cameras deliver values linear in the light (``"linear"``, the default). Webcams, phones and most
renderers deliver them encoded for display: ``"srgb"`` (IEC 61966-2-1: a value's share x of full scale is
12.92 l below l = 0.0031308, else 1.055 l^(1/2.4) - 0.055, of the linear share l) or ``"gamma G"`` (x = l^(1/G),
G in [1, 4]). The edge model (a blurred step, clipped) holds in linear light only: on an sRGB frame a target printed
without a sheet on grey ground read 0.45-0.53 % short at every exposure, 0.00-0.04 % once linearised (seed 4's
encoded-001 of ``livetrack evaluate detection``). A camera whose encoding is stated (``CameraModel.encoding``)
has its frames mapped to 16-bit linear values by a table before the tracker reads them
(``estimator.tracker.Tracker``): one compiled table look-up per frame, ~0.43 ms for 1920 x 1200.
"""

from __future__ import annotations

import dataclasses
import functools
import re
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from livetrack.camera.model import CameraModel

LINEAR = "linear"
SRGB = "srgb"
_GAMMA = re.compile(r"^gamma\s+([0-9]*\.?[0-9]+)$")
MIN_GAMMA, MAX_GAMMA = 1.0, 4.0
LINEAR_BIT_DEPTH = 16
"""The bit depth of the linearised frames (their values 0 .. 65535, full scale mapped to full scale)."""


def encoding_problem(encoding: object) -> str | None:
    """Why ``encoding`` is no encoding livetrack knows, or None when it is one (in its ``canonical`` spelling)."""
    if isinstance(encoding, str) and canonical(encoding) == encoding:
        return None
    if isinstance(encoding, str) and canonical(encoding) is not None:
        return f"must be spelt {canonical(encoding)!r}, got {encoding!r}"
    return (f"must be '{LINEAR}', '{SRGB}' or 'gamma G' with G in [{MIN_GAMMA:g}, {MAX_GAMMA:g}] "
            f"(e.g. 'gamma 2.2'), got {encoding!r}")


def canonical(encoding: str) -> str | None:
    """``encoding`` as livetrack spells it (lower case, single space: "sRGB" -> "srgb", "Gamma  2.2" ->
    "gamma 2.2"), or None when it is no known encoding."""
    text = " ".join(encoding.split()).lower()
    if text in (LINEAR, SRGB):
        return text
    m = _GAMMA.match(text)
    if m and MIN_GAMMA <= float(m.group(1)) <= MAX_GAMMA:
        return f"gamma {float(m.group(1)):g}"
    return None


def decode_share(encoding: str, share: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """The linear share of full scale of each encoded share ``share`` (both in [0, 1])."""
    x = np.clip(np.asarray(share, dtype=np.float64), 0.0, 1.0)
    if encoding == LINEAR:
        return x
    if encoding == SRGB:
        return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    problem = encoding_problem(encoding)
    if problem is not None:
        raise ValueError(f"encoding {problem}")
    gamma = float(_GAMMA.match(encoding.strip()).group(1))  # type: ignore[union-attr]
    return x**gamma


@functools.lru_cache(maxsize=16)
def linear_table(encoding: str, bit_depth: int) -> npt.NDArray[np.uint16]:
    """(2^bit_depth,) uint16: each code's linear value on a 16-bit scale (0 -> 0, full scale -> 65535), rounded.
    Read-only, cached."""
    top = (1 << bit_depth) - 1
    table = decode_share(encoding, np.arange(top + 1) / top)
    out = np.rint(table * ((1 << LINEAR_BIT_DEPTH) - 1)).astype(np.uint16)
    out.flags.writeable = False
    return out


def linearise(image: np.ndarray, encoding: str, bit_depth: int) -> npt.NDArray[np.uint16]:
    """``image`` (H, W) of ``bit_depth``-bit codes (uint8 or uint16) as 16-bit linear values (a new array; values
    above the bit depth's full scale read as full scale). TypeError for other dtypes (float images carry no codes
    to look up). Compiled (``estimator.lut_kernel.lut_to16``): ~0.43 ms per 1920x1200 frame on one core."""
    from livetrack.estimator.lut_kernel import lut_to16

    if image.dtype not in (np.uint8, np.uint16):
        raise TypeError(f"an encoded ({encoding}) frame must be uint8 or uint16 codes, got {image.dtype}")
    table = _full_table(encoding, bit_depth, 8 if image.dtype == np.uint8 else 16)
    return lut_to16(image, table, np.empty(image.shape, np.uint16))


@functools.lru_cache(maxsize=16)
def _full_table(encoding: str, bit_depth: int, type_bits: int) -> npt.NDArray[np.uint16]:
    """``linear_table`` with an entry for every value of a ``type_bits``-bit type (those above the bit depth's full
    scale at full scale). Read-only, cached."""
    table = linear_table(encoding, bit_depth)
    if table.size < (1 << type_bits):
        table = np.concatenate([table, np.full((1 << type_bits) - table.size, table[-1], np.uint16)])
        table.flags.writeable = False
    return table[: 1 << type_bits] if table.size > (1 << type_bits) else table


def linear_dn(encoding: str, bit_depth: int) -> Callable[[npt.NDArray[np.float64]], npt.NDArray[np.float64]] | None:
    """A map of ``bit_depth``-bit codes (float arrays, rounded and clipped to the codes) to linear values on the
    same scale (0 .. full scale), or None for a linear camera: for whoever meters raw frames in linear light
    (``exposure_control``) without linearising whole frames."""
    if encoding == LINEAR:
        return None
    top = (1 << bit_depth) - 1
    table = linear_table(encoding, bit_depth).astype(np.float64) * (top / ((1 << LINEAR_BIT_DEPTH) - 1))

    def decode(values: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        return table[np.clip(np.rint(values), 0, top).astype(np.intp)]

    return decode


def as_linear(camera: CameraModel, images: list[np.ndarray]) -> tuple[CameraModel, list[np.ndarray]]:
    """``camera`` and its ``images`` as a linear camera would give them: unchanged for a linear camera; else the
    images linearised (``linearise``) and the camera's 16-bit linear twin (for whoever models pixel values in
    linear light from frames as recorded: ``modelcheck``'s file adapters)."""
    if camera.encoding == LINEAR:
        return camera, images
    linear = [linearise(image, camera.encoding, camera.bit_depth) for image in images]
    return dataclasses.replace(camera, bit_depth=LINEAR_BIT_DEPTH, encoding=LINEAR), linear
