"""Printed planar patterns for the simulator: what reflectance each point of a sheet in the target plane has.

A texture lives in the target plane (metres; x right, y down seen from the front, z away from the viewer) and
covers the sheet ``bounds_m``; the renderer (``livetrack.sim.coverage``) handles the sheet's border itself.

Every texture gives its ``reflectance`` at points (vectorised). Textures made of sharp edges may also give
(the optional ``EdgeTexture`` protocol):

- ``edge_distance_m(x, y)``: a lower bound on the distance from each point to the nearest reflectance edge
  (not counting the sheet border); the renderer uses it to prove a whole pixel uniform;
- ``cell_average(x, y, jac, side_px)``: the average reflectance over a small pixel-space square (a sub-cell
  of a pixel) around each point: the texture linearises its nearest edge(s) there through the local Jacobian
  ``jac`` of the pixel-to-plane map and takes the exact area on each side (``square_fraction_within``),
  which is exact for straight edges of any orientation (point sampling is not: see ``coverage``).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from livetrack.targets.spec import TargetSpec

FloatArray = npt.NDArray[np.float64]

PAPER_WHITE = 0.85
"""Default reflectance of white paper."""
INK_BLACK = 0.04
"""Default reflectance of black ink (matte laser toner)."""
DEFAULT_SHEET_FACTOR = 2.8
"""Default sheet of a ``TargetTexture``: a square of side 2.8 outer radii, centred on the target."""
CURVED_EDGE_REFINE = 4.0
"""``TargetTexture.cell_average`` splits a square again when the image of a circle crosses it with a radius of
curvature below this many square sides (where linearising the circle would err by more than ~2 % of the
square). Raising it costs time only on small circles (code dots and child levels seen from afar)."""
CURVED_EDGE_DEPTH = 1
"""How many times a square may be split (each split: 16 squares of a quarter side). A second split changed the
dark area of the default target by < 5e-5 relative at 6 to 40 m but multiplied the time of a target seen at
89 degrees by ten."""


@runtime_checkable
class PlanarTexture(Protocol):
    """Anything printed on a flat sheet."""

    @property
    def bounds_m(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) of the sheet in the target plane, metres."""
        ...

    def reflectance(self, x_m: FloatArray, y_m: FloatArray) -> FloatArray:
        """Reflectance in [0, 1] at target-plane points (any shape); defined beyond the sheet too."""
        ...


@runtime_checkable
class EdgeTexture(PlanarTexture, Protocol):
    """A texture that also knows where its edges are (see the module docstring)."""

    def edge_distance_m(self, x_m: FloatArray, y_m: FloatArray) -> FloatArray:
        """Lower bound on the distance (metres, >= 0) to the nearest reflectance edge, shaped as ``x_m``."""
        ...

    def cell_average(self, x_m: FloatArray, y_m: FloatArray, jac: FloatArray, side_px: float) -> FloatArray:
        """Average reflectance (K,) over the axis-aligned pixel-space square of side ``side_px`` centred on
        each point (K,); ``jac`` (K, 2, 2) = d(x_m, y_m)/d(pixel x, pixel y) there. Edges are linearised
        through ``jac`` (use ``square_fraction_within``)."""
        ...


# ---------------------------------------------------------------------------------------------- helpers
def _sigma_max(jac: FloatArray) -> FloatArray:
    """Largest singular value of each 2x2 matrix in (K, 2, 2)."""
    a, b, c, d = jac[:, 0, 0], jac[:, 0, 1], jac[:, 1, 0], jac[:, 1, 1]
    fro2 = a * a + b * b + c * c + d * d
    det = a * d - b * c
    return np.sqrt(0.5 * (fro2 + np.sqrt(np.maximum(fro2 * fro2 - 4.0 * det * det, 0.0))))


def square_fraction_within(t_px: FloatArray, mx: FloatArray, my: FloatArray, side_px: float) -> FloatArray:
    """Area fraction of an axis-aligned square of side ``side_px`` centred on a point that lies on the point's
    side of a straight line at distance ``t_px`` >= 0 (inf allowed) along the unit normal (mx, my) (pixels).

    It is the CDF at ``t_px`` of the projection of a uniform square onto the normal (a trapezoid
    distribution): exact for any orientation.
    """
    a = side_px * np.abs(mx)
    b = side_px * np.abs(my)
    a, b = np.maximum(np.maximum(a, b), 1e-30), np.minimum(a, b)  # the floor only guards a zero normal
    hi = 0.5 * (a + b)
    lo = 0.5 * (a - b)
    t = np.minimum(t_px, hi)
    mid = 0.5 + t / a
    top = 1.0 - (hi - t) ** 2 / (2.0 * np.maximum(a * b, 1e-30))
    return np.where(t <= lo, mid, top)


def _pixel_normal(jac: FloatArray, nx: FloatArray, ny: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Pixel-space gradient J^T n of a plane function whose plane gradient is the unit vector n: (gx, gy)."""
    return jac[:, 0, 0] * nx + jac[:, 1, 0] * ny, jac[:, 0, 1] * nx + jac[:, 1, 1] * ny


# ---------------------------------------------------------------------------------------------- target
@dataclass(frozen=True)
class _Circle:
    cx: float
    cy: float
    radius: float


@dataclass(frozen=True)
class TargetTexture:
    """A ``TargetSpec`` printed on a white sheet.

    ``sheet_size_m``: (width, height) of the sheet, centred on the target; None -> a square of side 2.8 R.
    ``white``, ``black``: reflectances of paper and ink (defaults 0.85 and 0.04).
    Every edge of a target is a circle separating black from white, which the edge methods use.
    """

    spec: TargetSpec
    sheet_size_m: tuple[float, float] | None = None
    white: float = PAPER_WHITE
    black: float = INK_BLACK

    @property
    def bounds_m(self) -> tuple[float, float, float, float]:
        if self.sheet_size_m is None:
            w = h = DEFAULT_SHEET_FACTOR * self.spec.outer_radius_m
        else:
            w, h = self.sheet_size_m
        return (-w / 2.0, w / 2.0, -h / 2.0, h / 2.0)

    def reflectance(self, x_m: FloatArray, y_m: FloatArray) -> FloatArray:
        unit = self.spec.reflectance(x_m, y_m)
        return self.black + (self.white - self.black) * unit

    # -- edges
    @cached_property
    def _levels(self) -> tuple[tuple[tuple[float, ...], tuple[_Circle, ...], float, float, float], ...]:
        """Per level: (concentric radii, code dots, ring radius, dot radius, child outer radius or -1)."""
        out = []
        for _, spec in self.spec.levels():
            radii = [spec.outer_radius_m, spec.inner_radius_m]
            if spec.centre_dot_radius_m > 0:
                radii.append(spec.centre_dot_radius_m)
            dots: tuple[_Circle, ...] = ()
            ring = dot = 0.0
            if spec.code is not None:
                ring, dot = spec.code.ring_radius_m, spec.code.dot_radius_m
                dots = tuple(_Circle(float(x), float(y), dot) for x, y in spec.code.white_dot_centres_m())
            child_r = spec.child.outer_radius_m if spec.child is not None else -1.0
            out.append((tuple(radii), dots, ring, dot, child_r))
        return tuple(out)

    def edge_distance_m(self, x_m: FloatArray, y_m: FloatArray) -> FloatArray:
        x = np.asarray(x_m, dtype=np.float64)
        y = np.asarray(y_m, dtype=np.float64)
        shape = x.shape
        x, y = x.ravel(), y.ravel()
        out = self._edge_distance(0, x, y, np.hypot(x, y))
        return out.reshape(shape)

    def _edge_distance(self, level: int, x: FloatArray, y: FloatArray, r: FloatArray) -> FloatArray:
        radii, dots, ring, dot, child_r = self._levels[level]
        d = np.abs(r - radii[0])
        for rad in radii[1:]:
            np.minimum(d, np.abs(r - rad), out=d)
        if dots:
            near = np.flatnonzero(np.abs(r - ring) - dot < d)
            if near.size:
                xs, ys = x[near, None], y[near, None]
                cx = np.array([c.cx for c in dots])
                cy = np.array([c.cy for c in dots])
                dd = np.abs(np.hypot(xs - cx, ys - cy) - dot).min(axis=1)
                d[near] = np.minimum(d[near], dd)
        if child_r > 0:
            near = np.flatnonzero(r - child_r < d)
            if near.size:
                d[near] = np.minimum(d[near], self._edge_distance(level + 1, x[near], y[near], r[near]))
        return d

    def cell_average(self, x_m: FloatArray, y_m: FloatArray, jac: FloatArray, side_px: float) -> FloatArray:
        """See ``EdgeTexture``. The nearest circle (in pixels) is linearised; for a circle of radius rho px
        that is off by about side^3 / (12 rho) px^2 where it crosses the square, so squares crossed by a
        circle's image curved more tightly than ``CURVED_EDGE_REFINE`` sides are split again into 4 x 4 (up to
        ``CURVED_EDGE_DEPTH`` times). Only the nearest of two edges crossing one square is seen."""
        x = np.asarray(x_m, dtype=np.float64).ravel()
        y = np.asarray(y_m, dtype=np.float64).ravel()
        jac = np.asarray(jac, dtype=np.float64).reshape(-1, 2, 2)
        return self._cell_average(x, y, jac, side_px, 0)

    def _cell_average(self, x: FloatArray, y: FloatArray, jac: FloatArray, side_px: float,
                      depth: int) -> FloatArray:
        here = self.reflectance(x, y)
        across = (self.white + self.black) - here  # every target edge separates black from white
        best = np.full(x.shape, np.inf)
        normal = np.zeros(x.shape + (2,))
        rho_px = np.full(x.shape, np.inf)
        smax = _sigma_max(jac)
        self._nearest(0, x, y, np.hypot(x, y), jac, smax, best, normal, rho_px, np.arange(x.size))
        keep = square_fraction_within(best, normal[:, 0], normal[:, 1], side_px)
        value = here * keep + across * (1.0 - keep)
        if depth < CURVED_EDGE_DEPTH:
            crossed = best < 0.5 * side_px * (np.abs(normal[:, 0]) + np.abs(normal[:, 1]))
            k = np.flatnonzero(crossed & (rho_px < CURVED_EDGE_REFINE * side_px))
            if k.size:
                n = 4
                off = ((np.arange(n) + 0.5) / n - 0.5) * side_px
                du, dv = np.tile(off, n), np.repeat(off, n)  # pixel offsets of the 16 sub-squares
                jk = jac[k]
                xs = x[k, None] + jk[:, 0, 0, None] * du + jk[:, 0, 1, None] * dv
                ys = y[k, None] + jk[:, 1, 0, None] * du + jk[:, 1, 1, None] * dv
                sub = self._cell_average(xs.ravel(), ys.ravel(), np.repeat(jk, n * n, axis=0), side_px / n,
                                         depth + 1)
                value[k] = sub.reshape(k.size, n * n).mean(axis=1)
        return value

    def _nearest(self, level: int, x: FloatArray, y: FloatArray, r: FloatArray, jac: FloatArray,
                 smax: FloatArray, best: FloatArray, normal: FloatArray, rho_px: FloatArray,
                 idx: npt.NDArray[np.intp]) -> None:
        """Update ``best``/``normal`` at ``idx`` (the points x, y, r, jac, smax) with this level's circles."""
        radii, dots, ring, dot, child_r = self._levels[level]
        for rad in radii:
            self._update(x, y, 0.0, 0.0, rad, jac, best, normal, rho_px, idx)
        if dots:
            # A dot is no nearer (in the plane) than | r - ring | - dot, hence no nearer in pixels than that
            # over the largest singular value of the Jacobian.
            sel = np.flatnonzero((np.abs(r - ring) - dot) < best[idx] * smax)
            if sel.size:
                for c in dots:
                    self._update(x[sel], y[sel], c.cx, c.cy, c.radius, jac[sel], best, normal, rho_px,
                                 idx[sel])
        if child_r > 0:
            sel = np.flatnonzero((r - child_r) < best[idx] * smax)
            if sel.size:
                self._nearest(level + 1, x[sel], y[sel], r[sel], jac[sel], smax[sel], best, normal, rho_px,
                              idx[sel])

    @staticmethod
    def _update(x: FloatArray, y: FloatArray, cx: float, cy: float, radius: float, jac: FloatArray,
                best: FloatArray, normal: FloatArray, rho_px: FloatArray, idx: npt.NDArray[np.intp]) -> None:
        vx, vy = x - cx, y - cy
        dist = np.hypot(vx, vy)
        safe = np.where(dist > 0.0, dist, 1.0)
        nx = np.where(dist > 0.0, vx / safe, 1.0)
        ny = np.where(dist > 0.0, vy / safe, 0.0)
        e = dist - radius  # > 0 outside the circle
        gx, gy = _pixel_normal(jac, nx, ny)
        gn = np.hypot(gx, gy)
        d_px = np.abs(e) / gn
        better = d_px < best[idx]
        if not np.any(better):
            return
        s = np.where(e > 0.0, -1.0, 1.0)[better] / gn[better]  # toward the circle
        where = idx[better]
        best[where] = d_px[better]
        normal[where, 0] = s * gx[better]
        normal[where, 1] = s * gy[better]
        # Radius of curvature of the circle's image (px): rho |adj(J) tau|^3 / det(J)^2, tau the tangent.
        jb = jac[better]
        tx, ty = -ny[better], nx[better]
        ax = jb[:, 1, 1] * tx - jb[:, 0, 1] * ty
        ay = -jb[:, 1, 0] * tx + jb[:, 0, 0] * ty
        det = jb[:, 0, 0] * jb[:, 1, 1] - jb[:, 0, 1] * jb[:, 1, 0]
        rho_px[where] = radius * np.hypot(ax, ay) ** 3 / (det * det)


# ---------------------------------------------------------------------------------------------- raster
@dataclass(frozen=True, eq=False)
class ImageTexture:
    """A raster pattern (an ArUco or AprilTag image, a checkerboard) printed on a white sheet.

    ``image``: (h, w) floats in [0, 1] (0 black, 1 white), each cell a uniform patch (nearest-cell lookup).
    With ``margin_m`` = 0 the reflectance beyond the image continues its border cells (the sheet ends there).
    ``size_m``: side of the square the image fills, centred on the origin; image columns run along +x and rows
    along +y, so a cell is ``size_m / w`` wide and ``size_m / h`` high. ``margin_m``: white border beyond it
    (the sheet). ``white``, ``black``: reflectances of paper and ink.
    """

    image: FloatArray
    size_m: float
    margin_m: float = 0.0
    white: float = PAPER_WHITE
    black: float = INK_BLACK

    def __post_init__(self) -> None:
        img = np.asarray(self.image, dtype=np.float64)
        if img.ndim != 2 or img.size == 0:
            raise ValueError(f"image must be a non-empty (h, w) array, got shape {img.shape}")
        if np.any(img < 0.0) or np.any(img > 1.0):
            raise ValueError("image values must lie in [0, 1]")
        if self.size_m <= 0 or self.margin_m < 0:
            raise ValueError("size_m must be > 0 and margin_m >= 0")
        # Two rings of cells around the image (lookups clip into them, so every cell has 8 neighbours): white
        # paper with a margin; without one, the image's own border cells continued, so that the image's
        # edge is the sheet's border alone (which the renderer handles), not a second edge at the same place.
        if self.margin_m > 0:
            padded = np.pad(img, 2, mode="constant", constant_values=1.0)
        else:
            padded = np.pad(img, 2, mode="edge")
        object.__setattr__(self, "_padded", self.black + (self.white - self.black) * padded)

    @property
    def bounds_m(self) -> tuple[float, float, float, float]:
        half = self.size_m / 2.0 + self.margin_m
        return (-half, half, -half, half)

    @property
    def cell_m(self) -> tuple[float, float]:
        """(width, height) of one image cell in metres."""
        h, w = np.shape(self.image)
        return self.size_m / w, self.size_m / h

    def _cells(self, x: FloatArray, y: FloatArray) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
        """Padded (row, col) of each point's cell; points beyond the image land in the white rings."""
        h, w = np.shape(self.image)
        cw, ch = self.cell_m
        col = np.floor((x + self.size_m / 2.0) / cw)
        row = np.floor((y + self.size_m / 2.0) / ch)
        col = np.clip(col, -1, w).astype(np.intp) + 2
        row = np.clip(row, -1, h).astype(np.intp) + 2
        return row, col

    def reflectance(self, x_m: FloatArray, y_m: FloatArray) -> FloatArray:
        x = np.asarray(x_m, dtype=np.float64)
        y = np.asarray(y_m, dtype=np.float64)
        row, col = self._cells(x, y)
        return self._padded[row, col]

    def _cell_box(self, row: npt.NDArray[np.intp], col: npt.NDArray[np.intp]) -> tuple[FloatArray, ...]:
        """x0, x1, y0, y1 of padded cells (cells of the white rings are infinite outward)."""
        h, w = np.shape(self.image)
        cw, ch = self.cell_m
        x0 = -self.size_m / 2.0 + (col - 2) * cw
        y0 = -self.size_m / 2.0 + (row - 2) * ch
        x1, y1 = x0 + cw, y0 + ch
        x0 = np.where(col <= 1, -np.inf, x0)
        y0 = np.where(row <= 1, -np.inf, y0)
        x1 = np.where(col >= w + 2, np.inf, x1)
        y1 = np.where(row >= h + 2, np.inf, y1)
        return x0, x1, y0, y1

    def edge_distance_m(self, x_m: FloatArray, y_m: FloatArray) -> FloatArray:
        x = np.asarray(x_m, dtype=np.float64)
        y = np.asarray(y_m, dtype=np.float64)
        row, col = self._cells(x, y)
        here = self._padded[row, col]
        cw, ch = self.cell_m
        # Edges beyond the 3x3 block around the own cell are at least one cell away.
        d = np.full(x.shape, min(cw, ch))
        # Outside the image, the nearest edge is no nearer than the image square itself.
        half = self.size_m / 2.0
        outside = np.hypot(np.maximum(np.abs(x) - half, 0.0), np.maximum(np.abs(y) - half, 0.0))
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                if di == 0 and dj == 0:
                    continue
                nr, nc = row + di, col + dj
                differs = self._padded[nr, nc] != here
                x0, x1, y0, y1 = self._cell_box(nr, nc)
                dist = np.hypot(np.maximum(np.maximum(x0 - x, x - x1), 0.0),
                                np.maximum(np.maximum(y0 - y, y - y1), 0.0))
                d = np.where(differs, np.minimum(d, dist), d)
        return np.maximum(d, outside)

    def cell_average(self, x_m: FloatArray, y_m: FloatArray, jac: FloatArray, side_px: float) -> FloatArray:
        """See ``EdgeTexture``. The nearer vertical and the nearer horizontal cell boundary are linearised and
        the square split between the four cells around them in proportion to the fractions on each side of
        each line: exact for one straight edge, and for corners when the image axes are aligned with the pixel
        axes; otherwise a corner's error stays inside the one square that holds it."""
        x = np.asarray(x_m, dtype=np.float64).ravel()
        y = np.asarray(y_m, dtype=np.float64).ravel()
        jac = np.asarray(jac, dtype=np.float64).reshape(-1, 2, 2)
        row, col = self._cells(x, y)
        x0, x1, y0, y1 = self._cell_box(row, col)
        dx_lo, dx_hi = x - x0, x1 - x
        dy_lo, dy_hi = y - y0, y1 - y
        dj = np.where(dx_lo < dx_hi, -1, 1)
        di = np.where(dy_lo < dy_hi, -1, 1)
        # Pixel-space gradients of the plane x and y coordinates (columns of J^T).
        gxx, gxy = jac[:, 0, 0], jac[:, 0, 1]
        gyx, gyy = jac[:, 1, 0], jac[:, 1, 1]
        nx_norm = np.hypot(gxx, gxy)
        ny_norm = np.hypot(gyx, gyy)
        fx = square_fraction_within(np.minimum(dx_lo, dx_hi) / nx_norm, gxx / nx_norm, gxy / nx_norm, side_px)
        fy = square_fraction_within(np.minimum(dy_lo, dy_hi) / ny_norm, gyx / ny_norm, gyy / ny_norm, side_px)
        p = self._padded
        return (fx * fy * p[row, col] + (1.0 - fx) * fy * p[row, col + dj]
                + fx * (1.0 - fy) * p[row + di, col] + (1.0 - fx) * (1.0 - fy) * p[row + di, col + dj])
