"""Results of the coarse detector: a candidate target level, and the trace of each step."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from livetrack.estimator.conics import Ellipse
from livetrack.targets.spec import TargetSpec

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class Candidate:
    """One detected target level.

    target_id: the configured target's id; level: 0 = outermost, 1 = the nested target, ...; spec: that level's
    spec. outer / inner: image ellipses (pixels) of the black disk's outer edge and of the white inner disk's
    edge, from a mid-level threshold (biased by exposure like any threshold; the sub-pixel edge fit removes it).
    rotation_slots: ``codebook.decode``'s rotation, relative to the image +x direction from the centre (the
    target's +x axis lies about ``rotation_slots * 2 pi / N`` from it); None if the code is symmetric.
    heading_rad: image-plane angle (from +x toward +y) of the target's +x axis at the centre, from the slot grid
    (a few degrees); None if unknown. code_margin: soft-distance gap (slots) to the next best code or rotation.
    code_values: (N,) soft slot values in [0, 1] as read on the slot grid nearest the image +x direction from
    the centre: ``code_values[j]`` ~ bit ``(j - rotation_slots) mod N`` of the code.
    black_level, white_level: median image values (input units) seen in the black annulus / white inner disk.
    level_ambiguous: the code is that of several levels and the pair's surroundings look like its parent's
    without its code being readable (e.g. clipped): ``level`` is the outermost, which may be wrong by the
    fractal scale; the tracker reports such a candidate as a failure (stage "level"), not a pose.
    darker_outside: the ground just outside the outer edge is darker than the black ring all round (a target
    printed without a sheet, on darker ground: black velvet, a shadow): the outer edge's bright side is the ring,
    inward (``code.darker_outside``). The tracker fits that edge with its normal turned (``Tracker._samples``).
    """

    target_id: int
    level: int
    spec: TargetSpec
    outer: Ellipse
    inner: Ellipse
    rotation_slots: int | None
    heading_rad: float | None
    code_margin: float
    code_values: FloatArray
    black_level: float
    white_level: float
    level_ambiguous: bool = False
    darker_outside: bool = False


@dataclass(frozen=True)
class TraceEvent:
    """One step of the detector on one blob or pair, recorded when ``detect`` is given a ``trace`` list (a
    diagnostic: which stage lost a target). Stages, in the order a target passes them:

    - "blob": a dark blob of a pyramid level that gave no pair; ``detail`` says why ("no hole", "short contour",
      "size", "hole area/centre", "holes too small", "outer fit", "outer size", "inner fit/ratio").
    - "pair": a concentric pair kept after de-duplication (``detail``: "plain", "closed", "wide", "crop").
    - "border": a pair too close to the image border.
    - "code": a pair whose verification or code failed for one geometry (``detail``: the reason).
    - "candidate": a pair identified (``detail``: "id N level L", with " ambiguous" when the level is).

    ``level``: the pyramid level (0 = full resolution) of the blob or pair, -1 after the pyramid stage;
    ``centre_px`` and ``semi_major_px`` in full-image pixels."""

    stage: str
    level: int
    centre_px: tuple[float, float]
    semi_major_px: float
    detail: str
