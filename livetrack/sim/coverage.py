"""Exact geometric rendering: each pixel's area-average reflectance of the sheets a camera sees.

Pipeline per placement (a texture on a sheet at a pose):

1. The sheet's outline is clipped to the near plane and to the image's field of view and projected, giving a
   pixel ROI.
2. Undistorted normalized coordinates of every pixel CORNER come from a per-camera cache (the exact Newton
   inverse of the lens model, computed once); pixel centres and sub-pixel points are bilinear interpolations
   of it (exact without distortion; 4e-5 px at worst in the corners of a 1920 x 1200 image with k1 = -0.1
   and f = 1800 px, see ``tests/test_sim_coverage.py``). The inverse plane homography maps them to the target
   plane; rays that meet the plane behind the camera see no sheet.
3. Tiles of 8 x 8 pixels, then the pixels of the remaining tiles, are *uniform* when the texture's
   ``edge_distance_m`` at their centre exceeds the radius of their footprint on the plane (the largest
   centre-to-corner distance: the image of a square under a homography is the quadrilateral of its corners)
   and the sheet's border is as far: they take the value at their centre. This test is exact whatever the
   feature size or tilt. Textures without edge information fall back to comparing point samples at the
   corners and the centre of each pixel, with the mixed mask dilated by one pixel (which can miss features
   smaller than about half a pixel).
4. Every other pixel is split into n x n sub-cells (``supersampling`` = n^2). The texture's ``cell_average``
   linearises its nearest edge(s) in each sub-cell (in pixel space, through the local Jacobian) and takes the
   exact area on each side; the sheet's border is linearised the same way (a pixel crossed only by the border
   uses one cell, the border being straight at that scale). Straight edges of any orientation and position
   are exact; circles are off by about h^3 / (12 rho) px^2 per sub-cell of side h crossed by a circle of
   radius rho px, and small circles are split further (``texture.CURVED_EDGE_REFINE``); two edges inside
   one sub-cell are approximated. Plain point sampling cannot reach this at a practical sample count: any
   N-point pattern has half-plane orientations at which a pixel's value jumps by ~1/sqrt(N) (the 89-point
   Fibonacci lattice is a square lattice turned by 32 degrees), so per-pixel errors of a few percent
   remain at 64 to 89 samples. Textures without edge information are point-sampled at the sub-cell
   centres.
5. Sheets are composited back to front (painter's algorithm on the depth of the target origin, ``pose.t``
   z) with their coverage as alpha, over ``background``.

Measured (``tests/test_sim_coverage.py``, ``livetrack bench-sim``): dark area of a frontal two-level target
within 2e-6 (1.5 m) to 4e-5 (5 m) relative; straight edges exact to 1e-10 at any angle; 0.05-0.1 s for a
1920 x 1200 frame with the 0.125 m target at 1.5 m (the corner map, 1-2 s, once per camera).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from livetrack.camera import CameraModel
from livetrack.geometry import Pose
from livetrack.sim.texture import EdgeTexture, PlanarTexture, square_fraction_within

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

DEFAULT_SUPERSAMPLING = 16
"""Sub-cells per mixed pixel (4 x 4). Straight edges are exact at any value; on circles the area error falls
about as 1 / supersampling (dark area of the default target at 6 m: 7e-5 relative with 4, 2e-5 with 16,
9e-6 with 64). Cost: the mixed pixels' share of the render time grows linearly with it (1.5 m frame: ~0.06 s
with 16, ~0.12 s with 64)."""

NEAR_PLANE_M = 1e-6
"""Sheet parts closer than this to the camera plane (metres) are clipped."""

TILE_PX = 8
"""Side of the tiles first tested whole for being off the sheet or of one reflectance (textures with edge
information only); the pixels of the other tiles are tested one by one. A speed setting: results do not
depend on it."""

_SAMPLES_PER_CHUNK = 1 << 18
"""Bound on the sub-samples processed at once (memory: ~40 doubles each)."""


@dataclass(frozen=True)
class Placement:
    """A texture on a sheet at ``pose`` (target-to-camera)."""

    pose: Pose
    texture: PlanarTexture


# ---------------------------------------------------------------------------------------------- corner map
class _CornerMap:
    """Undistorted normalized coordinates of the pixel corners of one camera, filled in blocks on demand (the
    first frames pay only for the pixels their sheets cover)."""

    BLOCK = 64

    def __init__(self, camera: CameraModel) -> None:
        self.camera = camera
        self.data = np.empty((camera.height + 1, camera.width + 1, 2))
        blocks = (-(-(camera.height + 1) // self.BLOCK), -(-(camera.width + 1) // self.BLOCK))
        self.done = np.zeros(blocks, dtype=bool)
        cam = camera
        xs = np.arange(cam.width + 1, dtype=np.float64) - 0.5
        ys = np.arange(cam.height + 1, dtype=np.float64) - 0.5
        border_px = np.concatenate([np.column_stack([xs, np.full_like(xs, ys[0])]),
                                    np.column_stack([xs, np.full_like(xs, ys[-1])]),
                                    np.column_stack([np.full_like(ys, xs[0]), ys]),
                                    np.column_stack([np.full_like(ys, xs[-1]), ys])])
        border = cam.pixels_to_normalized(border_px)
        self.lo, self.hi = border.min(axis=0), border.max(axis=0)  # the image's box in normalized coordinates

    def region(self, i0: int, i1: int, j0: int, j1: int) -> FloatArray:
        """Corners [i0:i1, j0:j1] (rows, columns of the (H + 1, W + 1) corner grid)."""
        b = self.BLOCK
        bi0, bi1, bj0, bj1 = i0 // b, -(-i1 // b), j0 // b, -(-j1 // b)
        todo = np.argwhere(~self.done[bi0:bi1, bj0:bj1])
        if todo.size:
            # Whole rows of missing blocks at once (fewer, larger Newton solves).
            for bi in np.unique(todo[:, 0]) + bi0:
                cols = np.flatnonzero(~self.done[bi, bj0:bj1]) + bj0
                self._fill(bi * b, min((bi + 1) * b, self.data.shape[0]), cols[0] * b,
                           min((cols[-1] + 1) * b, self.data.shape[1]))
                self.done[bi, cols[0]:cols[-1] + 1] = True
        return self.data[i0:i1, j0:j1]

    def _fill(self, i0: int, i1: int, j0: int, j1: int) -> None:
        cam = self.camera
        xs = np.arange(j0, j1, dtype=np.float64) - 0.5
        ys = np.arange(i0, i1, dtype=np.float64) - 0.5
        if cam.has_distortion:
            grid = np.empty((ys.size, xs.size, 2))
            grid[..., 0] = xs[None, :]
            grid[..., 1] = ys[:, None]
            self.data[i0:i1, j0:j1] = cam.pixels_to_normalized(grid)
        else:
            self.data[i0:i1, j0:j1, 0] = ((xs - cam.cx) / cam.fx)[None, :]
            self.data[i0:i1, j0:j1, 1] = ((ys - cam.cy) / cam.fy)[:, None]


_CORNER_CACHE: OrderedDict[tuple[object, ...], _CornerMap] = OrderedDict()
_CORNER_CACHE_SIZE = 4


def _camera_key(camera: CameraModel) -> tuple[object, ...]:
    return (camera.width, camera.height, float(camera.fx), float(camera.fy), float(camera.cx),
            float(camera.cy), tuple(float(d) for d in camera.dist))


def _corners(camera: CameraModel) -> _CornerMap:
    key = _camera_key(camera)
    cached = _CORNER_CACHE.get(key)
    if cached is not None:
        _CORNER_CACHE.move_to_end(key)
        return cached
    cached = _CORNER_CACHE[key] = _CornerMap(camera)
    while len(_CORNER_CACHE) > _CORNER_CACHE_SIZE:
        _CORNER_CACHE.popitem(last=False)
    return cached


def corner_map(camera: CameraModel) -> FloatArray:
    """(H + 1, W + 1, 2) undistorted normalized coordinates of the pixel corners: entry [i, j] is pixel
    position (x, y) = (j - 0.5, i - 0.5), from the exact Newton inverse of the lens model.

    Cached for the last four cameras (37 MB each at 2.3 Mpx) and filled in 64 x 64 blocks as renders need
    them; this call fills all of it (about 1.5 s for 2.3 Mpx with distortion, once). Read-only view."""
    cmap = _corners(camera)
    out = cmap.region(0, camera.height + 1, 0, camera.width + 1)
    out = out.view()
    out.setflags(write=False)
    return out


# ---------------------------------------------------------------------------------------------- geometry
def _to_plane(hinv: FloatArray, n: FloatArray) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Normalized (..., 2) -> target plane x, y (...) and whether the ray meets the plane in front."""
    u, v = n[..., 0], n[..., 1]
    qx = hinv[0, 0] * u + hinv[0, 1] * v + hinv[0, 2]
    qy = hinv[1, 0] * u + hinv[1, 1] * v + hinv[1, 2]
    qw = hinv[2, 0] * u + hinv[2, 1] * v + hinv[2, 2]  # = 1 / depth of the point on the plane
    front = qw > 1e-12
    inv = np.where(front, 1.0 / np.where(front, qw, 1.0), 0.0)
    x = np.where(front, qx * inv, np.inf)
    y = np.where(front, qy * inv, np.inf)
    return x, y, front


def _clip_polygon(poly: FloatArray, normal: FloatArray, offset: float) -> FloatArray:
    """Sutherland-Hodgman: keep the part of polygon (K, D) with normal . p >= offset."""
    if len(poly) == 0:
        return poly
    out = []
    s = poly @ normal - offset
    for k in range(len(poly)):
        a, b = poly[k], poly[(k + 1) % len(poly)]
        sa, sb = s[k], s[(k + 1) % len(poly)]
        if sa >= 0:
            out.append(a)
        if (sa >= 0) != (sb >= 0):
            out.append(a + (b - a) * (sa / (sa - sb)))
    return np.array(out).reshape(-1, poly.shape[1])


def sheet_roi(camera: CameraModel, pose: Pose, bounds_m: tuple[float, float, float, float],
              margin_px: int = 2) -> tuple[int, int, int, int] | None:
    """Pixel rows i0:i1 and columns j0:j1 (half-open) that can see the sheet, or None if none can."""
    xmin, xmax, ymin, ymax = bounds_m
    corners = np.array([[xmin, ymin, 0.0], [xmax, ymin, 0.0], [xmax, ymax, 0.0], [xmin, ymax, 0.0]])
    poly = _clip_polygon(pose.apply(corners), np.array([0.0, 0.0, 1.0]), NEAR_PLANE_M)
    if len(poly) < 3:
        return None
    norm = poly[:, :2] / poly[:, 2:3]
    cmap = _corners(camera)
    lo, hi = cmap.lo, cmap.hi
    for axis in range(2):
        e = np.zeros(2)
        e[axis] = 1.0
        norm = _clip_polygon(norm, e, lo[axis])
        norm = _clip_polygon(norm, -e, -hi[axis])
    if len(norm) < 3:
        return None
    # Dense points along the outline (distortion bends straight lines), projected with the lens model.
    steps = np.linspace(0.0, 1.0, 65)[:-1, None]
    ends = np.roll(norm, -1, axis=0)
    outline = np.concatenate([a + steps * (b - a) for a, b in zip(norm, ends, strict=True)])
    px = camera.normalized_to_pixels(outline)
    j0 = int(np.floor(px[:, 0].min() + 0.5)) - margin_px
    j1 = int(np.floor(px[:, 0].max() + 0.5)) + margin_px + 1
    i0 = int(np.floor(px[:, 1].min() + 0.5)) - margin_px
    i1 = int(np.floor(px[:, 1].max() + 0.5)) + margin_px + 1
    i0, j0 = max(i0, 0), max(j0, 0)
    i1, j1 = min(i1, camera.height), min(j1, camera.width)
    if i0 >= i1 or j0 >= j1:
        return None
    return i0, i1, j0, j1


def _sheet_signed_m(x: FloatArray, y: FloatArray, bounds: tuple[float, float, float, float],
                    disk_m: float | None = None) -> FloatArray:
    """Signed plane distance (metres) to the sheet's border, > 0 inside (Chebyshev-like: the nearest side; for
    a round sheet of radius ``disk_m`` centred on the origin, the distance to its circle)."""
    if disk_m is not None:
        return disk_m - np.hypot(x, y)
    xmin, xmax, ymin, ymax = bounds
    return np.minimum(np.minimum(x - xmin, xmax - x), np.minimum(y - ymin, ymax - y))


def _sheet_alpha(x: FloatArray, y: FloatArray, jac: FloatArray, bounds: tuple[float, float, float, float],
                 side_px: float, disk_m: float | None = None) -> FloatArray:
    """Fraction of the pixel-space square of side ``side_px`` around each point (K,) that lies on the sheet:
    the nearer vertical and the nearer horizontal side are linearised through ``jac`` (K, 2, 2) and the
    fractions inside each multiplied (exact along a side; at a sheet corner exact when the sheet's axes are
    aligned with the pixel axes). A round sheet (radius ``disk_m``) has its circle linearised instead."""
    if disk_m is not None:
        r = np.hypot(x, y)
        safe = np.where(r > 0.0, r, 1.0)
        nx, ny = np.where(r > 0.0, x / safe, 1.0), np.where(r > 0.0, y / safe, 0.0)
        gx, gy = jac[:, 0, 0] * nx + jac[:, 1, 0] * ny, jac[:, 0, 1] * nx + jac[:, 1, 1] * ny
        gn = np.maximum(np.hypot(gx, gy), 1e-300)
        dist = disk_m - r
        within = square_fraction_within(np.abs(dist) / gn, gx / gn, gy / gn, side_px)
        return np.where(dist >= 0, within, 1.0 - within)
    xmin, xmax, ymin, ymax = bounds
    out = np.ones(x.shape)
    for lo, hi, gx, gy in ((x - xmin, xmax - x, jac[:, 0, 0], jac[:, 0, 1]),
                           (y - ymin, ymax - y, jac[:, 1, 0], jac[:, 1, 1])):
        gn = np.hypot(gx, gy)  # pixel-space gradient of the plane coordinate
        dist = np.minimum(lo, hi)  # < 0 beyond a side
        within = square_fraction_within(np.abs(dist) / gn, gx / gn, gy / gn, side_px)
        out *= np.where(dist >= 0, within, 1.0 - within)
    return out


# ---------------------------------------------------------------------------------------------- rendering
def render_reflectance(camera: CameraModel, placements: Sequence[Placement],
                       background: float | npt.ArrayLike = 0.2,
                       supersampling: int = DEFAULT_SUPERSAMPLING) -> FloatArray:
    """(H, W) float64: each pixel's area-average reflectance of what it sees, lens distortion included.

    ``placements`` are drawn back to front by the depth of their target origin (correct for sheets that do
    not interpenetrate and whose origins order them), each composited over the image with its exact
    coverage; ``background`` (reflectance: one value, or an (H, W) image of the pixels' background, e.g.
    ``texture.background_image``) where no sheet is seen. ``supersampling``: sub-cells per mixed pixel, a
    perfect square (see ``DEFAULT_SUPERSAMPLING``).
    """
    n_sub = int(round(np.sqrt(supersampling)))
    if n_sub < 1 or n_sub * n_sub != supersampling:
        raise ValueError(f"supersampling must be a perfect square (1, 4, 9, 16, ...), got {supersampling}")
    if np.ndim(background) == 0:
        image = np.full((camera.height, camera.width), float(background))  # type: ignore[arg-type]
    else:
        image = np.array(background, dtype=np.float64)
        if image.shape != (camera.height, camera.width):
            raise ValueError(f"background image {image.shape} != camera (height, width) "
                             f"{(camera.height, camera.width)}")
    order = sorted(placements, key=lambda p: -float(p.pose.t[2]))
    for placement in order:
        _draw(camera, placement, image, n_sub)
    return image


def _footprint(cx: FloatArray, cy: FloatArray, x: FloatArray, y: FloatArray, margin: float) -> FloatArray:
    """Radius (metres) of a disk around (x, y) holding the quadrilateral of the four corners (a tuple of four
    (cx, cy) arrays, shaped as x): its largest distance to a corner, enlarged by ``margin`` (relative) for the
    slight bending of the sides by the lens."""
    foot = np.zeros(x.shape)
    with np.errstate(invalid="ignore"):
        for sx, sy in zip(cx, cy, strict=True):
            np.maximum(foot, np.hypot(sx - x, sy - y), out=foot)
    return foot * (1.0 + margin) + 1e-15


def _draw(camera: CameraModel, placement: Placement, image: FloatArray, n_sub: int) -> None:
    texture = placement.texture
    bounds = tuple(float(b) for b in texture.bounds_m)
    disk = getattr(texture, "sheet_disk_radius_m", None)  # a round sheet (edge-to-edge target), else None
    roi = sheet_roi(camera, placement.pose, bounds)  # type: ignore[arg-type]
    if roi is None:
        return
    i0, i1, j0, j1 = roi
    h, w = i1 - i0, j1 - j0
    cmap = _corners(camera).region(i0, i1 + 1, j0, j1 + 1)
    hinv = np.linalg.inv(placement.pose.plane_to_normalized_homography())
    cx, cy, cfront = _to_plane(hinv, cmap)  # plane coordinates of the ROI's pixel corners
    sub = image[i0:i1, j0:j1]
    edge_texture = isinstance(texture, EdgeTexture)

    # Tiles of TILE_PX x TILE_PX pixels that are provably off the sheet, or on it with one reflectance.
    todo = np.ones((h, w), dtype=bool)
    if edge_texture:
        ti, tj = np.r_[0:h:TILE_PX, h], np.r_[0:w:TILE_PX, w]
        tcx, tcy, tfront = cx[np.ix_(ti, tj)], cy[np.ix_(ti, tj)], cfront[np.ix_(ti, tj)]
        tn = cmap[np.ix_(ti, tj)]
        x, y, front = _to_plane(hinv, 0.25 * (tn[:-1, :-1] + tn[:-1, 1:] + tn[1:, :-1] + tn[1:, 1:]))
        ok = front & tfront[:-1, :-1] & tfront[:-1, 1:] & tfront[1:, :-1] & tfront[1:, 1:]
        x, y = np.where(ok, x, 0.0), np.where(ok, y, 0.0)
        corners = (slice(None, -1), slice(1, None))
        radius = _footprint(tuple(tcx[a, b] for a in corners for b in corners),
                            tuple(tcy[a, b] for a in corners for b in corners), x, y, 1e-2)
        radius = np.where(ok, radius, np.inf)
        signed = _sheet_signed_m(x, y, bounds, disk)
        # Off the sheet: provably beyond its border, or wholly beyond the plane's horizon (behind the camera).
        behind = ~(front | tfront[:-1, :-1] | tfront[:-1, 1:] | tfront[1:, :-1] | tfront[1:, 1:])
        off = (ok & (signed < -radius)) | behind
        on = ok & (signed > radius)
        if np.any(on):
            on[on] = texture.edge_distance_m(x[on], y[on]) > radius[on]
        if np.any(on):
            value = np.zeros(on.shape)
            value[on] = texture.reflectance(x[on], y[on])
            expand = np.repeat(np.repeat(on, TILE_PX, axis=0), TILE_PX, axis=1)[:h, :w]
            sub[expand] = np.repeat(np.repeat(value, TILE_PX, axis=0), TILE_PX, axis=1)[:h, :w][expand]
        todo = ~np.repeat(np.repeat(on | off, TILE_PX, axis=0), TILE_PX, axis=1)[:h, :w]

    # Pixels of the other tiles.
    r, c = np.nonzero(todo)
    if r.size == 0:
        return
    x, y, front = _to_plane(hinv, 0.25 * (cmap[r, c] + cmap[r, c + 1] + cmap[r + 1, c] + cmap[r + 1, c + 1]))
    ok = front & cfront[r, c] & cfront[r, c + 1] & cfront[r + 1, c] & cfront[r + 1, c + 1]
    x, y = np.where(ok, x, 0.0), np.where(ok, y, 0.0)
    foot = _footprint((cx[r, c], cx[r, c + 1], cx[r + 1, c], cx[r + 1, c + 1]),
                      (cy[r, c], cy[r, c + 1], cy[r + 1, c], cy[r + 1, c + 1]), x, y, 1e-3)
    foot = np.where(ok, foot, np.inf)
    signed = np.where(ok, _sheet_signed_m(x, y, bounds, disk), -np.inf)
    behind = ~(front | cfront[r, c] | cfront[r, c + 1] | cfront[r + 1, c] | cfront[r + 1, c + 1])
    outside = (signed < -foot) | behind  # pixels straddling the horizon stay mixed
    inside = signed > foot
    # Pixels over which the texture provably has one value.
    if edge_texture:
        clear = np.zeros(x.shape, dtype=bool)
        seen = np.flatnonzero(~outside)
        if seen.size:
            clear[seen] = texture.edge_distance_m(x[seen], y[seen]) > foot[seen]
    else:
        clear = _agree(texture, cx, cy, r, c, x, y)
    # Uniform pixels take the value at their centre.
    uniform = inside & clear
    if np.any(uniform):
        sub[r[uniform], c[uniform]] = texture.reflectance(x[uniform], y[uniform])
    # Pixels on one side of the sheet only (texture uniform): the side is straight at the pixel scale, one
    # cell is exact. Pixels at a corner of the sheet go with the sub-cells below.
    xmin, xmax, ymin, ymax = bounds
    if disk is None:
        at_corner = (np.minimum(np.abs(x - xmin), np.abs(xmax - x)) < foot) & (
            np.minimum(np.abs(y - ymin), np.abs(ymax - y)) < foot)
        clear &= ~at_corner
    # A round sheet's border is curved at the pixel scale when small: its pixels take the sub-cells too.
    groups = ((clear & ~inside & ~outside, 1 if disk is None else n_sub, "sheet"), (~clear & inside, n_sub, "texture"),
              (~clear & ~inside & ~outside, n_sub, "both"))
    for group, n, mode in groups:
        rows, cols = r[group], c[group]
        per_chunk = max(1, _SAMPLES_PER_CHUNK // (n * n))
        for k in range(0, rows.size, per_chunk):
            rk, ck = rows[k:k + per_chunk], cols[k:k + per_chunk]
            value, alpha = _mixed_pixels(texture, hinv, cmap, cx, cy, rk, ck, n, bounds, mode, disk)
            sub[rk, ck] = value + (1.0 - alpha) * sub[rk, ck]


def _agree(texture: PlanarTexture, cx: FloatArray, cy: FloatArray, r: npt.NDArray[np.intp],
           c: npt.NDArray[np.intp], x: FloatArray, y: FloatArray) -> BoolArray:
    """Fallback for textures without edge information, at ROI pixels (r, c) with centres (x, y): True where
    the pixel's corners and centre, and those of its 8 neighbours, have one reflectance."""
    corners = texture.reflectance(np.where(np.isfinite(cx), cx, 0.0), np.where(np.isfinite(cy), cy, 0.0))
    centre = np.full((cx.shape[0] - 1, cx.shape[1] - 1), np.nan)
    centre[r, c] = texture.reflectance(x, y)
    same = (corners[:-1, :-1] == centre) & (corners[:-1, 1:] == centre)
    same &= (corners[1:, :-1] == centre) & (corners[1:, 1:] == centre)
    mixed = ~same
    grown = mixed.copy()
    grown[1:] |= mixed[:-1]
    grown[:-1] |= mixed[1:]
    mixed = grown.copy()
    grown[:, 1:] |= mixed[:, :-1]
    grown[:, :-1] |= mixed[:, 1:]
    return ~grown[r, c]


def _mixed_pixels(texture: PlanarTexture, hinv: FloatArray, cmap: FloatArray, cx: FloatArray, cy: FloatArray,
                  r: npt.NDArray[np.intp], c: npt.NDArray[np.intp], n_sub: int,
                  bounds: tuple[float, float, float, float], mode: str,
                  disk: float | None = None) -> tuple[FloatArray, FloatArray]:
    """Premultiplied value and coverage of pixels (r, c) of the ROI, from n_sub x n_sub sub-cells.

    ``mode``: "texture" (pixels well inside the sheet: coverage 1), "sheet" (texture uniform over the pixel:
    only the border is linearised) or "both"."""
    m = r.size
    # Jacobian d(plane)/d(pixel) of each pixel from its four plane corners.
    with np.errstate(invalid="ignore"):
        dxx = 0.5 * ((cx[r, c + 1] - cx[r, c]) + (cx[r + 1, c + 1] - cx[r + 1, c]))
        dyx = 0.5 * ((cy[r, c + 1] - cy[r, c]) + (cy[r + 1, c + 1] - cy[r + 1, c]))
        dxy = 0.5 * ((cx[r + 1, c] - cx[r, c]) + (cx[r + 1, c + 1] - cx[r, c + 1]))
        dyy = 0.5 * ((cy[r + 1, c] - cy[r, c]) + (cy[r + 1, c + 1] - cy[r, c + 1]))
    jac = np.empty((m, 2, 2))
    jac[:, 0, 0], jac[:, 0, 1], jac[:, 1, 0], jac[:, 1, 1] = dxx, dxy, dyx, dyy
    ok = np.all(np.isfinite(jac), axis=(1, 2))
    jac[~ok] = np.eye(2)
    # Sub-cell centres by bilinear interpolation of the normalized corner map.
    f = (np.arange(n_sub) + 0.5) / n_sub
    fu = np.tile(f, n_sub)  # along x
    fv = np.repeat(f, n_sub)  # along y
    n = (cmap[r, c][:, None, :] * ((1 - fu) * (1 - fv))[None, :, None]
         + cmap[r, c + 1][:, None, :] * (fu * (1 - fv))[None, :, None]
         + cmap[r + 1, c][:, None, :] * ((1 - fu) * fv)[None, :, None]
         + cmap[r + 1, c + 1][:, None, :] * (fu * fv)[None, :, None])
    x, y, front = _to_plane(hinv, n)  # (m, s)
    front = (front & ok[:, None]).ravel()
    x = np.where(front, x.ravel(), 0.0)
    y = np.where(front, y.ravel(), 0.0)
    jac_s = np.repeat(jac, n_sub * n_sub, axis=0) if n_sub > 1 else jac
    side = 1.0 / n_sub
    if mode == "texture":
        alpha = front.astype(np.float64)
    else:
        alpha = np.where(front, _sheet_alpha(x, y, jac_s, bounds, side, disk), 0.0)
    if mode != "sheet" and isinstance(texture, EdgeTexture):
        value = texture.cell_average(x, y, jac_s, side)
    else:
        value = texture.reflectance(x, y)
    shape = (m, n_sub * n_sub)
    return (alpha * value).reshape(shape).mean(axis=1), alpha.reshape(shape).mean(axis=1)
