"""The compiled kernels around the edge LM (livetrack/estimator/edge_glue_kernels.py) against their numpy
references: the sampled pixels and their distances, the pixel values and masks, and the start levels and crossings
give the same numbers; the covariance summary agrees to 1e-9; a warmed-up process compiles nothing more for the
image types it was warmed for."""

import numpy as np
import pytest

from livetrack.estimator import edge_glue_kernels as glue
from livetrack.estimator import edge_kernels, fit_edges, fit_edges_two_pass
from livetrack.estimator import edge_samples as samples
from livetrack.estimator.edges import solver, start
from tests.test_edges import SAT
from tests.test_kernels import edges_at

pytestmark = pytest.mark.skipif(not edge_kernels._HAVE_NUMBA, reason="numba not installed")


def _points(seed, n=400, shape=(60, 80)):
    """Points all over an image of ``shape`` and a little beyond its borders (profiles cut by the border, or
    entirely outside), some on pixel centres and half-pixel positions (ties of the rounding), random normals."""
    rng = np.random.default_rng(seed)
    h, w = shape
    pts = np.stack([rng.uniform(-6, w + 6, n), rng.uniform(-6, h + 6, n)], axis=1)
    pts[: n // 4] = np.round(pts[: n // 4] * 2.0) / 2.0
    theta = rng.uniform(0, 2 * np.pi, n)
    theta[: n // 8] = rng.integers(0, 8, n // 8) * (np.pi / 4)  # on and at 45 degrees to the axes
    return pts, np.stack([np.cos(theta), np.sin(theta)], axis=1), rng.uniform(-0.2, 0.2, n)


@pytest.mark.parametrize("half_width_px, tangent_half_width_px", [(4.0, 0.5), (6.0, 0.0), (2.5, 1.0)])
@pytest.mark.parametrize("curved", [False, True])
def test_compiled_sample_geometry_is_the_reference(half_width_px, tangent_half_width_px, curved):
    shape = (60, 80)
    pts, nrm, kappa = _points(1, shape=shape)
    stencil = np.ascontiguousarray(samples._stencil(half_width_px, tangent_half_width_px))
    ref = samples._geometry_numpy(shape, pts, nrm, kappa if curved else None, stencil)
    got = glue.sample_geometry(shape[0], shape[1], pts, nrm, kappa, curved, stencil)
    got = got[:4] + (got[4][:, None],)
    assert ref[2].sum(axis=1).min() == 0 < ref[2].sum(axis=1).max()  # some profiles entirely outside
    for r, c in zip(ref, got, strict=True):
        assert r.shape == c.shape and r.dtype == c.dtype
        assert np.array_equal(r, c)


def _image(dtype, seed=2, shape=(60, 80)):
    """An image of ``dtype`` with values below 0 / at 0 and at / above the clip level (and NaN / inf for floats)."""
    rng = np.random.default_rng(seed)
    top = {np.uint8: 255.0, np.uint16: 4095.0}.get(dtype, 1.0)
    img = rng.uniform(-0.1 * top, 1.1 * top, shape)
    if np.dtype(dtype).kind == "f":
        img[rng.random(shape) < 0.02] = np.nan
        img[rng.random(shape) < 0.01] = np.inf
    else:
        img = np.clip(np.round(img), 0, np.iinfo(dtype).max)
    return img.astype(dtype), top


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32, np.float64])
@pytest.mark.parametrize("noise_model", [None, (4.0, 0.05)])
@pytest.mark.parametrize("reach", [False, True])
def test_compiled_pixel_reading_is_the_reference(dtype, noise_model, reach, monkeypatch):
    img, sat = _image(dtype)
    pts, nrm, kappa = _points(3, shape=img.shape)
    reach_px = np.random.default_rng(4).uniform(0.5, 5.0, (len(pts), 2)) if reach else None
    out = {}
    for kernels in ("numpy", "numba"):
        monkeypatch.setenv("LIVETRACK_KERNELS", kernels)
        out[kernels] = samples.sample_profiles(img, pts, nrm, sat, 4.0, 0.5, noise_model, kappa, reach_px)
    (ref, ref_n, ref_c), (got, got_n, got_c) = out["numpy"], out["numba"]
    assert np.array_equal(ref_n, got_n) and np.array_equal(ref_c, got_c)
    assert ref_c.sum() > 0 and ref.any_top
    for name in samples.Profiles._ARRAYS + ("n_valid", "n_span"):
        r, c = getattr(ref, name), getattr(got, name)
        assert r.shape == c.shape and r.dtype == c.dtype, name
        assert np.array_equal(r, c), name
    assert (ref.any_clipped, ref.any_top) == (got.any_clipped, got.any_top)


@pytest.mark.parametrize("kernels", ["numpy", "numba"])
def test_profiles_cut_short_by_their_reach_keep_every_valid_sample(kernels, monkeypatch):
    """``reach_px`` leaves out samples between valid ones (the pixels are in row-major order, not along the
    normal): taking rows keeps all the valid samples, trimming only columns where no row has one."""
    monkeypatch.setenv("LIVETRACK_KERNELS", kernels)
    img, sat = _image(np.uint16)
    pts, nrm, kappa = _points(5, shape=img.shape)
    reach_px = np.random.default_rng(6).uniform(1.0, 2.0, (len(pts), 2))  # every profile cut short
    prof = samples.sample_profiles(img, pts, nrm, sat, 4.0, 0.5, None, kappa, reach_px)[0]
    assert prof.n_span.max() > 2 * prof.n_valid.max()  # trimmed to the most valid samples of a row, half would go
    rows = np.flatnonzero(prof.n_valid > 0)
    taken = prof.take(rows)
    assert taken.valid.sum() == prof.valid.sum()
    assert np.array_equal(taken.n_span, prof.n_span[rows]) and taken.valid.shape[1] == prof.n_span.max()


def test_an_image_the_kernel_was_not_warmed_for_is_read_by_numpy(monkeypatch):
    """A strided view (e.g. a region of interest) or an int32 image: the numpy lines, the same numbers."""
    img, sat = _image(np.uint16)
    pts, nrm, kappa = _points(4, shape=img.shape)
    for other in (img[:, ::-1], img.astype(np.int32)):
        assert not samples._compiled_read(other)
        monkeypatch.setenv("LIVETRACK_KERNELS", "numba")
        got = samples.sample_profiles(other, pts, nrm, sat, 4.0, 0.5, None, kappa)[0]
        monkeypatch.setenv("LIVETRACK_KERNELS", "numpy")
        ref = samples.sample_profiles(np.ascontiguousarray(other), pts, nrm, sat, 4.0, 0.5, None, kappa)[0]
        assert np.array_equal(ref.data, got.data) and np.array_equal(ref.valid, got.valid)


@pytest.mark.parametrize("clipped", [False, True])
def test_compiled_levels_and_crossing_are_the_reference(clipped):
    img, _, init, normals = edges_at(None, clipped)
    img = img.copy()
    img[::7, ::5] = 0.0  # some samples clipped at 0: profiles clipped at 0 only, and at both ends
    prof, _, _ = samples.sample_profiles(img, init, normals, SAT, 4.0, 0.5, None, None)
    assert prof.clip_lo.any() and (prof.clip_hi.any() or not clipped)
    args = (prof.u0, prof.data, prof.valid, prof.clip_hi, prof.clip_lo)
    ref = start._levels_crossing(*args, SAT)
    got = glue.levels_crossing(*(np.ascontiguousarray(x) for x in args), SAT)
    for r, c in zip(ref, got, strict=True):
        assert np.array_equal(r, c)
    assert (ref[3] != 0).mean() > 0.5  # most profiles cross


def _normal_equations(clipped, fixed, weighted):
    """Normal equations at the solution of real fits (the compiled LM), as ``solver._fit`` hands them on."""
    img, _, init, normals = edges_at(None, clipped)
    prof, n_samples, n_clipped = samples.sample_profiles(img, init, normals, SAT, 4.0, 0.5,
                                                         (4.0, 0.05) if weighted else None, None)
    n = len(init)
    d0, _, lb0, lw0 = start._initial_params(prof.u0, prof.data, prof.valid, prof.clip_hi, prof.clip_lo, SAT,
                                            np.full(n, 0.9), prof.a, prof.b).T
    params = np.stack([d0, np.full(n, 0.9), np.where(prof.top[:, 0] > 0, lw0, lb0),
                       np.log(np.maximum(lw0 - lb0, 1e-3))], axis=1)
    fixed_sigma, fixed_c = fixed != "free", fixed == "sigma+contrast"
    out = edge_kernels.levenberg_marquardt(params, *solver._kernel_arrays(prof), SAT, fixed_sigma, weighted, 0.0, 1.0,
                                           fixed_c, 4.0, 0.3, 5.0, 8, solver.BLIND_STEP_PX, 3, 0.01)
    return params, out, prof.top, n_samples, n_clipped, fixed_sigma, fixed_c


@pytest.mark.parametrize("clipped", [False, True])
@pytest.mark.parametrize("fixed", ["free", "sigma", "sigma+contrast"])
@pytest.mark.parametrize("weighted", [False, True])
def test_compiled_fit_summary_matches_the_reference(clipped, fixed, weighted):
    """Position standard deviations within 1e-9 relative (Gaussian elimination against LAPACK's inverse), residual
    RMS and ``ok`` the same."""
    params, (a_mat, g, cost, ssr, n_live, blind), top, n_samples, n_clipped, fixed_sigma, fixed_c = \
        _normal_equations(clipped, fixed, weighted)
    n_params = (3 if fixed_sigma else 4) - (1 if fixed_c else 0)
    limits = (4.0, 0.3, 5.0, 0.02 * SAT)
    ref = solver._summary_numpy(params, a_mat.copy(), g, cost, ssr, n_live, blind, top, fixed_sigma, fixed_c,
                                weighted, n_params, n_samples, n_clipped, *limits)
    lb, lw = solver._levels(params, top)
    got = glue.fit_summary(params, a_mat.copy(), g, cost, ssr, n_live, blind, lb, lw, fixed_sigma, fixed_c,
                           weighted, n_params, n_samples, n_clipped, *limits, solver.CONVERGED_STEP_PX)
    std_ref, rms_ref, _, _, ok_ref = ref
    std, rms, ok = got
    assert ok_ref.any()
    assert np.array_equal(ok_ref, ok)
    assert np.array_equal(rms_ref, rms)
    finite = np.isfinite(std_ref)
    assert np.array_equal(finite, np.isfinite(std))
    assert np.abs(std - std_ref)[finite].max() <= 1e-9 * np.abs(std_ref[finite]).max()


def test_a_warmed_up_process_compiles_nothing_more_when_fitting(monkeypatch):
    """The kernels' argument types at a fit are those the warm-up compiled (or loaded): no compilation during a
    frame, for each image dtype it warms (writeable or read-only), curved or straight, clipped or not, weighted,
    with a contrast hint."""
    monkeypatch.setenv("LIVETRACK_KERNELS", "numba")
    edge_kernels.warm_up()
    kernels = edge_kernels._warm_functions()
    before = [len(k.signatures) for k in kernels]
    img, _, init, normals = edges_at(None, True)
    for dtype in glue.READ_DTYPES:
        for writeable in (True, False):
            frame = np.clip(img, 0, 255 if dtype == np.uint8 else SAT).astype(dtype)
            frame.flags.writeable = writeable
            first = fit_edges_two_pass(frame, init, normals, SAT, curvature_per_px=np.full(len(init), 0.02),
                                       shared_contrast=True, reach_px=np.full((len(init), 2), 3.0))
            fit_edges_two_pass(frame, init, normals, SAT, start=first, noise_model=(4.0, 0.05))
            fit_edges_two_pass(frame, init, normals, SAT, start=first, shared_contrast=True, contrast_hint=1.3 * SAT)
            fit_edges(frame, init, normals, SAT, fix_sigma=0.9)
    assert [len(k.signatures) for k in kernels] == before


def test_compiled_masked_median_is_numpys(monkeypatch):
    """``masked_median`` (the tracker's medians) gives ``np.median(values[mask])``'s number, odd and even counts,
    ties and signed zeros included; NaN when a chosen value is NaN or none is chosen; ``median_where`` runs it or
    numpy by ``LIVETRACK_KERNELS``."""
    rng = np.random.default_rng(7)
    for n in (1, 2, 3, 4, 5, 16, 17, 300, 511):
        for values in (rng.normal(0.8, 0.1, n), rng.integers(0, 4, n).astype(np.float64), -np.zeros(n)):
            mask = rng.random(n) < 0.7
            mask[0] = True
            ref = np.median(values[mask])
            got = glue.masked_median(values, mask)
            assert got == ref and np.signbit(got) == np.signbit(ref)
    values = rng.normal(size=9)
    values[4] = np.nan
    mask = np.ones(9, dtype=bool)
    assert np.isnan(glue.masked_median(values, mask)) and np.isnan(np.median(values))
    mask[4] = False
    assert glue.masked_median(values, mask) == np.median(values[mask])
    assert np.isnan(glue.masked_median(values, np.zeros(9, dtype=bool)))
    for choice in ("numba", "numpy"):
        monkeypatch.setenv("LIVETRACK_KERNELS", choice)
        assert glue.median_where(values, mask) == np.median(values[mask])


@pytest.mark.parametrize("contrast", ["scalar", "per point"])
@pytest.mark.parametrize("clipped", [True, False])
def test_compiled_start_of_clipped_profiles_of_known_contrast_is_the_reference(contrast, clipped, monkeypatch):
    """``start._initial_params`` with a known contrast (tracked over-exposed frames): the compiled transition
    samples and scipy's ndtri through ``scipy_ndtri`` (``hinted_start_terms``) give the numpy reference's numbers,
    for profiles clipped high (over-exposed) and clipped at 0 only (some dark samples at 0)."""
    from scipy.special import ndtri

    p = np.random.default_rng(4).uniform(-1e-12, 1.0 + 1e-12, 20_001)
    p[:2] = 0.0, 1.0
    fn = glue.scipy_ndtri()
    assert np.array_equal(np.array([fn(v) for v in p]), ndtri(p))
    img, _, init, normals = edges_at(None, clipped)
    img = img.copy()
    img[::7, ::5] = 0.0
    prof, _, _ = samples.sample_profiles(img, init, normals, SAT, 4.0, 0.5, None, None)
    n = len(init)
    known = 1.3 * SAT if contrast == "scalar" else np.random.default_rng(5).uniform(0.8, 3.0, n) * SAT
    sig0 = np.random.default_rng(6).uniform(0.6, 1.4, n)
    args = (prof.u0, prof.data, prof.valid, prof.clip_hi, prof.clip_lo, SAT, sig0, prof.a, prof.b, known)
    monkeypatch.setenv("LIVETRACK_KERNELS", "numpy")
    ref = start._initial_params(*args)
    monkeypatch.setenv("LIVETRACK_KERNELS", "numba")
    got = start._initial_params(*args)
    assert np.array_equal(got, ref)
    high, low = prof.clip_hi.any(axis=1), prof.clip_lo.any(axis=1)
    assert high.mean() > 0.5 if clipped else (not high.any() and 0.1 < low.mean() < 0.9)


@pytest.mark.parametrize("fixed", [False, True])
def test_compiled_start_from_earlier_fits_is_the_reference(fixed, monkeypatch):
    """``solver._fit`` started from earlier fits (tracked frames): the compiled start (``start_blur``,
    ``start_params``) gives the numpy branch's parameters exactly: earlier fits not ok, with a non-finite blur or
    level, or inverted levels are not used; still edges start at their earlier offset and levels, moved ones at
    their data; the blur is the earlier fit's, clipped, unless fixed."""
    img, _, init, normals = edges_at(None, False)
    prof, n_samples, n_clipped = samples.sample_profiles(img, init, normals, SAT, 4.0, 0.5, None, None)
    n = len(init)
    first = fit_edges(img, init, normals, SAT)
    rng = np.random.default_rng(8)
    ok = first.ok & (rng.random(n) < 0.9)
    offset = first.offset_px + np.where(rng.random(n) < 0.5, 0.0, rng.uniform(-0.5, 0.5, n))
    sigma = np.where(rng.random(n) < 0.1, 7.0, first.sigma_px)  # some beyond the blur bounds: clipped
    black, white = first.black_level.copy(), first.white_level.copy()
    sigma[1], black[2], white[3], black[4] = np.nan, np.inf, np.nan, white[4] + 1.0
    start_fits = (ok, offset, sigma, black, white)
    seen = {}

    def spy(params, *args):
        seen[edge_kernels.kernels()] = params.copy()

    monkeypatch.setattr(solver, "_solve", spy)
    for choice in ("numpy", "numba"):
        monkeypatch.setenv("LIVETRACK_KERNELS", choice)
        solver._fit(prof, init, normals, SAT, np.full(n, 0.9), fixed, n_samples, n_clipped, 4.0, (0.3, 5.0),
                    0.02 * SAT, 8, False, start_fits)
    assert np.array_equal(seen["numba"], seen["numpy"])
    still = np.abs(seen["numpy"][:, 0] - offset) == 0
    assert 0.2 < still.mean() < 0.9


def test_compiled_unit_normals_are_check_points_numpy_lines(monkeypatch):
    rng = np.random.default_rng(7)
    nrm = rng.normal(size=(300, 2)) * rng.uniform(1e-3, 1e3, (300, 1))
    nrm[:10] = 0.0  # zero length: divided by 1
    nrm[10, 0] = np.nan
    pts = rng.uniform(0, 50, (300, 2))
    image = np.zeros((60, 80))
    got = samples.check_points(image, pts, nrm)
    monkeypatch.setenv(edge_kernels.KERNELS_ENV, "numpy")
    edge_kernels.reset_kernels()
    try:
        ref = samples.check_points(image, pts, nrm)
    finally:
        monkeypatch.undo()
        edge_kernels.reset_kernels()
    assert np.array_equal(got[0], ref[0])
    assert np.array_equal(got[1], ref[1], equal_nan=True)


def test_compiled_bounds_are_numpys_min_and_max():
    rng = np.random.default_rng(8)
    for n in (1, 2, 517):
        pts = rng.uniform(-100, 2000, (n, 2))
        x, y = pts[:, 0], pts[:, 1]
        assert glue.bounds_xy(pts) == (x.min(), y.min(), x.max(), y.max())
    pts[5, 1] = np.nan
    lo_x, lo_y, hi_x, hi_y = glue.bounds_xy(pts)
    assert (lo_x, hi_x) == (pts[:, 0].min(), pts[:, 0].max()) and np.isnan(lo_y) and np.isnan(hi_y)
