"""The simulator's PSF and print effects added for the model check's catalogue: anisotropic Gaussian core,
exponential and Lorentzian tails, ink floor (livetrack.sim.optics, livetrack.sim.effects)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from livetrack.config.checks import ConfigError
from livetrack.geometry import Pose, look_rotation
from livetrack.modelcheck.simulate import HiddenEffect, disk_grid_formation
from livetrack.modelcheck.texture import DiskGridTexture
from livetrack.sim.coverage import Placement
from livetrack.sim.effects import Effects
from livetrack.sim.optics import OpticsModel, anisotropic_gaussian_kernel, tail_kernel


def _moments(k: np.ndarray) -> tuple[float, float, float]:
    n = k.shape[0] // 2
    x = np.arange(-n, n + 1, dtype=np.float64)
    k = k.astype(np.float64)
    return (float(np.sum(k * x[None, :] ** 2)), float(np.sum(k * x[:, None] ** 2)),
            float(np.sum(k * x[None, :] * x[:, None])))


@pytest.mark.parametrize("sx, sy, angle", [(2.0, 1.0, 0.0), (2.0, 1.0, 90.0), (3.0, 1.5, 30.0)])
def test_anisotropic_kernel_has_the_stated_covariance(sx, sy, angle):
    k = anisotropic_gaussian_kernel(sx, sy, angle)
    assert k.sum() == pytest.approx(1.0, abs=1e-5)
    vxx, vyy, vxy = _moments(k)
    a = math.radians(angle)
    c, s = math.cos(a), math.sin(a)
    assert vxx == pytest.approx(sx**2 * c * c + sy**2 * s * s, rel=0.01, abs=0.01)
    assert vyy == pytest.approx(sx**2 * s * s + sy**2 * c * c, rel=0.01, abs=0.01)
    assert vxy == pytest.approx((sx**2 - sy**2) * s * c, abs=0.02)


def test_tail_kernels_match_their_formulas():
    b = 3.0
    k = tail_kernel("exponential", b).astype(np.float64)
    vxx, vyy, vxy = _moments(k)
    # 2-D exponential exp(-r/b): <r^2> = 6 b^2, so 3 b^2 per axis (+ 1/12 of the pixel average)
    assert vxx == pytest.approx(3 * b * b + 1 / 12, rel=0.01) and vyy == pytest.approx(vxx, rel=1e-6)
    assert abs(vxy) < 1e-6
    lor = tail_kernel("lorentzian", b).astype(np.float64)
    lsf = lor.sum(axis=0)  # line spread: the 1-D Lorentzian b / (pi (x^2 + b^2)), times the kept energy
    n = lor.shape[0] // 2
    kept = 1.0 - 1.0 / math.sqrt(1 + 30.0**2)
    for x in (0, 3, 9):
        assert lsf[n + x] * kept == pytest.approx(b / (math.pi * (x * x + b * b)), rel=0.03), x
    with pytest.raises(ValueError, match="tail kind"):
        tail_kernel("cauchy", 1.0)


def test_optics_with_tail_and_anisotropy_keep_energy_and_validate():
    rng = np.random.default_rng(0)
    img = np.zeros((80, 80), np.float32)
    img[30:50, 30:50] = rng.random((20, 20)).astype(np.float32)
    for o in (OpticsModel(psf_sigma_px=1.0, psf_sigma_y_px=0.7, psf_angle_deg=20.0),
              OpticsModel(psf_sigma_px=0.8, tail_fraction=0.2, tail_scale_px=1.0),
              OpticsModel(psf_sigma_px=0.8, tail_fraction=0.1, tail_kind="lorentzian", tail_scale_px=0.5)):
        assert float(o.apply(img).sum()) == pytest.approx(float(img.sum()), rel=1e-4)
        assert o.scaled(3).support_radius_px() == pytest.approx(3 * o.support_radius_px(), rel=1e-6)
    # axis-aligned anisotropy takes the separable path and matches the 2-D kernel
    a = OpticsModel(psf_sigma_px=1.2, psf_sigma_y_px=0.7, psf_angle_deg=90.0).apply(img)
    b = OpticsModel(psf_sigma_px=1.2, psf_sigma_y_px=0.7, psf_angle_deg=89.999999).apply(img)
    assert np.max(np.abs(a - b)) < 1e-4
    for kwargs in ({"psf_sigma_y_px": 0.0}, {"tail_fraction": 1.0}, {"tail_kind": "gauss"},
                   {"tail_scale_px": -1.0}):
        with pytest.raises(ValueError):
            OpticsModel(**kwargs)


def test_effects_from_a_scenario_mapping_fold_into_the_optics():
    e = Effects.from_dict({"anisotropic_core": {"sigma_x_px": 1.1, "sigma_y_px": 0.9, "angle_deg": 10},
                           "exponential_tail": {"fraction": 0.2, "scale_px": 1.0}})
    o = e.fold_optics(OpticsModel())
    assert (o.psf_sigma_px, o.psf_sigma_y_px, o.psf_angle_deg) == (1.1, 0.9, 10.0)
    assert (o.tail_fraction, o.tail_kind, o.tail_scale_px) == (0.2, "exponential", 1.0)
    o = Effects.from_dict({"lorentzian_tail": {"fraction": 0.1}}).fold_optics(OpticsModel())
    assert (o.tail_kind, o.tail_scale_px) == ("lorentzian", 0.5)
    with pytest.raises(ValueError, match="cannot both"):
        Effects.from_dict({"lorentzian_tail": None, "exponential_tail": None})
    with pytest.raises(ConfigError, match=r"effects\.anisotropic_core\.sigma_y_px"):
        Effects.from_dict({"anisotropic_core": {"sigma_y_px": 0}})
    with pytest.raises(ConfigError, match=r"effects\.ink_floor\.black_to_white"):
        Effects.from_dict({"ink_floor": {"black_to_white": 1.5}})
    with pytest.raises(ValueError, match="both in effects"):
        e.fold_optics(OpticsModel(tail_fraction=0.1))


def _disk_image(name: str | None, params: dict, exposure_fraction: float) -> tuple[np.ndarray, object]:
    hidden = HiddenEffect(name, None, None, params)
    f = disk_grid_formation(hidden, width=160, height=120, psf_sigma_px=0.9)
    tex = DiskGridTexture(pitch_m=0.008, radius_m=0.002, half_size_m=0.1)
    placement = Placement(Pose(look_rotation(0.0, 0.0), np.array([0.0, 0.0, 0.2])), tex)
    exposure = f.nominal_exposure_us(tex.white, exposure_fraction)
    return f.expected_dn([placement], exposure), f


def _centre(img: np.ndarray) -> tuple[int, int]:
    """(row, col) of the darkest pixel's disk near the image centre: centroid of the dark pixels there."""
    cy, cx = img.shape[0] // 2, img.shape[1] // 2
    win = img[cy - 12:cy + 13, cx - 12:cx + 13]
    rows, cols = np.nonzero(win < 0.5 * (win.min() + win.max()))
    return cy - 12 + round(float(rows.mean())), cx - 12 + round(float(cols.mean()))


def _dark_extent(img: np.ndarray, thr: float) -> tuple[float, float]:
    """Widths (px) of the dark run through the centre disk along x and y."""
    cy, cx = _centre(img)
    row, col = img[cy, cx - 15:cx + 16] < thr, img[cy - 15:cy + 16, cx] < thr
    return float(row.sum()), float(col.sum())


def test_rendered_effects_act_as_stated():
    top = 4095.0
    # anisotropic core: 10x over-exposed, the disk shrinks more along the wide (x) axis
    img, _ = _disk_image("anisotropic_core", {"sigma_x_px": 1.6, "sigma_y_px": 0.6, "angle_deg": 0.0}, 10.0)
    wx, wy = _dark_extent(img, 0.5 * top)
    assert wx < wy - 1.0, (wx, wy)
    # heavy tail: the dark side next to an edge is lifted far more than by the Gaussian alone
    plain, _ = _disk_image(None, {}, 0.5)
    tail, _ = _disk_image("exponential_tail", {"fraction": 0.2, "scale_px": 1.0}, 0.5)
    cy, cx = _centre(plain)
    r = 8  # disk radius (px) at 0.2 m, f = 800
    inside = (slice(cy - 1, cy + 2), slice(cx + r - 3, cx + r - 2))  # 2-3 px inside the edge
    assert float(np.mean(tail[inside])) > float(np.mean(plain[inside])) + 10.0
    # ink floor: the disk centre reads black_to_white x the paper
    ink, _ = _disk_image("ink_floor", {"black_to_white": 0.07}, 0.5)
    paper = float(np.median(ink))
    cy, cx = _centre(ink)
    assert float(ink[cy, cx]) / paper == pytest.approx(0.07, abs=0.005)
