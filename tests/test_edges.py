"""Edge-formation model and model-based sub-pixel edges: round trips on rendered edges of known position.

Independent renderers provide the truth: ``render_supersampled`` averages the exactly blurred half-plane
``Phi(distance / sigma)`` over 24 x 24 sub-pixel points (pixel integration done numerically);
``render_filtered`` and the disk test blur a sharp shape drawn on a 16-20x finer grid with
``scipy.ndimage.gaussian_filter`` and block-average it (blur and pixel integration both numerical).  The
model itself (``edge_intensity``, checked against ``scipy.integrate.dblquad``) renders the large tiled
images for the noise and speed tests.
"""

import dataclasses
import time

import numpy as np
import pytest
from scipy import integrate, ndimage
from scipy.special import ndtr

from livetrack.estimator import (
    EdgeFits,
    edge_intensity,
    edge_response,
    fit_edges,
    fit_edges_two_pass,
    footprint_widths,
)
from livetrack.estimator import edges as edges_module
from livetrack.estimator.edge_model import SMALL_B, edge_response_rows
from livetrack.estimator.edges import solver as edges_solver

SAT = 255.0


def unit(angle_deg):
    t = np.deg2rad(angle_deg)
    return np.array([np.cos(t), np.sin(t)])


def render_supersampled(shape, point, normal, sigma, lb, lw, sat, ss=24):
    """Clipped image of the edge through ``point`` (x, y) with ``normal`` (black -> white)."""
    h, w = shape
    ys, xs = np.mgrid[0:h, 0:w].astype(float)
    u = normal[0] * (xs - point[0]) + normal[1] * (ys - point[1])
    sub = (np.arange(ss) + 0.5) / ss - 0.5
    acc = np.zeros(shape)
    for dy in sub:
        for dx in sub:
            acc += ndtr((u + normal[0] * dx + normal[1] * dy) / sigma)
    return np.clip(lb + (lw - lb) * acc / ss**2, 0.0, sat)


def render_filtered(shape, x0, sigma, lb, lw, sat, fine=20):
    """Vertical edge at x = x0 (white on the right): sharp area coverage on a fine grid, Gaussian filter,
    block average."""
    h, w = shape
    edges = (np.arange(w * fine + 1) / fine) - 0.5  # fine cell boundaries in px
    cover = np.clip((edges[1:] - x0) * fine, 0.0, 1.0)  # bright fraction of each fine cell
    fine_img = np.tile(cover, (h * fine, 1))
    blurred = ndimage.gaussian_filter(fine_img, sigma * fine, mode="nearest", truncate=6.0)
    pix = blurred.reshape(h, fine, w, fine).mean(axis=(1, 3))
    return np.clip(lb + (lw - lb) * pix, 0.0, sat)


def points_on_edge(point, normal, n, spacing=1.7, jitter=0.6, seed=0):
    """n true points along the edge line and initial guesses displaced along the normal by up to jitter."""
    rng = np.random.default_rng(seed)
    tangent = np.array([-normal[1], normal[0]])
    t = (np.arange(n) - (n - 1) / 2) * spacing
    truth = point + t[:, None] * tangent
    init = truth + rng.uniform(-jitter, jitter, (n, 1)) * normal
    return truth, init, np.tile(normal, (n, 1))


def along_normal_error(fits: EdgeFits, truth):
    return ((fits.points_px - truth) * fits.normals).sum(axis=1)


def threshold_crossing_along_row(img, point, normal):
    """Naive edge: on the image row through ``point``, where the pixels first cross the mid-level of the
    row's min and max (linear interpolation); returned as signed distance (px) along the normal from the
    true edge line."""
    y0 = int(round(point[1]))
    row = img[y0]
    mid = 0.5 * (row.min() + row.max())
    i = int(np.argmax(row >= mid))
    x_cross = i - 1 + (mid - row[i - 1]) / (row[i] - row[i - 1])
    x_line = point[0] - (y0 - point[1]) * normal[1] / normal[0]  # the edge line on that row
    return (x_cross - x_line) * normal[0]


# ---------------------------------------------------------------------------------------------- model


@pytest.mark.parametrize("angle_deg", [0.0, 1e-4, 0.3, 0.57, 0.58, 20.0, 45.0, 71.0, 90.0, 135.0, 200.0])
@pytest.mark.parametrize("sigma", [0.3, 0.8, 2.0])
def test_edge_response_matches_2d_integration(angle_deg, sigma):
    n = unit(angle_deg)
    a, b = footprint_widths(n)
    for u in [-3.7, -0.9, -0.2, 0.0, 0.35, 1.4, 4.2]:
        ref, _ = integrate.dblquad(
            lambda y, x, u=u: ndtr((u + n[0] * x + n[1] * y) / sigma), -0.5, 0.5, -0.5, 0.5,
            epsabs=1e-12, epsrel=1e-12,
        )
        assert abs(edge_response(u, sigma, a, b) - ref) < 1e-9


def test_edge_response_axis_aligned_is_box_filtered_step():
    # b = 0: E = F(u + 1/2) - F(u - 1/2), F(s) = s Phi(s/sigma) + sigma phi(s/sigma)  (METHOD.md)
    sigma = 0.7
    u = np.linspace(-4, 4, 81)

    def big_f(s):
        return s * ndtr(s / sigma) + sigma * np.exp(-0.5 * (s / sigma) ** 2) / np.sqrt(2 * np.pi)

    np.testing.assert_allclose(edge_response(u, sigma, 1.0, 0.0), big_f(u + 0.5) - big_f(u - 0.5), atol=1e-14)


def test_edge_response_symmetry_limits_and_branch_continuity():
    u = np.linspace(-6, 6, 241)
    for a, b in [(1.0, 0.0), (0.9, 0.3), (np.sqrt(0.5), np.sqrt(0.5))]:
        e = edge_response(u, 1.1, a, b)
        np.testing.assert_allclose(e + e[::-1], 1.0, atol=1e-13)  # E(u) + E(-u) = 1
        assert np.all(np.diff(e) >= 0) and e[0] < 1e-6 and e[-1] > 1 - 1e-6
    below = SMALL_B * (1 - 1e-9)
    above = SMALL_B * (1 + 1e-9)
    for sigma in [0.3, 1.0, 4.0]:
        lo = edge_response(u, sigma, np.sqrt(1 - below**2), below, derivatives=True)
        hi = edge_response(u, sigma, np.sqrt(1 - above**2), above, derivatives=True)
        for x, y in zip(lo, hi, strict=True):
            np.testing.assert_allclose(x, y, atol=1e-10)


def _random_edge_arguments(seed: int, n: int, u_max: float, sigma_range: tuple[float, float]):
    """(u, sigma, a, b) for n random edge samples: a third of the edge normals within 0.02 rad of an axis (the
    small-b branch of the model), the rest at any angle."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(-u_max, u_max, n)
    sigma = rng.uniform(*sigma_range, n)
    theta = np.concatenate([rng.uniform(-0.02, 0.02, n // 3), rng.uniform(0, 2 * np.pi, n - n // 3)])
    a, b = footprint_widths(np.stack([np.cos(theta), np.sin(theta)], axis=1))
    return u, sigma, a, b


def test_edge_response_derivatives_match_finite_differences():
    u, sigma, a, b = _random_edge_arguments(3, 3000, u_max=5.0, sigma_range=(0.3, 5.0))
    _, e_u, e_s = edge_response(u, sigma, a, b, derivatives=True)
    h = 1e-5
    fd_u = (edge_response(u + h, sigma, a, b) - edge_response(u - h, sigma, a, b)) / (2 * h)
    fd_s = (edge_response(u, sigma + h, a, b) - edge_response(u, sigma - h, a, b)) / (2 * h)
    np.testing.assert_allclose(e_u, fd_u, atol=1e-7)
    np.testing.assert_allclose(e_s, fd_s, atol=1e-7)


def test_edge_intensity_clips_to_sensor_range():
    u = np.linspace(-5, 5, 11)
    i = edge_intensity(u, 1.0, -100.0, 1000.0, SAT, 1.0, 0.0)
    raw = -100.0 + 1100.0 * edge_response(u, 1.0, 1.0, 0.0)
    np.testing.assert_array_equal(i, np.clip(raw, 0.0, SAT))
    assert i.min() == 0.0 and i.max() == SAT and ((i > 0) & (i < SAT)).sum() == 1


# ---------------------------------------------------------------------------------------------- fits


@pytest.mark.parametrize("sigma", [0.8, 1.5])
@pytest.mark.parametrize("angle_deg", [0.0, 20.0, 45.0, 160.0, 250.0])
def test_fit_recovers_unclipped_edge(sigma, angle_deg):
    n = unit(angle_deg)
    point = np.array([20.37, 19.81])  # sub-pixel position
    img = render_supersampled((41, 41), point, n, sigma, 30.0, 210.0, SAT)
    truth, init, normals = points_on_edge(point, n, 9)
    fits = fit_edges(img, init, normals, SAT)
    err = along_normal_error(fits, truth)
    assert fits.ok.all()
    assert np.abs(err).max() < 0.01
    np.testing.assert_allclose(fits.sigma_px, sigma, atol=0.01)
    np.testing.assert_allclose(fits.black_level, 30.0, atol=0.5)
    np.testing.assert_allclose(fits.white_level, 210.0, atol=0.5)


@pytest.mark.parametrize("sigma", [0.8, 1.5])
def test_fit_recovers_edge_rendered_by_gaussian_filter(sigma):
    x0 = 15.27
    img = render_filtered((9, 31), x0, sigma, 25.0, 220.0, SAT)
    truth, init, normals = points_on_edge(np.array([x0, 4.0]), unit(0.0), 3, spacing=1.0)
    fits = fit_edges(img, init, normals, SAT)
    assert fits.ok.all()
    assert np.abs(along_normal_error(fits, truth)).max() < 0.01


@pytest.mark.parametrize("dtype, scale", [(np.uint8, 1.0), (np.uint16, 4095.0 / 255.0)])
def test_fit_integer_images(dtype, scale):
    n = unit(30.0)
    point = np.array([20.6, 20.2])
    sat = SAT * scale
    img = np.rint(render_supersampled((41, 41), point, n, 1.0, 30.0 * scale, 210.0 * scale, sat)).astype(dtype)
    truth, init, normals = points_on_edge(point, n, 9)
    fits = fit_edges(img, init, normals, sat)
    assert fits.ok.all()
    # rounding to integers is the only error: ~0.004 px for 8 bits, ~0.0003 px for 12 bits
    assert np.abs(along_normal_error(fits, truth)).max() < (0.02 if dtype == np.uint8 else 0.002)


@pytest.mark.parametrize("sigma", [0.8, 1.5])
@pytest.mark.parametrize("angle_deg", [0.0, 20.0, 45.0])
@pytest.mark.parametrize("exposure", ["over", "under"])
def test_fit_removes_exposure_bias_of_threshold(sigma, angle_deg, exposure):
    # over: white would read 4 x saturation; under: black would read -3 x white (clipped at 0)
    lb, lw = (10.0, 4.0 * SAT) if exposure == "over" else (-600.0, 200.0)
    n = unit(angle_deg)
    point = np.array([20.37, 19.81])
    img = render_supersampled((41, 41), point, n, sigma, lb, lw, SAT)
    assert (img == (SAT if exposure == "over" else 0.0)).sum() > 100
    truth, init, normals = points_on_edge(point, n, 9)
    fits = fit_edges(img, init, normals, SAT, fix_sigma=sigma)
    err = along_normal_error(fits, truth)
    assert fits.ok.all()
    assert np.abs(err).max() < 0.02
    # the naive mid-level crossing of the same clipped profile, along the row through the edge
    naive = threshold_crossing_along_row(img, point, n)
    if exposure == "over":
        assert naive < -0.5 * sigma  # white grows into the black side
    else:
        assert naive > 0.5 * sigma
    print(f"{exposure} sigma {sigma} angle {angle_deg}: fit |err| <= {np.abs(err).max():.4f} px, "
          f"threshold {naive:+.3f} px")


def test_fit_clipped_free_sigma_never_silently_wrong():
    # 4-parameter fits of clipped profiles are ill-conditioned; whatever converges must be right
    rng = np.random.default_rng(11)
    results = []
    for _ in range(12):
        n = unit(rng.uniform(0, 360))
        sigma = rng.uniform(0.7, 1.6)
        lb, lw = (15.0, SAT * rng.uniform(1.5, 5.0)) if rng.random() < 0.5 else (-rng.uniform(100, 700), 190.0)
        point = np.array([20.0, 20.0]) + rng.uniform(-0.5, 0.5, 2)
        img = render_supersampled((41, 41), point, n, sigma, lb, lw, SAT, ss=16)
        truth, init, normals = points_on_edge(point, n, 5, seed=int(rng.integers(1000)))
        fits = fit_edges(img, init, normals, SAT, half_width_px=6.0, iterations=30)
        results.append((fits.ok, along_normal_error(fits, truth)))
    ok = np.concatenate([r[0] for r in results])
    err = np.concatenate([r[1] for r in results])
    assert ok.mean() > 0.5
    assert np.abs(err[ok]).max() < 0.02


def tiled_edges(rng, n_x, n_y, tile, sigma, lb, lw, sat, jitter=0.6):
    """Image of n_x * n_y tiles, one straight edge per tile (random angle, sub-pixel position), rendered
    with the model itself (exact for the model); sigma, lb, lw scalars or per tile (N,).  Returns image,
    truth (N, 2), initial points, normals."""
    n = n_x * n_y
    theta = rng.uniform(0, 2 * np.pi, n)
    normals = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    centre = np.stack(
        [(np.arange(n) % n_x) * tile + tile // 2, (np.arange(n) // n_x) * tile + tile // 2], axis=1
    ) + rng.uniform(-0.5, 0.5, (n, 2))
    ys, xs = np.mgrid[0 : n_y * tile, 0 : n_x * tile].astype(float)
    k = (ys // tile).astype(int) * n_x + (xs // tile).astype(int)
    u = normals[k, 0] * (xs - centre[k, 0]) + normals[k, 1] * (ys - centre[k, 1])
    a, b = footprint_widths(normals[k])
    per_tile = [np.broadcast_to(np.asarray(x, dtype=float), (n,))[k] for x in (sigma, lb, lw)]
    img = edge_intensity(u, per_tile[0], per_tile[1], per_tile[2], sat, a, b)
    tangent = np.stack([-normals[:, 1], normals[:, 0]], axis=1)
    init = centre + rng.uniform(-jitter, jitter, (n, 1)) * normals + rng.uniform(-2, 2, (n, 1)) * tangent
    return img, centre, init, normals


def poisson_gaussian(rng, img, read_var, gain, sat):
    """Sensor noise on the unclipped signal ``img``, then clipping to [0, sat]."""
    noisy = rng.poisson(np.maximum(img, 0.0) / gain) * gain + rng.normal(0.0, np.sqrt(read_var), img.shape)
    return np.clip(noisy, 0.0, sat)


@pytest.mark.parametrize("weighted", [True, False])
def test_position_std_matches_scatter_under_poisson_gaussian_noise(weighted):
    rng = np.random.default_rng(7)
    read_var, gain = 4.0, 0.5
    img, truth, init, normals = tiled_edges(rng, 25, 20, 21, 1.0, 30.0, 200.0, np.inf)
    noisy = poisson_gaussian(rng, img, read_var, gain, SAT)
    fits = fit_edges(noisy, init, normals, SAT, noise_model=(read_var, gain) if weighted else None)
    err = along_normal_error(fits, truth)
    assert fits.ok.mean() > 0.99
    scatter = np.sqrt(np.mean(err[fits.ok] ** 2))
    predicted = np.sqrt(np.mean(fits.position_std_px[fits.ok] ** 2))
    print(f"weighted={weighted}: scatter {scatter:.4f} px, predicted {predicted:.4f} px")
    assert 0.7 < scatter / predicted < 1.4
    assert abs(np.mean(err[fits.ok])) < 3 * scatter / np.sqrt(fits.ok.sum()) + 1e-3  # unbiased


def test_position_std_matches_scatter_for_overexposed_edges():
    # 4x overexposed, blur known: only the dark tail is seen, so contrast and position trade off and the
    # scatter is several times that of a well-exposed edge; position_std_px must say so.  Weighted fit: the
    # unweighted residual variance is dominated by the quiet dark samples and would understate it.
    rng = np.random.default_rng(8)
    read_var, gain = 4.0, 0.5
    img, truth, init, normals = tiled_edges(rng, 25, 20, 25, 1.0, 20.0, 4.0 * SAT, np.inf)
    noisy = poisson_gaussian(rng, img, read_var, gain, SAT)
    fits = fit_edges(noisy, init, normals, SAT, fix_sigma=1.0, half_width_px=5.0, noise_model=(read_var, gain))
    err = along_normal_error(fits, truth)
    assert fits.ok.mean() > 0.95
    scatter = np.sqrt(np.mean(err[fits.ok] ** 2))
    predicted = np.sqrt(np.mean(fits.position_std_px[fits.ok] ** 2))
    print(f"overexposed: scatter {scatter:.4f} px, predicted {predicted:.4f} px, median {np.median(err):+.4f}")
    assert 0.7 < scatter / predicted < 1.4
    assert abs(np.median(err[fits.ok])) < 0.03  # the naive threshold is off by ~1.1 px here


def test_flat_patch_is_not_ok():
    rng = np.random.default_rng(2)
    pts = np.array([[10.0, 10.0], [20.3, 15.7], [30.0, 30.0]])
    normals = np.array([[1.0, 0.0], [0.6, 0.8], [0.0, -1.0]])
    flat = np.full((40, 40), 120.0)
    assert not fit_edges(flat, pts, normals, SAT).ok.any()
    noisy = flat + rng.normal(0, 3.0, flat.shape)
    assert not fit_edges(noisy, pts, normals, SAT).ok.any()
    assert not fit_edges(np.full((40, 40), SAT), pts, normals, SAT).ok.any()  # saturated everywhere


def test_points_near_and_beyond_the_border():
    n = unit(0.0)
    img = render_supersampled((30, 30), np.array([2.3, 15.0]), n, 1.0, 30.0, 210.0, SAT, ss=8)
    pts = np.array([[2.3, 15.0], [2.3, 0.0], [2.3, 29.4], [-20.0, 15.0], [2.3, 45.0], [np.nan, 3.0]])
    fits = fit_edges(img, pts, np.tile(n, (len(pts), 1)), SAT)
    assert len(fits) == len(pts)
    assert fits.ok[:3].all() and not fits.ok[3:].any()
    assert fits.n_samples[3] == 0 and fits.n_samples[4] == 0 and fits.n_samples[5] == 0
    # the window is cut by the left border (only 2 dark columns are inside), yet the edge is found
    assert np.abs(fits.points_px[:3, 0] - 2.3).max() < 0.01
    wide = render_supersampled((30, 40), np.array([12.3, 15.0]), n, 1.0, 30.0, 210.0, SAT, ss=8)
    inside = fit_edges(wide, pts[:1] + [10.0, 0.0], n[None], SAT)  # the same edge 10 px further in
    assert fits.n_samples[0] < inside.n_samples[0]
    assert abs(inside.points_px[0, 0] - 12.3) < 0.01
    empty = fit_edges(img, np.zeros((0, 2)), np.zeros((0, 2)), SAT)
    assert len(empty) == 0


def test_both_sides_clipped_never_silently_wrong():
    # Lb < 0 and Lw > S: only a narrow band of the transition is unclipped; fits are flagged or right
    rng = np.random.default_rng(12)
    ok_all, err_all = [], []
    for sigma in [0.8, 1.5]:
        for angle_deg in [0.0, 20.0, 45.0]:
            for lb, lw in [(-400.0, 1020.0), (-150.0, 400.0)]:
                n = unit(angle_deg)
                point = np.array([20.0, 20.0]) + rng.uniform(-0.5, 0.5, 2)
                img = render_supersampled((41, 41), point, n, sigma, lb, lw, SAT, ss=12)
                truth, init, normals = points_on_edge(point, n, 5)
                for fix in [sigma, None]:
                    fits = fit_edges(img, init, normals, SAT, fix_sigma=fix, iterations=15)
                    ok_all.append(fits.ok)
                    err_all.append(along_normal_error(fits, truth))
    ok, err = np.concatenate(ok_all), np.concatenate(err_all)
    assert np.abs(err[ok]).max(initial=0.0) < 0.02
    assert ok.mean() < 0.5  # most of these are not identifiable from so few samples


def test_single_line_sampling():
    n = unit(33.0)
    point = np.array([20.37, 19.81])
    img = render_supersampled((41, 41), point, n, 1.1, 30.0, 210.0, SAT)
    truth, init, normals = points_on_edge(point, n, 9)
    strip = fit_edges(img, init, normals, SAT)
    line = fit_edges(img, init, normals, SAT, tangent_half_width_px=0.0)
    assert line.ok.all() and np.abs(along_normal_error(line, truth)).max() < 0.01
    assert (line.n_samples < strip.n_samples).all()


def test_fixed_sigma_per_point_and_wrong_sigma_bias():
    rng = np.random.default_rng(4)
    img, truth, init, normals = tiled_edges(rng, 6, 5, 21, 1.2, 20.0, 3.0 * SAT, SAT)
    right = fit_edges(img, init, normals, SAT, fix_sigma=np.full(len(init), 1.2))
    assert right.ok.all() and np.abs(along_normal_error(right, truth)).max() < 0.01
    np.testing.assert_array_equal(right.sigma_px, 1.2)
    # a blur 0.3 px too small: the overexposed fit must move the edge to fit the same tail (known limit)
    wrong = fit_edges(img, init, normals, SAT, fix_sigma=0.9)
    assert np.abs(along_normal_error(wrong, truth)).mean() > 0.05
    with pytest.raises(ValueError):
        fit_edges(img, init, normals, SAT, fix_sigma=0.0)


def test_5000_points_vectorised():
    rng = np.random.default_rng(5)
    img, truth, init, normals = tiled_edges(rng, 100, 50, 17, 1.0, 30.0, 210.0, SAT)
    fit_edges(img, init[:10], normals[:10], SAT)  # warm-up
    t0 = time.perf_counter()
    fits = fit_edges(img, init, normals, SAT)
    elapsed = time.perf_counter() - t0
    print(f"5000 edge points: {elapsed * 1e3:.0f} ms")
    assert elapsed < 1.0
    assert fits.ok.all() and np.abs(along_normal_error(fits, truth)).max() < 1e-3


@pytest.mark.parametrize("white_disk", [True, False])
def test_curvature_removes_curved_edge_bias(white_disk):
    # disk of radius 10 px blurred by sigma = 1.2 px: sharp disk on a 16x finer grid, gaussian_filter, block mean
    radius, sigma, fine, size = 10.0, 1.2, 16, 36
    centre = np.array([17.31, 17.83])
    f = (np.arange(size * fine) + 0.5) / fine - 0.5
    xx, yy = np.meshgrid(f, f)
    disk = ((xx - centre[0]) ** 2 + (yy - centre[1]) ** 2 <= radius**2).astype(float)
    pix = ndimage.gaussian_filter(disk, sigma * fine, truncate=6.0).reshape(size, fine, size, fine).mean((1, 3))
    img = 20.0 + 180.0 * (pix if white_disk else 1.0 - pix)
    theta = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    radial = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    pts = centre + radius * radial
    normals = -radial if white_disk else radial  # black -> white
    kappa = 1.0 / radius if white_disk else -1.0 / radius  # centre of curvature on the bright side: +
    straight = fit_edges(img, pts, normals, SAT)
    curved = fit_edges(img, pts, normals, SAT, curvature_per_px=kappa)
    err_straight = np.linalg.norm(straight.points_px - centre, axis=1) - radius
    err_curved = np.linalg.norm(curved.points_px - centre, axis=1) - radius
    print(f"white disk {white_disk}: radius error straight {err_straight.mean():+.4f}, curved {err_curved.mean():+.4f}")
    assert straight.ok.all() and curved.ok.all()
    # blurred disks shrink whatever their colour: ~(sigma^2 + 1/12) / (2 R) and more from the sampled strip
    assert err_straight.mean() < -(sigma**2 + 1 / 12) / (2 * radius)
    assert abs(err_curved.mean()) < 0.003 and np.abs(err_curved).max() < 0.01


def test_two_pass_fits_clipped_edges_with_the_frame_blur():
    rng = np.random.default_rng(9)
    n = 400
    over = rng.random(n) < 0.5  # half the edges 4x overexposed, the blur (1.3 px) unknown to the caller
    lw = np.where(over, 4.0 * SAT, 200.0)
    img, truth, init, normals = tiled_edges(rng, 20, 20, 21, 1.3, 20.0, lw, SAT)
    single = fit_edges(img, init, normals, SAT)
    fits = fit_edges_two_pass(img, init, normals, SAT)
    err = along_normal_error(fits, truth)
    assert fits.ok.all() and np.abs(err).max() < 0.005
    np.testing.assert_allclose(fits.sigma_px, 1.3, atol=1e-3)
    assert (fits.n_clipped[over] > 0).all() and (fits.n_clipped[~over] == 0).all()
    # the single free-sigma pass leaves many clipped edges unconverged (flagged, not wrong)
    assert single.ok[over].mean() < fits.ok[over].mean()
    assert np.abs(along_normal_error(single, truth)[single.ok]).max() < 0.02
    with pytest.raises(ValueError):
        fit_edges_two_pass(img, init, normals, SAT, fix_sigma=1.0)


def test_stacked_row_evaluation_matches_edge_response():
    """The fit's one-pass evaluation (4 corners stacked, small b by the expansion about SMALL_B) is the model."""
    rng = np.random.default_rng(11)
    n = 3000
    theta = np.concatenate([rng.uniform(-0.02, 0.02, n // 3), rng.uniform(0, 2 * np.pi, n - n // 3)])
    a, b = footprint_widths(np.stack([np.cos(theta), np.sin(theta)], axis=1))
    sigma = rng.uniform(0.3, 5.0, (n, 1))
    u = rng.uniform(-6, 6, (n, 17))
    exact = edge_response(u, sigma, a[:, None], b[:, None], derivatives=True)
    rows = edge_response_rows(u, sigma, a[:, None], b[:, None])
    for x, y in zip(exact, rows, strict=True):
        np.testing.assert_allclose(y, x, atol=2e-9)


@pytest.mark.parametrize("over", [False, True])
def test_start_from_the_last_fits_gives_the_same_edges_and_follows_a_move(over, monkeypatch):
    """Tracking: starting from the last frame's fits at the same points reproduces them (unclipped: with one
    model evaluation per point; clipped profiles start from their data); after a 0.3 px move the started fit
    finds the same edges as a fresh one."""
    rng = np.random.default_rng(12)
    lw = 4.0 * SAT if over else 200.0
    img, truth, init, normals = tiled_edges(rng, 10, 10, 21, 1.1, 20.0, lw, SAT)
    noisy = poisson_gaussian(rng, img, 4.0, 0.05, SAT)
    first = fit_edges_two_pass(noisy, init, normals, SAT)
    counts = []
    original = edges_solver._evaluate_normal  # counted on the numpy reference (the compiled LM does the same)
    monkeypatch.setenv("LIVETRACK_KERNELS", "numpy")

    def counting(params, *args):
        counts.append(len(params))
        return original(params, *args)

    edges_solver._evaluate_normal = counting
    try:
        again = fit_edges_two_pass(noisy, init, normals, SAT, start=first)
    finally:
        edges_solver._evaluate_normal = original
    assert np.array_equal(again.ok, first.ok) and first.ok.mean() > 0.95
    diff = np.linalg.norm(again.points_px - first.points_px, axis=1)[first.ok]
    print(f"restart moved {np.mean(diff > 1e-4):.1%} of the points by > 1e-4 px, at most {diff.max():.1e} px")
    assert diff.max() < 1e-4
    if not over:
        assert sum(counts) <= len(init) + 10  # one evaluation per point (a few not-ok points iterate on)
    # the edges move 0.3 px along their normals
    moved_truth = truth + 0.3 * normals
    rng2 = np.random.default_rng(13)
    tile = 21
    ys, xs = np.mgrid[0 : 10 * tile, 0 : 10 * tile].astype(float)
    k = (ys // tile).astype(int) * 10 + (xs // tile).astype(int)
    u = normals[k, 0] * (xs - moved_truth[k, 0]) + normals[k, 1] * (ys - moved_truth[k, 1])
    a, b = footprint_widths(normals[k])
    moved_img = poisson_gaussian(rng2, edge_intensity(u, 1.1, 20.0, lw, np.inf, a, b), 4.0, 0.05, SAT)
    followed = fit_edges_two_pass(moved_img, init, normals, SAT, start=first)
    fresh = fit_edges_two_pass(moved_img, init, normals, SAT)
    both = followed.ok & fresh.ok
    print(f"ok after the move: followed {followed.ok.mean():.0%}, fresh {fresh.ok.mean():.0%}")
    assert followed.ok.sum() >= fresh.ok.sum() - 2 and both.mean() > 0.8
    if not over:  # all clipped: pass 2 has no frame blur to take (1.0 px for 1.1), hence a bias (known limit)
        assert np.abs(along_normal_error(followed, moved_truth)[both]).max() < 0.2  # noise: ~0.03 px rms
    assert np.abs(followed.points_px - fresh.points_px)[both].max() < edges_module.CONVERGED_STEP_PX


def test_start_must_match_the_points():
    img, _, init, normals = tiled_edges(np.random.default_rng(1), 3, 3, 21, 1.0, 20.0, 200.0, SAT)
    fits = fit_edges_two_pass(img, init, normals, SAT)
    with pytest.raises(ValueError, match="start has 9 fits for 8 points"):
        fit_edges_two_pass(img, init[:8], normals[:8], SAT, start=fits)


# ---------------------------------------------------------------------------------------------- known PSF halo
HALO = (0.03, 6.0)


def render_supersampled_halo(shape, point, normal, sigma, halo, lb, lw, sat, ss=16):
    """``render_supersampled`` for the PSF (1 - f) G(sigma) + f G(sigma_h): the exactly blurred half-plane
    ``(1 - f) Phi(d / sigma) + f Phi(d / sigma_h)`` averaged over ss x ss sub-pixel points."""
    f, sigma_h = halo
    h, w = shape
    ys, xs = np.mgrid[0:h, 0:w].astype(float)
    u = normal[0] * (xs - point[0]) + normal[1] * (ys - point[1])
    sub = (np.arange(ss) + 0.5) / ss - 0.5
    acc = np.zeros(shape)
    for dy in sub:
        for dx in sub:
            d = u + normal[0] * dx + normal[1] * dy
            acc += (1.0 - f) * ndtr(d / sigma) + f * ndtr(d / sigma_h)
    return np.clip(lb + (lw - lb) * acc / ss**2, 0.0, sat)


def test_halo_response_derivatives_match_finite_differences():
    from livetrack.estimator.edge_model import halo_edge_response

    u, sigma, a, b = _random_edge_arguments(21, 2000, u_max=6.0, sigma_range=(0.4, 3.0))
    e, e_u, e_s = halo_edge_response(u, sigma, a, b, HALO, derivatives=True)
    h = 1e-5
    fd_u = (halo_edge_response(u + h, sigma, a, b, HALO) - halo_edge_response(u - h, sigma, a, b, HALO)) / (2 * h)
    fd_s = (halo_edge_response(u, sigma + h, a, b, HALO) - halo_edge_response(u, sigma - h, a, b, HALO)) / (2 * h)
    np.testing.assert_allclose(e_u, fd_u, atol=1e-7)
    np.testing.assert_allclose(e_s, fd_s, atol=1e-7)
    # the mixture of the two Gaussian responses; no halo: the plain response
    np.testing.assert_allclose(e, 0.97 * edge_response(u, sigma, a, b) + 0.03 * edge_response(u, 6.0, a, b),
                               atol=1e-15)
    np.testing.assert_array_equal(halo_edge_response(u, sigma, a, b, (0.0, 6.0)), edge_response(u, sigma, a, b))


@pytest.mark.parametrize("fixed_sigma", [False, True])
@pytest.mark.parametrize("clipped", [False, True])
def test_halo_fit_jacobian_matches_finite_differences(fixed_sigma, clipped):
    """The analytic Jacobian of the fit's residuals (offset, sigma, level, log contrast) with the halo, on
    curved edges, against central differences of the residuals."""
    rng = np.random.default_rng(5)
    n = 60
    lw = 3.0 * SAT if clipped else 200.0
    img, _, init, normals = tiled_edges(rng, 6, 10, 21, 1.0, 20.0, lw, SAT)
    kappa = rng.uniform(-0.05, 0.05, n)
    prof, _, _ = edges_module.sample_profiles(img, init, normals, SAT, 4.0, 0.5, None, kappa)
    params = np.column_stack([rng.uniform(-0.3, 0.3, n), rng.uniform(0.8, 1.3, n), np.full(n, 20.0),
                              np.log(np.full(n, lw - 20.0))])
    resid, jac = edges_module._evaluate(params, prof, SAT, fixed_sigma, HALO)
    for k in range(4):
        if fixed_sigma and k == 1:
            assert not jac[:, 1].any()
            continue
        h = 1e-6
        up, down = params.copy(), params.copy()
        up[:, k] += h
        down[:, k] -= h
        r_up, _ = edges_module._evaluate(up, prof, SAT, fixed_sigma, HALO)
        r_down, _ = edges_module._evaluate(down, prof, SAT, fixed_sigma, HALO)
        # residual = data - model: its derivative is minus the model's (the Jacobian holds the model's);
        # samples crossing a clip level within +-h have no derivative on one side: compare elsewhere
        fd = -(r_up - r_down) / (2 * h)
        steady = np.abs(fd - jac[:, k]) < 1e-3 * (np.abs(fd) + 1.0) + 1e-4
        assert steady.mean() > 0.995, (k, steady.mean())


def test_halo_none_or_zero_is_the_plain_fit():
    rng = np.random.default_rng(4)
    img, _, init, normals = tiled_edges(rng, 5, 5, 21, 1.1, 20.0, 3.0 * SAT, SAT)
    plain = fit_edges_two_pass(img, init, normals, SAT, curvature_per_px=0.02)
    for halo in (None, (0.0, 6.0)):
        other = fit_edges_two_pass(img, init, normals, SAT, curvature_per_px=0.02, halo=halo)
        for name in EdgeFits.__dataclass_fields__:
            np.testing.assert_array_equal(getattr(other, name), getattr(plain, name))
    with pytest.raises(ValueError, match="halo"):
        fit_edges(img, init, normals, SAT, halo=(1.2, 6.0))


@pytest.mark.parametrize("angle_deg", [0.0, 30.0])
@pytest.mark.parametrize("exposure", [1.0, 4.0, 16.0])
def test_halo_model_removes_the_halo_bias_of_overexposed_edges(angle_deg, exposure):
    """Edges rendered with a 3 % halo of 6 px: the fit with the halo known is unbiased at any exposure; the
    Gaussian model is pulled into the black as the exposure grows."""
    sigma = 0.8
    n = unit(angle_deg)
    point = np.array([30.37, 29.81])
    lb, lw = 0.05 * exposure * 0.6 * SAT, exposure * 0.6 * SAT
    img = render_supersampled_halo((61, 61), point, n, sigma, HALO, lb, lw, SAT)
    truth, init, normals = points_on_edge(point, n, 9)
    # 6 px: at 16x only ~4 samples of a 4 px half width stay unclipped (too few for 3 parameters: not ok)
    known = fit_edges(img, init, normals, SAT, fix_sigma=sigma, halo=HALO, iterations=30, half_width_px=6.0)
    plain = fit_edges(img, init, normals, SAT, fix_sigma=sigma, iterations=30, half_width_px=6.0)
    err_known = along_normal_error(known, truth)
    err_plain = along_normal_error(plain, truth)
    print(f"x{exposure} angle {angle_deg}: halo known {err_known.mean():+.4f} px, Gaussian only "
          f"{err_plain.mean():+.4f} px")
    assert known.ok.all()
    assert np.abs(err_known).max() < 0.01
    if exposure >= 4:
        assert err_plain.mean() < -0.02 * exposure / 4  # white grows: the edge is found inside the black


@pytest.mark.parametrize("exposure", [4.0, 16.0])
def test_shared_contrast_of_clipped_profiles_cuts_their_scatter(exposure):
    """Over-exposed noisy edges (known blur and halo, 12-bit levels): clipped profiles refitted with one shared
    contrast scatter several times less along their normals than with a contrast each, and every point stays
    ok. The shared value is the median of the noisy per-point fits, a little off at 16x: that moves every edge
    alike (~0.09 px here), which the pose's exposure bias delta absorbs."""
    rng = np.random.default_rng(17)
    sat = 4095.0
    n_x, n_y, tile = 20, 15, 25
    img, truth, init, normals = tiled_edges(rng, n_x, n_y, tile, 0.8, 0.0, 1.0, np.inf)
    # re-render the same edges with the halo: edge_intensity's levels 0..1 give E, mixed here
    n = n_x * n_y
    ys, xs = np.mgrid[0 : n_y * tile, 0 : n_x * tile].astype(float)
    k = (ys // tile).astype(int) * n_x + (xs // tile).astype(int)
    u = normals[k, 0] * (xs - truth[k, 0]) + normals[k, 1] * (ys - truth[k, 1])
    a, b = footprint_widths(normals[k])
    lw = exposure * 0.55 * sat
    signal = edge_intensity(u, 0.8, 0.047 * lw, lw, np.inf, a, b, halo=HALO)
    noisy = np.rint(poisson_gaussian(rng, signal, 4.2, 0.41, sat))
    options = dict(halo=HALO, sigma_fallback_px=0.8, sigma_init_px=0.8, iterations=20)
    own = fit_edges_two_pass(noisy, init, normals, sat, **options)
    shared = fit_edges_two_pass(noisy, init, normals, sat, shared_contrast=True, **options)
    assert (own.n_clipped > 0).all() and len(own) == n
    err_own, err_shared = along_normal_error(own, truth), along_normal_error(shared, truth)
    sd_own, sd_shared = np.std(err_own[own.ok]), np.std(err_shared[shared.ok])
    print(f"x{exposure}: scatter {sd_own:.3f} px (ok {own.ok.mean():.2f}) -> {sd_shared:.3f} px "
          f"(ok {shared.ok.mean():.2f}); mean {np.mean(err_shared[shared.ok]):+.4f} px")
    assert shared.ok.mean() > 0.98 and shared.ok.mean() >= own.ok.mean()
    assert sd_shared < 0.5 * sd_own
    assert abs(np.mean(err_shared[shared.ok])) < (0.01 if exposure < 8 else 0.12)
    contrast = shared.white_level - shared.black_level
    assert np.ptp(contrast) < 1e-6 * contrast[0]  # one contrast for all


def overexposed_tiles(exposure, seed=23):
    """Tiled over-exposed 12-bit edges (sigma 0.8 px, no halo) as a sensor records them: shot noise, the charge
    clipped at full well (the top code), read noise (sd 2 DN), rounding and the ADC clip, so that about half of
    the saturated pixels read a few DN below the top code. Returns image, truth, initial points, normals, top code."""
    rng = np.random.default_rng(seed)
    sat, gain, read_sd = 4095.0, 0.41, 2.0
    lw = exposure * 0.55 * sat
    img, truth, init, normals = tiled_edges(rng, 20, 15, 25, 0.8, 0.047 * lw, lw, np.inf)
    charge = np.minimum(rng.poisson(img / gain) * gain, sat)
    return np.clip(np.rint(charge + rng.normal(0.0, read_sd, img.shape)), 0, sat), truth, init, normals, sat


def count_model_rows(monkeypatch):
    """Patch the model evaluation to count the profile rows evaluated; returns the list of row counts (the numpy
    reference kernels are selected: the compiled ones evaluate the same rows, see tests/test_kernels.py)."""
    monkeypatch.setenv("LIVETRACK_KERNELS", "numpy")
    rows = []
    original = edges_solver.edge_response_rows

    def counted(v, sig, a, b):
        rows.append(v.shape[0])
        return original(v, sig, a, b)

    monkeypatch.setattr(edges_solver, "edge_response_rows", counted)
    return rows


def test_clip_margin_removes_the_pull_of_saturated_pixels_read_below_the_top_code(monkeypatch):
    """At 4x, saturated pixels reading the top code minus read noise taken as unclipped white pull each edge ~1 px
    into the black, and their large residuals slow the fit; with the tracker's default margin (1 % of the top
    code) the edges are unbiased and the fit needs several times fewer model evaluations."""
    img, truth, init, normals, sat = overexposed_tiles(4.0)
    assert ((img < sat) & (img > sat - 10)).sum() > 1000  # the pixels in question
    rows = count_model_rows(monkeypatch)
    options = dict(sigma_fallback_px=0.8, sigma_init_px=0.8, iterations=30, shared_contrast=True)
    plain = fit_edges_two_pass(img, init, normals, sat, **options)
    cost_plain = sum(rows)
    rows.clear()
    margin = fit_edges_two_pass(img, init, normals, sat - 0.01 * sat, **options)
    cost_margin = sum(rows)
    err_plain, err_margin = along_normal_error(plain, truth), along_normal_error(margin, truth)
    print(f"mean error {np.mean(err_plain[plain.ok]):+.3f} px -> {np.mean(err_margin[margin.ok]):+.4f} px; "
          f"rows evaluated {cost_plain} -> {cost_margin}")
    assert margin.ok.mean() > 0.98
    assert np.mean(err_plain[plain.ok]) < -0.3
    assert abs(np.mean(err_margin[margin.ok])) < 0.01
    assert cost_margin < 0.5 * cost_plain


def test_contrast_hint_skips_the_contrast_measurement_and_gives_the_same_edges(monkeypatch):
    """Fitted again from its own fits with its shared contrast as the hint (a static target at constant exposure in
    tracking mode), a frame of clipped edges costs a fraction of the model evaluations and gives the same edges; a
    hint 2x off (an exposure change the hint missed) is refused (residuals grow) and the contrast measured again."""
    img, truth, init, normals, sat = overexposed_tiles(4.0)
    clip_level = 0.99 * sat
    options = dict(sigma_fallback_px=0.8, sigma_init_px=0.8, shared_contrast=True)
    rows = count_model_rows(monkeypatch)
    first = fit_edges_two_pass(img, init, normals, clip_level, **options)
    contrast = float(np.median((first.white_level - first.black_level)[first.ok]))
    begin = dataclasses.replace(first, offset_px=first.offset_px.copy())
    points = init  # the same sample points: offsets relative to them
    rows.clear()
    again = fit_edges_two_pass(img, points, normals, clip_level, start=begin, contrast_hint=contrast, **options)
    cost_hint = sum(rows)
    rows.clear()
    fresh = fit_edges_two_pass(img, points, normals, clip_level, start=begin, **options)
    cost_fresh = sum(rows)
    rows.clear()
    wrong = fit_edges_two_pass(img, points, normals, clip_level, start=begin, contrast_hint=2 * contrast, **options)
    print(f"rows evaluated: hint {cost_hint}, no hint {cost_fresh}, wrong hint {sum(rows)}")
    assert again.ok.mean() > 0.98
    assert np.abs(again.offset_px - first.offset_px)[again.ok & first.ok].max() < 2e-3
    assert cost_hint < 0.5 * cost_fresh
    assert np.abs(wrong.offset_px - fresh.offset_px)[wrong.ok & fresh.ok].max() < 1e-6
    assert sum(rows) > cost_fresh  # the refused attempt, then the measurement
