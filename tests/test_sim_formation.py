"""Image formation (radiometry, optics, sensor, effects) against analytic truth."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
import pytest
from scipy import optimize, special

from livetrack.camera import CameraModel
from livetrack.config.checks import ConfigError
from livetrack.geometry import Pose, look_rotation
from livetrack.sim.coverage import Placement
from livetrack.sim.effects import (
    EFFECTS,
    Blooming,
    Defocus,
    Effects,
    GammaEncoding,
    Halo,
    Jpeg,
    LensDistortion,
    MotionBlur,
    Nonlinear,
    SrgbEncoding,
    VeilingGlare,
    Vignetting,
)
from livetrack.sim.formation import ImageFormation, Radiometry
from livetrack.sim.optics import OpticsModel, gaussian_kernel, line_kernel, pillbox_kernel
from livetrack.sim.sensor import SensorModel
from livetrack.sim.texture import ImageTexture

W, H = 64, 48
CAM = CameraModel(W, H, 500.0, 500.0, (W - 1) / 2, (H - 1) / 2, bit_depth=12)
TOP = 4095


def formation(**kwargs) -> ImageFormation:
    return ImageFormation(camera=kwargs.pop("camera", CAM), **kwargs)


def flat(value: float, shape: tuple[int, int] = (H, W)) -> np.ndarray:
    return np.full(shape, value)


def edge_placement(angle_deg: float, offset_px: tuple[float, float]) -> Placement:
    """A sheet covering the whole image, black for plane x < 0 and white for x > 0, at 1 m, frontal, rolled by
    ``angle_deg``; the edge passes through pixel CAM centre + ``offset_px``."""
    texture = ImageTexture(np.array([[0.0, 1.0]]), size_m=2.0)
    t = np.array([offset_px[0] / CAM.fx, offset_px[1] / CAM.fy, 1.0])
    return Placement(Pose(look_rotation(0.0, 0.0, angle_deg), t), texture)


def crossing(profile: np.ndarray, level: float) -> float:
    """Sub-pixel position where a rising ``profile`` first crosses ``level``: cubic through 4 samples."""
    k = int(np.flatnonzero((profile[:-1] < level) & (profile[1:] >= level))[0])
    xs = np.arange(k - 1, k + 3)
    coef = np.polyfit(xs - k, profile[xs] - level, 3)
    roots = [r.real for r in np.roots(coef) if abs(r.imag) < 1e-9 and -1e-9 <= r.real <= 1 + 1e-9]
    assert len(roots) == 1
    return k + roots[0]


# ---------------------------------------------------------------------------------------------- radiometry
def test_white_paper_at_nominal_exposure_reads_55_percent_of_full_well():
    f = formation()
    exposure = f.nominal_exposure_us(0.85, 0.55)
    assert exposure == pytest.approx(0.55 * 10000 / (0.85 * Radiometry().white_rate_e_per_us))
    assert 1800 < exposure < 2200  # the documented ~2000 us default
    dn = f.expected_dn_from_optical(flat(0.85), exposure)
    np.testing.assert_allclose(dn, 0.55 * TOP, rtol=1e-6)
    # The same through the real renderer: a uniform white sheet filling the frame.
    sheet = Placement(Pose(np.eye(3), np.array([0.0, 0.0, 1.0])), ImageTexture(np.ones((1, 1)), size_m=2.0))
    np.testing.assert_allclose(f.expected_dn([sheet], exposure), 0.55 * TOP, rtol=1e-6)


def test_uniform_field_without_blur_or_noise_is_exact():
    sensor = SensorModel(black_level_dn=64.0, dn_per_e=0.3)
    for optics in (OpticsModel(psf_sigma_px=0.0), OpticsModel(psf_sigma_px=0.8)):
        f = formation(optics=optics, sensor=sensor)
        for refl, exposure in ((0.37, 1234.5), (0.04, 100.0), (0.85, 3000.0)):
            electrons = refl * 3.2 * exposure
            truth = 64.0 + 0.3 * electrons
            np.testing.assert_allclose(f.expected_dn_from_optical(flat(refl), exposure), truth, rtol=1e-6)
            image = f.render_from_optical(flat(refl), exposure, noise=False)
            assert image.dtype == np.uint16
            assert np.all(image == round(truth))


# ---------------------------------------------------------------------------------------------- optics
@pytest.mark.parametrize("optics", [
    OpticsModel(psf_sigma_px=0.8),
    OpticsModel(psf_sigma_px=0.8, halo_fraction=0.05, halo_sigma_px=6.0),
    OpticsModel(psf_sigma_px=0.0, defocus_radius_px=2.3),
    OpticsModel(psf_sigma_px=0.5, motion_blur_px=4.2, motion_blur_angle_deg=33.0),
])
def test_psf_conserves_energy(optics):
    rng = np.random.default_rng(3)
    image = np.zeros((120, 140))
    image[40:80, 50:90] = rng.random((40, 40)) * 1000.0
    out = optics.apply(image)
    assert out.dtype == np.float32 and out.shape == image.shape
    assert float(out.sum(dtype=np.float64)) == pytest.approx(image.sum(), rel=1e-5)
    assert not np.array_equal(out, image)


def test_optical_image_of_a_target_conserves_energy_and_converges_with_oversampling():
    from livetrack.sim.texture import TargetTexture
    from livetrack.targets.spec import TargetSpec

    cam = CameraModel(160, 120, 400.0, 400.0, 79.5, 59.5, dist=(-0.2, 0.0, 0.0, 0.0, 0.0), bit_depth=12)
    placement = Placement(Pose(look_rotation(25.0, 40.0, 10.0), np.array([0.03, -0.02, 1.3])),
                          TargetTexture(TargetSpec.default(3, 0.1)))
    effects = Effects(halo=Halo(fraction=0.05, sigma_px=4.0))
    images = {}
    for n in (1, 3, 4):
        f = formation(camera=cam, optics=OpticsModel(psf_sigma_px=0.8, oversampling=n), effects=effects)
        reflectance = f.reflectance([placement])
        images[n] = f.optical_image([placement])
        assert float(images[n].sum(dtype=np.float64)) == pytest.approx(reflectance.sum(), rel=5e-5)
    np.testing.assert_array_equal(images[1], formation(camera=cam, optics=OpticsModel(oversampling=1),
                                                       effects=effects).optics_in_use.apply(reflectance))
    step = 0.85 - 0.04
    # Oversampling 3 and 4 agree to the predicted 1/n^2 error (~0.3 % of the step); 1 is off by several %.
    assert np.max(np.abs(images[3] - images[4])) < 0.004 * step
    assert np.max(np.abs(images[1] - images[4])) > 0.01 * step


def test_kernels_have_their_analytic_second_moments():
    for sigma in (0.8, 2.0, 6.0):
        k = gaussian_kernel(sigma).astype(np.float64)
        x = np.arange(k.size) - k.size // 2
        assert k.sum() == pytest.approx(1.0, abs=1e-6)
        assert np.sum(k * x * x) == pytest.approx(sigma**2, rel=0.01)  # sampled Gaussian, 1 %
    r = 3.0
    k = pillbox_kernel(r).astype(np.float64)
    y, x = np.mgrid[:k.shape[0], :k.shape[1]] - k.shape[0] // 2
    assert np.sum(k * (x * x + y * y)) == pytest.approx(r * r / 2 + 1 / 6, rel=0.02)  # disk + pixel box
    length, angle = 6.0, 30.0
    k = line_kernel(length, angle).astype(np.float64)
    y, x = np.mgrid[:k.shape[0], :k.shape[1]] - k.shape[0] // 2
    along = x * math.cos(math.radians(angle)) + y * math.sin(math.radians(angle))
    assert np.sum(k * along) == pytest.approx(0.0, abs=1e-6)  # centred
    # uniform segment L^2/12 plus the bilinear split's spread (1/6 px^2 on average)
    assert np.sum(k * along**2) == pytest.approx(length**2 / 12 + 1 / 6, abs=0.03)
    k = line_kernel(length, 0.0).astype(np.float64)
    assert np.sum(k * y * y) == pytest.approx(0.0, abs=1e-12)  # no spread across a horizontal motion


def edge_profile_model(sigma: float, angle_deg: float) -> Callable[[np.ndarray], np.ndarray]:
    """Normalised (0 -> 1) profile along an image row across a straight edge at ``angle_deg`` from vertical,
    as a function of x - x_edge: the step convolved with the Gaussian PSF and the pixel square (whose
    projection on the edge normal is two boxes of widths |cos a| and |sin a|), by 64 x 64 point quadrature
    of the boxes (error < 1e-5)."""
    c, s = abs(math.cos(math.radians(angle_deg))), abs(math.sin(math.radians(angle_deg)))
    q = (np.arange(64) + 0.5) / 64 - 0.5
    shifts = (q[:, None] * c + q[None, :] * s).ravel()

    def model(dx: np.ndarray) -> np.ndarray:
        u = np.asarray(dx)[..., None] * c + shifts
        return np.mean(special.ndtr(u / sigma), axis=-1)

    return model


@pytest.mark.parametrize("angle_deg", [0.0, 20.0, 37.0])
@pytest.mark.parametrize("offset_px", [(0.0, 0.0), (0.27, 0.1), (0.5, -0.3), (-0.81, 0.45)])
def test_gaussian_psf_keeps_the_50_percent_crossing_of_a_straight_edge(angle_deg, offset_px):
    """Fit the physical edge profile (its 50 % crossing is x_edge by symmetry) to each row of the rendered
    noise-free image: position within 0.02 px of the truth, and the whole profile within 0.4 % of the step
    (the PSF acts on a 3x finer grid: 0.26 % expected; on the pixel image it would be 2.8 %)."""
    sigma = 0.8
    f = formation(optics=OpticsModel(psf_sigma_px=sigma))
    exposure = f.nominal_exposure_us(0.85, 0.55)  # white at 55 %: no clipping
    dn = f.expected_dn([edge_placement(angle_deg, offset_px)], exposure)
    assert dn.max() < 0.6 * TOP
    lo, hi = 0.04 * 3.2 * exposure * TOP / 1e4, 0.85 * 3.2 * exposure * TOP / 1e4
    model = edge_profile_model(sigma, angle_deg)
    a = math.radians(angle_deg)
    x0, y0 = CAM.cx + offset_px[0], CAM.cy + offset_px[1]
    xs = np.arange(W, dtype=np.float64)
    for row in range(12, H - 12, 3):
        true_x = x0 - (row - y0) * math.tan(a)  # the edge line through (x0, y0), direction (-sin a, cos a)
        window = np.abs(xs - true_x) < 8
        data = (dn[row, window] - lo) / (hi - lo)
        fit = optimize.minimize_scalar(lambda e, d=data, x=xs[window]: np.sum((model(x - e) - d) ** 2),
                                       bounds=(true_x - 1, true_x + 1), method="bounded",
                                       options={"xatol": 1e-6})
        assert abs(fit.x - true_x) < 0.02
        assert np.max(np.abs(model(xs[window] - fit.x) - data)) < 4e-3
        assert crossing(dn[row], 0.5 * (lo + hi)) == pytest.approx(true_x, abs=0.04)  # plain cubic: coarser


@pytest.mark.parametrize("factor", [2.0, 4.0, 8.0])
def test_overexposed_edge_moves_into_the_dark_side_as_the_clipped_edge_model_predicts(factor):
    """White at ``factor`` x full well: the mid-level threshold between black and saturation crosses where the
    unclipped profile P (PSF and pixel box) reaches (S - B) / (2 (W - B)) (METHOD.md, the exposure bias)."""
    sigma = 1.2
    f = formation(optics=OpticsModel(psf_sigma_px=sigma), sensor=SensorModel(dn_per_e=0.4))
    exposure = factor * 10000 / (0.85 * 3.2)  # white paper at ``factor`` x full well
    offset = 0.37
    dn = f.expected_dn([edge_placement(0.0, (offset, 0.0))], exposure)
    white, black = factor * 4000.0, factor * 4000.0 * 0.04 / 0.85
    S = 4000.0  # full well, below the top code
    assert dn.max() == pytest.approx(S)
    level = 0.5 * (black + S)
    model = edge_profile_model(sigma, 0.0)
    p = (S - black) / (2 * (white - black))
    shift = optimize.brentq(lambda u: model(np.array([u]))[0] - p, -6, 6)
    assert shift < -0.5 * sigma  # into the dark side
    true_x = CAM.cx + offset
    xs = np.arange(W, dtype=np.float64)
    samples = np.minimum(black + (white - black) * model(xs - true_x), S)
    sim_cross = crossing(dn[H // 2], level)
    # Same interpolation on the model's own samples: only the simulator's departure from the model remains.
    assert sim_cross == pytest.approx(crossing(samples, level), abs=0.01)
    assert sim_cross - true_x == pytest.approx(shift, abs=0.2)  # cubic interpolation on the curved tail


# ---------------------------------------------------------------------------------------------- sensor
def test_clipping_at_full_well_and_at_the_top_code():
    # dn_per_e puts full well at 2000 DN: over-exposure clips at full well, well below the top code.
    f = formation(sensor=SensorModel(dn_per_e=0.2, read_noise_e=0.0))
    exposure = 3.0 * 10000 / (0.85 * 3.2)  # white at 3x full well
    np.testing.assert_allclose(f.expected_dn_from_optical(flat(0.85), exposure), 2000.0, rtol=1e-6)
    # +20 dB (x10): full well would be 20000 DN, so the ADC clips at the top code.
    np.testing.assert_array_equal(f.expected_dn_from_optical(flat(0.85), exposure, gain_db=20.0), TOP)
    noisy = f.render_from_optical(flat(0.85), exposure, gain_db=20.0, rng=np.random.default_rng(1))
    assert np.all(noisy == TOP)
    # Default gain: full well reads exactly the top code; an 8-bit sensor gives uint8.
    cam8 = dataclasses.replace(CAM, bit_depth=8)
    f8 = formation(camera=cam8, sensor=SensorModel(bit_depth=8))
    img = f8.render_from_optical(flat(0.85), exposure, rng=np.random.default_rng(1))
    # Read noise (0.13 DN RMS here) comes after the full-well clip: saturated pixels read the top code or,
    # rarely, one below.
    assert img.dtype == np.uint8 and img.min() >= 254 and np.mean(img == 255) > 0.99
    # Dark: read noise around a zero black level clips at 0 DN.
    dark = f8.render_from_optical(flat(0.0), 100.0, rng=np.random.default_rng(2))
    assert dark.min() == 0


@pytest.mark.parametrize(("mean_e", "read_e", "dn_per_e", "gain_db"), [
    (3000.0, 5.0, 0.4, 0.0),     # Gaussian-approximated shot noise + read noise
    (800.0, 20.0, 0.4, 6.0),     # gain scales the noise with the signal
    (25.0, 0.0, 1.0, 0.0),       # exact Poisson draws (integers at 1 DN/e: no quantisation noise)
])
def test_flat_field_variance_is_shot_plus_read_noise(mean_e, read_e, dn_per_e, gain_db):
    sensor = SensorModel(read_noise_e=read_e, dn_per_e=dn_per_e, black_level_dn=100.0)
    f = formation(sensor=sensor, optics=OpticsModel(psf_sigma_px=0.0))
    exposure = mean_e / 3.2
    shape = (200, 200)
    cam = dataclasses.replace(CAM, width=shape[1], height=shape[0])
    f = dataclasses.replace(f, camera=cam)
    image = f.render_from_optical(flat(1.0, shape), exposure, gain_db, rng=np.random.default_rng(5))
    g = dn_per_e * 10 ** (gain_db / 20)
    quantisation = 0.0 if dn_per_e == 1.0 and gain_db == 0 else 1 / 12
    expected_var = (mean_e + read_e**2) * g * g + quantisation
    values = image.astype(np.float64)
    tolerance = 4 * math.sqrt(expected_var / values.size) + 0.01
    assert values.mean() == pytest.approx(100.0 + g * mean_e, abs=tolerance)
    assert values.var() == pytest.approx(expected_var, rel=0.03)  # 40000 samples: 1 sigma = 0.7 %


def test_rendering_is_deterministic_under_a_seed():
    f = formation(effects=Effects(halo=Halo()))
    refl = np.random.default_rng(0).random((H, W))
    a = f.render_from_optical(refl, 2000.0, rng=np.random.default_rng(42))
    b = f.render_from_optical(refl, 2000.0, rng=np.random.default_rng(42))
    c = f.render_from_optical(refl, 2000.0, rng=np.random.default_rng(43))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


# ---------------------------------------------------------------------------------------------- effects
def test_registry_lists_every_effect_with_documented_parameters():
    assert set(EFFECTS) == {f.name for f in dataclasses.fields(Effects)}
    for name, cls in EFFECTS.items():
        assert cls.NAME == name
        params = cls.parameters()
        assert params or name == "srgb_encoding"  # (the sRGB curve has no free parameter)
        assert all(p["unit"] and p["doc"] for p in params.values())
        assert cls.__doc__
    effects = Effects.from_dict({"halo": {"fraction": 0.05}, "lens_distortion": {"dist": [-0.2]},
                                 "blooming": None})
    assert effects.halo == Halo(fraction=0.05, sigma_px=6.0)
    assert effects.lens_distortion.dist == (-0.2, 0.0, 0.0, 0.0, 0.0)
    assert effects.blooming == Blooming()
    assert Effects.from_dict(effects.to_dict()) == effects
    with pytest.raises(ConfigError, match=r"^effects\.halo\.frac: unknown key"):
        Effects.from_dict({"halo": {"frac": 0.1}})
    with pytest.raises(ConfigError, match=r"^effects\.halo\.fraction: must be < 1"):
        Effects.from_dict({"halo": {"fraction": 1.5}})
    with pytest.raises(ConfigError, match=r"^effects\.glare: unknown key"):
        Effects.from_dict({"glare": {}})
    with pytest.raises(ValueError, match="both"):
        formation(optics=OpticsModel(halo_fraction=0.1), effects=Effects(halo=Halo()))


def column_spot(sensor: SensorModel) -> tuple[np.ndarray, np.ndarray]:
    """A 3x3 spot at 10x full well on a dark field (100 e): incident and held charge."""
    electrons = np.full((H, W), 100.0)
    electrons[22:25, 30:33] = 1e5
    return electrons, sensor.well(electrons).astype(np.float64)


def test_blooming_spreads_saturated_charge_along_columns_only_and_conserves_it():
    electrons, plain = column_spot(SensorModel())
    _, bloomed = column_spot(dataclasses.replace(SensorModel(), bloom_spill_fraction=1.0))
    # Charge is kept (the spill stays inside the 48 rows): total = incident.
    assert bloomed.sum() == pytest.approx(electrons.sum(), rel=1e-6)
    assert plain.sum() == pytest.approx(electrons.sum() - 9 * (1e5 - 1e4), rel=1e-6)  # clipped, drained
    changed = np.argwhere(np.abs(bloomed - plain) > 1e-3)
    assert set(changed[:, 1]) == {30, 31, 32}  # only the spot's columns
    column = bloomed[:, 31]
    full = np.flatnonzero(column >= 10000 - 1e-3)
    # 3 x 9e4 e excess spreads over 27 more pixels, symmetric up and down around rows 22..24.
    assert full[0] == 22 - 13 and full[-1] == 24 + 13
    assert column[full[0] - 1] == pytest.approx(column[full[-1] + 1], rel=1e-6) and column[full[0] - 1] > 100
    # With the nonlinear knee the charge a pixel does not hold spills too, and is still conserved.
    _, kneed = column_spot(SensorModel(bloom_spill_fraction=1.0, knee_fraction_of_full_well=0.8))
    assert kneed.sum() == pytest.approx(electrons.sum(), rel=1e-6) and kneed.max() <= 10000.0
    # Half the spill drains with spill_fraction 0.5.
    _, half = column_spot(dataclasses.replace(SensorModel(), bloom_spill_fraction=0.5))
    assert half.sum() == pytest.approx(plain.sum() + 0.5 * (electrons.sum() - plain.sum()), rel=1e-6)


def test_nonlinear_response_follows_the_documented_knee():
    k, F = 0.8, 10000.0
    f = formation(effects=Effects(nonlinear=Nonlinear(knee_fraction_of_full_well=k)),
                  sensor=SensorModel(dn_per_e=1.0))
    q = np.array([[1000.0, 7999.0, 8000.0, 9000.0, 10000.0, 20000.0, 1e6]])
    held = f.sensor_in_use.well(q)[0].astype(np.float64)
    truth = np.where(q[0] <= k * F, q[0], F - (1 - k) * F * np.exp(-(q[0] - k * F) / ((1 - k) * F)))
    np.testing.assert_allclose(held, truth, rtol=1e-5)
    assert held[4] == pytest.approx(F * (1 - (1 - k) / math.e), rel=1e-5)  # 0.926 F at full well
    assert np.all(np.diff(held) > 0) and held[-1] <= F
    assert held[3] < 9000.0  # bends below linear above the knee


def test_vignetting_darkens_the_corners_by_the_formula():
    s = 0.4
    f = formation(effects=Effects(vignetting=Vignetting(strength=s)), optics=OpticsModel(psf_sigma_px=0.0))
    e = f.electrons_from_reflectance(flat(0.5), 1000.0)
    centre = 0.5 * 3.2 * 1000.0
    half_diag = 0.5 * math.hypot(W, H)
    r2 = ((0 - CAM.cx) ** 2 + (0 - CAM.cy) ** 2) / half_diag**2
    assert e[0, 0] == pytest.approx(centre * (1 - s * r2), rel=1e-5)
    assert e[0, 0] < 0.65 * centre
    assert e[H // 2, W // 2] == pytest.approx(centre, rel=1e-3)


def test_halo_lifts_the_dark_side_near_an_edge_and_glare_lifts_all_dark():
    exposure = 2000.0
    placement = [edge_placement(0.0, (0.3, 0.0))]
    plain = formation().expected_electrons(placement, exposure)
    halo = formation(effects=Effects(halo=Halo(fraction=0.05, sigma_px=4.0))).expected_electrons(placement,
                                                                                                    exposure)
    edge = int(CAM.cx)
    assert np.all(halo[:, edge - 6:edge - 1] > plain[:, edge - 6:edge - 1] + 5)  # dark side, near: lifted
    assert np.all(halo[:, edge + 3:edge + 8] < plain[:, edge + 3:edge + 8])  # bright side gives light away
    np.testing.assert_allclose(halo[:, :10], plain[:, :10], rtol=1e-3)  # far from the edge: unchanged
    glare_formation = formation(effects=Effects(veiling_glare=VeilingGlare(0.05)))
    glare = glare_formation.expected_electrons(placement, exposure)
    mean = plain.mean()
    np.testing.assert_allclose(glare, 0.95 * plain + 0.05 * mean, rtol=1e-5)
    assert np.all(glare[:, :10] > plain[:, :10]) and np.all(glare[:, -10:] < plain[:, -10:])


def edge_width(row: np.ndarray) -> float:
    """10-90 % rise distance of a rising profile, in pixels."""
    lo, hi = row[:5].mean(), row[-5:].mean()
    return crossing(row, lo + 0.9 * (hi - lo)) - crossing(row, lo + 0.1 * (hi - lo))


def test_defocus_and_motion_blur_widen_edges_in_their_directions():
    exposure = 2000.0
    vertical = [edge_placement(0.0, (0.3, 0.0))]    # edge along y: profile along rows
    horizontal = [edge_placement(90.0, (0.0, 0.3))]  # edge along x, white below: profile along columns
    base = formation()
    defocus = formation(effects=Effects(defocus=Defocus(radius_px=3.0)))
    moving = formation(effects=Effects(motion_blur=MotionBlur(length_px=6.0, angle_deg=0.0)))
    w0 = edge_width(base.expected_electrons(vertical, exposure)[H // 2])
    assert edge_width(defocus.expected_electrons(vertical, exposure)[H // 2]) > w0 + 1.5
    assert edge_width(moving.expected_electrons(vertical, exposure)[H // 2]) > w0 + 2.5
    col0 = base.expected_electrons(horizontal, exposure)[:, W // 2]
    col1 = moving.expected_electrons(horizontal, exposure)[:, W // 2]
    assert edge_width(col0) == pytest.approx(w0, abs=0.01)  # same phase, turned by 90 degrees
    assert edge_width(col1) == pytest.approx(edge_width(col0), abs=0.01)  # motion along the edge: no change


def test_lens_distortion_effect_renders_through_other_coefficients():
    f = formation(effects=Effects(lens_distortion=LensDistortion((-0.3, 0.0, 0.0, 0.0, 0.0))))
    assert f.camera == CAM and f.render_camera.dist == (-0.3, 0.0, 0.0, 0.0, 0.0)
    # An edge 20 px right of the centre moves inward by about k1 r^3 / f^2 pixels under barrel distortion.
    placement = [edge_placement(0.0, (20.0, 0.0))]
    level = 0.5 * (0.04 + 0.85) * 3.2 * 2000.0
    x_plain = crossing(formation().expected_electrons(placement, 2000.0)[int(CAM.cy)], level)
    x_dist = crossing(f.expected_electrons(placement, 2000.0)[int(CAM.cy)], level)
    assert x_plain == pytest.approx(CAM.cx + 20.0, abs=0.02)
    r = 20.0 / CAM.fx
    assert x_dist - x_plain == pytest.approx(-0.3 * r**3 * CAM.fx, abs=0.02)


# ---------------------------------------------------------------------------------------------- output
def srgb(x: np.ndarray) -> np.ndarray:
    """The sRGB encoding (IEC 61966-2-1), written out here as the reference."""
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


@pytest.mark.parametrize("black_dn", [0.0, 64.0])
def test_srgb_and_gamma_encodings_map_the_linear_range_through_their_curves(black_dn):
    sensor = SensorModel(black_level_dn=black_dn, dn_per_e=0.3)
    refl = np.linspace(0.0, 1.0, W)[None, :].repeat(H, axis=0)  # 0 .. 1300 e .. over full scale
    exposure = 1300.0
    linear = formation(sensor=sensor).expected_dn_from_optical(refl, exposure)
    share = np.clip((linear - black_dn) / (TOP - black_dn), 0.0, 1.0)
    for effects, curve in ((Effects(srgb_encoding=SrgbEncoding()), srgb),
                           (Effects(gamma_encoding=GammaEncoding(gamma=2.2)), lambda x: x ** (1 / 2.2))):
        f = formation(sensor=sensor, effects=effects)
        truth = black_dn + (TOP - black_dn) * curve(share)
        np.testing.assert_allclose(f.expected_dn_from_optical(refl, exposure), truth, rtol=1e-5, atol=1e-3)
        image = f.render_from_optical(refl, exposure, noise=False)
        assert np.max(np.abs(image.astype(np.float64) - truth)) <= 0.5 + 1e-3  # rounded once, after the curve
    # the curve lifts the darks: 1 % of the range reads 10 % in sRGB
    assert srgb(np.array(0.01)) == pytest.approx(0.0998, abs=1e-4)


def test_jpeg_compresses_8_bit_frames_only_and_keeps_the_mean():
    cam8 = dataclasses.replace(CAM, bit_depth=8)
    refl = 0.2 + 0.6 * (np.indices((H, W)).sum(axis=0) // 8 % 2)  # 8 px diagonal bands: edges for JPEG
    plain = formation(camera=cam8, sensor=SensorModel(bit_depth=8)).render_from_optical(refl, 2000.0, noise=False)
    f = formation(camera=cam8, sensor=SensorModel(bit_depth=8), effects=Effects(jpeg=Jpeg(quality=60.0)))
    coded = f.render_from_optical(refl, 2000.0, noise=False)
    assert coded.dtype == np.uint8 and coded.shape == plain.shape
    diff = coded.astype(np.float64) - plain
    assert 0.3 < np.abs(diff).mean() < 15.0  # lossy (ringing at the 97 DN steps of the bands), the same image
    assert abs(diff.mean()) < 1.0
    assert np.abs(diff).mean() > 2 * np.abs(formation(camera=cam8, sensor=SensorModel(bit_depth=8), effects=Effects(
        jpeg=Jpeg(quality=95.0))).render_from_optical(refl, 2000.0, noise=False).astype(np.float64) - plain).mean()
    with pytest.raises(ValueError, match="8-bit"):
        formation(effects=Effects(jpeg=Jpeg()))
    with pytest.raises(ValueError, match="one output curve"):
        Effects(srgb_encoding=SrgbEncoding(), gamma_encoding=GammaEncoding())
    with pytest.raises(ConfigError, match=r"^effects\.jpeg\.quality: must be <= 100"):
        Effects.from_dict({"jpeg": {"quality": 101}})
    assert Effects.from_dict({"srgb_encoding": None}).srgb_encoding == SrgbEncoding()
