"""The input of the analysis: an exposure series of one static black/white disk grid.

``ExposureSeries`` holds, per exposure, one or more *sub-images* that sample the same scene: a monochrome
frame is one sub-image; a raw Bayer mosaic under a narrowband filter gives the colour channel(s) carrying the
signal (e.g. G1 and G2), each a sub-image on a 2-pixel grid. Pixel (x, y) coordinates are those of the full
sensor image, (0, 0) the centre of its top-left pixel; sub-image pixel (row i, col j) sits at
``(x0 + step * j, y0 + step * i)``.

Adapters (the only I/O of the package): ``from_recording`` (a livetrack recording v1 of a disk grid, ``meta``
``pattern: disk_grid`` and ``pitch_m``) and ``from_exposure_series_disks`` (the real folder as it is).
"""

from __future__ import annotations

import math
import os
import re
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

BAYER_GBRG = {"G1": (0, 0), "B": (1, 0), "R": (0, 1), "G2": (1, 1)}
"""GBRG mosaic: channel -> (x0, y0) of its first pixel (row 0: G B G B ..., row 1: R G R G ...)."""

REAL_SHUTTER_MS = (25, 50, 100, 250, 500, 2000, 3916)
HOT_PIXEL_DARK_DN = 4.0
"""Pixels whose mean dark frame exceeds this (DN) at the exposure are left out (hot pixels)."""


@dataclass(frozen=True)
class SubGrid:
    """Where a sub-image's pixels sit on the sensor: (x0 + step * col, y0 + step * row)."""

    x0: int
    y0: int
    step: int
    label: str

    def coords(self, shape: tuple[int, int]) -> tuple[FloatArray, FloatArray]:
        """Full-sensor (x, y) of every pixel of a sub-image of ``shape``: two (h, w) float64 arrays."""
        h, w = shape
        x = self.x0 + self.step * np.arange(w, dtype=np.float64)
        y = self.y0 + self.step * np.arange(h, dtype=np.float64)
        return np.broadcast_to(x[None, :], shape).copy(), np.broadcast_to(y[:, None], shape).copy()


@dataclass(frozen=True)
class ExposureSeries:
    """Frames of one static scene at several exposure times.

    images : [frame][sub-image] (h, w) float64 DN, black level (dark frame) subtracted.
    valid : [frame][sub-image] (h, w) bool, False for hot or otherwise unusable pixels.
    exposure_ms : (F,) exposure (shutter) time of each frame, milliseconds.
    grids : one ``SubGrid`` per sub-image.
    saturation_dn : the code a clipped pixel reads (after black subtraction).
    pitch_m : lattice pitch of the disk grid (metres).
    black_to_white : reflectance ratio ink / paper when known (a simulated or specified print), else None.
    width, height : full sensor image size (px); centre_px : the point vignetting and distortion are centred
        on (the principal point if known, else the image centre); focal_px : focal length if known.
    """

    name: str
    images: list[list[FloatArray]]
    valid: list[list[BoolArray]]
    exposure_ms: FloatArray
    grids: list[SubGrid]
    saturation_dn: float
    pitch_m: float
    width: int
    height: int
    centre_px: tuple[float, float]
    black_to_white: float | None = None
    focal_px: float | None = None
    notes: dict[str, object] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return len(self.images)

    @property
    def half_diagonal_px(self) -> float:
        return 0.5 * math.hypot(self.width, self.height)

    def subset(self, frames: list[int]) -> ExposureSeries:
        """The same series restricted to ``frames`` (indices)."""
        return ExposureSeries(self.name, [self.images[i] for i in frames], [self.valid[i] for i in frames],
                              self.exposure_ms[frames], self.grids, self.saturation_dn, self.pitch_m, self.width,
                              self.height, self.centre_px, self.black_to_white, self.focal_px, self.notes)


# ---------------------------------------------------------------------------------------------- adapters
def from_recording(path: str | os.PathLike) -> ExposureSeries:
    """A recording of a static disk grid (``meta: {pattern: disk_grid, pitch_m: ...}``; optional
    ``white_reflectance`` and ``black_reflectance``). Frames are sorted by exposure."""
    from livetrack.camera.encoding import as_linear
    from livetrack.recording import Recording

    rec = Recording.open(path)
    meta = rec.meta or {}
    if meta.get("pattern") != "disk_grid" or "pitch_m" not in meta:
        raise ValueError(f"{path}: not a disk-grid recording (meta needs pattern: disk_grid and pitch_m); other "
                         "patterns (livetrack ring targets) are not supported by `livetrack model` yet")
    frames = sorted(((f.exposure_us, img) for f, img in rec.iter_images()), key=lambda p: p[0])
    if len(frames) < 3:
        raise ValueError(f"{path}: need >= 3 readable frames at different exposures, got {len(frames)}")
    cam, linear = as_linear(rec.camera, [img for _, img in frames])  # the model's pixel values are linear
    frames = [(e, img) for (e, _), img in zip(frames, linear, strict=True)]
    ratio = None
    if "white_reflectance" in meta and "black_reflectance" in meta:
        ratio = float(meta["black_reflectance"]) / float(meta["white_reflectance"])
    images = [[img.astype(np.float64)] for _, img in frames]
    valid = [[np.ones(img.shape, bool)] for _, img in frames]
    return ExposureSeries(name=Path(path).name, images=images, valid=valid,
                          exposure_ms=np.array([e / 1000.0 for e, _ in frames]),
                          grids=[SubGrid(0, 0, 1, "mono")], saturation_dn=float((1 << cam.bit_depth) - 1),
                          pitch_m=float(meta["pitch_m"]), width=cam.width, height=cam.height,
                          centre_px=(cam.cx, cam.cy), black_to_white=ratio, focal_px=float(cam.fx),
                          notes={"source": "recording", "path": str(path)})


def _read_tif(file: Path) -> npt.NDArray[np.uint8]:
    import tifffile

    return np.asarray(tifffile.imread(file))


def available_filters(folder: str | os.PathLike) -> list[str]:
    """Filters (e.g. '550nm') with frames in an exposure-series-disks folder, sorted by wavelength."""
    found = {m.group(1) for f in (Path(folder) / "frames").glob("*.tif")
             if (m := re.search(r"_(\d+nm)_\d+ms_", f.name))}
    return sorted(found, key=lambda s: int(s[:-2]))


def from_exposure_series_disks(folder: str | os.PathLike, filter_nm: str) -> ExposureSeries:
    """The real folder ``exposure-series-disks`` for one filter present in it (e.g. '550nm').

    Raw GBRG Bayer crops, 8 bit, 255 = clipped; the mean of the two ``d1`` dark frames of the same shutter time
    is subtracted and pixels hotter than ``HOT_PIXEL_DARK_DN`` in it are left out. The sub-images are the
    Bayer channel(s) with the most signal (white-level rate): G1 + G2 when green wins, else the single channel.
    Pitch 8 mm; no intrinsics: distortion and vignetting are centred on the crop centre.
    """
    folder = Path(folder)
    if filter_nm not in available_filters(folder):
        raise ValueError(f"filter {filter_nm!r} not in {folder} (filters there: "
                         f"{', '.join(available_filters(folder)) or 'none'})")
    frames: dict[int, Path] = {}
    for f in sorted((folder / "frames").glob(f"*_{filter_nm}_*ms_*.tif")):
        m = re.search(r"_(\d+)ms_", f.name)
        if m:
            frames[int(m.group(1))] = f
    if len(frames) < 3:
        raise ValueError(f"{folder}: fewer than 3 frames for filter {filter_nm}")
    darks: dict[int, list[Path]] = defaultdict(list)
    for f in sorted((folder / "dark_frames").glob("d1_dark_*ms_*.tif")):
        m = re.search(r"_(\d+)ms_", f.name)
        if m:
            darks[int(m.group(1))].append(f)
    shutters = sorted(frames)
    raw = {s: _read_tif(frames[s]).astype(np.float64) for s in shutters}
    dark = {s: (np.mean([_read_tif(f).astype(np.float64) for f in darks[s]], axis=0) if darks.get(s)
                else np.zeros_like(raw[s])) for s in shutters}
    h, w = raw[shutters[0]].shape
    # Signal rate of each Bayer channel: 99th percentile over the shortest unclipped exposure.
    rates = {}
    for ch, (x0, y0) in BAYER_GBRG.items():
        best = 0.0
        for s in shutters:
            sub = raw[s][y0::2, x0::2]
            if np.mean(sub >= 255) < 0.01:
                best = max(best, float(np.percentile(sub, 99)) / s)
        rates[ch] = best
    top = max(rates, key=lambda c: rates[c])
    chosen = ["G1", "G2"] if top in ("G1", "G2") else [top]
    grids = [SubGrid(BAYER_GBRG[c][0], BAYER_GBRG[c][1], 2, c) for c in chosen]
    images, valid = [], []
    for s in shutters:
        ims, oks = [], []
        for g in grids:
            sub = raw[s][g.y0::2, g.x0::2]
            d = dark[s][g.y0::2, g.x0::2]
            clipped = sub >= 255
            ims.append(np.where(clipped, 255.0, sub - d))
            oks.append(d < HOT_PIXEL_DARK_DN)
        images.append(ims)
        valid.append(oks)
    return ExposureSeries(name=f"exposure-series-disks {filter_nm}", images=images, valid=valid,
                          exposure_ms=np.array(shutters, dtype=np.float64), grids=grids, saturation_dn=255.0,
                          pitch_m=0.008, width=w, height=h, centre_px=((w - 1) / 2, (h - 1) / 2),
                          black_to_white=None, focal_px=None,
                          notes={"source": "exposure-series-disks", "filter": filter_nm, "channels": chosen,
                                 "channel_rate_dn_per_ms": rates})
