"""Simulation scenarios: a YAML file describing camera, sensor, optics, effects, targets, their poses and the
exposures, turned into a sequence of rendered frames with their truth poses.

File layout (every key validated, unknown keys rejected with their path; only ``camera``, ``targets`` and
one of ``poses`` / ``trajectory`` are required)::

    name: paper-lab
    seed: 1                                   # trajectory and noise; default 0
    camera: {width: 1920, height: 1200, fx: 1800, fy: 1800, cx: 959.5, cy: 599.5, dist: [-0.1, 0, 0, 0, 0],
             bit_depth: 12}
    sensor: {full_well_e: 10000, read_noise_e: 5, black_level_dn: 0}   # + dn_per_e, shot_noise,
                                                                       #   exact_poisson_below_e
    optics: {psf_sigma_px: 0.8, oversampling: 3}                      # OpticsModel
    effects: {halo: {fraction: 0.03, sigma_px: 6.0}}                   # livetrack.sim.effects.EFFECTS
    radiometry: {white_rate_e_per_us: 3.2}
    scene: {white_reflectance: 0.85, black_reflectance: 0.04, background_reflectance: 0.2, supersampling: 16,
            background_texture: {kind: noise, scales_px: [2, 8, 32], contrast: 0.3},   # optional, below
            illumination: {gradient: 0.4, angle_deg: 30},     # optional: irradiance x (1 + gradient p)
            sheet_side_factor: 2.8}                           # white sheet side / R; "none": no sheet
    targets: [{id: 3, outer_radius_m: 0.125}]          # TargetSpec.from_dict, short or full form
    poses:                                             # either explicit steps ...
      - {target_id: 3, t_m: [0.1, 0.0, 2.0], tilt_deg: 20, tilt_axis_deg: 30, roll_deg: 0}  # or q_xyzw
      - [{target_id: 3, t_m: [...]}, {target_id: 5, t_m: [...]}]    # a list: several targets at once
    trajectory: {kind: spread, count: 20, distance_m: [1.5, 6.0], tilt_deg: [0, 50], margin_px: 20}  # ... or
    exposure: {nominal_us: auto, white_fraction_of_full_well: 0.55, factors: [0.25, 1, 4], gain_db: 0}
    timing: {fps: 30, start_ns: 0}

Explicit poses: ``t_m`` is the target origin in the camera frame; the rotation is
``geometry.look_rotation(tilt_deg, tilt_axis_deg, roll_deg)`` (tilt from the optical axis; all default 0,
frontal) or the quaternion ``q_xyzw``. ``target_id`` may be left out when there is a single target.

The ``spread`` trajectory (seeded, deterministic) places each target (``target_ids``, default all) at
``count`` steps with distances and tilts spread over their ranges (Latin hypercube: one value per equal
slice, in shuffled order), random tilt axes and rolls, the tilt measured from the line of sight (at 0 the
target faces the camera), image positions spread over the frame, and the whole sheet at least ``margin_px``
inside the image (checked on its projected outline, lens distortion included) and clear of the other targets'
sheets.

Scene: ``background_reflectance`` is the (mean) reflectance of what is seen beyond the sheets; a
``background_texture`` (seeded by the scenario's seed unless it has its own ``seed``) modulates it in pixel
space (``livetrack.sim.texture``): ``{kind: noise, scales_px: [2, 8, 32], contrast: 0.3}`` (carpet, foliage:
value noise with one layer per feature size, relative deviation ``contrast``), ``{kind: text, line_height_px:
12, ink_reflectance: 0.04}`` (lines of printed-like glyphs on the background), ``{kind: checker, square_px:
40, dark_reflectance: 0.04, angle_deg: 0}`` or ``{kind: image, file: PATH}`` (a picture stretched over the
frame, scaled to mean ``background_reflectance``; PATH relative to the scenario file). ``illumination``
tilts the light over the whole scene, targets included (``formation.Illumination``; vignetting is the
``vignetting`` effect). ``sheet_side_factor``: side of the square white sheet around each target in outer
radii (>= 2, default 2.8); ``none``: no sheet, the target printed edge-to-edge on the background.

Frames are every pose step x every exposure factor, pose-major; frame k is at ``start_ns + k / fps``.
``exposure.nominal_us: auto`` is the exposure putting white paper at ``white_fraction_of_full_well`` of full
well (``ImageFormation.nominal_exposure_us``). Each exposure must fit in the frame period.
"""

from __future__ import annotations

import importlib.resources
import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from livetrack.camera import CameraModel
from livetrack.config import checks as cc
from livetrack.geometry import Pose, look_rotation, rotation_from_rotvec
from livetrack.sim.coverage import DEFAULT_SUPERSAMPLING, Placement
from livetrack.sim.effects import Effects
from livetrack.sim.formation import DEFAULT_WHITE_RATE_E_PER_US, Illumination, ImageFormation, Radiometry
from livetrack.sim.optics import OpticsModel
from livetrack.sim.sensor import SensorModel
from livetrack.sim.texture import (
    DEFAULT_SHEET_FACTOR,
    INK_BLACK,
    PAPER_WHITE,
    BackgroundPattern,
    CheckerBackground,
    ImageBackground,
    NoiseBackground,
    TargetTexture,
    TextBackground,
)
from livetrack.targets.spec import TargetSpec

FloatArray = npt.NDArray[np.float64]

DEFAULT_SCENARIO = "default.yaml"
"""Built-in scenario (``livetrack/data/scenarios/``) used when none is given."""

OUTLINE_POINTS_PER_SIDE = 32
"""Points per sheet side when checking that a sheet lies inside the image (distortion bends the sides)."""

_TOP_KEYS = ["name", "seed", "camera", "sensor", "optics", "effects", "radiometry", "scene", "targets",
             "poses", "trajectory", "exposure", "timing"]


@dataclass(frozen=True)
class SimFrame:
    """One rendered frame. ``image`` (H, W) uint8/uint16; ``truth`` target id -> target-to-camera Pose."""

    frame_index: int
    timestamp_ns: int
    exposure_us: float
    gain_db: float
    image: npt.NDArray[np.unsignedinteger]
    truth: dict[int, Pose]
    pose_index: int = 0
    exposure_factor: float = 1.0


@dataclass(frozen=True)
class Scene:
    """Reflectances of paper, ink and background (0..1), the sub-cells per edge pixel when rendering, the
    background's texture (its resolved scenario section, None: uniform), the illumination gradient and the
    sheet around each target (side in outer radii; None: no sheet, printed edge-to-edge)."""

    white_reflectance: float = PAPER_WHITE
    black_reflectance: float = INK_BLACK
    background_reflectance: float = 0.2
    supersampling: int = DEFAULT_SUPERSAMPLING
    background_texture: Mapping[str, Any] | None = None
    illumination: Illumination | None = None
    sheet_side_factor: float | None = DEFAULT_SHEET_FACTOR


@dataclass(frozen=True)
class Scenario:
    """A loaded scenario: the image formation, the targets, the pose steps and the exposures.

    ``steps[i]`` maps target id -> Pose for pose step i; frame k shows step ``k // len(exposure_factors)`` at
    exposure ``exposures_us[k % len(exposure_factors)]``. ``source`` is the resolved content (trajectory
    expanded into explicit poses, ``nominal_us`` resolved) as a plain dict: loading it again gives the same
    frames.
    """

    name: str
    seed: int
    formation: ImageFormation
    targets: tuple[TargetSpec, ...]
    scene: Scene
    steps: tuple[dict[int, Pose], ...]
    nominal_exposure_us: float
    exposure_factors: tuple[float, ...]
    gain_db: float
    fps: float
    start_ns: int = 0
    source: Mapping[str, Any] = field(default_factory=dict, compare=False, repr=False)

    # ------------------------------------------------------------------ loading
    @classmethod
    def from_file(cls, file: str | Path, seed: int | None = None) -> Scenario:
        """Load and validate a scenario file; ``seed`` overrides the file's seed (trajectory and noise)."""
        return cls.from_dict(cc.load_yaml(file), seed=seed, path="", base_dir=Path(file).parent)

    @classmethod
    def default(cls, seed: int | None = None) -> Scenario:
        """The built-in default scenario (small and quick)."""
        resource = importlib.resources.files("livetrack") / "data" / "scenarios" / DEFAULT_SCENARIO
        with importlib.resources.as_file(resource) as file:
            return cls.from_file(file, seed=seed)

    @classmethod
    def from_dict(cls, data: Any, seed: int | None = None, path: str = "",
                  base_dir: Path | None = None) -> Scenario:
        """Validate a scenario mapping (module docstring); errors are ``ConfigError`` naming the key.
        ``base_dir``: where relative file names (a background image) are looked up (default: the current
        directory)."""
        cc.mapping(data, path, required=["camera", "targets"], optional=_TOP_KEYS)
        name = cc.string(data, "name", path, default="scenario")
        file_seed = cc.integer(data, "seed", path, default=0, ge=0)
        seed = file_seed if seed is None else int(seed)
        camera = CameraModel.from_dict(data["camera"], cc.join(path, "camera"))
        if camera.extra:
            raise cc.ConfigError(cc.join(path, "camera.image_formation"),
                                 "not used by scenarios (use sensor, optics and effects)")
        sensor = _sensor(_section(data, "sensor"), cc.join(path, "sensor"), camera.bit_depth)
        optics = _optics(_section(data, "optics"), cc.join(path, "optics"))
        effects = Effects.from_dict(data.get("effects"), cc.join(path, "effects"))
        radiometry = _radiometry(_section(data, "radiometry"), cc.join(path, "radiometry"))
        scene = _scene(_section(data, "scene"), cc.join(path, "scene"))
        texture = scene.background_texture
        if texture is not None and texture["kind"] == "image" and base_dir is not None:
            # Resolved against the scenario's folder, so that the resolved content loads from anywhere.
            file = Path(texture["file"])
            scene = replace(scene, background_texture={**texture, "file": str(file if file.is_absolute()
                                                                              else base_dir / file)})
        pattern = _background_pattern(scene, camera, seed, cc.join(path, "scene.background_texture"),
                                      base_dir)
        formation = ImageFormation(camera=camera, radiometry=radiometry, optics=optics, sensor=sensor,
                                   effects=effects, background_reflectance=scene.background_reflectance,
                                   supersampling=scene.supersampling, background_pattern=pattern,
                                   illumination=scene.illumination)
        targets = _targets(data["targets"], cc.join(path, "targets"))
        textures = {t.id: _texture(t, scene) for t in targets}
        has_poses, has_traj = data.get("poses") is not None, data.get("trajectory") is not None
        if has_poses and has_traj:
            raise cc.ConfigError(cc.join(path, "trajectory"), "give either 'poses' or 'trajectory', not both")
        if not has_poses and not has_traj:
            raise cc.ConfigError(cc.join(path, "poses"), "missing: give 'poses' (explicit) or 'trajectory'")
        if has_poses:
            steps = _explicit_steps(data["poses"], cc.join(path, "poses"), [t.id for t in targets])
        else:
            rng = np.random.default_rng(np.random.SeedSequence([seed, 1]))
            steps = _spread(data["trajectory"], cc.join(path, "trajectory"), formation.render_camera,
                            textures, rng)
        nominal, fraction, factors, gain_db = _exposure(_section(data, "exposure"), cc.join(path, "exposure"),
                                                        formation, scene)
        fps, start_ns = _timing(_section(data, "timing"), cc.join(path, "timing"))
        longest = nominal * max(factors)
        if longest > 1e6 / fps:
            raise cc.ConfigError(cc.join(path, "exposure.factors"),
                                 f"longest exposure {longest:.0f} us exceeds the frame period "
                                 f"{1e6 / fps:.0f} us at {fps:g} fps")
        source = {
            "name": name, "seed": seed, "camera": camera.to_dict(),
            "sensor": {"full_well_e": sensor.full_well_e, "read_noise_e": sensor.read_noise_e,
                       "black_level_dn": sensor.black_level_dn, "dn_per_e": sensor.dn_per_e_at_0db,
                       "shot_noise": sensor.shot_noise,
                       "exact_poisson_below_e": sensor.exact_poisson_below_e},
            "optics": {"psf_sigma_px": optics.psf_sigma_px, "oversampling": optics.oversampling},
            "effects": effects.to_dict(),
            "radiometry": {"white_rate_e_per_us": radiometry.white_rate_e_per_us},
            "scene": _scene_dict(scene),
            "targets": [t.to_dict() for t in targets],
            "poses": [[_pose_dict(tid, pose) for tid, pose in step.items()] for step in steps],
            "exposure": {"nominal_us": nominal, "white_fraction_of_full_well": fraction,
                         "factors": list(factors), "gain_db": gain_db},
            "timing": {"fps": fps, "start_ns": start_ns},
        }
        return cls(name=name, seed=seed, formation=formation, targets=tuple(targets), scene=scene,
                   steps=tuple(steps), nominal_exposure_us=nominal, exposure_factors=tuple(factors),
                   gain_db=gain_db, fps=fps, start_ns=start_ns, source=source)

    def to_dict(self) -> dict[str, Any]:
        """The resolved scenario as plain YAML-ready data (see ``source``)."""
        return _plain(self.source)

    # ------------------------------------------------------------------ frames
    @property
    def camera(self) -> CameraModel:
        """The camera model of the recording (the tracker's; ``lens_distortion`` renders differently)."""
        return self.formation.camera

    @property
    def camera_stating_encoding(self) -> CameraModel:
        """``camera`` with the output encoding its frames are delivered in (the ``srgb_encoding`` or
        ``gamma_encoding`` effect) stated, as the camera file of such a camera would: what the simulated camera
        source hands on (``sources.sim_source``). Without either effect, ``camera``."""
        effects = self.formation.effects
        if effects.srgb_encoding is not None:
            return replace(self.camera, encoding="srgb")
        if effects.gamma_encoding is not None:
            return replace(self.camera, encoding=f"gamma {effects.gamma_encoding.gamma:g}")
        return self.camera

    @property
    def exposures_us(self) -> tuple[float, ...]:
        return tuple(self.nominal_exposure_us * f for f in self.exposure_factors)

    def __len__(self) -> int:
        return len(self.steps) * len(self.exposure_factors)

    def _check_index(self, frame_index: int) -> None:
        if not 0 <= frame_index < len(self):
            raise IndexError(f"frame {frame_index} outside 0..{len(self) - 1}")

    def pose_index(self, frame_index: int) -> int:
        self._check_index(frame_index)
        return frame_index // len(self.exposure_factors)

    def timestamp_ns(self, frame_index: int) -> int:
        return self.start_ns + round(frame_index * 1e9 / self.fps)

    def truth_for(self, frame_index: int) -> dict[int, Pose]:
        return dict(self.steps[self.pose_index(frame_index)])

    def placements_for(self, frame_index: int) -> list[Placement]:
        """The targets of frame ``frame_index`` as ``Placement``s (pose + printed sheet)."""
        step = self.steps[self.pose_index(frame_index)]
        by_id = {t.id: t for t in self.targets}
        return [Placement(pose, _texture(by_id[tid], self.scene)) for tid, pose in step.items()]

    def render_frame(self, frame_index: int, noise: bool = True,
                     optical: FloatArray | None = None) -> SimFrame:
        """Render one frame; noise from a generator seeded by (seed, frame_index), so any frame can be
        rendered alone and equals the one ``frames`` yields. ``optical`` may pass the step's precomputed
        ``ImageFormation.optical_image``."""
        pose_index = self.pose_index(frame_index)
        factor = self.exposure_factors[frame_index % len(self.exposure_factors)]
        exposure_us = self.nominal_exposure_us * factor
        if optical is None:
            optical = self.formation.optical_image(self.placements_for(frame_index))
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 2, frame_index]))
        image = self.formation.render_from_optical(optical, exposure_us, self.gain_db, rng, noise)
        return SimFrame(frame_index=frame_index, timestamp_ns=self.timestamp_ns(frame_index),
                        exposure_us=exposure_us, gain_db=self.gain_db, image=image,
                        truth=self.truth_for(frame_index), pose_index=pose_index, exposure_factor=factor)

    def frames(self, max_frames: int | None = None, noise: bool = True) -> Iterator[SimFrame]:
        """Render frames 0, 1, ... (at most ``max_frames``), the optical image once per pose step."""
        count = len(self) if max_frames is None else min(len(self), max(0, max_frames))
        cached: tuple[int, FloatArray] | None = None
        for k in range(count):
            step = self.pose_index(k)
            if cached is None or cached[0] != step:
                cached = (step, self.formation.optical_image(self.placements_for(k)))
            yield self.render_frame(k, noise=noise, optical=cached[1])


# ---------------------------------------------------------------------------------------------- sections
def _section(data: Mapping, key: str) -> Any:
    """An optional section: {} when absent or null (any other value is checked by its reader)."""
    value = data.get(key)
    return {} if value is None else value


def _sensor(data: Any, path: str, bit_depth: int) -> SensorModel:
    cc.mapping(data, path, optional=["full_well_e", "read_noise_e", "black_level_dn", "dn_per_e",
                                     "shot_noise", "exact_poisson_below_e"])
    top = (1 << bit_depth) - 1
    dn_per_e = None
    if data.get("dn_per_e") is not None:
        dn_per_e = cc.number(data, "dn_per_e", path, gt=0)
    return SensorModel(
        full_well_e=cc.number(data, "full_well_e", path, default=10000.0, gt=0),
        read_noise_e=cc.number(data, "read_noise_e", path, default=5.0, ge=0),
        black_level_dn=cc.number(data, "black_level_dn", path, default=0.0, ge=0, lt=top),
        bit_depth=bit_depth,
        dn_per_e=dn_per_e,
        shot_noise=cc.boolean(data, "shot_noise", path, default=True),
        exact_poisson_below_e=cc.number(data, "exact_poisson_below_e", path, default=100.0, ge=0),
    )


def _optics(data: Any, path: str) -> OpticsModel:
    cc.mapping(data, path, optional=["psf_sigma_px", "oversampling"])
    return OpticsModel(psf_sigma_px=cc.number(data, "psf_sigma_px", path, default=0.8, ge=0),
                       oversampling=cc.integer(data, "oversampling", path, default=3, choices=range(1, 9)))


def _radiometry(data: Any, path: str) -> Radiometry:
    cc.mapping(data, path, optional=["white_rate_e_per_us"])
    return Radiometry(cc.number(data, "white_rate_e_per_us", path, default=DEFAULT_WHITE_RATE_E_PER_US, gt=0))


def _scene(data: Any, path: str) -> Scene:
    cc.mapping(data, path, optional=["white_reflectance", "black_reflectance", "background_reflectance",
                                     "supersampling", "background_texture", "illumination",
                                     "sheet_side_factor"])
    white = cc.number(data, "white_reflectance", path, default=PAPER_WHITE, gt=0, le=1)
    black = cc.number(data, "black_reflectance", path, default=INK_BLACK, ge=0, le=1)
    if black >= white:
        raise cc.ConfigError(cc.join(path, "black_reflectance"), f"must be below white_reflectance ({white})")
    supersampling = cc.integer(data, "supersampling", path, default=DEFAULT_SUPERSAMPLING, ge=1)
    if math.isqrt(supersampling) ** 2 != supersampling:
        raise cc.ConfigError(cc.join(path, "supersampling"),
                             f"must be a perfect square (1, 4, 9, 16, ...), got {supersampling}")
    background = cc.number(data, "background_reflectance", path, default=0.2, ge=0, le=1)
    texture = None
    if data.get("background_texture") is not None:
        texture = _background_texture(data["background_texture"], cc.join(path, "background_texture"))
    illumination = None
    if data.get("illumination") is not None:
        ipath = cc.join(path, "illumination")
        cc.mapping(data["illumination"], ipath, optional=["gradient", "angle_deg"])
        illumination = Illumination(gradient=cc.number(data["illumination"], "gradient", ipath, default=0.0,
                                                       ge=0, lt=1),
                                    angle_deg=cc.number(data["illumination"], "angle_deg", ipath, default=0.0))
    sheet: float | None = DEFAULT_SHEET_FACTOR
    raw = data.get("sheet_side_factor")
    if isinstance(raw, str):
        if raw != "none":
            raise cc.ConfigError(cc.join(path, "sheet_side_factor"),
                                 f"must be a number >= 2 or 'none' (no sheet), got {raw!r}")
        sheet = None
    elif raw is not None:
        sheet = cc.number(data, "sheet_side_factor", path, ge=2.0)
    return Scene(white_reflectance=white, black_reflectance=black, background_reflectance=background,
                 supersampling=supersampling, background_texture=texture, illumination=illumination,
                 sheet_side_factor=sheet)


_TEXTURE_KEYS = {"noise": ["scales_px", "contrast", "seed"], "text": ["line_height_px", "ink_reflectance", "seed"],
                 "checker": ["square_px", "dark_reflectance", "angle_deg"], "image": ["file"]}


def _background_texture(data: Any, path: str) -> dict[str, Any]:
    """The validated ``scene.background_texture`` section, defaults filled in (plain data)."""
    cc.mapping(data, path, required=["kind"], optional=sorted({k for v in _TEXTURE_KEYS.values() for k in v}))
    kind = cc.string(data, "kind", path, choices=sorted(_TEXTURE_KEYS))
    for key in data:
        if key != "kind" and key not in _TEXTURE_KEYS[kind]:
            raise cc.ConfigError(cc.join(path, str(key)),
                                 f"not a parameter of kind {kind!r} (allowed: {', '.join(_TEXTURE_KEYS[kind])})")
    out: dict[str, Any] = {"kind": kind}
    if kind in ("noise", "text") and data.get("seed") is not None:
        out["seed"] = cc.integer(data, "seed", path, ge=0)
    if kind == "noise":
        scales = cc.number_list(data, "scales_px", path, default=[2.0, 8.0, 32.0])
        if not scales or min(scales) <= 0:
            raise cc.ConfigError(cc.join(path, "scales_px"), f"must be a non-empty list of sizes > 0, got {scales}")
        out.update(scales_px=scales, contrast=cc.number(data, "contrast", path, default=0.3, ge=0))
    elif kind == "text":
        out.update(line_height_px=cc.number(data, "line_height_px", path, default=12.0, gt=0),
                   ink_reflectance=cc.number(data, "ink_reflectance", path, default=INK_BLACK, ge=0, le=1))
    elif kind == "checker":
        out.update(square_px=cc.number(data, "square_px", path, default=40.0, gt=0),
                   dark_reflectance=cc.number(data, "dark_reflectance", path, default=INK_BLACK, ge=0, le=1),
                   angle_deg=cc.number(data, "angle_deg", path, default=0.0))
    else:
        out["file"] = cc.string(data, "file", path)
    return out


def _background_pattern(scene: Scene, camera: CameraModel, seed: int, path: str,
                        base_dir: Path | None) -> BackgroundPattern | None:
    """The scene's background pattern for this camera (None: uniform). Reads the image file of ``kind: image``."""
    tex = scene.background_texture
    if tex is None:
        return None
    base, w, h = scene.background_reflectance, camera.width, camera.height
    kind = tex["kind"]
    if kind == "noise":
        return NoiseBackground(base, tuple(tex["scales_px"]), tex["contrast"], w, h, tex.get("seed", seed))
    if kind == "text":
        return TextBackground(base, tex["line_height_px"], w, h, tex["ink_reflectance"], tex.get("seed", seed))
    if kind == "checker":
        return CheckerBackground(base, tex["square_px"], tex["dark_reflectance"], tex["angle_deg"])
    import cv2

    file = Path(tex["file"])
    if not file.is_absolute() and base_dir is not None:
        file = base_dir / file
    image = cv2.imread(str(file), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_ANYDEPTH)
    if image is None:
        raise cc.ConfigError(cc.join(path, "file"), f"cannot read the image {file}")
    top = 255.0 if image.dtype == np.uint8 else 65535.0 if image.dtype == np.uint16 else max(float(image.max()), 1.0)
    return ImageBackground(image.astype(np.float64) / top, base, w, h)


def _scene_dict(scene: Scene) -> dict[str, Any]:
    out: dict[str, Any] = {"white_reflectance": scene.white_reflectance,
                           "black_reflectance": scene.black_reflectance,
                           "background_reflectance": scene.background_reflectance,
                           "supersampling": scene.supersampling,
                           "sheet_side_factor": "none" if scene.sheet_side_factor is None else scene.sheet_side_factor}
    if scene.background_texture is not None:
        out["background_texture"] = dict(scene.background_texture)
    if scene.illumination is not None:
        out["illumination"] = {"gradient": scene.illumination.gradient,
                               "angle_deg": scene.illumination.angle_deg}
    return out


def _targets(data: Any, path: str) -> list[TargetSpec]:
    if not isinstance(data, list) or not data:
        raise cc.ConfigError(path, "must be a non-empty list of target specs")
    targets = [TargetSpec.from_dict(item, cc.join(path, i)) for i, item in enumerate(data)]
    seen: set[int] = set()
    for i, t in enumerate(targets):
        if t.id in seen:
            raise cc.ConfigError(cc.join(cc.join(path, i), "id"), f"duplicate target id {t.id}")
        seen.add(t.id)
    return targets


def _texture(spec: TargetSpec, scene: Scene) -> TargetTexture:
    if scene.sheet_side_factor is None:
        return TargetTexture(spec, white=scene.white_reflectance, black=scene.black_reflectance,
                             edge_to_edge=True)
    side = scene.sheet_side_factor * spec.outer_radius_m
    return TargetTexture(spec, sheet_size_m=(side, side), white=scene.white_reflectance,
                         black=scene.black_reflectance)


def _exposure(data: Any, path: str, formation: ImageFormation,
              scene: Scene) -> tuple[float, float, list[float], float]:
    cc.mapping(data, path, optional=["nominal_us", "white_fraction_of_full_well", "factors", "gain_db"])
    fraction = cc.number(data, "white_fraction_of_full_well", path, default=0.55, gt=0)
    if data.get("nominal_us") in (None, "auto"):
        nominal = formation.nominal_exposure_us(scene.white_reflectance, fraction)
    else:
        nominal = cc.number(data, "nominal_us", path, gt=0)
    factors = cc.number_list(data, "factors", path, default=[1.0])
    if not factors:
        raise cc.ConfigError(cc.join(path, "factors"), "must not be empty")
    for i, f in enumerate(factors):
        if f <= 0:
            raise cc.ConfigError(f"{cc.join(path, 'factors')}[{i}]", f"must be > 0, got {f}")
    return nominal, fraction, factors, cc.number(data, "gain_db", path, default=0.0, ge=0)


def _timing(data: Any, path: str) -> tuple[float, int]:
    cc.mapping(data, path, optional=["fps", "start_ns"])
    fps = cc.number(data, "fps", path, default=30.0, gt=0)
    return fps, cc.integer(data, "start_ns", path, default=0, ge=0)


# ---------------------------------------------------------------------------------------------- poses
def _explicit_steps(data: Any, path: str, ids: list[int]) -> list[dict[int, Pose]]:
    if not isinstance(data, list) or not data:
        raise cc.ConfigError(path, "must be a non-empty list of poses")
    steps = []
    for i, item in enumerate(data):
        item_path = cc.join(path, i)
        entries = item if isinstance(item, list) else [item]
        if not entries:
            raise cc.ConfigError(item_path, "must not be empty")
        step: dict[int, Pose] = {}
        for j, entry in enumerate(entries):
            entry_path = cc.join(item_path, j) if isinstance(item, list) else item_path
            tid, pose = _pose(entry, entry_path, ids)
            if tid in step:
                raise cc.ConfigError(cc.join(entry_path, "target_id"),
                                     f"target {tid} placed twice in this step")
            step[tid] = pose
        steps.append(step)
    return steps


def _pose(data: Any, path: str, ids: list[int]) -> tuple[int, Pose]:
    cc.mapping(data, path, required=["t_m"], optional=["target_id", "tilt_deg", "tilt_axis_deg", "roll_deg",
                                                       "q_xyzw"])
    if "target_id" in data:
        tid = cc.integer(data, "target_id", path)
        if tid not in ids:
            raise cc.ConfigError(cc.join(path, "target_id"), f"no target with id {tid} (targets: {ids})")
    elif len(ids) == 1:
        tid = ids[0]
    else:
        raise cc.ConfigError(cc.join(path, "target_id"), "missing (required with several targets)")
    t = np.array(cc.number_list(data, "t_m", path, length=3))
    if t[2] <= 0:
        raise cc.ConfigError(cc.join(path, "t_m"),
                             f"the target must be in front of the camera (z > 0), got {t}")
    if "q_xyzw" in data:
        angles = [k for k in ("tilt_deg", "tilt_axis_deg", "roll_deg") if k in data]
        if angles:
            raise cc.ConfigError(cc.join(path, angles[0]), "give either q_xyzw or tilt/roll angles, not both")
        q = np.array(cc.number_list(data, "q_xyzw", path, length=4))
        if np.linalg.norm(q) < 1e-9:
            raise cc.ConfigError(cc.join(path, "q_xyzw"), "must not be zero")
        pose = Pose.from_quaternion(q, t)
    else:
        R = look_rotation(cc.number(data, "tilt_deg", path, default=0.0, ge=0, lt=90),
                          cc.number(data, "tilt_axis_deg", path, default=0.0),
                          cc.number(data, "roll_deg", path, default=0.0))
        pose = Pose(R, t)
    return tid, pose


def _pose_dict(tid: int, pose: Pose) -> dict[str, Any]:
    return {"target_id": int(tid), "t_m": [float(v) for v in pose.t],
            "q_xyzw": [float(v) for v in pose.quaternion]}


def _range(data: Mapping, key: str, path: str, lo_ok: float,
           hi_lim: float | None = None) -> tuple[float, float]:
    values = cc.number_list(data, key, path, length=2)
    lo, hi = values
    if lo < lo_ok or hi < lo or (hi_lim is not None and hi >= hi_lim):
        limit = f" and below {hi_lim}" if hi_lim is not None else ""
        raise cc.ConfigError(cc.join(path, key),
                             f"must be [low, high] with {lo_ok} <= low <= high{limit}, got {values}")
    return lo, hi


def facing_rotation(ray: FloatArray) -> FloatArray:
    """(3, 3) smallest rotation taking the camera +z axis onto the unit vector ``ray`` (3,)."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, ray)
    s = float(np.linalg.norm(axis))
    if s < 1e-15:
        return np.eye(3)
    return rotation_from_rotvec(axis / s * math.atan2(s, float(ray @ z)))


def sheet_outline_px(camera: CameraModel, placement: Placement,
                     points_per_side: int = OUTLINE_POINTS_PER_SIDE) -> FloatArray | None:
    """(4 * points_per_side, 2) pixel positions along the border of the placement's sheet, or None if part
    of it is not in front of the camera."""
    xmin, xmax, ymin, ymax = placement.texture.bounds_m
    s = np.linspace(0.0, 1.0, points_per_side, endpoint=False)
    xs = np.concatenate([xmin + s * (xmax - xmin), np.full_like(s, xmax), xmax - s * (xmax - xmin),
                         np.full_like(s, xmin)])
    ys = np.concatenate([np.full_like(s, ymin), ymin + s * (ymax - ymin), np.full_like(s, ymax),
                         ymax - s * (ymax - ymin)])
    cam_pts = placement.pose.apply(np.column_stack([xs, ys, np.zeros_like(xs)]))
    if np.any(cam_pts[:, 2] <= 1e-6):
        return None
    return camera.project(cam_pts)


def sheet_inside(camera: CameraModel, placement: Placement, margin_px: float = 0.0) -> bool:
    """True if the sheet of ``placement`` is wholly in front of the camera and ``margin_px`` inside the
    image."""
    outline = sheet_outline_px(camera, placement)
    return outline is not None and bool(np.all(camera.contains(outline, margin_px)))


def _spread(data: Any, path: str, camera: CameraModel, textures: Mapping[int, TargetTexture],
            rng: np.random.Generator) -> list[dict[int, Pose]]:
    cc.mapping(data, path, required=["kind", "count"], optional=["distance_m", "tilt_deg", "margin_px",
                                                                  "target_ids"])
    cc.string(data, "kind", path, choices=["spread"])
    count = cc.integer(data, "count", path, ge=1)
    d_lo, d_hi = _range(data, "distance_m", path, 1e-3) if "distance_m" in data else (1.0, 4.0)
    t_lo, t_hi = _range(data, "tilt_deg", path, 0.0, 90.0) if "tilt_deg" in data else (0.0, 45.0)
    margin = cc.number(data, "margin_px", path, default=10.0, ge=0)
    ids = list(textures)
    if data.get("target_ids") is not None:
        raw = data["target_ids"]
        if not isinstance(raw, list) or not raw or not all(isinstance(v, int) and not isinstance(v, bool)
                                                             for v in raw):
            raise cc.ConfigError(cc.join(path, "target_ids"),
                                 f"must be a non-empty list of target ids, got {raw!r}")
        for i, tid in enumerate(raw):
            if tid not in textures:
                raise cc.ConfigError(f"{cc.join(path, 'target_ids')}[{i}]", f"no target with id {tid}")
        if len(set(raw)) != len(raw):
            raise cc.ConfigError(cc.join(path, "target_ids"), "duplicate ids")
        ids = list(raw)

    def strata(n: int) -> FloatArray:
        """n values in [0, 1), one per slice of width 1/n, shuffled."""
        return (rng.permutation(n) + rng.random(n)) / n

    draws = {tid: {"d": strata(count), "tilt": strata(count), "x": strata(count), "y": strata(count),
                   "axis": rng.random(count) * 360.0, "roll": rng.random(count) * 360.0} for tid in ids}
    centre = np.array([(camera.width - 1) / 2.0, (camera.height - 1) / 2.0])
    span = np.array([camera.width - 1 - 2 * margin, camera.height - 1 - 2 * margin])
    steps: list[dict[int, Pose]] = []
    for i in range(count):
        step: dict[int, Pose] = {}
        boxes: list[FloatArray] = []
        for tid in ids:
            dr = draws[tid]
            distance = d_lo + (d_hi - d_lo) * dr["d"][i]
            tilt = t_lo + (t_hi - t_lo) * dr["tilt"][i]
            tilted = look_rotation(tilt, dr["axis"][i], dr["roll"][i])
            first = centre + (np.array([dr["x"][i], dr["y"][i]]) - 0.5) * span
            # Candidates: the drawn image position, then shrinking toward the centre, then random positions.
            candidates = [centre + (first - centre) * s for s in np.linspace(1.0, 0.0, 11)]
            candidates += list(centre + (rng.random((200, 2)) - 0.5) * span)
            for pixel in candidates:
                ray = camera.unproject(pixel)
                pose = Pose(facing_rotation(ray) @ tilted, distance * ray)
                outline = sheet_outline_px(camera, Placement(pose, textures[tid]))
                if outline is None or not np.all(camera.contains(outline, margin)):
                    continue
                box = np.concatenate([outline.min(axis=0) - margin, outline.max(axis=0) + margin])
                if any(_overlap(box, other) for other in boxes):
                    continue
                step[tid] = pose
                boxes.append(box)
                break
            else:
                raise cc.ConfigError(path, f"step {i}: cannot place target {tid} at {distance:.3f} m with "
                                     f"tilt {tilt:.1f} deg fully inside the image (margin {margin:g} px) and "
                                     "clear of the other targets; use larger distances, fewer targets or a "
                                     "smaller margin")
        steps.append(step)
    return steps


def _overlap(a: FloatArray, b: FloatArray) -> bool:
    """Do boxes (xmin, ymin, xmax, ymax) overlap?"""
    return bool(a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3])


def _plain(value: Any) -> Any:
    """Nested data with numpy scalars and tuples turned into plain Python (for YAML)."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def load_scenario(file: str | Path | None = None, seed: int | None = None) -> Scenario:
    """``Scenario.from_file(file)``, or the built-in default when ``file`` is None."""
    return Scenario.default(seed=seed) if file is None else Scenario.from_file(file, seed=seed)


__all__: Sequence[str] = ["Scenario", "Scene", "SimFrame", "load_scenario", "sheet_inside",
                          "sheet_outline_px"]
