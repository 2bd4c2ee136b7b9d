"""Reading a pair's code on the whole image when the search covered a region of interest only."""

from __future__ import annotations

import numpy as np

from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect.code import _identify, identify_off_centre
from livetrack.estimator.detect.geometry import _Entry, _Geometry
from livetrack.estimator.detect.levels import _shifted
from livetrack.estimator.detect.options import DetectOptions
from livetrack.estimator.detect.results import Candidate


class _WholeImageReader:
    """``code._identify`` and ``code.identify_off_centre`` of pairs found in a region of interest (pixels of the
    region, whose top-left corner is (``x0``, ``y0``) in ``whole``), read on ``whole``, the image the region was
    cut from; the candidates' ellipses in the region's pixels again. Without a region (``x0 = y0 = 0``) the
    calls are those functions' own.

    The code is read inside the pair, but which fractal level it is (``levels._choose_level``) is read around
    it, on its parent's ring, up to 5 of its radii out: a tracking window around a target tracked on its nested
    level (its outer level out of the frame, or its edges not fitting) holds little of that parent. Read on the
    window alone, the parent was "unseen" and the pair taken for the outermost level, at 5x its distance: held-out
    seed 7's single-019 (a 26 px nested ring in a 97 x 96 px window, its parent 131 px, whole in the frame),
    tracked at x8 exposure, jumped from +0.008 % to +400 % at the first windowed search and stayed there. The
    samples inside the region are the same numbers either way (bilinear samples of the same pixels)."""

    def __init__(self, whole: np.ndarray, x0: int, y0: int, groups: dict[_Geometry, list[_Entry]],
                 full: float) -> None:
        self.whole, self.groups, self.full = whole, groups, full
        self.shift = np.array([x0, y0], dtype=np.float64) if x0 or y0 else None

    def _in_whole(self, e: Ellipse) -> Ellipse:
        return e if self.shift is None else Ellipse(e.centre_px + self.shift, e.semi_axes_px, e.angle_rad)

    def _in_region(self, found: list[Candidate]) -> list[Candidate]:
        return found if self.shift is None else [_shifted(c, -self.shift) for c in found]

    def identify(self, outer: Ellipse, inner: Ellipse, opts: DetectOptions,
                 reasons: list[str] | None = None) -> list[Candidate]:
        """``code._identify`` of the pair (region pixels)."""
        return self._in_region(_identify(self.whole, self._in_whole(outer), self._in_whole(inner), self.groups,
                                         self.full, opts, reasons))

    def off_centre(self, outer: Ellipse, inner: Ellipse, opts: DetectOptions, reasons: list[str],
                   centre_first: bool = False) -> tuple[Ellipse, list[Candidate]]:
        """``code.identify_off_centre`` of the pair (region pixels): (the outer ellipse read, its candidates)."""
        moved, found = identify_off_centre(self.whole, self._in_whole(outer), self._in_whole(inner), self.groups,
                                           self.full, opts, reasons, centre_first)
        if self.shift is not None:
            moved = Ellipse(moved.centre_px - self.shift, moved.semi_axes_px, moved.angle_rad)
        return moved, self._in_region(found)
