"""Detection rate in varied simulated scenes: is every visible target found, and nothing else?

A seeded sweep (``build_cases``) of scenes as varied as the world, not tuned to livetrack's defaults:

- targets from ~0.05 % to ~45 % of the frame area (outer radius 19 to 570 px on 1920 x 1200), tilted 0 to 70
  degrees from the line of sight, anywhere in the image; some scenes hold several targets at once, some put a
  target against the border or in a corner of a strongly distorted lens (k1 = -0.3);
- backgrounds black, grey, white, textured (carpet and foliage noise, printed text, chessboard, bright noise,
  real photos of other circular markers when given) and lit unevenly (illumination gradient and vignetting);
  white sheets of several sizes, or none (the target printed edge-to-edge on the background);
- 8, 12 and 16-bit sensors, each scene at exposures from x0.25 to x32 of the one putting white paper at 55 %
  of full well;
- a family of scenes with optics and sensors far from the others' (``_draw_optics``: a PSF core of 0.5-2.2 px or
  an elliptical one, defocus, motion blur, veiling glare, wide halos, heavy PSF tails, a soft knee, blooming,
  grey ink), drawn from its own random stream;
- a family of frames delivered as other renderers and cameras deliver them (``_draw_encoding``: sRGB or a
  display gamma, JPEG compression), from its own stream too;
- a family of sensors whose pixels clip below the top code (``_draw_sensor``: a full well read at 80-97 % of the
  range, a black level, 2-20 e of read noise), from its own stream.

Each frame goes through the ``Tracker`` (as ``livetrack detect`` runs it: one full search per frame, exposure
compensation on). Per target and frame:

- **visible**: measured on the rendered frame at the truth pose. The black ring's pixels (level 0, between the
  inner white disk and the outer edge: at least ``MIN_COVERAGE`` of their area black on the target) and the
  inner white disk's pixels (as much white) come from exact-coverage renderings; visible when at least
  ``MIN_MASK_PX`` of each exist, ``(white - ring) / white >= MIN_CONTRAST`` (medians, black level removed) and
  ``white - ring >= NOISE_SIGMAS x`` the pixel noise (the larger of the two sets' pixel-to-pixel deviations,
  at least 0.5 DN of quantisation), and the outer ellipse's semi-minor axis is at least ``MIN_SEMI_MINOR_PX``
  (smaller targets with a dark ring are reported apart: too small to identify);
- **found**: a pose reported with ``fit.ok``, the right id, and its centre projected within
  ``max(2 px, 0.25 x the outer semi-minor axis)`` of the truth's; ``detected`` also counts a right detection
  whose pose failed (``FrameResult.failures`` / a fit not ok);
- the relative distance error of each found pose; a found pose more than ``GROSS_ERROR_PCT`` off in distance is
  also counted as a gross error (e.g. a fractal level taken for another).

False positives: any reported target (ok or not) away from every truth target, on frames with targets and on
a no-target set: the textured backgrounds alone, uncoded ring decoys (black rings without code dots) on them,
and real photos (``other-markers``, ``chessboard``) at three brightness scalings.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable, Container, Iterable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from livetrack.camera import CameraModel
from livetrack.estimator.detect import Detector, TraceEvent
from livetrack.estimator.shared_edge_bias import circle_bias_covariance, outer_circle_bias_covariance
from livetrack.estimator.tracker import FrameResult, Tracker, TrackerOptions
from livetrack.geometry import Pose, look_rotation
from livetrack.sim.coverage import Placement, corner_map, render_reflectance
from livetrack.sim.scenario import Scenario, facing_rotation
from livetrack.sim.texture import TargetTexture
from livetrack.targets.spec import TargetSpec

FloatArray = npt.NDArray[np.float64]

MIN_CONTRAST = 0.10
"""Least (white - ring) / white, medians over the rendered pixels, for a target to count as visible."""
NOISE_SIGMAS = 3.0
"""Least (white - ring) in units of the pixel noise for a target to count as visible."""
MIN_MASK_PX = 4
"""Least ring and inner-white pixels for the contrast to be measured."""
MIN_SEMI_MINOR_PX = 8.0
"""Least semi-minor axis (px) of the outer ellipse for a target to count as visible: below it the code dots
(0.2 R across) span under 1.6 px in the narrow direction and no reader can tell the id, however dark the ring.
Such targets are reported apart (``ring_visible`` True, ``visible`` False)."""
MIN_COVERAGE = 0.9
"""A pixel counts as the ring's (the inner disk's) when at least this share of its area is the ring's black (the
inner disk's white): the blur across the ring is in what is measured, the pixels straddling an edge are not."""
GROSS_ERROR_PCT = 5.0
"""A found pose whose distance is off by more than this (percent) is counted as a gross error."""
POOL_IDS = (1, 3, 5, 8, 12)
"""Target ids every tracker looks for (the scenes place some of them): a wrong id is a miss."""
EXPOSURES = (0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0)
QUICK_EXPOSURES = (0.25, 1.0, 4.0, 32.0)
AREA_FRACTIONS = (0.0005, 0.002, 0.01, 0.05, 0.2, 0.45)
TILTS_DEG = (0.0, 30.0, 50.0, 70.0)
OUTER_RADIUS_M = 0.125

CAMERAS: dict[str, dict[str, Any]] = {
    "1920x1200-12bit": {"width": 1920, "height": 1200, "fx": 1800, "fy": 1800, "cx": 959.5, "cy": 599.5,
                        "dist": [-0.1, 0, 0, 0, 0], "bit_depth": 12},
    "1280x800-8bit": {"width": 1280, "height": 800, "fx": 1150, "fy": 1150, "cx": 641.0, "cy": 398.0,
                      "dist": [-0.05, 0.01, 0, 0, 0], "bit_depth": 8},
    "1280x960-16bit-wide": {"width": 1280, "height": 960, "fx": 700, "fy": 700, "cx": 639.5, "cy": 479.5,
                            "dist": [-0.3, 0.08, 0, 0, 0], "bit_depth": 16},
}
"""The cameras of the sweep; the last is a wide lens with strong barrel distortion (border and corner cases)."""

BACKGROUNDS: dict[str, dict[str, Any]] = {
    "black": {"background_reflectance": 0.02},
    "grey": {"background_reflectance": 0.2},
    "white": {"background_reflectance": 0.92},
    "carpet": {"background_reflectance": 0.45,
               "background_texture": {"kind": "noise", "scales_px": [1.5, 4, 12], "contrast": 0.4}},
    "foliage": {"background_reflectance": 0.3,
                "background_texture": {"kind": "noise", "scales_px": [6, 20, 70], "contrast": 0.6}},
    "text": {"background_reflectance": 0.85, "background_texture": {"kind": "text", "line_height_px": 11}},
    "bright-noise": {"background_reflectance": 0.9,
                     "background_texture": {"kind": "noise", "scales_px": [2, 8, 32], "contrast": 0.15}},
    "checker": {"background_reflectance": 0.8, "background_texture": {"kind": "checker", "square_px": 37,
                                                                      "angle_deg": 17}},
    "gradient": {"background_reflectance": 0.6, "illumination": {"gradient": 0.6, "angle_deg": 35}},
}
"""Backgrounds by name (scenario ``scene`` sections); ``gradient`` also gets vignetting (effects)."""
TEXTURED = ("carpet", "foliage", "text", "bright-noise", "checker")
SHEETS: tuple[float | str, ...] = (2.8, 2.8, 2.2, 4.0, "none")
"""Sheet sizes drawn per scene (side in outer radii; "none": printed edge-to-edge)."""


# ---------------------------------------------------------------------------------------------- the sweep
@dataclass(frozen=True)
class Case:
    """One scene (a scenario with several exposures): its family, background and camera names."""

    name: str
    family: str  # "single", "multi", "border", "no-sheet", "optics", "encoded", "sensor"
    background: str
    camera: str
    scenario: dict[str, Any]


def build_cases(seed: int = 0, scale: float = 1.0, quick: bool = False) -> list[Case]:
    """The seeded scenes. ``scale`` multiplies the number of single-target scenes (default ~ one per area x tilt
    pair, on rotating backgrounds and cameras); ``quick``: fewer scenes and exposures."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 101]))
    exposures = QUICK_EXPOSURES if quick else EXPOSURES
    cases: list[Case] = []
    names = list(BACKGROUNDS)
    cams = list(CAMERAS)
    # Single targets: every area x tilt pair (a few in quick mode), background and camera rotating.
    pairs = [(a, t) for a in AREA_FRACTIONS for t in TILTS_DEG]
    n_single = max(1, round(len(pairs) * scale * (0.5 if quick else 1.0)))
    order = rng.permutation(len(pairs))
    for k in range(n_single):
        area, tilt = pairs[order[k % len(pairs)]]
        bg = names[k % len(names)]
        cam = cams[(k // len(names) + k) % 2]  # the two ordinary cameras; the wide one has its own family
        data = _scenario(cam, bg, exposures, rng, seed * 1000 + k)
        _add_single(cases, Case(f"single-{k:03d}", "single", bg, cam, data), area, tilt, rng)
    # Several targets at once (different sizes), on the textured and bright backgrounds.
    n_multi = max(1, round(6 * scale * (0.5 if quick else 1.0)))
    for k in range(n_multi):
        bg = (TEXTURED + ("white", "gradient"))[k % (len(TEXTURED) + 2)]
        cam = cams[k % 2]
        data = _scenario(cam, bg, exposures, rng, seed * 1000 + 500 + k)
        wanted = [(float(rng.choice(AREA_FRACTIONS[:4])), float(rng.choice(TILTS_DEG[:3]))) for _ in range(3)]
        step = _place(data, wanted, rng, where="anywhere")
        if step is None:
            continue
        data["poses"] = [step]
        cases.append(Case(f"multi-{k:03d}", "multi", bg, cam, data))
    # Border and corner of a strongly distorted wide lens.
    n_border = max(1, round(8 * scale * (0.5 if quick else 1.0)))
    for k in range(n_border):
        bg = names[(3 * k + 1) % len(names)]
        cam = "1280x960-16bit-wide"
        data = _scenario(cam, bg, exposures, rng, seed * 1000 + 800 + k)
        area = float(rng.choice(AREA_FRACTIONS[:4]))
        tilt = float(rng.choice(TILTS_DEG[:3]))
        step = _place(data, [(area, tilt)], rng, where="corner" if k % 2 == 0 else "border")
        if step is None:
            continue
        data["poses"] = [step]
        cases.append(Case(f"border-{k:03d}", "border", bg, cam, data))
    # Printed edge to edge, without a white sheet (a panel, a sticker, a target on a vehicle): the ring's outer
    # edge borders the ground itself, grey or textured. One in five scenes above has no sheet too, black ground
    # included (ink at 0.04 on ground at 0.02: its outer edge a step down, ``Candidate.darker_outside``, since
    # session 27). This family keeps to the others (its scenes unchanged since session 7, for comparison).
    bare_grounds = [n for n in names if n != "black"]
    n_bare = max(1, round(NO_SHEET_SCENES * scale * (0.5 if quick else 1.0)))
    for k in range(n_bare):
        bg = bare_grounds[(5 * k + 2) % len(bare_grounds)]
        cam = cams[k % 2]
        data = _scenario(cam, bg, exposures, rng, seed * 1000 + 900 + k)
        data["scene"]["sheet_side_factor"] = "none"
        area = float(rng.choice(AREA_FRACTIONS[:5]))
        tilt = float(rng.choice(TILTS_DEG))
        _add_single(cases, Case(f"no-sheet-{k:03d}", "no-sheet", bg, cam, data), area, tilt, rng)
    def family(name: str, stream: int, scenes: int, seed_base: int, draw: Callable[..., None],
               background: Callable[[int], str], camera: Callable[[int], str]) -> None:
        """A family of single-target scenes drawn from its own random stream (``stream``), so that the scenes before
        it stay as they were: each scene ``draw`` n from ``_scenario`` (a sheet on black ground kept)."""
        frng = np.random.default_rng(np.random.SeedSequence([seed, stream]))
        for k in range(max(1, round(scenes * scale * (0.5 if quick else 1.0)))):
            bg, cam = background(k), camera(k)
            data = _scenario(cam, bg, exposures, frng, seed * 1000 + seed_base + k)
            if bg == "black" and data["scene"]["sheet_side_factor"] == "none":
                data["scene"]["sheet_side_factor"] = 2.8  # a sheet on black ground here (these scenes kept as made)
            draw(data, frng)
            area = float(frng.choice(AREA_FRACTIONS))
            tilt = float(frng.choice(TILTS_DEG))
            _add_single(cases, Case(f"{name}-{k:03d}", name, bg, cam, data), area, tilt, frng)

    # Optics and sensors other than the sweep's own (a blurred, defocused, moving or glaring lens, heavy PSF
    # tails, a soft or blooming pixel, grey ink).
    family("optics", 107, OPTICS_SCENES, 950, _draw_optics, lambda k: names[(5 * k + 1) % len(names)],
           lambda k: cams[k % 2])
    # Frames as other renderers and cameras deliver them (sRGB or gamma-encoded, JPEG-compressed).
    family("encoded", 109, ENCODED_SCENES, 970, _draw_encoding, lambda k: names[(4 * k + 2 + seed) % len(names)],
           lambda k: cams[(k + 1) % 2])
    # Sensors whose pixels clip below the top code (a full well read short of it, a black level).
    family("sensor", 113, SENSOR_SCENES, 990, _draw_sensor, lambda k: names[(3 * k + 1 + seed) % len(names)],
           lambda k: cams[k % 2])
    return cases


SENSOR_SCENES = 4
"""Scenes of the sensor family at ``scale`` 1 (``_draw_sensor``)."""


def _draw_sensor(data: dict[str, Any], rng: np.random.Generator) -> None:
    """A sensor whose pixels clip below the top code: its full well read at 80-97 % of the range above the black
    level (a gain, or an ADC range wider than the well), a black level of 1-6 % of full scale in half of them, and
    2-20 e of read noise (the clipped pixels carry it: their clip is a narrow peak, not one code)."""
    top = (1 << int(data["camera"]["bit_depth"])) - 1
    sensor = data["sensor"]
    black = round(float(rng.uniform(0.01, 0.06)) * top) if rng.random() < 0.5 else 0
    sensor["black_level_dn"] = black
    sensor["read_noise_e"] = float(rng.uniform(2.0, 20.0))
    sensor["dn_per_e"] = float(rng.uniform(0.8, 0.97)) * (top - black) / sensor["full_well_e"]


ENCODED_SCENES = 6
"""Scenes of the encoded family at ``scale`` 1 (``_draw_encoding``)."""


def _draw_encoding(data: dict[str, Any], rng: np.random.Generator) -> None:
    """Deliver a scenario's frames as another renderer or camera would: sRGB-encoded (two in three) or through
    a display gamma of 1.8-2.4, and on 8-bit cameras JPEG-compressed at quality 60-95 (two in three)."""
    effects = data["effects"]
    if rng.random() < 2.0 / 3.0:
        effects["srgb_encoding"] = {}
    else:
        effects["gamma_encoding"] = {"gamma": float(rng.uniform(1.8, 2.4))}
    if data["camera"]["bit_depth"] == 8 and rng.random() < 2.0 / 3.0:
        effects["jpeg"] = {"quality": float(rng.uniform(60.0, 95.0))}


OPTICS_SCENES = 8
"""Scenes of the optics family at ``scale`` 1 (``_draw_optics``)."""


def _draw_optics(data: dict[str, Any], rng: np.random.Generator) -> None:
    """Replace a scenario's optics and effects by a draw far from the sweep's defaults: a PSF core of 0.5-2.2 px
    (or an elliptical one), and each with its own odds defocus (1-3 px), motion blur (2-8 px), veiling glare
    (2-10 %), a wide halo (1-8 %, 3-12 px), an exponential or Lorentzian tail, a soft knee (0.6-0.9 of full
    well), blooming and grey ink (black at 3-15 % of the paper)."""
    data["optics"]["psf_sigma_px"] = float(rng.uniform(0.5, 2.2))
    effects: dict[str, Any] = {k: v for k, v in data["effects"].items() if k == "vignetting"}

    def u(lo: float, hi: float) -> float:
        return float(rng.uniform(lo, hi))

    draws: list[tuple[float, str, Callable[[], dict[str, Any]]]] = [
        (0.2, "anisotropic_core", lambda: {"sigma_x_px": u(0.8, 2.0), "sigma_y_px": u(0.5, 0.9),
                                           "angle_deg": u(-90, 90)}),
        (0.3, "defocus", lambda: {"radius_px": u(1.0, 3.0)}),
        (0.3, "motion_blur", lambda: {"length_px": u(2.0, 8.0), "angle_deg": u(-180, 180)}),
        (0.3, "veiling_glare", lambda: {"fraction": u(0.02, 0.1)}),
        (0.4, "halo", lambda: {"fraction": u(0.01, 0.08), "sigma_px": u(3.0, 12.0)}),
        (0.2, "exponential_tail", lambda: {"fraction": u(0.1, 0.3), "scale_px": u(0.5, 1.0)}),
        (0.2, "lorentzian_tail", lambda: {"fraction": u(0.05, 0.15), "scale_px": u(0.3, 0.5)}),
        (0.3, "nonlinear", lambda: {"knee_fraction_of_full_well": u(0.6, 0.9)}),
        (0.2, "blooming", lambda: {"spill_fraction": u(0.05, 0.3)}),
        (0.5, "ink_floor", lambda: {"black_to_white": u(0.03, 0.15)}),
    ]
    for odds, name, params in draws:
        if rng.random() < odds and not (name == "lorentzian_tail" and "exponential_tail" in effects):
            effects[name] = params()  # (one tail per PSF core)
    data["effects"] = effects


def _add_single(cases: list[Case], case: Case, area: float, tilt_deg: float, rng: np.random.Generator) -> None:
    """Place one target of (area fraction, tilt) anywhere in ``case``'s scenario and append the case; nothing when
    it does not fit."""
    step = _place(case.scenario, [(area, tilt_deg)], rng, where="anywhere")
    if step is not None:
        case.scenario["poses"] = [step]
        _coarse_optics_if_large(case.scenario, area)
        cases.append(case)


NO_SHEET_SCENES = 8
"""Scenes of the no-sheet family at ``scale`` 1 (one per background but black, rotating)."""


LARGE_AREA_FRACTION = 0.01
"""Targets above this share of the frame are rendered without optical oversampling (the PSF applied to the
pixels: a few % of an edge's step off at sharp edges; rendering them oversampled costs 5-10 s per scene)."""


def _coarse_optics_if_large(data: dict[str, Any], area: float) -> None:
    if area > LARGE_AREA_FRACTION:
        data["optics"]["oversampling"] = 1


def make_case(name: str, family: str, background: str, camera: str,
              wanted: Sequence[tuple[float, float]], exposures: Sequence[float], seed: int,
              where: str = "anywhere", sheet: float | str | None = None) -> Case:
    """One scene built by hand: targets of the given (area fraction, tilt deg) placed ``where`` ("anywhere",
    "border", "corner"), seeded; ``sheet`` overrides the drawn sheet size. ValueError if they do not fit."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 103]))
    data = _scenario(camera, background, exposures, rng, seed)
    if sheet is not None:
        data["scene"]["sheet_side_factor"] = sheet
    step = _place(data, wanted, rng, where=where)
    if step is None:
        raise ValueError(f"cannot place {wanted} {where} in {camera}")
    data["poses"] = [step]
    _coarse_optics_if_large(data, max(a for a, _ in wanted))
    return Case(name, family, background, camera, data)


def _scenario(camera: str, background: str, exposures: Sequence[float], rng: np.random.Generator,
              seed: int) -> dict[str, Any]:
    """A scenario dict (poses to be filled in) for a camera, a background and a drawn sheet and PSF."""
    scene = copy.deepcopy(BACKGROUNDS[background])
    scene["sheet_side_factor"] = SHEETS[int(rng.integers(len(SHEETS)))]
    scene["supersampling"] = 4
    effects: dict[str, Any] = {}
    if rng.random() < 0.5:
        effects["halo"] = {"fraction": 0.03, "sigma_px": 6.0}
    if background == "gradient":
        effects["vignetting"] = {"strength": 0.4}
    return {
        "name": f"detection-{background}", "seed": int(seed), "camera": copy.deepcopy(CAMERAS[camera]),
        "sensor": {"full_well_e": 10000, "read_noise_e": 5, "black_level_dn": 0},
        "optics": {"psf_sigma_px": float(rng.uniform(0.7, 1.1)), "oversampling": 2},
        "effects": effects, "scene": scene,
        "targets": [{"id": i, "outer_radius_m": OUTER_RADIUS_M} for i in POOL_IDS],
        "exposure": {"nominal_us": "auto", "white_fraction_of_full_well": 0.55, "factors": list(exposures)},
        "timing": {"fps": 1.0},
    }


def _place(data: dict[str, Any], wanted: Sequence[tuple[float, float]], rng: np.random.Generator,
           where: str) -> list[dict[str, Any]] | None:
    """Poses for targets of the given (area fraction, tilt) with distinct ids, the outer disk of each at least 6
    px inside the image and clear of the others: random positions (``where`` "anywhere"), or against a side
    ("border") or in a corner ("corner") of the image. None when no placement was found."""
    camera = CameraModel.from_dict(data["camera"], "camera")
    w, h = camera.width, camera.height
    ids = [int(i) for i in rng.permutation(POOL_IDS)[: len(wanted)]]
    step: list[dict[str, Any]] = []
    boxes: list[FloatArray] = []
    for tid, (area, tilt) in zip(ids, wanted, strict=True):
        r_px = math.sqrt(area * w * h / math.pi)
        distance = camera.fx * OUTER_RADIUS_M / r_px
        axis, roll = float(rng.uniform(0, 360)), float(rng.uniform(0, 360))
        tilted = look_rotation(tilt, axis, roll)
        for _ in range(400):
            if where == "anywhere":
                pixel = rng.uniform([0, 0], [w - 1, h - 1])
            else:  # the centre about one radius from a side (two sides: a corner)
                off = rng.uniform(8 + r_px * 0.3, 8 + r_px * 4.0, size=2)
                pixel = np.array([off[0] if rng.random() < 0.5 else w - 1 - off[0],
                                  off[1] if rng.random() < 0.5 else h - 1 - off[1]])
                if where == "border":
                    axis = int(rng.integers(2))
                    pixel[axis] = rng.uniform(0.2, 0.8) * ((w, h)[axis] - 1)
            ray = camera.unproject(pixel)
            pose = Pose(facing_rotation(ray) @ tilted, distance * ray)
            outline = disk_outline_px(camera, pose, OUTER_RADIUS_M)
            if outline is None or not np.all(camera.contains(outline, 6.0)):
                continue
            # Clear of the others: the boxes of the sheets (which may run out of the image) must not overlap.
            sheet = _sheet_outline_px(camera, pose, data.get("scene", {}).get("sheet_side_factor", 2.8))
            if sheet is None:
                continue
            box = np.concatenate([sheet.min(axis=0) - 4, sheet.max(axis=0) + 4])
            if any(b[0] < box[2] and box[0] < b[2] and b[1] < box[3] and box[1] < b[3] for b in boxes):
                continue
            boxes.append(box)
            step.append({"target_id": tid, "t_m": [float(v) for v in pose.t],
                         "q_xyzw": [float(v) for v in pose.quaternion]})
            break
        else:
            return None
    return step


def _sheet_outline_px(camera: CameraModel, pose: Pose, side_factor: float | str, n: int = 24) -> FloatArray | None:
    """(4 n, 2) pixel positions along the border of a target's sheet (its disk when ``side_factor`` is "none"),
    or None if part of it is behind the camera."""
    if side_factor == "none":
        return disk_outline_px(camera, pose, OUTER_RADIUS_M)
    h = 0.5 * float(side_factor) * OUTER_RADIUS_M
    t = np.linspace(-h, h, n, endpoint=False)
    xs = np.concatenate([t, np.full(n, h), -t, np.full(n, -h)])
    ys = np.concatenate([np.full(n, -h), t, np.full(n, h), -t])
    pts = pose.apply(np.column_stack([xs, ys, np.zeros_like(xs)]))
    if np.any(pts[:, 2] <= 1e-6):
        return None
    return camera.project(pts)


def disk_outline_px(camera: CameraModel, pose: Pose, radius_m: float, n: int = 96) -> FloatArray | None:
    """(n, 2) pixel positions of a target's outer circle, or None if part of it is behind the camera."""
    a = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    pts = pose.apply(np.column_stack([radius_m * np.cos(a), radius_m * np.sin(a), np.zeros(n)]))
    if np.any(pts[:, 2] <= 1e-6):
        return None
    return camera.project(pts)


# ---------------------------------------------------------------------------------------------- visibility
@dataclass(frozen=True)
class Visibility:
    """The ring's contrast measured on a rendered frame. ``contrast``: (white - ring) / white (medians, black
    level removed); ``snr``: (white - ring) / noise; None when too few pixels could be measured."""

    ring_px: int
    white_px: int
    contrast: float | None
    snr: float | None

    @property
    def visible(self) -> bool:
        return (self.contrast is not None and self.snr is not None and self.contrast >= MIN_CONTRAST
                and self.snr >= NOISE_SIGMAS)


@dataclass(frozen=True)
class TargetMasks:
    """Where to measure a target in a frame: a window (x0, y0, x1, y1) and its ring and inner-white pixels."""

    window: tuple[int, int, int, int]
    ring: npt.NDArray[np.bool_]
    white: npt.NDArray[np.bool_]


def target_masks(camera: CameraModel, spec: TargetSpec, pose: Pose) -> TargetMasks | None:
    """The pixels of the black ring (level 0, between the inner disk and the outer edge: annulus and gaps
    between the code dots) and of the inner white disk, each covered at least ``MIN_COVERAGE`` by its colour,
    from exact-coverage renderings of the target at ``pose`` through ``camera`` (the render camera)."""
    outline = disk_outline_px(camera, pose, spec.outer_radius_m)
    if outline is None:
        return None
    x0 = max(int(math.floor(outline[:, 0].min())) - 3, 0)
    y0 = max(int(math.floor(outline[:, 1].min())) - 3, 0)
    x1 = min(int(math.ceil(outline[:, 0].max())) + 4, camera.width)
    y1 = min(int(math.ceil(outline[:, 1].max())) + 4, camera.height)
    if x1 - x0 < 3 or y1 - y0 < 3:
        return None
    # Exact coverage of each pixel by the target's black and by its white, rendered through the whole camera
    # (whose lens inverse is cached from one call to the next).
    cover = {}
    for name, white, black in (("black", 0.0, 1.0), ("white", 1.0, 0.0)):
        texture = TargetTexture(spec, white=white, black=black, edge_to_edge=True)
        cover[name] = render_reflectance(camera, [Placement(pose, texture)], background=0.0,
                                         supersampling=4)[y0:y1, x0:x1]
    # Target-plane radius of every pixel centre (to tell the level-0 ring from the inner disk).
    corners = corner_map(camera)[y0:y1 + 1, x0:x1 + 1]
    normalized = 0.25 * (corners[:-1, :-1] + corners[:-1, 1:] + corners[1:, :-1] + corners[1:, 1:])
    hinv = np.linalg.inv(pose.plane_to_normalized_homography())
    q = normalized @ hinv[:, :2].T + hinv[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.hypot(q[..., 0] / q[..., 2], q[..., 1] / q[..., 2])
    ring = (cover["black"] >= MIN_COVERAGE) & (r > spec.inner_radius_m)
    inner = (cover["white"] >= MIN_COVERAGE) & (r < spec.inner_radius_m)
    return TargetMasks((x0, y0, x1, y1), ring, inner)


def measure_visibility(image: npt.NDArray[Any], masks: TargetMasks | None, black_level_dn: float) -> Visibility:
    """Ring contrast and signal-to-noise in ``image`` at ``masks`` (see the module docstring)."""
    if masks is None:
        return Visibility(0, 0, None, None)
    x0, y0, x1, y1 = masks.window
    crop = image[y0:y1, x0:x1].astype(np.float64) - black_level_dn
    ring, white = crop[masks.ring], crop[masks.white]
    if ring.size < MIN_MASK_PX or white.size < MIN_MASK_PX:
        return Visibility(int(ring.size), int(white.size), None, None)
    ring_dn, white_dn = float(np.median(ring)), float(np.median(white))
    noise = max(_pixel_noise(crop, masks.ring), _pixel_noise(crop, masks.white), 0.5)
    diff = white_dn - ring_dn
    contrast = diff / white_dn if white_dn > 0 else 0.0
    return Visibility(int(ring.size), int(white.size), contrast, diff / noise)


def _pixel_noise(crop: FloatArray, mask: npt.NDArray[np.bool_]) -> float:
    """Pixel-to-pixel noise (DN) inside ``mask``: robust deviation of the differences of horizontally adjacent
    pixels over sqrt(2), blind to smooth shading (halo, vignetting); the values' robust deviation when fewer
    than 4 pairs exist."""
    pairs = mask[:, :-1] & mask[:, 1:]
    if pairs.sum() >= 4:
        diff = (crop[:, 1:] - crop[:, :-1])[pairs]
        return float(1.4826 * np.median(np.abs(diff - np.median(diff))) / math.sqrt(2.0))
    values = crop[mask]
    return float(1.4826 * np.median(np.abs(values - np.median(values))))


# ---------------------------------------------------------------------------------------------- outcomes
@dataclass(frozen=True)
class TargetOutcome:
    """One target in one frame."""

    case: str
    family: str
    background: str
    camera: str
    bit_depth: int
    sheet: str
    exposure_factor: float
    target_id: int
    distance_m: float
    tilt_deg: float
    area_fraction: float
    semi_minor_px: float
    contrast: float | None
    snr: float | None
    ring_visible: bool  # the ring's contrast criterion alone
    visible: bool  # ring_visible and semi_minor_px >= MIN_SEMI_MINOR_PX
    found: bool
    detected: bool
    wrong_id: bool
    distance_error_pct: float | None
    centre_error_px: float | None
    failure: str | None
    explain: str | None = None  # a visible target missed, with ``explain``: the stage that lost it
    residual_rms_px: float | None = None  # found: the pose fit's edge residuals
    distance_sd_pct: float | None = None  # found: the distance's standard deviation from the fit's covariance
    dots_scale: float | None = None  # found: where the code dots lie relative to the pose (``TargetResult``)
    # found from its edges: the distance sd (%) that a bias of 1 px sd shared by each circle's edges adds
    # (``shared_edge_bias``; scales with that bias: for b px, b times this, in quadrature with the rest)
    circle_bias_sd_pct: float | None = None
    outer_bias_sd_pct: float | None = None  # the distance sd (%) per px of a bias of the outermost circle alone
    delta_px: float | None = None  # the found pose's exposure bias (the white's, px)
    outer_share: float | None = None  # its outermost circle's share of it (None: whole; TargetResult.outer_share)
    outer_level: int | None = None  # the outermost fractal level in its pose (0: the target's own outer circle)


@dataclass(frozen=True)
class EmptyOutcome:
    """One frame without any of our targets: what was reported there (each a false positive)."""

    source: str
    kind: str  # "background", "decoys", "photo"
    reported: int
    ids: tuple[int, ...]


@dataclass
class DetectionResult:
    targets: list[TargetOutcome] = field(default_factory=list)
    empty: list[EmptyOutcome] = field(default_factory=list)
    spurious: list[dict[str, Any]] = field(default_factory=list)  # reports away from every truth target
    seconds: float = 0.0

    def summary(self) -> dict[str, Any]:
        visible = [t for t in self.targets if t.visible]
        found = [t for t in visible if t.found]
        errors = np.array([abs(t.distance_error_pct) for t in found if t.distance_error_pct is not None])
        # how honest the claimed precision is: the share of found distances within 3 of their own sd
        z = np.array([abs(t.distance_error_pct) / t.distance_sd_pct for t in found
                      if t.distance_error_pct is not None and t.distance_sd_pct])
        fp_empty = sum(e.reported for e in self.empty)
        return {
            "targets": len(self.targets), "visible": len(visible), "found": len(found),
            "found_rate": len(found) / len(visible) if visible else None,
            "detected_rate": (sum(t.detected for t in visible) / len(visible)) if visible else None,
            "wrong_id": sum(t.wrong_id for t in visible),
            "gross_pose_errors": int(np.sum(errors > GROSS_ERROR_PCT)),
            "found_invisible": sum(t.found for t in self.targets if not t.visible),
            "ring_visible_too_small": sum(t.ring_visible and not t.visible for t in self.targets),
            "found_too_small": sum(t.found for t in self.targets if t.ring_visible and not t.visible),
            "invisible": len(self.targets) - len(visible),
            "no_target_frames": len(self.empty), "false_positives_no_target": fp_empty,
            "false_positives_with_targets": len(self.spurious),
            "median_abs_distance_error_pct": float(np.median(errors)) if errors.size else None,
            "p95_abs_distance_error_pct": float(np.percentile(errors, 95)) if errors.size else None,
            "max_abs_distance_error_pct": float(errors.max()) if errors.size else None,
            "distance_within_3sd": float(np.mean(z <= 3.0)) if z.size else None,
            **self._in_specified_range(visible),
            "seconds": self.seconds,
        }

    @staticmethod
    def _in_specified_range(visible: list[TargetOutcome]) -> dict[str, Any]:
        """The visible targets covering ``SPECIFIED_AREA_FRACTIONS`` of the frame, and how many were found."""
        lo, hi = SPECIFIED_AREA_FRACTIONS
        inside = [t for t in visible if lo <= t.area_fraction <= hi]
        found = sum(t.found for t in inside)
        return {"visible_in_specified_range": len(inside), "found_in_specified_range": found,
                "found_rate_in_specified_range": found / len(inside) if inside else None}

    def table(self, key: str) -> list[dict[str, Any]]:
        """Rows per value of ``key`` (an outcome field or "area"/"tilt" bins): visible, found, rate, errors."""
        groups: dict[Any, list[TargetOutcome]] = {}
        for t in self.targets:
            groups.setdefault(_group_value(t, key), []).append(t)
        rows = []
        for value in sorted(groups, key=_sort_key):
            ts = groups[value]
            vis = [t for t in ts if t.visible]
            fnd = [t for t in vis if t.found]
            err = [abs(t.distance_error_pct) for t in fnd if t.distance_error_pct is not None]
            rows.append({key: value, "frames": len(ts), "visible": len(vis), "found": len(fnd),
                         "found_rate": len(fnd) / len(vis) if vis else None,
                         "median_abs_distance_error_pct": float(np.median(err)) if err else None,
                         "max_abs_distance_error_pct": float(np.max(err)) if err else None})
        return rows

    def misses(self) -> list[TargetOutcome]:
        return [t for t in self.targets if t.visible and not t.found]

    def to_dict(self) -> dict[str, Any]:
        return {"summary": self.summary(),
                "tables": {k: self.table(k) for k in TABLE_KEYS},
                "targets": [asdict(t) for t in self.targets],
                "no_target": [asdict(e) for e in self.empty],
                "spurious": self.spurious}


SPECIFIED_AREA_FRACTIONS = (0.0005, 0.6)
"""The share of the frame a target covers (its outer disk as seen, tilt included) over which detection is specified
(issue 10: "a target covering 0.05 % to 60 % of the frame"). The sweep also draws smaller ones (tilted targets of
its smallest size, at ~0.03-0.05 %): they count in ``found_rate``, and the summary gives the rate within this range
apart."""

TABLE_KEYS = ("exposure_factor", "area", "size", "background", "tilt", "family", "bit_depth", "sheet")


def _size_bin(semi_minor_px: float) -> str:
    for hi, name in ((12.0, "b<12px"), (20.0, "b12-20px"), (40.0, "b20-40px"), (100.0, "b40-100px")):
        if semi_minor_px < hi:
            return name
    return "b>=100px"


_SIZE_ORDER = ["b<12px", "b12-20px", "b20-40px", "b40-100px", "b>=100px"]


def _area_bin(area: float) -> str:
    for hi, name in ((0.001, "<0.1%"), (0.005, "0.1-0.5%"), (0.02, "0.5-2%"), (0.1, "2-10%"), (0.3, "10-30%")):
        if area < hi:
            return name
    return ">=30%"


_AREA_ORDER = ["<0.1%", "0.1-0.5%", "0.5-2%", "2-10%", "10-30%", ">=30%"]


def _group_value(t: TargetOutcome, key: str) -> Any:
    if key == "area":
        return _area_bin(t.area_fraction)
    if key == "tilt":
        return f"{int(round(t.tilt_deg / 10.0) * 10)} deg"
    if key == "size":  # the outer ellipse's semi-minor axis b
        return _size_bin(t.semi_minor_px)
    return getattr(t, key)


def _sort_key(value: Any) -> tuple[int, Any]:
    if isinstance(value, str) and value in _AREA_ORDER:
        return (0, _AREA_ORDER.index(value))
    if isinstance(value, str) and value in _SIZE_ORDER:
        return (0, _SIZE_ORDER.index(value))
    if isinstance(value, str) and value.endswith(" deg"):
        return (0, int(value.split()[0]))
    if isinstance(value, (int, float)):
        return (0, value)
    return (1, str(value))


# ---------------------------------------------------------------------------------------------- running
def _tracker(camera: CameraModel, targets: Sequence[TargetSpec]) -> Tracker:
    """The tracker as ``livetrack detect`` builds it (exposure compensation on, a full search per frame)."""
    return Tracker(camera, list(targets), TrackerOptions(compensate_exposure=True))


def _distance_sd_pct(t_m: FloatArray, covariance: FloatArray) -> float:
    """The distance's standard deviation (percent of it) from a fit's covariance, first order (its t block)."""
    distance_m = float(np.linalg.norm(t_m))
    variance = float(t_m @ covariance[:3, :3] @ t_m) / distance_m**2
    return 100.0 * math.sqrt(max(variance, 0.0)) / distance_m


def _circle_bias_sd_pct(target) -> float | None:
    """The distance sd (%) a bias of 1 px shared by each of a found target's circles adds to its covariance; None
    for a pose from the 2-D model (its covariance is the model's) or without the edges' gain."""
    if target.target_model is not None:
        return None
    added = circle_bias_covariance(target.fit, 1.0)
    return None if added is None else _distance_sd_pct(target.fit.pose.t, added)


def _outer_bias_sd_pct(target) -> float | None:
    """The distance sd (%) a bias of 1 px of a found target's outermost circle alone adds to its covariance; None as
    for ``_circle_bias_sd_pct``."""
    if target.target_model is not None:
        return None
    added = outer_circle_bias_covariance(target.fit, 1.0)
    return None if added is None else _distance_sd_pct(target.fit.pose.t, added)


def _line_of_sight_tilt_deg(pose: Pose) -> float:
    ray = pose.t / np.linalg.norm(pose.t)
    return math.degrees(math.acos(float(np.clip(abs(pose.normal_cam @ ray), -1.0, 1.0))))


def run_case(case: Case, result: DetectionResult, explain: bool = False, encoding_known: bool = False,
             exposures: Container[float] | None = None) -> None:
    """Render every frame of ``case`` (``exposures``: only those at these exposure factors, each the same frame,
    noise included, as in the whole case), track it and append the outcomes to ``result``; with ``explain``, each
    visible target missed gets the stage that lost it (``explain_miss``, from a traced detection of the frame).
    ``encoding_known``: the tracker's camera states the scene's output encoding
    (``Scenario.camera_stating_encoding``), as a user who knows it would; otherwise linear, as ``livetrack detect``
    takes a camera file that says nothing."""
    scenario = Scenario.from_dict(case.scenario)
    camera, render_camera = scenario.camera, scenario.formation.render_camera
    tracker = _tracker(scenario.camera_stating_encoding if encoding_known else camera, scenario.targets)
    by_id = {t.id: t for t in scenario.targets}
    placements = scenario.placements_for(0)
    truth = scenario.truth_for(0)
    masks = {tid: target_masks(render_camera, by_id[tid], pose) for tid, pose in truth.items()}
    geometry = {}
    for tid, pose in truth.items():
        outline = disk_outline_px(render_camera, pose, by_id[tid].outer_radius_m)
        centre = camera.project(pose.t[None, :])[0]
        area = _polygon_area(outline) / (camera.width * camera.height)
        spread = np.linalg.norm(outline - outline.mean(axis=0), axis=1)
        geometry[tid] = (centre, area, float(np.min(spread)), float(np.max(spread)))
    detector = Detector(scenario.targets) if explain else None
    sheet = str(case.scenario["scene"].get("sheet_side_factor", 2.8))
    black = scenario.formation.sensor.black_level_dn
    optical = scenario.formation.optical_image(placements)
    factors = scenario.exposure_factors
    for k in range(len(scenario)):
        if exposures is not None and factors[k % len(factors)] not in exposures:
            continue
        frame = scenario.render_frame(k, optical=optical)
        out = tracker.process(frame.image, frame.exposure_us)
        claimed: set[int] = set()
        trace: list[TraceEvent] | None = None
        for tid, pose in truth.items():
            centre, area, semi_minor, semi_major = geometry[tid]
            vis = measure_visibility(frame.image, masks[tid], black)
            tol = max(2.0, 0.25 * semi_minor)
            found = detected = wrong = False
            err = centre_err = rms = sd = dots = bias_sd = outer_sd = delta = share = outer_level = None
            failure = None
            for n, t in enumerate(out.targets):
                c = camera.project(t.pose.t[None, :])[0] if t.pose.t[2] > 0 else t.candidate.outer.centre_px
                d = float(np.hypot(*(c - centre)))
                near = d <= tol or float(np.hypot(*(t.candidate.outer.centre_px - centre))) <= tol
                if not near:
                    continue
                claimed.add(n)
                if t.target_id != tid:
                    wrong = True
                    continue
                detected = True
                if t.fit.ok and not found:
                    found = True
                    err = 100.0 * (t.pose.distance_m / pose.distance_m - 1.0)
                    centre_err = d
                    rms, sd = t.fit.residual_rms_px, _distance_sd_pct(t.pose.t, t.fit.covariance)
                    dots = t.dots_scale
                    bias_sd, outer_sd = _circle_bias_sd_pct(t), _outer_bias_sd_pct(t)
                    delta, share, outer_level = t.delta_px, t.outer_share, min(t.levels_used, default=None)
                elif not t.fit.ok:
                    failure = f"pose_fit: {getattr(t.fit, 'reason', '')}"
            for f in getattr(out, "failures", []):
                if f.target_id == tid and np.hypot(*(np.asarray(f.centre_px) - centre)) <= tol:
                    detected = True
                    failure = failure or f"{f.stage}: {f.reason}"
            why = None
            if detector is not None and vis.visible and semi_minor >= MIN_SEMI_MINOR_PX and not found:
                if trace is None:
                    trace = []
                    detector.detect(frame.image, saturation=float(camera.saturation_level), trace=trace)
                why = explain_miss(trace, centre, semi_minor, semi_major, failure, wrong)
            result.targets.append(TargetOutcome(
                case=case.name, family=case.family, background=case.background, camera=case.camera,
                bit_depth=camera.bit_depth, sheet=sheet, exposure_factor=frame.exposure_factor, target_id=tid,
                distance_m=pose.distance_m, tilt_deg=_line_of_sight_tilt_deg(pose), area_fraction=area,
                semi_minor_px=semi_minor, contrast=vis.contrast, snr=vis.snr, ring_visible=vis.visible,
                visible=vis.visible and semi_minor >= MIN_SEMI_MINOR_PX,
                found=found, detected=detected, wrong_id=wrong and not found, distance_error_pct=err,
                centre_error_px=centre_err, failure=failure, explain=why, residual_rms_px=rms, distance_sd_pct=sd,
                dots_scale=dots, circle_bias_sd_pct=bias_sd, outer_bias_sd_pct=outer_sd, delta_px=delta,
                outer_share=share, outer_level=outer_level))
        for n, t in enumerate(out.targets):
            if n not in claimed:
                result.spurious.append({"case": case.name, "exposure_factor": frame.exposure_factor,
                                        "target_id": t.target_id,
                                        "centre_px": [float(v) for v in t.candidate.outer.centre_px]})


_STAGE_RANK = {"blob": 0, "pair": 1, "border": 2, "code": 2, "candidate": 3}


def explain_miss(trace: Sequence[TraceEvent], centre_px: FloatArray, semi_minor_px: float, semi_major_px: float,
                 failure: str | None = None, wrong_id: bool = False) -> str:
    """Which stage lost a visible target, from the detector's trace of the frame: the furthest stage that an
    event at the target's place and of about its outer size reached. "stage: detail" with stage one of
    ``no blob`` (nothing dark of its size there), ``blob`` (dark blobs there, no ellipse pair: why, per pyramid
    level), ``pair`` (a pair whose ratio matches no configured geometry), ``border``, ``code`` (a pair that
    failed verification or its code: the reasons), ``identified`` (a candidate, lost after: de-duplication or
    nesting), ``wrong id``, or the tracker's own failure (``failure``: pose fit, level)."""
    if wrong_id:
        return "wrong id"
    if failure:
        return failure
    tol = max(3.0, 0.3 * semi_minor_px)
    near = [e for e in trace
            if math.hypot(e.centre_px[0] - centre_px[0], e.centre_px[1] - centre_px[1]) <= tol
            and 0.5 * semi_minor_px <= e.semi_major_px <= 1.6 * semi_major_px + 2.0]
    if not near:
        return "no blob: nothing dark of its size there"
    top = max(_STAGE_RANK[e.stage] for e in near)
    at = [e for e in near if _STAGE_RANK[e.stage] == top]
    if top == 3:
        return "identified: " + ", ".join(sorted({e.detail for e in at})) + " (lost after)"
    if top == 2:
        if any(e.stage == "border" for e in at):
            return "border: pair too close to the image border"
        return "code: " + "; ".join(sorted({e.detail for e in at}))
    if top == 1:
        return "pair: ratio matches no geometry (" + ", ".join(sorted({f"L{e.level}" for e in at})) + ")"
    by_level: dict[int, set[str]] = {}
    for e in at:
        by_level.setdefault(e.level, set()).add(e.detail)
    return "blob: " + "; ".join(f"L{lv} " + ", ".join(sorted(d)) for lv, d in sorted(by_level.items()))


def explain_counts(outcomes: Iterable[TargetOutcome]) -> dict[str, int]:
    """Misses per stage (the part of ``explain`` before its colon), most first."""
    counts: dict[str, int] = {}
    for t in outcomes:
        if t.explain is not None:
            stage = t.explain.split(":")[0]
            counts[stage] = counts.get(stage, 0) + 1
    return dict(sorted(counts.items(), key=lambda kv: -kv[1]))


def _polygon_area(points: FloatArray) -> float:
    x, y = points[:, 0], points[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def decoy_spec(index: int, outer_radius_m: float = OUTER_RADIUS_M) -> TargetSpec:
    """An uncoded ring (no code dots): the look of a ring target, without an id. Ratios vary with ``index``."""
    ratio = (0.4, 0.55, 0.3, 0.65)[index % 4]
    return TargetSpec(id=900 + index, outer_radius_m=outer_radius_m, inner_radius_m=ratio * outer_radius_m)


def run_no_target(cases: Sequence[Case], result: DetectionResult, exposures: Sequence[float],
                  rng: np.random.Generator) -> None:
    """Frames without our targets: each textured background (and the gradient) alone, and with three uncoded
    ring decoys, at the given exposures."""
    seen: set[tuple[str, str]] = set()
    for case in cases:
        if case.background not in TEXTURED + ("gradient", "white") or (case.background, case.camera) in seen:
            continue
        seen.add((case.background, case.camera))
        data = copy.deepcopy(case.scenario)
        data["exposure"]["factors"] = list(exposures)
        scenario = Scenario.from_dict(data)
        camera = scenario.camera
        formation = scenario.formation
        tracker = _tracker(camera, scenario.targets)
        decoys = []
        for i in range(3):
            spec = decoy_spec(i)
            step = _place({"camera": data["camera"]}, [(float(rng.choice(AREA_FRACTIONS[:4])), 20.0 * i)], rng,
                          where="anywhere")
            if step is None:
                continue
            pose = Pose.from_quaternion(np.array(step[0]["q_xyzw"]), np.array(step[0]["t_m"]))
            decoys.append(Placement(pose, TargetTexture(spec, white=scenario.scene.white_reflectance,
                                                        black=scenario.scene.black_reflectance)))
        for kind, placements in (("background", []), ("decoys", decoys)):
            optical = formation.optical_image(placements)
            for e, factor in enumerate(scenario.exposure_factors):
                image = formation.render_from_optical(optical, scenario.nominal_exposure_us * factor,
                                                      rng=np.random.default_rng([case.scenario["seed"], e, 7]))
                out = tracker.process(image, scenario.nominal_exposure_us * factor)
                _record_empty(result, f"{case.background}/{case.camera} x{factor:g}", kind, out)


def _record_empty(result: DetectionResult, source: str, kind: str, out: FrameResult) -> None:
    result.empty.append(EmptyOutcome(source=source, kind=kind, reported=len(out.targets),
                                     ids=tuple(int(t.target_id) for t in out.targets)))


def run_photos(photos: Iterable[tuple[str, npt.NDArray[Any]]], result: DetectionResult,
               targets: Sequence[TargetSpec]) -> None:
    """Real photos of no target of ours (other circular markers, chessboards), each as given and scaled x0.25
    and x4 (clipped): everything reported is a false positive. Camera: f = image width, centred, no
    distortion."""
    for name, image in photos:
        gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        depth = 8 if gray.dtype == np.uint8 else 16
        top = (1 << depth) - 1
        h, w = gray.shape
        camera = CameraModel(width=w, height=h, fx=float(w), fy=float(w), cx=(w - 1) / 2.0, cy=(h - 1) / 2.0,
                             bit_depth=depth)
        tracker = _tracker(camera, targets)
        for scale in (1.0, 0.25, 4.0):
            scaled = np.clip(np.rint(gray.astype(np.float64) * scale), 0, top).astype(gray.dtype)
            out = tracker.process(scaled)
            _record_empty(result, f"{name} x{scale:g}", "photo", out)


def photo_cases(files: Sequence[str], seed: int = 0, quick: bool = False) -> list[Case]:
    """Targets on real photos used as backgrounds (``kind: image``, stretched over the frame, mean reflectance
    0.6): per photo a small target (0.1 % of the frame) and a medium one (1 %), tilted 30 and 50 degrees."""
    exposures = QUICK_EXPOSURES if quick else EXPOSURES
    cases = []
    for n, file in enumerate(files):
        rng = np.random.default_rng(np.random.SeedSequence([seed, 104, n]))
        data = _scenario("1280x800-8bit", "grey", exposures, rng, seed * 1000 + 900 + n)
        data["scene"].update({"background_reflectance": 0.6,
                              "background_texture": {"kind": "image", "file": str(file)}})
        step = _place(data, [(0.001, 30.0), (0.01, 50.0)], rng, where="anywhere")
        if step is None:
            continue
        data["poses"] = [step]
        cases.append(Case(f"photo-{n:03d}", "single", "photo", "1280x800-8bit", data))
    return cases


def run_detection_sweep(seed: int = 0, scale: float = 1.0, quick: bool = False,
                        photos: Iterable[tuple[str, npt.NDArray[Any]]] = (),
                        progress: Callable[[str], None] | None = None,
                        cases: Sequence[Case] | None = None,
                        background_files: Sequence[str] = (), explain: bool = False,
                        encoding_known: bool = False) -> DetectionResult:
    """The whole evaluation (module docstring): the seeded scenes (and targets on the ``background_files``
    photos), the no-target set, the ``photos``. ``encoding_known``: ``run_case``'s."""
    t0 = time.perf_counter()
    result = DetectionResult()
    cases = build_cases(seed, scale, quick) if cases is None else list(cases)
    cases += photo_cases(background_files, seed, quick)
    for n, case in enumerate(cases):
        run_case(case, result, explain, encoding_known)
        if progress:
            done = [t for t in result.targets if t.case == case.name]
            vis = [t for t in done if t.visible]
            progress(f"{n + 1}/{len(cases)} {case.name} ({case.background}, {case.camera}): "
                     f"{sum(t.found for t in vis)}/{len(vis)} visible found")
    rng = np.random.default_rng(np.random.SeedSequence([seed, 202]))
    run_no_target(cases, result, QUICK_EXPOSURES if quick else (0.25, 1.0, 4.0, 16.0), rng)
    pool = [TargetSpec.default(i, OUTER_RADIUS_M) for i in POOL_IDS]
    run_photos(photos, result, pool)
    if progress:
        progress(f"no-target set: {len(result.empty)} frames, "
                 f"{sum(e.reported for e in result.empty)} false positives")
    result.seconds = time.perf_counter() - t0
    return result
