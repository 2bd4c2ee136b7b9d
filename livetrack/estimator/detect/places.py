"""Places of ellipses (centre and semi-axes as plain floats) and the de-duplication of ellipses and pairs by place.

Two ellipses lie at one place when their centres are within a quarter of the smaller semi-minor axis plus a pixel
and their semi-major axes within a ratio of each other (``_same_place``, ``_places_match``). The detector keeps the
first pair or small-blob ellipse found at each place (``_dedupe_pairs``, ``_dedupe_ellipses``) and tests later
finds against the kept ones; ``_PlaceGrid`` files many kept places by square so that each test reads only those
nearby (textured frames keep hundreds). Pure bookkeeping: no image, no fit."""

from __future__ import annotations

import math

import numpy as np

from livetrack.estimator.conics import Ellipse


def _same_place(e1: Ellipse, e2: Ellipse, size_ratio: float = 1.4) -> bool:
    """Whether two ellipses lie at one place: their centres within a quarter of the smaller semi-minor axis plus a
    pixel, and ``e1``'s semi-major axis within ``size_ratio`` of ``e2``'s either way (``_places_match``)."""
    return _places_match(_place(e1), _place(e2), size_ratio)


def _place(e: Ellipse) -> tuple[float, float, float, float]:
    """An ellipse's centre and semi-axes as plain floats (x, y, a, b), for ``_places_match`` in a loop."""
    x, y = e.centre_px.tolist()
    a, b = e.semi_axes_px.tolist()
    return x, y, a, b


def _places_match(p: tuple[float, float, float, float], q: tuple[float, float, float, float],
                  size_ratio: float = 1.4) -> bool:
    """``_same_place`` of two ``_place``s: the distance between the centres is numpy's hypot as before, taken only
    when each of its components is within the reach (it is at least either), and the size test first: the same
    answers on plain floats (the deduplication of a textured frame's ~50 pairs made ~1600 of these tests with
    numpy scalars, ~2 ms)."""
    dx, dy = p[0] - q[0], p[1] - q[1]
    reach = 0.25 * min(p[3], q[3]) + 1.0
    return (abs(dx) <= reach and abs(dy) <= reach and 1.0 / size_ratio <= p[2] / q[2] <= size_ratio
            and bool(np.hypot(dx, dy) <= reach))


def _dedupe_ellipses(ellipses: list[Ellipse]) -> list[Ellipse]:
    """``ellipses`` in order without those at ``_same_place`` as one kept before; the test on plain floats (numpy
    scalars made it ~10x slower: a thousand small blobs of foliage cost ~14 ms a frame), against the kept ones near
    enough to pass it only (``_PlaceGrid``: the test against every kept one cost ~25 ms on a frame of printed
    text)."""
    kept: list[Ellipse] = []
    grid = _PlaceGrid()
    for e in ellipses:
        cx, cy = e.centre_px.tolist()
        a, b = e.semi_axes_px.tolist()
        for kx, ky, ka, kb in grid.near(cx, cy, b):
            dx, dy, reach = cx - kx, cy - ky, 0.25 * min(b, kb) + 1.0  # hypot is at least |dx| and |dy|
            if (abs(dx) <= reach and abs(dy) <= reach and math.hypot(dx, dy) <= reach
                    and 1.0 / 1.4 <= a / ka <= 1.4):
                break
        else:
            kept.append(e)
            grid.add((cx, cy, a, b))
    return kept


def _dedupe_pairs(pairs: list[tuple[int, Ellipse, Ellipse, str]]) -> list[tuple[int, Ellipse, Ellipse, str]]:
    """``pairs`` by level (stable) without those whose outer ellipse is at ``_same_place`` as a kept one's (tested
    against the kept ones near enough only: ``_PlaceGrid``)."""
    kept: list[tuple[int, Ellipse, Ellipse, str]] = []
    grid = _PlaceGrid()
    for pair in sorted(pairs, key=lambda p: p[0]):
        place = _place(pair[1])
        if not grid.matches(place):
            kept.append(pair)
            grid.add(place)
    return kept


class _PlaceGrid:
    """Places (x, y, a, b: ``_place``) by the square of ``PLACE_CELL_PX`` their centre lies in, for the tests of
    ``_places_match`` and ``_dedupe_ellipses`` against many kept places: both need each centre offset within
    0.25 min(b, b') + 1 <= 0.25 b + 1 (b: the semi-minor axis of the place tested), so only the places in the
    squares within that reach of its centre, and one square more each way (against the subtraction's rounding),
    can pass; ``near`` returns those (a superset, in no particular order: the tests only ask whether any passes).
    A reach or centre that is not finite, or that spans more squares than are filled, reads every place, and so
    do fewer than ``PLACE_GRID_FROM`` places (not filed by square: the bench's frames keep a dozen)."""

    def __init__(self, places: list[tuple[float, float, float, float]] = ()) -> None:
        self.cells: dict[tuple[int, int], list[tuple[float, float, float, float]]] | None = None
        self.every: list[tuple[float, float, float, float]] = []
        for place in places:
            self.add(place)

    def add(self, place: tuple[float, float, float, float]) -> None:
        self.every.append(place)
        if self.cells is None:  # the squares only from PLACE_GRID_FROM places on (below, reading all costs less)
            if len(self.every) < PLACE_GRID_FROM:
                return
            self.cells = {}
            for kept in self.every:
                self._file(kept)
        else:
            self._file(place)

    def _file(self, place: tuple[float, float, float, float]) -> None:
        x, y = place[0], place[1]
        if math.isfinite(x) and math.isfinite(y):  # (a place off every square matches no finite reach)
            key = (math.floor(x / PLACE_CELL_PX), math.floor(y / PLACE_CELL_PX))
            cell = self.cells.get(key)
            if cell is None:
                self.cells[key] = [place]
            else:
                cell.append(place)

    def matches(self, place: tuple[float, float, float, float]) -> bool:
        """Whether ``_places_match(place, k)`` for a kept place k."""
        return any(_places_match(place, k) for k in self.near(place[0], place[1], place[3]))

    def near(self, x: float, y: float, b: float) -> list[tuple[float, float, float, float]]:
        reach = 0.25 * b + 1.0
        if self.cells is None or not (math.isfinite(x) and math.isfinite(y) and math.isfinite(reach)):
            return self.every
        c0, c1 = math.floor((x - reach) / PLACE_CELL_PX) - 1, math.floor((x + reach) / PLACE_CELL_PX) + 1
        r0, r1 = math.floor((y - reach) / PLACE_CELL_PX) - 1, math.floor((y + reach) / PLACE_CELL_PX) + 1
        if (c1 - c0 + 1) * (r1 - r0 + 1) > len(self.cells):
            return self.every
        out: list[tuple[float, float, float, float]] = []
        cells = self.cells
        for col in range(c0, c1 + 1):
            for row in range(r0, r1 + 1):
                cell = cells.get((col, row))
                if cell is not None:
                    out += cell
        return out


PLACE_CELL_PX = 16.0
PLACE_GRID_FROM = 32
"""``_PlaceGrid``'s square side (pixels of the level or image the places are in), and how many places it keeps
before it files them by square (fewer are read all)."""
