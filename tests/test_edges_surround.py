"""What the design puts around an edge, modelled (``fit_edges_two_pass(white_step_px=..., white_disks=...)``)."""

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from livetrack.estimator.edges import BLIND_STEP_PX, fit_edges_two_pass
from livetrack.estimator.edges.surround import WhiteDisks

SUPERSAMPLING = 8
SIGMA_PX = 0.9


DOT_SLOTS = (0, 1, 3, 6)


def _dot_centres_px(outer_radius_px: float, centre: float) -> np.ndarray:
    angles = 2.0 * np.pi * (np.array(DOT_SLOTS) + 0.5) / 8
    return centre + 0.7 * outer_radius_px * np.stack([np.cos(angles), np.sin(angles)], axis=1)


def _small_target(outer_radius_px: float, nested: bool, size: int = 48,
                  dots: bool = False) -> tuple[np.ndarray, float, float]:
    """A black ring (inner radius 0.4 R) on white, its white disk holding a nested ring (0.08-0.2 R) or not, with
    white dots (radius 0.1 R on 0.7 R) or not, blurred by a Gaussian PSF and integrated over unit pixels
    (supersampled); 12-bit levels 100 + 3000 x white."""
    n = size * SUPERSAMPLING
    centre = size / 2 + 0.3
    coords = (np.arange(n) + 0.5) / SUPERSAMPLING - 0.5
    radius = np.hypot(*np.meshgrid(coords - centre, coords - centre))
    white = np.ones((n, n))
    white[radius < outer_radius_px] = 0.0
    white[radius < 0.4 * outer_radius_px] = 1.0
    if nested:
        white[(radius < 0.2 * outer_radius_px) & (radius >= 0.08 * outer_radius_px)] = 0.0
    for cx, cy in _dot_centres_px(outer_radius_px, centre) if dots else ():
        white[np.hypot(*np.meshgrid(coords - cx, coords - cy)) < 0.1 * outer_radius_px] = 1.0
    blurred = gaussian_filter(white, SIGMA_PX * SUPERSAMPLING)
    image = blurred.reshape(size, SUPERSAMPLING, size, SUPERSAMPLING).mean(axis=(1, 3))
    return 100.0 + 3000.0 * image, centre, centre


def _inner_circle_fit(image, cx, cy, outer_radius_px, white_step, start=None):
    angles = np.linspace(0.0, 2.0 * np.pi, 40, endpoint=False)
    r_px = 0.4 * outer_radius_px
    points = np.stack([cx + r_px * np.cos(angles), cy + r_px * np.sin(angles)], axis=1)
    normals = -np.stack([np.cos(angles), np.sin(angles)], axis=1)  # black (outside) to white (inside)
    step = r_px - 0.2 * outer_radius_px
    reach = np.stack([np.full(40, np.inf), np.full(40, max(step - 1.5, 1.5))], axis=1)
    return fit_edges_two_pass(image, points, normals, saturation=4095.0, curvature_per_px=1.0 / r_px,
                              reach_px=reach, half_width_px=min(4.0, 0.2 * outer_radius_px), start=start,
                              white_step_px=np.full(40, step) if white_step else None)


@pytest.mark.parametrize("outer_radius_px", [11.0, 14.0, 20.0])
def test_the_nested_ring_no_longer_pulls_the_inner_edge_into_the_black(outer_radius_px):
    """Its blur darkens the white side of the inner circle's short profiles: a single step read the edge
    0.17 / 0.06 / 0.02 px into the black at R = 11 / 14 / 20 px; with the step modelled, within 0.006 px, as
    on a target without the nested ring."""
    image, cx, cy = _small_target(outer_radius_px, nested=True)
    single = _inner_circle_fit(image, cx, cy, outer_radius_px, white_step=False)
    modelled = _inner_circle_fit(image, cx, cy, outer_radius_px, white_step=True)
    plain = _inner_circle_fit(*_small_target(outer_radius_px, nested=False), outer_radius_px, white_step=False)
    assert single.ok.all() and modelled.ok.all() and plain.ok.all()
    assert np.median(single.offset_px) < -0.015  # toward the black
    assert abs(np.median(modelled.offset_px)) < 0.006
    assert abs(np.median(plain.offset_px)) < 0.006


def test_tracking_from_the_last_fit_gives_the_search_fit():
    """Started from the last frame's fit, the step's share comes from it and one pass suffices: the same fits, within
    the step at which a point stops iterating."""
    image, cx, cy = _small_target(11.0, nested=True)
    searched = _inner_circle_fit(image, cx, cy, 11.0, white_step=True)
    tracked = _inner_circle_fit(image, cx, cy, 11.0, white_step=True, start=searched)
    assert tracked.ok.all()
    assert np.max(np.abs(tracked.offset_px - searched.offset_px)) < BLIND_STEP_PX


def test_no_step_within_reach_changes_nothing():
    """A step far beyond the profile (a large target's nested ring): the same fits as without it."""
    image, cx, cy = _small_target(11.0, nested=False)
    angles = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)
    points = np.stack([cx + 11.0 * np.cos(angles), cy + 11.0 * np.sin(angles)], axis=1)
    normals = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    kwargs = dict(saturation=4095.0, curvature_per_px=-1.0 / 11.0, half_width_px=2.0)
    without = fit_edges_two_pass(image, points, normals, **kwargs)
    far = fit_edges_two_pass(image, points, normals, white_step_px=np.full(24, 30.0), **kwargs)
    assert np.array_equal(without.offset_px, far.offset_px)


def _circle_fit(image, centre, radius_px, outer, step_px=None, disks=None):
    angles = np.linspace(0.0, 2.0 * np.pi, 48, endpoint=False)
    unit = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    sign = 1.0 if outer else -1.0  # black to white: outward on the outer circle, inward on the inner one
    reach = None if step_px is None else np.stack([np.full(48, np.inf), np.full(48, max(step_px - 1.5, 1.5))], 1)
    return fit_edges_two_pass(image, centre + radius_px * unit, sign * unit, saturation=4095.0,
                              curvature_per_px=-sign / radius_px, reach_px=reach, half_width_px=2.2,
                              white_step_px=None if step_px is None else np.full(48, step_px), white_disks=disks)


def test_the_code_dots_no_longer_pull_both_circles_into_the_white():
    """R = 11 px, four dots 2.2 px beyond both circles on their black side: their blur lifts the black samples of
    the profiles passing near them, and a single step read the outer circle 0.07 px toward the white, the inner
    one (its nested ring modelled) 0.01 px: unlike, so not an exposure bias but a scale error (-0.3 % here). With
    the dots' blurred disks in the model: 0.004 and -0.006 px."""
    r_px = 11.0
    image, centre, _ = _small_target(r_px, nested=True, dots=True)
    disks = WhiteDisks(_dot_centres_px(r_px, centre), np.tile(np.eye(2), (4, 1, 1)), np.full(4, 0.1 * r_px),
                       np.ones(4))
    step = 0.2 * r_px
    outer_alone = _circle_fit(image, centre, r_px, outer=True)
    outer = _circle_fit(image, centre, r_px, outer=True, disks=disks)
    inner = _circle_fit(image, centre, 0.4 * r_px, outer=False, step_px=step, disks=disks)
    assert outer_alone.ok.all() and outer.ok.all() and inner.ok.mean() > 0.9
    assert np.mean(outer_alone.offset_px) > 0.04
    assert abs(np.mean(outer.offset_px)) < 0.01
    assert abs(np.mean(inner.offset_px[inner.ok])) < 0.015


def test_the_compiled_shares_are_the_numpy_reference(monkeypatch):
    """The compiled step and disk shares (``surround_kernels``; the disk integral from a table) against the numpy
    reference (``scipy.special.chndtr``): within 1e-4 of the contrast, on a small target's profiles with a tilted
    disk's Jacobian."""
    from livetrack.estimator.edge_samples import sample_profiles
    from livetrack.estimator.edges import surround

    r_px = 11.0
    image, centre, _ = _small_target(r_px, nested=True, dots=True)
    searched = _circle_fit(image, centre, 0.4 * r_px, outer=False, step_px=0.2 * r_px)
    angles = np.linspace(0.0, 2.0 * np.pi, 48, endpoint=False)
    unit = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    prof, _, _ = sample_profiles(image, centre + 0.4 * r_px * unit, -unit, 4095.0, 2.2, 0.5, None,
                                 np.full(48, 1.0 / (0.4 * r_px)), None)
    squash = np.array([[1.0, 0.3], [0.0, 0.7]])  # a disk seen obliquely: its Jacobian (metres = px here)
    disks = WhiteDisks(_dot_centres_px(r_px, centre), np.tile(np.linalg.inv(squash), (4, 1, 1)),
                       np.full(4, 0.1 * r_px), np.full(4, np.sqrt(np.linalg.det(squash))))
    step = np.full(48, 0.2 * r_px)
    shares = {}
    for choice in ("numba", "numpy"):
        monkeypatch.setenv("LIVETRACK_KERNELS", choice)
        shares[choice] = (surround.step_share(prof, searched, step), surround.disks_share(prof, searched, disks))
    contrast = float(np.median(searched.white_level - searched.black_level))
    for compiled, reference in zip(shares["numba"], shares["numpy"], strict=True):
        assert np.abs(reference).max() > 0.05 * contrast  # the shares are there
        assert np.abs(compiled - reference).max() < 1e-4 * contrast


def test_the_disk_table_is_the_chi_square_integral():
    from scipy.special import chndtr

    from livetrack.estimator import surround_kernels

    rng = np.random.default_rng(4)
    a = rng.uniform(0.0, 15.9, 2000)
    b = rng.uniform(0.0, 23.9, 2000)
    table = surround_kernels.disk_table()
    got = np.array([surround_kernels._disk(x, y, table, 32.0) for x, y in zip(a, b, strict=True)])
    assert np.abs(got - chndtr(a * a, 2.0, b * b)).max() < 1e-4
