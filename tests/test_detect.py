"""Coarse detection: synthetic renders with known truth, degenerate images, real photos of our targets and of
other ring markers."""


import cv2
import numpy as np
import pytest

from livetrack.estimator.circle_pose import fit_conic, projected_centre
from livetrack.estimator.conics import Ellipse
from livetrack.estimator.detect import Candidate, Detector, detect, full_scale
from livetrack.estimator.detect.code import _shortlist
from livetrack.estimator.detect.pairs import _contours
from livetrack.estimator.detect.threshold import _noise, _normalise, _WorkImages
from livetrack.estimator.target_map import centre_homography
from livetrack.geometry import rotation_from_rotvec
from livetrack.targets import codebook
from livetrack.targets.spec import CodeSpec, TargetSpec, load_targets
from tests.realdata import read_photo, realdata_dir, target_photos

BOOK = [TargetSpec.default(i, 0.1) for i in range(len(codebook.code_book()))]
F_PX = 800.0


# ---------------------------------------------------------------------- synthetic images
def homography(shape, radius_px, at, tilt_deg=0.0, tilt_axis_deg=0.0, roll_deg=0.0, outer_radius_m=0.1):
    """Target plane (metres) -> pixels, for a pinhole camera (f = F_PX, centre of the image) looking at a target
    rotated by ``roll_deg`` in its plane, then tilted by ``tilt_deg`` about an in-plane axis; its centre images
    at ``at`` and its outer radius is about ``radius_px`` pixels."""
    h, w = shape
    cx, cy = (w - 1) / 2, (h - 1) / 2
    z = F_PX * outer_radius_m / radius_px
    axis = np.deg2rad(tilt_axis_deg)
    R = rotation_from_rotvec(np.deg2rad(tilt_deg) * np.array([np.cos(axis), np.sin(axis), 0.0])) @ \
        rotation_from_rotvec(np.array([0.0, 0.0, np.deg2rad(roll_deg)]))
    t = np.array([(at[0] - cx) * z / F_PX, (at[1] - cy) * z / F_PX, z])
    K = np.array([[F_PX, 0, cx], [0, F_PX, cy], [0, 0, 1.0]])
    H = K @ np.column_stack([R[:, 0], R[:, 1], t])
    return H / H[2, 2]


def project(H, pts):
    p = np.column_stack([pts, np.ones(len(pts))]) @ H.T
    return p[:, :2] / p[:, 2:]


def true_heading(H):
    p = project(H, np.array([[0.0, 0.0], [1e-5, 0.0]]))
    return float(np.arctan2(*(p[1] - p[0])[::-1]))


def angle_diff_deg(a, b):
    return abs((np.rad2deg(a - b) + 180.0) % 360.0 - 180.0)


def render(shape, items, ss=4, sigma=1.0, black=0.08, white=0.85, gain=1.0, offset=0.0, noise=0.004,
           background=0.3, sheet=1.5, full=255, dtype=np.uint8, seed=0):
    """Image of targets ``items`` = [(spec, H)] on square white sheets (half side ``sheet`` R) over a grey
    background: supersampled reflectance, Gaussian PSF (sigma px), levels, exposure (gain, offset), clipping
    to [0, 1], noise, quantisation to ``full``."""
    h, w = shape
    refl = np.full((h, w), background)
    for spec, H in items:
        half = spec.outer_radius_m * sheet
        corners = project(H, np.array([[-half, -half], [half, -half], [half, half], [-half, half]]))
        x0, y0 = np.maximum(np.floor(corners.min(axis=0)).astype(int) - 1, 0)
        x1, y1 = np.minimum(np.ceil(corners.max(axis=0)).astype(int) + 2, [w, h])
        if x1 <= x0 or y1 <= y0:
            continue
        ys, xs = np.mgrid[y0 * ss : y1 * ss, x0 * ss : x1 * ss]
        q = np.stack([(xs + 0.5) / ss - 0.5, (ys + 0.5) / ss - 0.5, np.ones(xs.shape)], axis=-1) @ \
            np.linalg.inv(H).T
        X, Y = q[..., 0] / q[..., 2], q[..., 1] / q[..., 2]
        on_sheet = (np.abs(X) <= half) & (np.abs(Y) <= half)
        value = np.where(on_sheet, spec.reflectance(X, Y), np.nan).reshape(y1 - y0, ss, x1 - x0, ss)
        below = np.broadcast_to(refl[y0:y1, x0:x1][:, None, :, None], value.shape)
        refl[y0:y1, x0:x1] = np.where(np.isnan(value), below, value).mean(axis=(1, 3))
    if sigma > 0:
        refl = cv2.GaussianBlur(refl, (0, 0), sigma)
    intensity = np.clip(gain * (black + (white - black) * refl) + offset, 0.0, 1.0)
    intensity = intensity + noise * np.random.default_rng(seed).standard_normal(intensity.shape)
    return np.clip(np.round(intensity * full), 0, full).astype(dtype)


def level0(cands):
    return [c for c in cands if c.level == 0]


# ---------------------------------------------------------------------- identity, heading, geometry
@pytest.mark.parametrize("target_id", [0, 5, 9, 13])
@pytest.mark.parametrize("tilt_deg", [0.0, 25.0, 50.0])
def test_id_and_heading_over_tilt_and_roll(target_id, tilt_deg):
    shape = (360, 480)
    for roll_deg in (17.0 + 61.0 * target_id, 200.0 - 37.0 * target_id):
        H = homography(shape, 40.0, (250, 170), tilt_deg, tilt_axis_deg=30.0 * target_id, roll_deg=roll_deg)
        cands = detect(render(shape, [(BOOK[target_id], H)]), BOOK)
        # The nested level (8 px here) may be found too, as itself.
        assert [(c.target_id, c.level) for c in cands if c.level == 0] == [(target_id, 0)]
        assert all((c.target_id, c.level) == (target_id, 1) for c in cands[1:])
        c = cands[0]
        assert isinstance(c, Candidate) and c.spec is BOOK[target_id]
        assert c.code_margin >= 1.5
        assert c.code_values.shape == (8,) and np.all((c.code_values >= 0) & (c.code_values <= 1))
        assert angle_diff_deg(c.heading_rad, true_heading(H)) < 4.0
        # rotation_slots: the heading seen from the image +x direction, in slots (perspective: +-1).
        slots = np.rad2deg(c.heading_rad) / 45.0
        assert min(abs((c.rotation_slots - slots) % 8), abs((slots - c.rotation_slots) % 8)) < 1.0
        # Ellipses: the images of the two circles (mid-level threshold, pixel-accurate here).
        t = np.linspace(0, 2 * np.pi, 90, endpoint=False)
        for ellipse, radius in ((c.outer, 0.1), (c.inner, 0.04)):
            circle = project(H, radius * np.column_stack([np.cos(t), np.sin(t)]))
            assert np.max(np.abs(ellipse.sampson_distance(circle))) < 0.6
        assert c.white_level > c.black_level + 100


@pytest.mark.parametrize("target_id, roll_deg", [(1, 0.0), (6, 100.0), (12, 222.0)])
def test_heading_under_strong_perspective(target_id, roll_deg):
    """Close and tilted 55 degrees: the ellipse centres are ~17 px off the imaged centre; the homography from
    the two concentric ellipses still samples the code in the right place."""
    shape = (480, 640)
    H = homography(shape, 170.0, (320, 240), 55.0, 20.0 * target_id, roll_deg)
    c, = level0(detect(render(shape, [(BOOK[target_id], H)]), BOOK))
    assert np.linalg.norm(c.outer.centre_px - project(H, np.zeros((1, 2)))[0]) > 10.0
    assert c.target_id == target_id and angle_diff_deg(c.heading_rad, true_heading(H)) < 2.0


@pytest.mark.parametrize("target_id", [0, 5, 13])
def test_small_targets(target_id):
    shape = (160, 200)
    for radius_px, tilt_deg in ((10.0, 0.0), (12.0, 30.0)):
        H = homography(shape, radius_px, (100, 80), tilt_deg, 30.0, 10.0 + 40.0 * target_id)
        c, = detect(render(shape, [(BOOK[target_id], H)], sigma=0.9), BOOK)
        assert c.target_id == target_id and angle_diff_deg(c.heading_rad, true_heading(H)) < 5.0


def test_frontal_geometry_and_levels():
    shape = (240, 320)
    H = homography(shape, 60.0, (150.3, 130.8), roll_deg=-30.0)
    c, = level0(detect(render(shape, [(BOOK[7], H)], black=0.1, white=0.9, noise=0.0), BOOK))
    assert np.allclose(c.outer.centre_px, [150.3, 130.8], atol=0.1)
    assert c.outer.a == pytest.approx(60.0, abs=0.5) and c.outer.b == pytest.approx(60.0, abs=0.5)
    assert c.inner.a == pytest.approx(24.0, abs=0.5)
    assert c.black_level == pytest.approx(0.1 * 255, abs=6) and c.white_level == pytest.approx(0.9 * 255, abs=6)
    assert c.rotation_slots == 7  # -30 degrees is closest to slot 7 (-45)
    assert angle_diff_deg(c.heading_rad, np.deg2rad(-30.0)) < 1.0


def test_two_targets_in_one_image():
    shape = (400, 640)
    H1 = homography(shape, 45.0, (160, 200), 30.0, 10.0, 80.0)
    H2 = homography(shape, 70.0, (470, 190), 20.0, 100.0, -120.0)
    cands = level0(detect(render(shape, [(BOOK[2], H1), (BOOK[11], H2)]), BOOK))
    assert sorted(c.target_id for c in cands) == [2, 11]
    for c, H in zip(sorted(cands, key=lambda c: c.target_id), (H1, H2), strict=True):
        assert np.linalg.norm(c.outer.centre_px - project(H, np.zeros((1, 2)))[0]) < 3.0
        assert angle_diff_deg(c.heading_rad, true_heading(H)) < 4.0


def test_only_configured_codes_are_reported():
    shape = (240, 320)
    image = render(shape, [(BOOK[3], homography(shape, 50.0, (160, 120), 20.0))])
    assert detect(image, [BOOK[0], BOOK[1], BOOK[2], BOOK[4]]) == []
    assert [c.target_id for c in level0(detect(image, [BOOK[3]]))] == [3]
    assert detect(image, []) == []


def test_symmetric_code_gives_no_heading():
    R = 0.08
    spec = TargetSpec(1, R, 0.4 * R, CodeSpec(8, 0.7 * R, 0.1 * R, "11111111"), centre_dot_radius_m=0.001)
    shape = (240, 320)
    H = homography(shape, 50.0, (160, 120), 35.0, 60.0, 10.0, outer_radius_m=R)
    c, = detect(render(shape, [(spec, H)]), [spec] + BOOK)
    assert c.target_id == 1 and c.rotation_slots is None and c.heading_rad is None


# ---------------------------------------------------------------------- dtype and exposure
@pytest.mark.parametrize("kind", ["uint16-12bit", "uint16-full", "float"])
def test_high_bit_depth_and_float_images(kind):
    shape = (300, 400)
    H = homography(shape, 35.0, (210, 140), 40.0, 20.0, 70.0)
    if kind == "float":
        image = render(shape, [(BOOK[6], H)], full=1000, dtype=np.float64) / 1000.0
        cands = detect(image, BOOK)
    else:
        full = 4095 if kind == "uint16-12bit" else 65535
        image = render(shape, [(BOOK[6], H)], full=full, dtype=np.uint16)
        cands = detect(image, BOOK, saturation=full)
    c, = level0(cands)
    assert c.target_id == 6 and angle_diff_deg(c.heading_rad, true_heading(H)) < 4.0
    assert c.black_level < 0.2 * image.max() < c.white_level


@pytest.mark.parametrize("dtype, full", [(np.uint8, 255), (np.uint16, 4095)])
def test_over_and_underexposed_4x(dtype, full):
    """White clipped at 4x exposure: the ring looks thinner; black clipped at 1/4: thicker. Both detected."""
    shape = (300, 400)
    H = homography(shape, 45.0, (200, 150), 30.0, 45.0, 33.0)
    ratios = {}
    for name, kw in {"normal": {}, "over": {"gain": 4.0}, "under": {"gain": 0.25, "offset": -0.06}}.items():
        image = render(shape, [(BOOK[10], H)], sigma=1.2, full=full, dtype=dtype, **kw)
        if name == "over":
            assert np.mean(image == full) > 0.3  # really clipped
        c, = level0(detect(image, BOOK, saturation=full))
        assert c.target_id == 10 and angle_diff_deg(c.heading_rad, true_heading(H)) < 5.0
        ratios[name] = c.inner.a / c.outer.a
    assert ratios["over"] > ratios["normal"] + 0.01 > ratios["under"] + 0.02


# ---------------------------------------------------------------------- any scene: no global statistics
def found_ids(cands):
    return sorted(c.target_id for c in level0(cands))


@pytest.mark.parametrize("dtype, full", [(np.uint8, 255), (np.uint16, 4095), (np.uint16, 65535)])
@pytest.mark.parametrize("radius_px", [22.0, 40.0])
def test_small_target_in_a_frame_saturated_but_for_its_ring(dtype, full, radius_px):
    """Paper and background clip, only the black ring (and code gaps) stay below saturation; the ring's dark
    pixels are far fewer than 0.5 % of the frame, which left a stretch between global percentiles nothing."""
    shape = (1200, 1600)
    H = homography(shape, radius_px, (830, 580), 25.0, 40.0, 15.0)
    image = render(shape, [(BOOK[7], H)], sigma=0.9, black=0.02, white=0.55, background=0.9, gain=8.0,
                   noise=0.003, full=full, dtype=dtype)
    dark = image < 0.9 * full
    assert dark.mean() < 0.005 and np.mean(image >= 0.98 * full) > 0.95
    assert found_ids(detect(image, BOOK, saturation=full)) == [7]


def test_a_dark_patch_elsewhere_changes_nothing():
    """Every decision is local: a black patch far from the target leaves its detection (ellipses, code) as it
    was."""
    shape = (600, 800)
    H = homography(shape, 35.0, (250, 300), 30.0, 10.0, 5.0)
    image = render(shape, [(BOOK[2], H)], sigma=0.9, black=0.02, white=0.55, background=0.9, gain=4.0,
                   full=4095, dtype=np.uint16)
    patched = image.copy()
    patched[20:120, 600:780] = 30
    a, b = (level0(detect(im, BOOK, saturation=4095)) for im in (image, patched))
    assert [c.target_id for c in a] == [c.target_id for c in b] == [2]
    assert np.allclose(a[0].outer.centre_px, b[0].outer.centre_px) and np.allclose(a[0].code_values, b[0].code_values)


@pytest.mark.parametrize("background", [0.0, 0.2, 0.6, 1.0])
def test_every_exposure_on_every_background(background):
    """x0.25 to x16 of nominal (paper at 55 % of full scale; ink at 2 % of it keeps its ring visible up to
    x16), on black to white backgrounds around the target's sheet."""
    shape = (480, 640)
    H = homography(shape, 30.0, (300, 250), 35.0, 120.0, 40.0)
    for gain in (0.25, 1.0, 4.0, 16.0):
        image = render(shape, [(BOOK[9], H)], sigma=0.9, black=0.01, white=0.55, background=background,
                       gain=gain, noise=0.002, full=4095, dtype=np.uint16, sheet=1.4)
        assert found_ids(detect(image, BOOK, saturation=4095)) == [9], f"x{gain}"


def test_illumination_gradient_and_several_targets():
    """A strong illumination gradient (x0.15 on the left to x3 on the right, clipped) over a textured
    background and three targets at different exposures along it: all three, nothing else."""
    shape = (600, 900)
    rng = np.random.default_rng(5)
    items = [(BOOK[i], homography(shape, r, at, tilt, 30.0 * i, 50.0 * i))
             for i, r, at, tilt in ((1, 40.0, (150, 300), 20.0), (6, 28.0, (450, 200), 45.0),
                                    (11, 55.0, (720, 380), 10.0))]
    image = render(shape, items, sigma=0.9, black=0.02, white=0.55, background=0.5, noise=0.0, full=4095,
                   dtype=np.float64) / 4095
    texture = cv2.resize(rng.uniform(0.6, 1.0, (60, 90)), (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR)
    sheets = np.zeros(shape, bool)
    for _, H in items:
        corner = project(H, np.array([[-0.15, -0.15], [0.15, -0.15], [0.15, 0.15], [-0.15, 0.15]]))
        cv2.fillConvexPoly(sheets.view(np.uint8), np.round(corner).astype(np.int32), 1)
    image = np.where(sheets, image, image * texture)
    gradient = np.geomspace(0.15, 3.0, shape[1])[None, :]
    image = np.clip(image * gradient + rng.normal(0, 0.002, shape), 0, 1)
    image = np.round(image * 4095).astype(np.uint16)
    assert found_ids(detect(image, BOOK, saturation=4095)) == [1, 6, 11]


def test_textured_scenes_without_targets_give_nothing():
    """Multi-scale noise, blotches and printed text, 8 and 12 bit, dark to over-exposed: no target."""
    rng = np.random.default_rng(11)
    shape = (480, 640)
    for k in range(9):
        base = np.zeros(shape, np.float32)
        for scale in (2, 5, 13, 40):
            small = rng.random((shape[0] // scale + 1, shape[1] // scale + 1)).astype(np.float32)
            base += cv2.resize(small, shape[::-1], interpolation=cv2.INTER_CUBIC) * rng.uniform(0.2, 1.0)
        base = (base - base.min()) / (base.max() - base.min())
        if k % 3 == 1:
            base = (base > 0.5).astype(np.float32) * 0.9 + 0.05
        elif k % 3 == 2:
            text = np.full(shape, 230, np.uint8)
            for _ in range(200):
                at = (int(rng.integers(0, 640)), int(rng.integers(0, 480)))
                cv2.putText(text, f"Oo0@{int(rng.integers(100))}", at, cv2.FONT_HERSHEY_SIMPLEX,
                            float(rng.uniform(0.3, 2.0)), 12, int(rng.integers(1, 4)))
            base = text.astype(np.float32) / 255
        gain = (0.25, 1.0, 4.0)[k % 3 if k < 3 else (k + 1) % 3]
        image = np.clip(cv2.GaussianBlur(base, (0, 0), 0.8) * gain + rng.normal(0, 0.005, shape), 0, 1)
        image = np.round(image * 4095).astype(np.uint16) if k % 2 else np.round(image * 255).astype(np.uint8)
        assert detect(image, BOOK) == []


@pytest.mark.parametrize("tilt_deg", [60.0, 70.0])
def test_strong_tilt(tilt_deg):
    shape = (480, 640)
    for axis in (0.0, 70.0, 135.0):
        H = homography(shape, 90.0, (320, 240), tilt_deg, axis, 25.0)
        image = render(shape, [(BOOK[12], H)], sigma=0.9, full=4095, dtype=np.uint16)
        assert found_ids(detect(image, BOOK, saturation=4095)) == [12]


# ---------------------------------------------------------------------- fractal levels, border, roi
def test_child_level_detected_when_large():
    shape = (700, 760)
    H = homography(shape, 300.0, (380, 350), 15.0, 30.0, 50.0)
    cands = detect(render(shape, [(BOOK[4], H)], sheet=1.2), BOOK)
    assert [(c.target_id, c.level) for c in cands] == [(4, 0), (4, 1)]
    parent, child = cands
    assert child.spec is BOOK[4].child and parent.spec is BOOK[4]
    assert child.outer.a == pytest.approx(0.2 * parent.outer.a, rel=0.05)
    assert np.linalg.norm(child.outer.centre_px - parent.inner.centre_px) < 0.05 * parent.inner.a
    assert angle_diff_deg(child.heading_rad, parent.heading_rad) < 5.0


def test_large_target_refined_on_a_coarser_level_keeps_pixel_coordinates():
    """R = 520 px is refined on pyramid level 2: the centre and radius must still be exact in full-size pixels
    (pyrDown maps level pixel x to full-size pixel 2 x)."""
    shape = (1100, 1100)
    at = (550.3, 549.6)
    c = level0(detect(render(shape, [(BOOK[3], homography(shape, 520.0, at, roll_deg=20.0))], sheet=1.15, ss=2),
                      BOOK))[0]
    assert np.allclose(c.outer.centre_px, at, atol=0.1)
    assert c.outer.a == pytest.approx(520.0, abs=0.5) and c.inner.a == pytest.approx(208.0, abs=0.5)


def test_child_alone_is_level_one():
    """Only the nested target fits in the image: the parent's black annulus around it sets the level."""
    shape = (400, 400)
    H = homography(shape, 300.0, (200, 200))  # child radius 60 px, the parent's outer edge out of the frame
    cands = detect(render(shape, [(BOOK[8], H)], sheet=1.2), BOOK)
    assert [(c.target_id, c.level) for c in cands] == [(8, 1)]


@pytest.mark.parametrize("background", [0.9, 1.0])
@pytest.mark.parametrize("gain", [0.25, 1.0])
def test_small_targets_on_a_ground_as_bright_as_their_sheet(background, gain):
    """11-13 px targets on a ground as bright as their sheet (text, bright noise, white): the nested level and
    the blur leave the inner disk grey, so against its window's mean the whole target reads dark and its blob
    has no usable hole. Found from the blob's own threshold (``refine._small_blob_pair``); the detector of
    2026-12-01 found 0 of these 12 at x0.25 and x1."""
    shape = (160, 200)
    found = []
    for tid in (0, 5, 12, 13):
        for radius_px, tilt_deg in ((11.0, 0.0), (12.5, 30.0), (13.0, 45.0)):
            H = homography(shape, radius_px, (100, 80), tilt_deg, 30.0, 10.0 + 40.0 * tid)
            image = render(shape, [(BOOK[tid], H)], sigma=1.0, background=background, gain=gain, sheet=2.0,
                           seed=tid)
            ids = [(c.target_id, c.level) for c in detect(image, BOOK)]
            assert ids in ([], [(tid, 0)])  # never a wrong id or level
            found.append(ids == [(tid, 0)])
    assert sum(found) >= 11, found


def test_small_targets_at_x16_whose_ring_is_cut_into_arcs():
    """14-21 px at x16 on a bright ground: the grown dots cut the ring into arcs and join the inner disk to the
    ground (no blob with a hole anywhere). The arcs' neighbourhood closed on a crop (``arc_pairs._pairs_of_arcs``)
    makes the ring whole again. The detector of 2026-12-01 found 9 of these 15."""
    shape = (160, 200)
    found = []
    for tid in (1, 3, 5, 8, 12):
        for radius_px, tilt_deg in ((14.0, 0.0), (17.0, 30.0), (21.0, 30.0)):
            H = homography(shape, radius_px, (100, 80), tilt_deg, 30.0, 10.0 + 40.0 * tid)
            image = render(shape, [(BOOK[tid], H)], sigma=1.0, background=0.9, gain=16.0, black=0.019, white=0.55,
                           sheet=2.0, seed=tid, noise=0.003)
            ids = [(c.target_id, c.level) for c in detect(image, BOOK)]
            assert ids in ([], [(tid, 0)])
            found.append(ids == [(tid, 0)])
    assert sum(found) >= 13, found


def test_pair_ratio_allows_an_exposure_shift_of_a_tenth_of_the_radius():
    """At x32 with a 3 % halo a 58 px target's pair read r/R = 0.53 for 0.4 (each edge 0.085 R into the black):
    beyond the 2.5 px bias, within the shift the code reader handles (``code._as_seen``)."""
    from livetrack.estimator.detect.code import MAX_EXPOSURE_SHIFT
    from livetrack.estimator.detect.pairs import _ratio_ok

    outer = Ellipse(np.array([100.0, 100.0]), np.array([52.4, 51.4]), 0.3)
    for seen, ok in ((0.537, True), (0.40, True), (0.30, True), (0.65, False), (0.22, False)):
        inner = Ellipse(outer.centre_px, outer.semi_axes_px * seen, 0.3)
        assert _ratio_ok(outer, inner, 0.4, 3.0, 0.1, MAX_EXPOSURE_SHIFT) is ok, seen
    assert not _ratio_ok(outer, Ellipse(outer.centre_px, outer.semi_axes_px * 0.537, 0.3), 0.4, 3.0, 0.1)


@pytest.mark.parametrize("tid", [3, 5, 9])
def test_ring_cut_into_arcs_by_grown_dots_at_x32(tid):
    """x32 on a bright ground, 28 px, tilted 30 deg: the grown dots join the inner disk and the outside, the ring is
    arcs (no contour with a hole; the code's black bands are white). Found with its id, as the outer level."""
    shape = (200, 220)
    H = homography(shape, 28.0, (110, 100), 30.0, 20.0, 15.0 * tid)
    image = render(shape, [(BOOK[tid], H)], sheet=2.0, gain=32.0, black=0.019, white=0.55, background=0.9,
                   sigma=1.0, noise=0.003)
    assert [(c.target_id, c.level) for c in detect(image, BOOK)] == [(tid, 0)]


def _clipped_right(tid, roll_deg=30.0, smudge_code=False):
    """A 150 px target lit ever more strongly to the right (gain 1 to 16, 16-bit): its black ring clips to white on
    the right, so the outer level is no pair any more while its nested level (28 px) stays clear. ``smudge_code``:
    the outer level's code ring (0.55-0.85 R) painted mid-grey, its dots unreadable."""
    shape = (500, 560)
    H = homography(shape, 150.0, (280, 250), 20.0, 10.0, roll_deg)
    img = render(shape, [(BOOK[tid], H)], sheet=1.3, full=65535, dtype=np.float64, noise=0.002)
    gain = np.linspace(1.0, 16.0, shape[1])[None, :]
    img = np.clip(img * gain, 0, 65535)
    if smudge_code:
        ys, xs = np.mgrid[0 : shape[0], 0 : shape[1]]
        q = np.stack([xs, ys, np.ones(xs.shape)], axis=-1) @ np.linalg.inv(H).T
        r = np.hypot(q[..., 0] / q[..., 2], q[..., 1] / q[..., 2]) / BOOK[tid].outer_radius_m
        grey = 0.5 * (0.08 * gain + np.minimum(0.85 * gain, 1.0)) * 65535  # half-way between black and white
        img = np.where((r > 0.55) & (r < 0.85), np.broadcast_to(grey, img.shape), img)
    return img.astype(np.uint16), H


@pytest.mark.parametrize("tid", [1, 3, 5])
@pytest.mark.parametrize("roll_deg", [0.0, 135.0, 270.0])
def test_child_alone_is_level_one_when_its_parent_clips_on_one_side(tid, roll_deg):
    """The parent's code, read slot by slot against its own bands where they are not clipped, sets the level
    (taken for the outer level, the nested one gave a distance 5x too large)."""
    image, _ = _clipped_right(tid, roll_deg)
    assert [(c.target_id, c.level, c.level_ambiguous) for c in detect(image, BOOK)] == [(tid, 1, False)]


def test_child_whose_parent_code_is_unreadable_is_ambiguous_and_reported():
    """Parent-like surroundings whose code cannot be read: the level is ambiguous; the tracker reports a failure
    (stage "level") rather than a pose that may be 5x off."""
    from livetrack.camera import CameraModel
    from livetrack.estimator.tracker import Tracker

    image, _ = _clipped_right(3, smudge_code=True)
    cands = detect(image, BOOK)
    assert [(c.target_id, c.level, c.level_ambiguous) for c in cands] == [(3, 0, True)]
    camera = CameraModel(560, 500, F_PX, F_PX, 279.5, 249.5, bit_depth=16)
    out = Tracker(camera, BOOK).process(image)
    assert out.targets == []
    assert [(f.target_id, f.stage) for f in out.failures] == [(3, "level")]
    assert "x5" in out.failures[0].reason


@pytest.mark.parametrize("background", ["black", "noise"])
def test_small_target_on_a_large_sheet_over_dark_ground_is_level_zero(background):
    """A white sheet (half side 2.2 R) on dark or textured ground around a lone small target looks like a parent's
    white disk and dark annulus: the dots missing where the parent would have them refute it."""
    shape = (300, 320)
    items = [(BOOK[tid], homography(shape, 30.0, at, 20.0, 40.0 * tid)) for tid, at in ((3, (90, 150)),
                                                                                        (5, (230, 150)))]
    image = render(shape, items, sheet=2.2, background=0.0)
    if background == "noise":
        rng = np.random.default_rng(4)
        texture = cv2.resize(rng.uniform(0, 255, (30, 32)), (320, 300), interpolation=cv2.INTER_NEAREST)
        sheets = render(shape, items, sheet=2.2, background=0.0, black=1.0, white=1.0, noise=0.0) > 0
        image = np.where(sheets, image, texture.astype(np.uint8))
    assert sorted((c.target_id, c.level) for c in detect(image, BOOK)) == [(3, 0), (5, 0)]


def test_trace_records_each_stage():
    """``detect(trace=...)``: the pair, its code and the candidate of a found target; the blobs of a texture."""
    shape = (200, 220)
    H = homography(shape, 30.0, (110, 100), 20.0, 0.0, 0.0)
    image = render(shape, [(BOOK[5], H)])
    trace = []
    cands = Detector(BOOK).detect(image, trace=trace)
    assert [c.target_id for c in cands] == [5]
    stages = {e.stage for e in trace}
    assert {"pair", "candidate"} <= stages
    candidate = [e for e in trace if e.stage == "candidate"]
    assert candidate[0].detail == "id 5 level 0" and np.hypot(candidate[0].centre_px[0] - 110,
                                                              candidate[0].centre_px[1] - 100) < 1.0
    assert Detector(BOOK).detect(image) == [] or [c.target_id for c in Detector(BOOK).detect(image)] == [5]
    # A ring without code dots: a pair whose code fails, with the reason.
    blank = TargetSpec(id=77, outer_radius_m=0.1, inner_radius_m=BOOK[5].inner_radius_m)
    trace = []
    assert Detector(BOOK).detect(render(shape, [(blank, H)]), trace=trace) == []
    codes = [e for e in trace if e.stage == "code"]
    assert codes and all(e.detail for e in codes)


@pytest.mark.parametrize("at", [(12, 150), (200, 8), (388, 140), (220, 292), (-20, -20)])
def test_target_cut_by_the_border_is_rejected(at):
    shape = (300, 400)
    image = render(shape, [(BOOK[3], homography(shape, 40.0, at))])
    assert detect(image, BOOK) == []


def test_border_margin():
    shape = (200, 200)
    image = render(shape, [(BOOK[3], homography(shape, 40.0, (45, 100)))], sigma=0.7)  # outer edge ~4.5 px in
    assert len(level0(detect(image, BOOK, border_margin_px=2.0))) == 1
    # The outer level is rejected; its nested level (8 px, well inside) may still be found, as level 1.
    assert [(c.target_id, c.level) for c in detect(image, BOOK, border_margin_px=10.0)] in ([], [(3, 1)])


def test_roi_limits_the_search_and_keeps_image_coordinates():
    shape = (300, 600)
    H1, H2 = homography(shape, 40.0, (130, 150)), homography(shape, 40.0, (450, 150))
    image = render(shape, [(BOOK[1], H1), (BOOK[12], H2)])
    assert sorted(c.target_id for c in detect(image, BOOK)) == [1, 12]
    c, = detect(image, BOOK, roi=(360, 60, 560, 250))
    assert c.target_id == 12
    assert np.allclose(c.outer.centre_px, [450, 150], atol=0.5)
    assert detect(image, BOOK, roi=(200, 0, 380, 300)) == []
    assert detect(image, BOOK, roi=(500, 500, 600, 600)) == []  # empty after clipping


def test_min_outer_radius():
    shape = (240, 320)
    image = render(shape, [(BOOK[9], homography(shape, 25.0, (160, 120)))])
    assert len(detect(image, BOOK)) == 1
    assert detect(image, BOOK, min_outer_radius_px=40.0) == []


# ---------------------------------------------------------------------- degenerate images
@pytest.mark.parametrize("image", [
    np.zeros((480, 640), np.uint8),
    np.full((480, 640), 255, np.uint8),
    np.full((480, 640), 4095, np.uint16),
    np.zeros((5, 5), np.uint8),
    np.zeros((1, 1000), np.uint8),
    np.random.default_rng(0).integers(0, 256, (37, 23)).astype(np.uint8),
    np.random.default_rng(1).integers(0, 256, (333, 517)).astype(np.uint8),
    np.random.default_rng(2).normal(100, 3, (481, 641)).astype(np.float32),
    np.full((100, 100), np.nan, np.float64),
    np.zeros((0, 0), np.uint8),
    np.ones((64, 64), bool),
])
def test_degenerate_images_give_nothing(image):
    assert detect(image, BOOK) == []
    assert detect(image, BOOK, saturation=255.0) == []


def test_bad_shape_raises():
    with pytest.raises(ValueError):
        detect(np.zeros((10, 10, 3), np.uint8), BOOK)


@pytest.mark.parametrize("inner_scale", [0.4, 1.0, 1e-6])
def test_centre_homography_maps_the_unit_circle_onto_the_outer_ellipse(inner_scale):
    """Also for degenerate pairs (identical or vanishing inner ellipse): then the affine map, no exception."""
    outer = Ellipse(np.array([100.0, 50.0]), np.array([40.0, 25.0]), 0.3)
    H = centre_homography(outer, outer.scaled(inner_scale))
    t = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    on_circle = project(H, np.column_stack([np.cos(t), np.sin(t)]))
    assert np.all(np.isfinite(H)) and np.max(np.abs(outer.sampson_distance(on_circle))) < 1e-6
    x_axis = project(H, np.array([[0.0, 0.0], [0.5, 0.0]]))
    assert abs(x_axis[1, 1] - x_axis[0, 1]) < 1e-9 and x_axis[1, 0] > x_axis[0, 0]  # +x images along +x


def test_shortlist_matches_full_decode():
    rng = np.random.default_rng(3)
    from livetrack.estimator.detect.geometry import _Entry

    entries = [_Entry(s.id, 0, s, None) for s in BOOK]
    codes = [s.code.bits for s in BOOK]
    for _ in range(300):
        truth = np.array([b == "1" for b in codebook.rotate(codes[rng.integers(len(codes))], rng.integers(8))])
        soft = np.clip(truth + rng.normal(0, 0.3, 8), 0, 1)
        full = codebook.decode(soft, codes, max_distance=2.0)
        short = _shortlist(soft, entries)
        part = codebook.decode(soft, short, max_distance=2.0)
        assert bool(full) == bool(part)
        if full:
            assert codes[full.index] == short[part.index]
            assert (full.rotation_slots, full.distance, full.margin) == (part.rotation_slots, part.distance,
                                                                         part.margin)


# ---------------------------------------------------------------------- cheap equivalents of plain computations
def test_contours_on_the_dark_bounding_box_equal_the_full_scan():
    rng = np.random.default_rng(5)
    for k in range(60):
        b = np.zeros((int(rng.integers(300, 700)), int(rng.integers(300, 700))), np.uint8)
        h, w = b.shape
        for _ in range(int(rng.integers(0, 6))):  # rings, disks, specks, some on the border
            at = (int(rng.integers(-10, w + 10)), int(rng.integers(-10, h + 10)))
            cv2.circle(b, at, int(rng.integers(2, 40)), 255, int(rng.choice([-1, 2, 5])))
            b[int(rng.integers(0, h)), int(rng.integers(0, w))] = 255
        if k % 10 == 0:
            b[:, int(rng.integers(0, w))] = 255
        want_c, want_h = cv2.findContours(b, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
        got_c, got_h = _contours(b)
        assert len(got_c) == len(want_c) and all(np.array_equal(g, c) for g, c in zip(got_c, want_c, strict=True))
        assert (got_h is None and want_h is None) or np.array_equal(got_h, want_h)


@pytest.mark.parametrize("dtype, full", [(np.uint8, 255), (np.uint16, 4095), (np.uint16, 65535), (np.float32, 1.0),
                                         (np.float64, 1000.0)])
def test_normalise_is_a_fixed_square_root_map(dtype, full):
    """The coarse stage's 8-bit image is round(255 sqrt(v / full)) whatever the scene holds: no statistics of
    the image, so a frame saturated but for a few dark pixels keeps them dark; band by band and on ROI views."""
    rng = np.random.default_rng(int(full))
    for k in range(12):
        shape = (int(rng.integers(40, 400)), int(rng.integers(40, 700)))
        img = (rng.random(shape) * full * 1.2).clip(0, full)
        if k % 4 == 1:
            img[:] = full
            img[5:8, 9:12] = 0.1 * full  # a 9-pixel dark spot in a saturated frame
        img = img.astype(dtype) if dtype in (np.float32, np.float64) else np.round(img).astype(dtype)
        if k % 3 == 0:
            img = img[1:-2, 5:]
        out, got_full = _normalise(img, full if k % 2 else None, _WorkImages())
        want_full = full if (k % 2 or dtype == np.float64) else full_scale(img, None)
        assert got_full == want_full
        want = np.clip(np.round(255.0 * np.sqrt(np.maximum(img.astype(np.float64), 0) / want_full)), 0, 255)
        assert np.abs(out.astype(int) - want).max() <= 1  # float32 rounding at half-levels
        if k % 4 == 1:
            assert out.min() <= 255 * np.sqrt(0.1) + 1 and np.median(out) == 255


def test_full_scale_from_the_data_when_not_given():
    assert full_scale(np.full((4, 4), 4000, np.uint16), None) == 4095.0
    assert full_scale(np.full((4, 4), 100, np.uint16), None) == 255.0
    assert full_scale(np.full((4, 4), 40000, np.uint16), None) == 65535.0
    assert full_scale(np.full((4, 4), 0.5, np.float32), None) == 1.0
    assert full_scale(np.full((4, 4), 7.0, np.float32), None) == 7.0
    assert full_scale(np.zeros((4, 4), np.uint8), None) is None
    assert full_scale(np.zeros((4, 4), np.uint8), 4095.0) == 4095.0


def test_noise_is_the_cleanest_tiles_median_absolute_difference():
    """Pure noise: the median absolute difference (/0.954) of the least noisy tile, close to the true sd. Texture
    over most of the frame with one clean patch: the patch's noise, not the texture's; saturated tiles do not
    count. Both figures agree where nothing is clipped."""
    rng = np.random.default_rng(2)
    for _ in range(10):
        sd = rng.uniform(2, 20)
        img = np.clip(rng.normal(128, sd, (400, 600)), 64, 250).astype(np.uint8)
        tiles, unclipped = _noise(img)
        assert 0.7 * sd < tiles <= 1.1 * sd and tiles == unclipped
    texture = cv2.resize(rng.uniform(0, 250, (60, 80)), (800, 600), interpolation=cv2.INTER_NEAREST)
    img = texture + rng.normal(0, 2.0, texture.shape)
    img[:200, :200] = 200 + rng.normal(0, 2.0, (200, 200))  # a sheet of paper
    img[400:, 600:] = 255  # saturated
    for noise in _noise(np.clip(img, 0, 255).astype(np.uint8)):
        assert 1.0 < noise < 3.0
    assert _noise(np.full((300, 300), 255, np.uint8)) == (0.0, 0.0)


def test_noise_of_an_over_exposed_frame_leaves_its_clipped_pixels_out():
    """A frame saturated but for grey squares and bands (noise sd 1.5 levels) covering 60 % of it: counting the
    clipped pairs as large differences puts each tile's median in the tail of the others (the conservative
    figure, twice the noise here, 21 levels for ~1 in a rendered x32 frame); the unclipped figure is the grey's
    noise."""
    rng = np.random.default_rng(5)
    yy, xx = np.mgrid[:600, :960]
    grey = ((yy // 40 + xx // 40) % 2 == 0) | ((yy % 40) < 8)
    img = np.where(grey, 232 + rng.normal(0, 1.5, grey.shape), 255)
    tiles, unclipped = _noise(np.clip(np.round(img), 0, 255).astype(np.uint8))
    assert 0.7 < unclipped < 2.2
    assert tiles >= 2 * unclipped


def test_centre_homography_centre_is_the_projected_centre():
    """The scalar homography puts the target origin at ``circle_pose.projected_centre`` of the pair, for
    tilted, noisy pairs."""
    rng = np.random.default_rng(4)
    t = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    circle = np.column_stack([np.cos(t), np.sin(t)])
    checked = 0
    for _ in range(200):
        H = homography((1200, 1920), rng.uniform(15, 300), (rng.uniform(200, 1700), rng.uniform(200, 1000)),
                       rng.uniform(0, 70), rng.uniform(0, 360), rng.uniform(0, 360))
        pair = []
        for radius in (0.1, rng.uniform(0.3, 0.7) * 0.1):
            e = Ellipse.from_conic(fit_conic(project(H, radius * circle)))
            pair.append(Ellipse(e.centre_px + rng.normal(0, 0.05, 2), e.semi_axes_px * rng.normal(1, 0.002, 2),
                                e.angle_rad + rng.normal(0, 0.005)))
        outer, inner = pair
        T = np.array([[outer.a, 0, outer.centre_px[0]], [0, outer.a, outer.centre_px[1]], [0, 0, 1.0]])
        c, _ = projected_centre(T.T @ outer.to_conic() @ T, T.T @ inner.to_conic() @ T)
        centre = project(centre_homography(outer, inner), np.zeros((1, 2)))[0]
        if np.hypot(c[0], c[1]) < 0.5 and np.hypot(*((T @ c)[:2] - outer.centre_px)) < 0.5 * outer.b:
            assert np.allclose(centre, (T @ c)[:2], atol=1e-6)
            checked += 1
        else:  # implausible centre: the affine map
            assert np.allclose(centre, outer.centre_px, atol=1e-9)
    assert checked > 150


def test_work_images_do_not_carry_over_between_calls():
    """Work images are kept from one call to the next (any size, any order): the results do not depend on what
    was detected before."""
    shape = (360, 480)
    H = homography(shape, 40.0, (250, 170), 20.0, 30.0, 10.0)
    image = render(shape, [(BOOK[3], H)], full=4095, dtype=np.uint16)
    first = detect(image, BOOK, saturation=4095.0)
    detect(render((700, 900), [(BOOK[5], homography((700, 900), 80.0, (400, 300)))]), BOOK)
    detect(image[:200, :300], BOOK)
    again = detect(image, BOOK, saturation=4095.0)
    assert [(c.target_id, c.rotation_slots) for c in again] == [(c.target_id, c.rotation_slots) for c in first]
    assert all(np.array_equal(a.outer.centre_px, b.outer.centre_px) and np.array_equal(a.code_values, b.code_values)
               for a, b in zip(first, again, strict=True))


# ---------------------------------------------------------------------- real photos
REAL = realdata_dir()
needs_real = pytest.mark.skipif(REAL is None, reason="real data folder not found (set LIVETRACK_REALDATA)")
PHOTOS = target_photos()
OTHERS = sorted((REAL / "other-markers").glob("*.png")) if REAL else []


@needs_real
def test_real_photos_exist():
    assert len(PHOTOS) >= 10 and len(OTHERS) >= 2


@needs_real
@pytest.mark.parametrize("path", OTHERS, ids=lambda p: p.stem)
def test_other_markers_are_not_our_targets(path):
    specs = load_targets(REAL / "target-photos" / "targets.yaml")
    image = read_photo(path)
    assert detect(image, specs) == []
    assert detect(image, BOOK) == []
    assert detect(image, specs + [TargetSpec.default(i, 0.5, levels=1) for i in range(14) if i not in (2, 5)]) \
        == []
