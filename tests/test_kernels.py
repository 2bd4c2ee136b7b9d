"""The compiled (numba) edge-fit kernels agree with the numpy reference: the edge-profile model and its
Jacobian, the normal equations of the clipped / halo / curved model, and whole fits (to 1e-9 px); the kernel
choice (``LIVETRACK_KERNELS``); the on-disk cache and its absence."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from livetrack.estimator import edge_kernels, fit_edges, fit_edges_two_pass
from livetrack.estimator import edges as edges_module
from livetrack.estimator.edge_model import SMALL_B, edge_response_rows
from tests.test_edges import SAT, poisson_gaussian, tiled_edges

pytestmark = pytest.mark.skipif(not edge_kernels._HAVE_NUMBA, reason="numba not installed")

ANGLES_DEG = {
    "axis": 0.0,  # b = 0 (the small-b expansion)
    "near-axis": 0.3,  # b < SMALL_B
    "30": 30.0,
    "diagonal": 45.0,
    "random": None,
}


def edges_at(angle_deg, clipped, seed=5, n=8):
    """Noisy tiled edges (n x n tiles) all at ``angle_deg`` (or random angles), over-exposed 4x or not."""
    rng = np.random.default_rng(seed)
    lw = 4.0 * SAT if clipped else 200.0
    img, truth, init, normals = tiled_edges(rng, n, n, 21, 0.9, 20.0, lw, SAT)
    if angle_deg is not None:  # re-render with one angle for all tiles
        t = np.deg2rad(angle_deg) + np.pi * (np.arange(n * n) % 2)  # both orientations
        normals = np.stack([np.cos(t), np.sin(t)], axis=1)
        img, truth, init, normals = _render(rng, truth, normals, n, lw)
    return poisson_gaussian(rng, img, 4.0, 0.05, SAT), truth, init, normals


def _render(rng, centre, normals, n, lw, tile=21):
    from livetrack.estimator import edge_intensity, footprint_widths

    ys, xs = np.mgrid[0 : n * tile, 0 : n * tile].astype(float)
    k = (ys // tile).astype(int) * n + (xs // tile).astype(int)
    u = normals[k, 0] * (xs - centre[k, 0]) + normals[k, 1] * (ys - centre[k, 1])
    a, b = footprint_widths(normals[k])
    img = edge_intensity(u, 0.9, 20.0, lw, SAT, a, b)
    tangent = np.stack([-normals[:, 1], normals[:, 0]], axis=1)
    init = centre + rng.uniform(-0.6, 0.6, (len(centre), 1)) * normals + rng.uniform(-2, 2, (len(centre), 1)) * tangent
    return img, centre, init, normals


@pytest.mark.parametrize("angle", list(ANGLES_DEG))
@pytest.mark.parametrize("sigma", [0.3, 0.8, 2.5])
def test_compiled_edge_response_and_derivatives_match_the_reference(angle, sigma):
    rng = np.random.default_rng(1)
    deg = ANGLES_DEG[angle]
    theta = rng.uniform(0, 2 * np.pi, 50) if deg is None else np.full(50, np.deg2rad(deg))
    nx, ny = np.abs(np.cos(theta)), np.abs(np.sin(theta))
    a, b = np.maximum(nx, ny)[:, None], np.minimum(nx, ny)[:, None]
    v = rng.uniform(-6, 6, (50, 23))
    sig = np.full((50, 1), sigma)
    ref = edge_response_rows(v, sig, a, b)
    got = edge_kernels.response_rows(v, sig[:, 0], a[:, 0].copy(), b[:, 0].copy())
    if deg is not None and deg < 1:
        assert (b < SMALL_B).all()
    for r, c in zip(ref, got, strict=True):
        assert np.abs(r - c).max() < 1e-12


def test_compiled_normal_cdf_matches_scipys_ndtr():
    """The kernels' Phi (a table of erfcx polynomials times the exp they share with the pdf) against the
    reference's scipy ``ndtr``: within 8e-16 everywhere, relatively within 2e-14 down to Phi(-10) (the rounding
    of exp(-z^2 / 2)); the pdf factor is exp(-z^2 / 2); NaN stays NaN and the far tails are exactly 0 and 1."""
    import numba
    from scipy.special import ndtr

    @numba.njit
    def cdf_pdf(z):
        cdf, pdf = np.empty_like(z), np.empty_like(z)
        for i in range(len(z)):
            cdf[i], pdf[i] = edge_kernels._cdf_pdf(z[i])
        return cdf, pdf

    z = np.concatenate([np.linspace(-45.0, 45.0, 900_001), np.random.default_rng(0).normal(0.0, 3.0, 100_000)])
    cdf, pdf = cdf_pdf(z)
    ref = ndtr(z)
    assert np.abs(cdf - ref).max() < 8e-16
    tail = (z < 0) & (z > -10)
    assert np.abs(cdf[tail] / ref[tail] - 1.0).max() < 2e-14
    assert np.allclose(pdf, np.exp(-0.5 * z * z), rtol=1e-15, atol=1e-300)  # libm and numpy: 1 ulp
    cdf, pdf = cdf_pdf(np.array([np.nan, np.inf, -np.inf, 1e300, -1e300, 0.0]))
    assert np.isnan(cdf[0]) and np.isnan(pdf[0])
    assert list(cdf[1:5]) == [1.0, 0.0, 1.0, 0.0] and list(pdf[1:]) == [0.0, 0.0, 0.0, 0.0, 1.0]
    assert abs(cdf[5] - 0.5) < 4.5e-16


def _profiles(clipped, angle):
    img, truth, init, normals = edges_at(ANGLES_DEG[angle], clipped)
    kappa = np.random.default_rng(2).uniform(-0.05, 0.05, len(init))
    prof, _, _ = edges_module.sample_profiles(img, init, normals, SAT, 4.0, 0.5, None, kappa)
    rng = np.random.default_rng(3)
    params = np.stack([rng.uniform(-0.5, 0.5, len(init)), rng.uniform(0.6, 1.2, len(init)),
                       np.where(prof.top[:, 0] > 0, 4 * SAT, 20.0) + rng.uniform(-5, 5, len(init)),
                       np.log(4 * SAT - 20.0) + rng.uniform(-0.3, 0.3, len(init))], axis=1)
    return prof, params


@pytest.mark.parametrize("angle", ["axis", "near-axis", "random"])
@pytest.mark.parametrize("clipped", [False, True])
@pytest.mark.parametrize("halo", [None, (0.03, 6.0)])
@pytest.mark.parametrize("fixed", ["free", "sigma", "sigma+contrast"])
def test_compiled_normal_equations_match_the_reference(angle, clipped, halo, fixed):
    """J^T J, J^T r, the costs and the live samples of the clipped, curved, optionally halo model."""
    prof, params = _profiles(clipped, angle)
    fixed_sigma, fixed_contrast = fixed != "free", fixed == "sigma+contrast"
    ref = edges_module._evaluate_normal(params, prof, SAT, fixed_sigma, False, halo, fixed_contrast)
    halo_f, halo_s = (0.0, 1.0) if halo is None else halo
    got = edge_kernels.evaluate_normal(params, *edges_module._kernel_arrays(prof), SAT, fixed_sigma, False, halo_f,
                                       halo_s, fixed_contrast)
    for r, c in zip(ref, got, strict=True):
        scale = max(np.abs(r).max(), 1.0)
        assert np.abs(r - c).max() < 1e-11 * scale
    if clipped:
        assert prof.any_clipped


def _both(fn, monkeypatch):
    monkeypatch.setenv("LIVETRACK_KERNELS", "numpy")
    ref = fn()
    monkeypatch.setenv("LIVETRACK_KERNELS", "numba")
    return ref, fn()


def _assert_same_fits(ref, got):
    assert np.array_equal(ref.ok, got.ok)
    assert np.array_equal(ref.n_samples, got.n_samples)
    finite = np.isfinite(ref.offset_px)
    assert np.array_equal(finite, np.isfinite(got.offset_px))
    assert np.abs(ref.offset_px - got.offset_px)[finite].max() < 1e-9  # px
    assert np.abs(ref.points_px - got.points_px)[finite].max() < 1e-9
    assert np.abs(ref.sigma_px - got.sigma_px)[finite].max() < 1e-9
    for name in ("black_level", "white_level", "residual_rms"):
        r, c = getattr(ref, name), getattr(got, name)
        assert np.abs(r - c)[finite].max() < 1e-9 * max(np.abs(r[finite]).max(), 1.0), name
    std = np.isfinite(ref.position_std_px)
    assert np.array_equal(std, np.isfinite(got.position_std_px))
    assert np.abs(ref.position_std_px - got.position_std_px)[std].max() < 1e-9


@pytest.mark.parametrize("angle", list(ANGLES_DEG))
@pytest.mark.parametrize("clipped", [False, True])
@pytest.mark.parametrize("halo", [None, (0.03, 6.0)])
def test_compiled_fits_match_the_reference_to_1e9_px(angle, clipped, halo, monkeypatch):
    img, truth, init, normals = edges_at(ANGLES_DEG[angle], clipped)
    kappa = np.full(len(init), 0.02)
    ref, got = _both(lambda: fit_edges_two_pass(img, init, normals, SAT, halo=halo, curvature_per_px=kappa,
                                                shared_contrast=True), monkeypatch)
    assert ref.ok.mean() > 0.8
    _assert_same_fits(ref, got)


@pytest.mark.parametrize("clipped", [False, True])
def test_compiled_fits_match_with_start_weights_and_fixed_sigma(clipped, monkeypatch):
    """Started from earlier fits (tracking), weighted by a noise model, and with a fixed per-point blur."""
    img, truth, init, normals = edges_at(None, clipped)
    first = fit_edges_two_pass(img, init, normals, SAT)
    ref, got = _both(lambda: fit_edges_two_pass(img, init, normals, SAT, start=first, noise_model=(4.0, 0.05)),
                     monkeypatch)
    _assert_same_fits(ref, got)
    sig = np.linspace(0.7, 1.1, len(init))
    ref, got = _both(lambda: fit_edges(img, init, normals, SAT, fix_sigma=sig, iterations=3), monkeypatch)
    _assert_same_fits(ref, got)


def test_kernel_choice(monkeypatch):
    monkeypatch.setenv("LIVETRACK_KERNELS", "numpy")
    assert edge_kernels.kernels() == "numpy"
    monkeypatch.delenv("LIVETRACK_KERNELS")
    assert edge_kernels.kernels() == "numba"  # the default
    monkeypatch.setenv("LIVETRACK_KERNELS", "fortran")
    with pytest.raises(ValueError, match="LIVETRACK_KERNELS"):
        edge_kernels.kernels()


def test_kernel_choice_cached():
    """The choice is read once and cached (a tracked frame asks ~12 times); reset_kernels makes it read again."""
    import os

    old = os.environ.get(edge_kernels.KERNELS_ENV)
    try:
        os.environ[edge_kernels.KERNELS_ENV] = "numpy"
        edge_kernels.reset_kernels()
        assert edge_kernels.kernels() == "numpy"
        os.environ[edge_kernels.KERNELS_ENV] = "numba"  # not through monkeypatch: the cache holds
        assert edge_kernels.kernels() == "numpy"
        edge_kernels.reset_kernels()
        assert edge_kernels.kernels() == "numba"
    finally:
        if old is None:
            os.environ.pop(edge_kernels.KERNELS_ENV, None)
        else:
            os.environ[edge_kernels.KERNELS_ENV] = old
        edge_kernels.reset_kernels()


def test_constants_are_checked():
    edge_kernels.check_constants({"SMALL_B": SMALL_B})
    with pytest.raises(RuntimeError, match="SMALL_B"):
        edge_kernels.check_constants({"SMALL_B": 2 * SMALL_B})


def test_kernels_release_the_gil_and_agree_when_run_from_two_threads(monkeypatch):
    """Every compiled kernel is ``nogil`` (the live pipeline's search and processing threads fit at once), and
    fits run concurrently from two threads equal the same fits run one after the other."""
    from concurrent.futures import ThreadPoolExecutor

    from livetrack.estimator import pose_kernels

    kernels = [getattr(module, name) for module in (edge_kernels, pose_kernels) for name in dir(module)
               if hasattr(getattr(module, name), "targetoptions")]
    assert len(kernels) >= 5 and all(k.targetoptions.get("nogil") for k in kernels), kernels
    monkeypatch.setenv("LIVETRACK_KERNELS", "numba")
    cases = [edges_at(angle, clipped) for angle in (None, *list(ANGLES_DEG.values())[:1]) for clipped in (False, True)]

    def run(case):
        image, _, points, normals = case
        return fit_edges_two_pass(image, points, normals, SAT, shared_contrast=True).offset_px

    serial = [run(c) for c in cases]
    with ThreadPoolExecutor(2) as pool:
        threaded = list(pool.map(run, cases))
    for a, b in zip(serial, threaded, strict=True):
        np.testing.assert_array_equal(a, b)


_PROBE = """
import json, sys, time
{prelude}
t0 = time.perf_counter()
from livetrack.estimator import edge_kernels
seconds = edge_kernels.warm_up()
print(json.dumps({{"seconds": seconds, **edge_kernels.cache_stats()}}))
"""


def _probe(env, prelude=""):
    out = subprocess.run([sys.executable, "-c", _PROBE.format(prelude=prelude)], env={**os.environ, **env},
                         capture_output=True, text=True, timeout=300, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.slow  # three fresh processes, two of which compile (15-50 s on a loaded machine)
def test_cache_is_written_then_loaded_and_its_absence_is_survived(tmp_path):
    """In a fresh cache directory the first process compiles (misses) and writes the cache; the next one loads
    it (hits, no compilation). Where no cache directory can be used at all, the kernels compile without one."""
    env = {"NUMBA_CACHE_DIR": str(tmp_path / "cache"), "LIVETRACK_KERNELS": "numba"}
    first = _probe(env)
    assert first["misses"] >= 2 and first["hits"] == 0
    again = _probe(env)
    assert again["misses"] == 0 and again["hits"] >= 2
    print(f"compile {first['seconds']:.2f} s, cache load {again['seconds']:.2f} s")
    no_locator = ("import numba.core.caching as c; getattr(c, \"CacheImpl\", getattr(c, \"_CacheImpl\", None))"
                  "._locator_classes = []")
    none = _probe(env, no_locator)
    assert none["hits"] == 0 and none["seconds"] > 0


@pytest.mark.parametrize("delta_px", [0.0, 0.7])
@pytest.mark.parametrize("estimate_delta", [True, False])
@pytest.mark.parametrize("huber", [3.0, None])
@pytest.mark.parametrize("tilt", ["frontal", "tilted", "darker ground"])
def test_compiled_pose_fit_matches_the_reference(delta_px, estimate_delta, huber, tilt, monkeypatch):
    """The pose Gauss-Newton (residuals, Jacobian, Huber weights, step halving, the blind last step): the same
    iterations, pose, delta, residuals and covariance as the numpy reference; "darker ground": tilted, the outer
    circle's white inside (no share of delta there: ``pose_fit.bias_weights``)."""
    from livetrack.estimator.pose_fit import fit_pose
    from livetrack.geometry import Pose, look_rotation
    from tests.test_pose import CAMERA, edge_observations

    rng = np.random.default_rng(7)
    angles = (0.0, 0.0, 10.0) if tilt == "frontal" else (35.0, 20.0, 15.0)
    pose = Pose(look_rotation(*angles), np.array([0.4, -0.2, 3.0]))
    obs = edge_observations(pose, delta_px, 0.05, rng)
    obs.std_px[:] = rng.uniform(0.03, 0.1, len(obs))  # unequal weights
    obs.points_px[::50] += 2.0  # outliers for the Huber weights
    if tilt == "darker ground":
        obs.white_outside[obs.radius_m >= obs.radius_m.max()] = False
    start = Pose(look_rotation(angles[0] + 3.0, angles[1] + 5.0, angles[2]), pose.t * 1.05)
    ref, got = _both(lambda: fit_pose(CAMERA, obs, start, estimate_delta=estimate_delta, huber_px=huber),
                     monkeypatch)
    assert ref.ok and got.ok and ref.iterations == got.iterations
    assert np.abs(ref.pose.t - got.pose.t).max() < 1e-9 * ref.pose.distance_m
    assert np.abs(ref.pose.R - got.pose.R).max() < 1e-9
    assert abs(ref.delta_px - got.delta_px) < 1e-9
    assert np.abs(ref.residuals_px - got.residuals_px).max() < 1e-9
    assert np.allclose(ref.covariance, got.covariance, rtol=1e-7, atol=0)


def test_pose_normal_equations_written_out_equal_the_matrix_products():
    """``pose_kernels._normal_equations`` sums J^T W J element by element (for speed): every element, the
    right-hand side and the cost equal the matrix products (to rounding)."""
    from livetrack.estimator import pose_kernels

    rng = np.random.default_rng(12)
    J, w, r = rng.standard_normal((300, 6)), rng.uniform(0.1, 2.0, 300), rng.standard_normal(300)
    m, rhs, cost = pose_kernels._normal_equations(J, w, r)
    np.testing.assert_allclose(m, (J.T * w) @ J, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(rhs, -(J.T * w) @ r, rtol=1e-12, atol=1e-12)
    assert cost == pytest.approx(float(np.sum(w * r * r)), rel=1e-12)
    assert np.array_equal(m, m.T)


def test_compiled_pose_fit_fails_as_the_reference(monkeypatch):
    """A start behind the camera: both fail with the same reason; a fit stopped at the cap: not ok, same pose."""
    from livetrack.estimator.pose_fit import fit_pose
    from livetrack.geometry import Pose, look_rotation
    from tests.test_pose import CAMERA, edge_observations

    rng = np.random.default_rng(8)
    pose = Pose(look_rotation(35.0, 20.0, 15.0), np.array([0.4, -0.2, 3.0]))
    obs = edge_observations(pose, 0.5, 0.05, rng)
    behind = Pose(pose.R, -pose.t)
    ref, got = _both(lambda: fit_pose(CAMERA, obs, behind), monkeypatch)
    assert not ref and not got and ref.reason == got.reason and ref.reason
    start = Pose(look_rotation(38.0, 25.0, 15.0), pose.t * 1.05)
    ref, got = _both(lambda: fit_pose(CAMERA, obs, start, max_iterations=1), monkeypatch)
    assert not ref.ok and not got.ok and ref.reason == got.reason
    assert np.abs(ref.pose.t - got.pose.t).max() < 1e-9


@pytest.mark.parametrize("estimate_delta", [True, False])
def test_compiled_pose_covariance_is_the_reference(estimate_delta):
    """``pose_kernels.pose_covariance`` against ``fit_pose``'s numpy lines (the inverse of J^T W J times the
    variance factor, then ``_expand_covariance``): equal to rounding; a singular normal matrix is status 1 where
    numpy's inverse raises."""
    from livetrack.estimator import pose_kernels
    from livetrack.estimator.pose_fit import _expand_covariance
    from livetrack.geometry import look_rotation

    rng = np.random.default_rng(13)
    n_params = 6 if estimate_delta else 5
    J, w, r = rng.standard_normal((400, 6)) * [500.0, 500.0, 80.0, 90.0, 90.0, 1.0], rng.uniform(100, 2500, 400), \
        rng.normal(0.0, 0.05, 400)
    R = look_rotation(30.0, 20.0, 10.0)
    Jp = J[:, :n_params]
    ref = _expand_covariance(np.linalg.inv((Jp.T * w) @ Jp) * float(np.sum(w * r * r) / (400 - n_params)), R, 0.11,
                             estimate_delta)
    got, status = pose_kernels.pose_covariance(J, w, r, n_params, R, 0.11**2, estimate_delta)
    assert status == 0
    np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-12 * np.abs(ref).max())
    J[:, 2] = 0.0
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.inv((J[:, :n_params].T * w) @ J[:, :n_params])
    got, status = pose_kernels.pose_covariance(J, w, r, n_params, R, 0.11**2, estimate_delta)
    assert status == 1 and np.isnan(got).all()
