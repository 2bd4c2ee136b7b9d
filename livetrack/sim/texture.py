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

import math
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
    ``edge_to_edge``: no sheet: the target is printed edge-to-edge, its black disk (radius R) is all there is
        and the background shows right beyond its outer edge (``sheet_disk_radius_m`` = R; ``sheet_size_m``
        must then be None). The renderer takes the disk's border as the sheet's (exact coverage, linearised per
        sub-cell like every circle); the texture is black up to and beyond R so that the border is one edge.
    Every edge of a target is a circle separating black from white, which the edge methods use.
    """

    spec: TargetSpec
    sheet_size_m: tuple[float, float] | None = None
    white: float = PAPER_WHITE
    black: float = INK_BLACK
    edge_to_edge: bool = False

    def __post_init__(self) -> None:
        if self.edge_to_edge and self.sheet_size_m is not None:
            raise ValueError("TargetTexture: give sheet_size_m or edge_to_edge, not both")
        if self.sheet_size_m is not None and min(self.sheet_size_m) < 2.0 * self.spec.outer_radius_m:
            raise ValueError(f"TargetTexture: sheet {self.sheet_size_m} m smaller than the target's disk "
                             f"(diameter {2.0 * self.spec.outer_radius_m} m)")

    @property
    def sheet_disk_radius_m(self) -> float | None:
        """Radius of a round sheet centred on the origin (the renderer's border), or None for the rectangle
        ``bounds_m``."""
        return self.spec.outer_radius_m if self.edge_to_edge else None

    @property
    def bounds_m(self) -> tuple[float, float, float, float]:
        if self.edge_to_edge:
            w = h = 2.0 * self.spec.outer_radius_m
        elif self.sheet_size_m is None:
            w = h = DEFAULT_SHEET_FACTOR * self.spec.outer_radius_m
        else:
            w, h = self.sheet_size_m
        return (-w / 2.0, w / 2.0, -h / 2.0, h / 2.0)

    def reflectance(self, x_m: FloatArray, y_m: FloatArray) -> FloatArray:
        unit = self.spec.reflectance(x_m, y_m)
        if self.edge_to_edge:
            x = np.asarray(x_m, dtype=np.float64)
            y = np.asarray(y_m, dtype=np.float64)
            unit = np.where(x * x + y * y > self.spec.outer_radius_m ** 2, 0.0, unit)
        return self.black + (self.white - self.black) * unit

    # -- edges
    @cached_property
    def _levels(self) -> tuple[tuple[tuple[float, ...], tuple[_Circle, ...], float, float, float], ...]:
        """Per level: (concentric radii, code dots, ring radius, dot radius, child outer radius or -1)."""
        out = []
        for level, spec in self.spec.levels():
            # Edge-to-edge: the outer circle of level 0 is the sheet's border, not an edge of the texture.
            radii = [spec.inner_radius_m] if self.edge_to_edge and level == 0 else [spec.outer_radius_m,
                                                                                       spec.inner_radius_m]
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


# ---------------------------------------------------------------------------------------------- backgrounds
# What the camera sees where no sheet is, as a function of the PIXEL position (x, y) (the scene behind the
# targets is far and unstructured in depth: a wall, the ground, the sky; its pattern is given in the image, so
# that its scale is set in pixels). Each pattern gives ``reflectance_px(x_px, y_px)`` in [0, 1] at any points
# (continuous positions: the renderer evaluates it on its oversampled grids too).
@runtime_checkable
class BackgroundPattern(Protocol):
    """A background seen in the image: reflectance at pixel positions."""

    def reflectance_px(self, x_px: FloatArray, y_px: FloatArray) -> FloatArray:
        """Reflectance in [0, 1] at pixel positions (any shape; (0, 0) the centre of the top-left pixel)."""
        ...


@dataclass(frozen=True, eq=False)
class UniformBackground:
    """One reflectance everywhere."""

    reflectance: float = 0.2

    def reflectance_px(self, x_px: FloatArray, y_px: FloatArray) -> FloatArray:
        return np.full(np.shape(x_px), float(self.reflectance))


def _smooth_grid_sample(grid: FloatArray, u: FloatArray, v: FloatArray) -> FloatArray:
    """Value noise: the (gh, gw) grid interpolated at grid coordinates (u, v) with a C1 (smoothstep) weight."""
    gh, gw = grid.shape
    u = np.clip(u, 0.0, gw - 1.000001)
    v = np.clip(v, 0.0, gh - 1.000001)
    j, i = np.floor(u).astype(np.intp), np.floor(v).astype(np.intp)
    fu, fv = u - j, v - i
    fu = fu * fu * (3.0 - 2.0 * fu)
    fv = fv * fv * (3.0 - 2.0 * fv)
    top = grid[i, j] * (1.0 - fu) + grid[i, j + 1] * fu
    bottom = grid[i + 1, j] * (1.0 - fu) + grid[i + 1, j + 1] * fu
    return top * (1.0 - fv) + bottom * fv


@dataclass(frozen=True, eq=False)
class NoiseBackground:
    """Procedural multi-scale noise (carpet at 1-4 px, foliage or gravel at 4-64 px): the sum of value-noise
    layers, one per feature size in ``scales_px`` (equal weights), scaled to unit standard deviation, then
    ``reflectance * (1 + contrast * noise)`` clipped to [0, 1]. ``width``/``height``: the area covered (pixels;
    beyond it the pattern continues its border). Deterministic in ``seed``."""

    reflectance: float
    scales_px: tuple[float, ...]
    contrast: float
    width: int
    height: int
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.scales_px or min(self.scales_px) <= 0:
            raise ValueError(f"NoiseBackground.scales_px must be positive, got {self.scales_px}")
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 11]))
        grids = []
        for s in self.scales_px:
            gw, gh = int(math.ceil(self.width / s)) + 3, int(math.ceil(self.height / s)) + 3
            grids.append(rng.standard_normal((gh, gw)))
        object.__setattr__(self, "_grids", tuple(grids))
        # Value noise with smoothstep weights has a standard deviation of about 0.6 of its grid's; measured
        # on a sample instead, so that the layers' sum has unit deviation whatever the scales.
        probe = np.random.default_rng(1)
        xs, ys = probe.random(4096) * self.width, probe.random(4096) * self.height
        object.__setattr__(self, "_norm", 1.0)
        object.__setattr__(self, "_norm", 1.0 / max(float(np.std(self._raw(xs, ys))), 1e-12))

    def _raw(self, x: FloatArray, y: FloatArray) -> FloatArray:
        out = np.zeros(np.shape(x))
        for s, grid in zip(self.scales_px, self._grids, strict=True):  # type: ignore[attr-defined]
            out += _smooth_grid_sample(grid, np.asarray(x) / s + 1.0, np.asarray(y) / s + 1.0)
        return out

    def reflectance_px(self, x_px: FloatArray, y_px: FloatArray) -> FloatArray:
        noise = self._raw(np.asarray(x_px, dtype=np.float64), np.asarray(y_px, dtype=np.float64))
        return np.clip(self.reflectance * (1.0 + self.contrast * self._norm * noise), 0.0, 1.0)  # type: ignore

    def reflectance_grid(self, x_px: FloatArray, y_px: FloatArray) -> FloatArray:
        """(len(y_px), len(x_px)) reflectance on the grid of the 1-D positions: as ``reflectance_px`` on the
        mesh, separably (each layer interpolated along x for every grid row, then along y): ~50x faster."""
        out = np.zeros((len(y_px), len(x_px)))
        for s, grid in zip(self.scales_px, self._grids, strict=True):  # type: ignore[attr-defined]
            gh, gw = grid.shape
            u = np.clip(np.asarray(x_px, dtype=np.float64) / s + 1.0, 0.0, gw - 1.000001)
            v = np.clip(np.asarray(y_px, dtype=np.float64) / s + 1.0, 0.0, gh - 1.000001)
            j, i = np.floor(u).astype(np.intp), np.floor(v).astype(np.intp)
            fu, fv = u - j, v - i
            fu = fu * fu * (3.0 - 2.0 * fu)
            fv = fv * fv * (3.0 - 2.0 * fv)
            rows = grid[:, j] * (1.0 - fu) + grid[:, j + 1] * fu  # (gh, W)
            out += rows[i] * (1.0 - fv)[:, None] + rows[i + 1] * fv[:, None]
        return np.clip(self.reflectance * (1.0 + self.contrast * self._norm * out), 0.0, 1.0)  # type: ignore


_GLYPH_ROWS, _GLYPH_COLS = 7, 5


@dataclass(frozen=True, eq=False)
class TextBackground:
    """Printed-text-like high-contrast pattern: lines of words made of random 5 x 7 dot-matrix glyphs (strokes of
    ink ``ink_reflectance`` on paper ``reflectance``), ``line_height_px`` the glyph height, lines 1.6 glyph
    heights apart, glyphs 0.75 of it wide (one column of spacing), words of 2-9 glyphs. Sharp edges: aliased
    where the strokes are below a pixel, as print seen from afar is. Deterministic in ``seed``."""

    reflectance: float
    line_height_px: float
    width: int
    height: int
    ink_reflectance: float = INK_BLACK
    seed: int = 0

    def __post_init__(self) -> None:
        if self.line_height_px <= 0:
            raise ValueError(f"TextBackground.line_height_px must be > 0, got {self.line_height_px}")
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 12]))
        glyphs = rng.random((40, _GLYPH_ROWS, _GLYPH_COLS)) < 0.42
        glyphs[:, :, -1] = False  # the spacing column
        lines = int(self.height / (1.6 * self.line_height_px)) + 3
        cols = int(self.width / (0.75 * self.line_height_px)) + 3
        table = rng.integers(0, len(glyphs), size=(lines, cols))
        for row in table:  # spaces between words
            k = int(rng.integers(0, 3))
            while k < cols:
                row[k] = -1
                k += int(rng.integers(3, 11))
        object.__setattr__(self, "_glyphs", glyphs)
        object.__setattr__(self, "_table", table)

    def reflectance_px(self, x_px: FloatArray, y_px: FloatArray) -> FloatArray:
        x = np.asarray(x_px, dtype=np.float64) + 0.5
        y = np.asarray(y_px, dtype=np.float64) + 0.5
        h = self.line_height_px
        table, glyphs = self._table, self._glyphs  # type: ignore[attr-defined]
        line = np.clip(np.floor(y / (1.6 * h)), 0, table.shape[0] - 1).astype(np.intp)
        v = y / h - 1.6 * line  # glyph rows in [0, 1) inside the line
        col = np.clip(np.floor(x / (0.75 * h)), 0, table.shape[1] - 1).astype(np.intp)
        u = x / (0.75 * h) - col
        glyph = table[line, col]
        gi = np.clip(np.floor(v * _GLYPH_ROWS), 0, _GLYPH_ROWS - 1).astype(np.intp)
        gj = np.clip(np.floor(u * _GLYPH_COLS), 0, _GLYPH_COLS - 1).astype(np.intp)
        ink = (glyph >= 0) & (v >= 0.0) & (v < 1.0) & glyphs[np.maximum(glyph, 0), gi, gj]
        return np.where(ink, self.ink_reflectance, self.reflectance)


@dataclass(frozen=True, eq=False)
class CheckerBackground:
    """A chessboard of squares ``square_px`` wide, turned by ``angle_deg``: ``reflectance`` and
    ``dark_reflectance`` alternate."""

    reflectance: float
    square_px: float
    dark_reflectance: float = INK_BLACK
    angle_deg: float = 0.0

    def reflectance_px(self, x_px: FloatArray, y_px: FloatArray) -> FloatArray:
        a = math.radians(self.angle_deg)
        x = np.asarray(x_px, dtype=np.float64)
        y = np.asarray(y_px, dtype=np.float64)
        u = (math.cos(a) * x + math.sin(a) * y) / self.square_px
        v = (-math.sin(a) * x + math.cos(a) * y) / self.square_px
        odd = (np.floor(u) + np.floor(v)) % 2 == 1
        return np.where(odd, self.dark_reflectance, self.reflectance)


@dataclass(frozen=True, eq=False)
class ImageBackground:
    """A picture (h, w) in [0, 1] stretched over the ``width`` x ``height`` frame (bilinear), its values scaled
    so that its mean is ``reflectance`` (clipped to [0, 1])."""

    image: FloatArray
    reflectance: float
    width: int
    height: int

    def __post_init__(self) -> None:
        img = np.asarray(self.image, dtype=np.float64)
        if img.ndim != 2 or min(img.shape) < 2:
            raise ValueError(f"ImageBackground.image must be (h, w) with h, w >= 2, got {img.shape}")
        gain = self.reflectance / max(float(img.mean()), 1e-6)
        object.__setattr__(self, "_scaled", np.clip(img * gain, 0.0, 1.0))

    def reflectance_px(self, x_px: FloatArray, y_px: FloatArray) -> FloatArray:
        img = self._scaled  # type: ignore[attr-defined]
        h, w = img.shape
        # Pixel centres of the picture spread over the frame's pixel centres.
        u = (np.asarray(x_px, dtype=np.float64) + 0.5) * (w / self.width) - 0.5
        v = (np.asarray(y_px, dtype=np.float64) + 0.5) * (h / self.height) - 0.5
        u, v = np.clip(u, 0.0, w - 1.000001), np.clip(v, 0.0, h - 1.000001)
        j, i = np.floor(u).astype(np.intp), np.floor(v).astype(np.intp)
        fu, fv = u - j, v - i
        top = img[i, j] * (1.0 - fu) + img[i, j + 1] * fu
        bottom = img[i + 1, j] * (1.0 - fu) + img[i + 1, j + 1] * fu
        return top * (1.0 - fv) + bottom * fv


def background_image(pattern: BackgroundPattern, width: int, height: int, x0_px: float = 0.0,
                     y0_px: float = 0.0, step_px: float = 1.0, samples: int = 2) -> npt.NDArray[np.float32]:
    """(height, width) float32: the pattern averaged over each cell of a grid whose cell (0, 0) is centred on
    pixel position (x0_px, y0_px) and whose cells are ``step_px`` apart (1 for the camera's pixels, 1/n for an
    n-times finer grid), from ``samples`` x ``samples`` points per cell (anti-aliasing of sharp patterns)."""
    if isinstance(pattern, UniformBackground):
        return np.full((height, width), pattern.reflectance, dtype=np.float32)
    out = np.zeros((height, width), dtype=np.float64)
    offsets = ((np.arange(samples) + 0.5) / samples - 0.5) * step_px
    x1, y1 = x0_px + np.arange(width) * step_px, y0_px + np.arange(height) * step_px
    separable = getattr(pattern, "reflectance_grid", None)
    xs, ys = (None, None) if separable is not None else np.meshgrid(x1, y1)
    for oy in offsets:
        for ox in offsets:
            if separable is not None:
                out += separable(x1 + ox, y1 + oy)
            else:
                out += pattern.reflectance_px(xs + ox, ys + oy)
    return (out / (samples * samples)).astype(np.float32)
