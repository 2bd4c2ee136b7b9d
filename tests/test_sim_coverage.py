"""Exact geometric rendering (livetrack.sim.coverage / texture) against analytic truth and brute force."""

from __future__ import annotations

import numpy as np
import pytest

from livetrack.camera import CameraModel
from livetrack.geometry import Pose, look_rotation, rotation_from_rotvec
from livetrack.sim import ImageTexture, Placement, TargetTexture, corner_map, render_reflectance
from livetrack.sim.texture import square_fraction_within
from livetrack.targets.spec import TargetSpec

F_PX = 1800.0
SMALL = CameraModel(640, 480, 900.0, 900.0, 319.5, 239.5)


def _frame(dist: tuple[float, ...] = (0.0,) * 5) -> CameraModel:
    return CameraModel(1920, 1200, F_PX, F_PX, 959.5, 599.5, dist=dist)  # type: ignore[arg-type]


def _unit(img: np.ndarray, white: float = 0.85, black: float = 0.04) -> np.ndarray:
    """Reflectance -> 0 black .. 1 white."""
    return (img - black) / (white - black)


def _half_plane_area(cx: np.ndarray, cy: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    """Exact area of the unit pixels centred at (cx, cy) where p . normal > offset (clipping + shoelace)."""
    out = np.empty(cx.shape)
    for k in range(cx.size):
        x, y = float(cx.flat[k]), float(cy.flat[k])
        square = np.array([[x - 0.5, y - 0.5], [x + 0.5, y - 0.5], [x + 0.5, y + 0.5], [x - 0.5, y + 0.5]])
        s = square @ normal - offset
        kept = []
        for i in range(4):
            a, b, sa, sb = square[i], square[(i + 1) % 4], s[i], s[(i + 1) % 4]
            if sa >= 0:
                kept.append(a)
            if (sa >= 0) != (sb >= 0):
                kept.append(a + (b - a) * sa / (sa - sb))
        if len(kept) < 3:
            out.flat[k] = 0.0
            continue
        p = np.array(kept)
        out.flat[k] = 0.5 * abs(p[:, 0] @ np.roll(p[:, 1], -1) - p[:, 1] @ np.roll(p[:, 0], -1))
    return out


def _brute_force(camera: CameraModel, pose: Pose, texture, rows: slice, cols: slice, n: int,
                 background: float) -> np.ndarray:
    """n x n point samples per pixel, each undistorted exactly (Newton) and looked up in the texture."""
    hinv = np.linalg.inv(pose.plane_to_normalized_homography())
    offsets = (np.arange(n) + 0.5) / n - 0.5
    ys, xs = np.mgrid[rows, cols].astype(np.float64)
    acc = np.zeros(ys.shape)
    xmin, xmax, ymin, ymax = texture.bounds_m
    for dy in offsets:
        px = np.stack([xs[..., None] + offsets, np.broadcast_to(ys[..., None] + dy, xs.shape + (n,))],
                      axis=-1)
        q = camera.pixels_to_normalized(px) @ hinv[:, :2].T + hinv[:, 2]
        x, y = q[..., 0] / q[..., 2], q[..., 1] / q[..., 2]
        on = (q[..., 2] > 0) & (x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax)
        acc += np.where(on, texture.reflectance(x, y), background).sum(axis=-1)
    return acc / (n * n)


# ---------------------------------------------------------------------------------------------- helpers
def test_square_fraction_matches_polygon_clipping():
    rng = np.random.default_rng(1)
    angles = rng.uniform(0, 2 * np.pi, 200)
    t = rng.uniform(0, 0.8, 200)
    got = square_fraction_within(t, np.cos(angles), np.sin(angles), 1.0)
    normals = np.column_stack([np.cos(angles), np.sin(angles)])
    want = np.array([1.0 - _half_plane_area(np.zeros(1), np.zeros(1), nrm, tt)[0]
                     for nrm, tt in zip(normals, t, strict=True)])
    np.testing.assert_allclose(got, want, atol=1e-12)


def test_corner_map_bilinear_interpolation_error_below_1e4_px():
    cam = _frame((-0.1, 0.0, 0.0, 0.0, 0.0))
    cmap = corner_map(cam)
    assert cmap.shape == (cam.height + 1, cam.width + 1, 2)
    rng = np.random.default_rng(2)
    w, h = cam.width, cam.height
    px = np.column_stack([rng.uniform(-0.5, w - 0.5, 5000), rng.uniform(-0.5, h - 0.5, 5000)])
    px[:4] = [[-0.4, -0.4], [w - 0.6, -0.3], [-0.2, h - 0.7], [w - 0.6, h - 0.6]]  # the image corners
    j = np.floor(px[:, 0] + 0.5).astype(int)
    i = np.floor(px[:, 1] + 0.5).astype(int)
    u = px[:, 0] + 0.5 - j
    v = px[:, 1] + 0.5 - i
    interp = ((1 - u) * (1 - v))[:, None] * cmap[i, j] + (u * (1 - v))[:, None] * cmap[i, j + 1] \
        + ((1 - u) * v)[:, None] * cmap[i + 1, j] + (u * v)[:, None] * cmap[i + 1, j + 1]
    err_px = np.abs(interp - cam.pixels_to_normalized(px)).max() * F_PX
    assert err_px < 1e-4  # measured: 4.2e-5 px at the image corners (k1 = -0.1), 0 without distortion


# ---------------------------------------------------------------------------------------------- area
@pytest.mark.parametrize("levels", [1, 2])
@pytest.mark.parametrize("offset_px", [(0.0, 0.0), (0.25, -0.4), (0.5, 0.5), (-0.13, 0.37)])
@pytest.mark.parametrize("distance_m", [1.5, 5.0])
def test_dark_area_of_frontal_target(levels, offset_px, distance_m):
    spec = TargetSpec.default(5, 0.125, levels=levels)
    tex = TargetTexture(spec)
    t = np.array([offset_px[0] * distance_m / F_PX, offset_px[1] * distance_m / F_PX, distance_m])
    img = render_reflectance(_frame(), [Placement(Pose(np.eye(3), t), tex)], background=tex.white)
    dark_m2 = (1.0 - _unit(img)).sum() * (distance_m / F_PX) ** 2
    assert dark_m2 == pytest.approx(spec.dark_area_m2(), rel=1e-4)  # measured: < 4e-5 at 5 m, 2e-6 at 1.5 m


def test_dark_area_error_falls_with_supersampling():
    spec = TargetSpec.default(5, 0.125)
    tex = TargetTexture(spec)
    errors = []
    for ss in (1, 4, 16, 64):
        img = render_reflectance(_frame(), [Placement(Pose(np.eye(3), np.array([0.0, 0.0, 6.0])), tex)],
                                 background=tex.white, supersampling=ss)
        errors.append(abs((1.0 - _unit(img)).sum() * (6.0 / F_PX) ** 2 / spec.dark_area_m2() - 1.0))
    # measured: 5e-5, 7e-5, 1.9e-5, 8.7e-6 (small circles are refined whatever the setting)
    assert errors[3] < errors[1] / 4
    assert errors[2] < 5e-5


# ---------------------------------------------------------------------------------------------- edges
@pytest.mark.parametrize("roll_deg", [0.0, 10.0, 30.0, 45.0])
@pytest.mark.parametrize("shift", [0.0, 0.23, 0.5, 0.77])
def test_straight_edge_is_exact_area_fraction(roll_deg, shift):
    # Left half black, right half white; the edge is the target-plane line x = 0, rolled about the axis.
    tex = ImageTexture(np.array([[0.0, 1.0], [0.0, 1.0]]), size_m=0.6, margin_m=0.05)
    z = 2.0
    t = np.array([0.37 * shift * z / SMALL.fx, 0.61 * shift * z / SMALL.fy, z])
    theta = np.radians(roll_deg)
    pose = Pose(rotation_from_rotvec(np.array([0.0, 0.0, theta])), t)
    unit = _unit(render_reflectance(SMALL, [Placement(pose, tex)]))
    u0 = SMALL.project(t)
    normal = np.array([np.cos(theta), np.sin(theta)])  # image direction of target +x (toward white)
    ii, jj = np.mgrid[200:280, 280:360]
    near = np.abs((jj - u0[0]) * normal[0] + (ii - u0[1]) * normal[1]) < 2.0
    exact = _half_plane_area(jj[near].astype(float), ii[near].astype(float), normal, float(u0 @ normal))
    assert np.abs(unit[ii[near], jj[near]] - exact).max() < 0.01  # measured: 5e-11
    # White area along each row -> the edge's x at the row centre.
    for i in range(200, 280):
        x_edge = u0[0] - (i - u0[1]) * np.tan(theta)
        j_lo, j_hi = int(x_edge) - 5, int(x_edge) + 6
        assert j_hi + 0.5 - unit[i, j_lo:j_hi + 1].sum() == pytest.approx(x_edge, abs=0.01)  # measured: 1e-13


def test_sheet_border_is_where_projected_and_occludes():
    tex = TargetTexture(TargetSpec.default(2, 0.05))  # sheet: a 0.14 m square
    z = 1.0
    t = np.array([0.0123, -0.0071, z])
    img = render_reflectance(SMALL, [Placement(Pose(np.eye(3), t), tex)], background=0.3)
    u0 = SMALL.project(t)
    half_px = 0.07 * SMALL.fx / z
    # Along row 240 the left border: coverage = overlap of the pixel with [u0x - half, ...].
    j = np.arange(int(u0[0] - half_px) - 3, int(u0[0] - half_px) + 4)
    cover = np.clip(j + 0.5 - (u0[0] - half_px), 0.0, 1.0)
    np.testing.assert_allclose(img[240, j], 0.3 + (tex.white - 0.3) * cover, atol=1e-9)
    i = np.arange(int(u0[1] + half_px) - 3, int(u0[1] + half_px) + 4)
    cover = np.clip((u0[1] + half_px) - (i - 0.5), 0.0, 1.0)
    np.testing.assert_allclose(img[i, 320], 0.3 + (tex.white - 0.3) * cover, atol=1e-9)
    # A black sheet behind, listed first or last: the near one is composited over it with its coverage.
    far = Placement(Pose(np.eye(3), np.array([0.0, 0.0, 3.0])), ImageTexture(np.zeros((1, 1)), size_m=2.0))
    near = Placement(Pose(np.eye(3), t), tex)
    alpha = 1.0 - (render_reflectance(SMALL, [near], background=0.6) - img) / 0.3
    far_alone = render_reflectance(SMALL, [far], background=0.3)
    want = img - (1.0 - alpha) * 0.3 + (1.0 - alpha) * far_alone
    for order in ([near, far], [far, near]):
        np.testing.assert_allclose(render_reflectance(SMALL, order, background=0.3), want, atol=1e-12)
    assert np.count_nonzero((alpha > 0.01) & (alpha < 0.99)) > 100 and np.any(far_alone == tex.black)


@pytest.mark.parametrize("t", [[0.0, 0.0, -2.0], [3.0, 0.0, 2.0], [0.0, -2.5, 2.0], [0.0, 0.0, 1e-9]])
def test_target_behind_or_outside_renders_background(t):
    tex = TargetTexture(TargetSpec.default(2, 0.125))
    img = render_reflectance(SMALL, [Placement(Pose(np.eye(3), np.array(t)), tex)], background=0.3)
    assert np.all(img == 0.3)


def test_sheet_facing_away_edge_on_and_crossing_the_camera_plane():
    tex = TargetTexture(TargetSpec.default(2, 0.125))
    # Seen edge-on: no area at all, at most the border's hairline.
    edge_on = render_reflectance(
        SMALL, [Placement(Pose(look_rotation(90.0), np.array([0.0, 0.0, 1.0])), tex)], background=0.3)
    assert np.abs(edge_on - 0.3).sum() < 1e-6
    # A sheet through the camera plane (half in front): only its front part shows, no crash, values bounded.
    crossing = render_reflectance(
        SMALL, [Placement(Pose(look_rotation(80.0), np.array([0.0, 0.0, 0.01])), tex)], background=0.3)
    assert crossing.min() >= tex.black - 1e-12 and crossing.max() <= tex.white + 1e-12


# ---------------------------------------------------------------------------------------------- centroid
@pytest.mark.parametrize("offset_px", [(0.0, 0.0), (0.3, 0.45), (-0.27, 0.11)])
def test_dark_centroid_of_frontal_target(offset_px):
    z = 1.5
    t = np.array([0.2 + offset_px[0] * z / F_PX, -0.1 + offset_px[1] * z / F_PX, z])
    cam = _frame()
    # A plain ring: the centroid is the projected centre.
    ring = TargetTexture(TargetSpec(id=0, outer_radius_m=0.1, inner_radius_m=0.04))
    dark = 1.0 - _unit(render_reflectance(cam, [Placement(Pose(np.eye(3), t), ring)], background=ring.white))
    ys, xs = np.mgrid[0:cam.height, 0:cam.width]
    centroid = np.array([(dark * xs).sum(), (dark * ys).sum()]) / dark.sum()
    np.testing.assert_allclose(centroid, cam.project(t), atol=0.02)  # measured: < 1e-5 px
    # The full two-level target: code dots pull the centroid by an analytic amount.
    spec = TargetSpec.default(5, 0.125)
    tex = TargetTexture(spec)
    moment = np.zeros(2)
    for _, level in spec.levels():
        moment -= np.pi * level.code.dot_radius_m**2 * level.code.white_dot_centres_m().sum(axis=0)
    want = cam.project(t) + F_PX / z * moment / spec.dark_area_m2()
    dark = 1.0 - _unit(render_reflectance(cam, [Placement(Pose(np.eye(3), t), tex)], background=tex.white))
    centroid = np.array([(dark * xs).sum(), (dark * ys).sum()]) / dark.sum()
    np.testing.assert_allclose(centroid, want, atol=0.02)  # measured: < 5e-5 px


# ---------------------------------------------------------------------------------------------- distortion
def test_distorted_tilted_target_near_corner_matches_brute_force():
    cam = CameraModel(800, 600, 700.0, 700.0, 399.5, 299.5, dist=(-0.1, 0.0, 0.0, 0.0, 0.0))
    spec = TargetSpec(id=0, outer_radius_m=0.012, inner_radius_m=0.005)
    tex = TargetTexture(spec)
    z = 1.0
    pose = Pose(look_rotation(35.0, 20.0), np.array([-0.52, -0.37, z]))  # ~30 px from the top-left corner
    img = render_reflectance(cam, [Placement(pose, tex)], background=tex.white)
    rows, cols = np.nonzero(img != tex.white)
    assert rows.min() > 2 and cols.min() > 2 and rows.max() < 80 and cols.max() < 80
    r = slice(rows.min() - 2, rows.max() + 3)
    c = slice(cols.min() - 2, cols.max() + 3)
    ref = _brute_force(cam, pose, tex, r, c, 64, tex.white)
    fast = img[r, c]
    assert np.abs(_unit(fast) - _unit(ref)).max() < 0.01
    ys, xs = np.mgrid[r, c]
    w_fast, w_ref = 1.0 - _unit(fast), 1.0 - _unit(ref)
    c_fast = np.array([(w_fast * xs).sum(), (w_fast * ys).sum()]) / w_fast.sum()
    c_ref = np.array([(w_ref * xs).sum(), (w_ref * ys).sum()]) / w_ref.sum()
    np.testing.assert_allclose(c_fast, c_ref, atol=0.01)
    assert w_fast.sum() == pytest.approx(w_ref.sum(), rel=1e-3)


def test_full_target_tilted_distorted_matches_brute_force():
    # Two levels with code dots, small enough that the child's dots are ~0.3 px: every path of the renderer.
    cam = CameraModel(800, 600, 700.0, 700.0, 399.5, 299.5, dist=(-0.1, 0.0, 0.0, 0.0, 0.0))
    tex = TargetTexture(TargetSpec.default(5, 0.03))
    pose = Pose(look_rotation(50.0, 30.0, 15.0), np.array([0.45, 0.3, 1.5]))
    img = render_reflectance(cam, [Placement(pose, tex)], background=tex.white)
    rows, cols = np.nonzero(img != tex.white)
    r = slice(rows.min() - 2, rows.max() + 3)
    c = slice(cols.min() - 2, cols.max() + 3)
    ref = _brute_force(cam, pose, tex, r, c, 48, tex.white)
    w_fast, w_ref = 1.0 - _unit(img[r, c]), 1.0 - _unit(ref)
    assert np.abs(w_fast - w_ref).max() < 0.01  # measured: 0.004 against 64 x 64 samples
    assert w_fast.sum() == pytest.approx(w_ref.sum(), rel=5e-4)  # measured: 1.2e-4
    ys, xs = np.mgrid[r, c]
    c_fast = np.array([(w_fast * xs).sum(), (w_fast * ys).sum()]) / w_fast.sum()
    c_ref = np.array([(w_ref * xs).sum(), (w_ref * ys).sum()]) / w_ref.sum()
    np.testing.assert_allclose(c_fast, c_ref, atol=0.005)  # measured: 4e-4 px


# ---------------------------------------------------------------------------------------------- raster
@pytest.mark.parametrize("margin_m", [0.05, 0.0])
def test_checker_cells_render_at_projected_positions(margin_m):
    checker = (np.indices((6, 6)).sum(axis=0) % 2).astype(float)
    tex = ImageTexture(checker, size_m=0.3, margin_m=margin_m)
    z = 2.0
    t = np.array([0.0013, -0.0021, z])
    img = render_reflectance(SMALL, [Placement(Pose(np.eye(3), t), tex)], background=0.3)
    # Frontal and axis-aligned: a pixel's value is a sum of products of interval overlaps.
    scale = SMALL.fx / z
    u0 = SMALL.project(t)
    half = 0.15 + margin_m
    bounds = np.concatenate([[-half], -0.15 + 0.05 * np.arange(7), [half]])
    cell = np.pad(tex.black + (tex.white - tex.black) * checker, 1, constant_values=tex.white)

    def overlaps(centres, origin):
        lo, hi = origin + scale * bounds[:-1], origin + scale * bounds[1:]
        c = centres[:, None]
        return np.clip(np.minimum(c + 0.5, hi) - np.maximum(c - 0.5, lo), 0, None)

    ox = overlaps(np.arange(SMALL.width, dtype=float), u0[0])  # (W, 8)
    oy = overlaps(np.arange(SMALL.height, dtype=float), u0[1])  # (H, 8)
    want = oy @ cell @ ox.T + 0.3 * (1.0 - oy.sum(axis=1)[:, None] * ox.sum(axis=1)[None, :])
    np.testing.assert_allclose(img, want, atol=1e-9)


def test_rotated_tilted_checker_matches_brute_force():
    checker = (np.indices((6, 6)).sum(axis=0) % 2).astype(float)
    tex = ImageTexture(checker, size_m=0.3, margin_m=0.0)
    rotation = rotation_from_rotvec(np.array([0.3, 0.2, np.radians(20.0)]))
    pose = Pose(rotation, np.array([0.0013, -0.0021, 2.0]))
    img = render_reflectance(SMALL, [Placement(pose, tex)], background=0.3)
    r, c = slice(170, 230), slice(150, 210)  # holds cell corners (junctions) and edges
    ref = _brute_force(SMALL, pose, tex, r, c, 48, 0.3)
    err = np.abs(img[r, c] - ref) / (tex.white - tex.black)
    assert err.max() < 0.01  # measured: < 0.004, the brute force's own resolution (1/96)
    assert np.count_nonzero((ref > tex.black + 0.01) & (ref < tex.white - 0.01)) > 100  # edges were seen


def test_supersampling_must_be_a_square():
    with pytest.raises(ValueError, match="perfect square"):
        render_reflectance(SMALL, [], supersampling=10)


class _PlainTexture:
    """A texture with only the basic protocol (no edge information): the renderer point-samples it."""

    def __init__(self, inner: TargetTexture) -> None:
        self.inner = inner
        self.bounds_m = inner.bounds_m

    def reflectance(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        return self.inner.reflectance(x_m, y_m)


def test_texture_without_edge_information_is_point_sampled():
    spec = TargetSpec.default(5, 0.125)
    tex = TargetTexture(spec)
    pose = Pose(look_rotation(25.0, 10.0), np.array([0.01, 0.02, 3.0]))
    exact = render_reflectance(SMALL, [Placement(pose, tex)], background=0.3)
    plain = render_reflectance(SMALL, [Placement(pose, _PlainTexture(tex))], background=0.3, supersampling=64)
    # 8 x 8 point samples: a pixel is off by at most ~1/8 of the contrast, the sum by far less.
    assert np.abs(plain - exact).max() < (tex.white - tex.black) / 8
    assert plain.sum() == pytest.approx(exact.sum(), rel=1e-5)
    assert np.count_nonzero(plain != exact) > 100  # the sampled path really ran
