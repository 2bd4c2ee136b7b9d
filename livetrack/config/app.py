"""Configuration of ``livetrack run``: YAML validated at the boundary.

Resolution order: the built-in defaults (``livetrack/data/config/default.yaml``, its ``tracker`` and ``pipeline``
sections completed from ``TrackerOptions()`` and ``PipelineOptions()``), then ``--config FILE`` merged
over them (mappings key by key, other values replaced), then the command-line overrides. The merged mapping is
validated once, here: every key is checked and an unknown key is an error naming its path (e.g.
``my.yaml: outputs.udp.destinaton: unknown key (allowed: destination, encoding, queue_size)``).

Sections: ``source`` (uri + options, checked by the source itself), ``camera`` and ``targets`` (null = the
source's, ``{file: PATH}``, or inline), ``tracker`` (``TrackerOptions`` fields), ``pipeline`` (threads and
hand-offs), ``outputs`` (rerun, udp, zmq, mavlink, record), ``mounting`` (camera on the vehicle, targets in
the world: ``livetrack.frames``), ``logging``. ``AppConfig.to_yaml()`` is the resolved config
that ``livetrack dump-config`` prints and that is saved beside every recording or .rrd output.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import re
from collections.abc import Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from livetrack.camera import CameraModel
from livetrack.camera.io import load_camera_uncertainty, load_camera_with_optics
from livetrack.camera.optics import CameraOptics, tracker_options_with_optics
from livetrack.config import checks as cc
from livetrack.estimator.tracker import TrackerOptions
from livetrack.exposure_control import ExposureControlOptions
from livetrack.frames import Mounting, TargetPlacement
from livetrack.sinks.mavlink import parse_connection as parse_mavlink_connection
from livetrack.sinks.rerun_mode import parse_mode
from livetrack.sinks.udp import parse_host_port
from livetrack.sources import check_source
from livetrack.targets.spec import TargetSpec, load_targets

SECTIONS = ["source", "camera", "targets", "tracker", "pipeline", "outputs", "logging"]
OPTIONAL_SECTIONS = ["mounting", "exposure_control"]  # absent from a hand-built mapping: the built-in default
ENCODINGS = ["binary", "json"]
LOG_LEVELS = ["debug", "info", "warning", "error"]
RESOLVED_CONFIG_SUFFIX = ".config.yaml"

# Sane ranges: beyond these a value is a typo or a unit mistake, not a setting (and some would exhaust memory:
# a queue of 1e32 items, 1e12 edge points per circle).
MAX_QUEUE = 100_000  # items in any queue or slot
MAX_SNDHWM = 10_000_000  # ZeroMQ messages
MAX_FRAMES = 10**12  # frames (a year at 30 000 fps)
MAX_EVERY_N = 1_000_000  # frames between periodic actions
MAX_TIMEOUT_S = 86_400.0  # seconds
MAX_PX = 100.0  # lengths along an edge profile (spacing, half width, blur)
MAX_IMAGE_PX = 100_000.0  # lengths in the image
MAX_POINTS_PER_CIRCLE = 20_000  # edge points per circle (the estimator's default is 360)
MAX_TRACKING_MARGIN = 100.0  # tracking window growth (fraction of the ellipse)
MAX_DN = 65_535.0  # digital numbers of a 16-bit sensor
MAX_MOUNT_OFFSET_M = 1000.0  # camera centre from the body origin
MAX_WORLD_M = 1e7  # target positions in local NED
MAX_RATE_HZ = 10_000.0  # MAVLink messages per target per second


@dataclass(frozen=True)
class SourceConfig:
    uri: str
    options: dict[str, Any]


@dataclass(frozen=True)
class PipelineConfig:
    max_frames: int | None
    lossless: bool | None
    slot_size: int
    read_timeout_s: float
    sink_queue_size: int
    sink_close_timeout_s: float
    search_worker: bool | None  # None: auto (``PipelineOptions.search_worker``)


@dataclass(frozen=True)
class RerunConfig:
    mode: str  # off | spawn | serve | connect | save
    argument: str | None  # connect: URL, save: PATH
    serve_bind: str
    serve_port: int
    spawn_port: int
    server_memory_limit: str
    image_every_n: int
    queue_size: int


@dataclass(frozen=True)
class UdpConfig:
    destination: tuple[str, int] | None
    encoding: str
    queue_size: int


@dataclass(frozen=True)
class ZmqConfig:
    endpoint: str | None
    encoding: str
    sndhwm: int
    queue_size: int


@dataclass(frozen=True)
class MavlinkConfig:
    connection: str | None  # udpout:HOST:PORT | serial:DEVICE:BAUD, None = off
    system_id: int
    component_id: int
    max_rate_hz: float
    vision_position_estimate: bool
    queue_size: int


@dataclass(frozen=True)
class RecordConfig:
    dir: Path | None
    overwrite: bool
    png_compression: int
    fsync_every_n_frames: int
    queue_size: int


@dataclass(frozen=True)
class OutputsConfig:
    rerun: RerunConfig
    udp: UdpConfig
    zmq: ZmqConfig
    record: RecordConfig
    mavlink: MavlinkConfig


@dataclass(frozen=True)
class LoggingConfig:
    level: str | None
    print_every_s: float


@dataclass(frozen=True)
class AppConfig:
    """The validated configuration. ``camera``/``targets`` None mean "the source's"."""

    source: SourceConfig
    camera: CameraModel | None
    targets: list[TargetSpec] | None
    tracker: TrackerOptions
    pipeline: PipelineConfig
    outputs: OutputsConfig
    logging: LoggingConfig
    resolved: dict[str, Any]  # the merged, validated mapping (paths made absolute), for dumping
    mounting: Mounting | None = None  # None: camera_to_body not configured (targets_in_world then ignored)
    exposure_control: ExposureControlOptions | None = None  # None: off

    def to_yaml(self, camera: CameraModel | None = None, targets: list[TargetSpec] | None = None) -> str:
        """The resolved config as YAML; with ``camera``/``targets`` (those actually used) inlined."""
        data = copy.deepcopy(self.resolved)
        if camera is not None:
            data["camera"] = camera.to_dict()
        if targets is not None:
            data["targets"] = [t.to_dict() for t in targets]
        header = "# livetrack resolved configuration (defaults + config file + command line)\n"
        return header + yaml.safe_dump(data, sort_keys=False, default_flow_style=False, width=110)


# ---------------------------------------------------------------------------------------------- loading
def default_config_data() -> dict[str, Any]:
    """The built-in defaults (a fresh copy: callers may change it)."""
    return copy.deepcopy(_default_config_data())


@functools.cache
def _default_config_data() -> dict[str, Any]:
    """default.yaml with its ``tracker`` and ``pipeline`` sections completed from ``TrackerOptions`` and
    ``PipelineOptions``: each default is written once, in its dataclass; the YAML holds only what the live
    config sets otherwise (and config-only keys). Keys in the dataclass's field order."""
    text = resources.files("livetrack").joinpath("data/config/default.yaml").read_text(encoding="utf-8")
    data = yaml.safe_load(text)
    data["tracker"] = {**tracker_option_defaults(), **(data.get("tracker") or {})}
    data["pipeline"] = {**pipeline_option_defaults(), **(data.get("pipeline") or {})}
    return data


SEARCH_WORKER_VALUES = {"auto": None, "on": True, "off": False}
"""``pipeline.search_worker`` in the config -> ``PipelineOptions.search_worker``."""
PIPELINE_KEYS = ["max_frames", "lossless", "slot_size", "read_timeout_s", "sink_queue_size", "sink_close_timeout_s",
                 "search_worker"]
"""The ``pipeline`` section: ``PipelineOptions`` fields (``search_wait_ms`` is not configurable)."""


def tracker_option_defaults() -> dict[str, Any]:
    """``TrackerOptions()``'s defaults as config values (tuples as lists), every config key of the ``tracker``
    section but ``propagate_camera_uncertainty`` (config only: in default.yaml)."""
    defaults = TrackerOptions()
    return {f.name: _plain(getattr(defaults, f.name)) for f in dataclasses.fields(TrackerOptions)
            if f.name != "camera_std"}  # camera_std: from the camera file


def pipeline_option_defaults() -> dict[str, Any]:
    """``PipelineOptions()``'s defaults as config values (``search_worker``: auto / on / off)."""
    from livetrack.pipeline import PipelineOptions  # not at the top: pipeline.py refers to AppConfig

    defaults = PipelineOptions()
    out = {key: getattr(defaults, key) for key in PIPELINE_KEYS}
    out["search_worker"] = next(k for k, v in SEARCH_WORKER_VALUES.items() if v is defaults.search_worker)
    return out


def _plain(value: Any) -> Any:
    return list(value) if isinstance(value, tuple) else value


def merge(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    """Deep merge: mappings key by key, anything else (lists, scalars, null) replaced."""
    out = copy.deepcopy(dict(base))
    for key, value in override.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def load_config(file: str | Path | None = None, overrides: Mapping[str, Any] | None = None) -> AppConfig:
    """Defaults + ``file`` + ``overrides`` (a mapping like the file's), validated. Raises ConfigError."""
    data = default_config_data()
    base_dir = Path.cwd()
    label = ""
    if file is not None:
        file = Path(file)
        user = cc.load_yaml(file)
        if user is None:
            user = {}
        if not isinstance(user, Mapping):
            raise cc.ConfigError(str(file), f"must be a mapping with sections {SECTIONS}, got "
                                            f"{type(user).__name__}")
        data = merge(data, user)
        base_dir = file.resolve().parent
        label = f"{file}: "
    if overrides:
        new_uri = (overrides.get("source") or {}).get("uri")
        old = data.get("source")
        if (isinstance(new_uri, str) and isinstance(old, dict)
                and _scheme(new_uri) != _scheme(str(old.get("uri", "")))):
            old["options"] = {}  # options of another kind of source do not apply
        data = merge(data, overrides)
    try:
        return parse_config(data, base_dir)
    except cc.ConfigError as exc:
        if label and not exc.path.startswith(label):
            raise cc.ConfigError(label + exc.path, exc.problem) from None
        raise


def parse_config(data: Any, base_dir: Path | None = None) -> AppConfig:
    """Validate a complete config mapping (as merged by ``load_config``)."""
    base_dir = base_dir or Path.cwd()
    cc.mapping(data, "", required=SECTIONS, optional=OPTIONAL_SECTIONS)
    resolved = copy.deepcopy(dict(data))
    for section in OPTIONAL_SECTIONS:
        resolved.setdefault(section, default_config_data()[section])
    source = _source(data["source"], "source")
    camera, resolved["camera"], optics = _camera(data["camera"], "camera", base_dir)
    targets, resolved["targets"] = _targets(data["targets"], "targets", base_dir)
    tracker = _tracker(data["tracker"], "tracker", tracker_options_with_optics(TrackerOptions(), optics))
    tracker = _camera_uncertainty(data["tracker"], "tracker", tracker, resolved["camera"])
    pipeline = _pipeline(data["pipeline"], "pipeline")
    resolved["pipeline"]["search_worker"] = next(k for k, v in SEARCH_WORKER_VALUES.items()
                                                 if v is pipeline.search_worker)
    outputs = _outputs(data["outputs"], "outputs", base_dir)
    resolved["outputs"]["rerun"]["mode"] = _rerun_mode_text(outputs.rerun)
    if outputs.record.dir is not None:
        resolved["outputs"]["record"]["dir"] = str(outputs.record.dir)
    logging_config = _logging(data["logging"], "logging")
    mounting = _mounting(resolved["mounting"], "mounting")
    exposure = _exposure_control(resolved["exposure_control"], "exposure_control")
    return AppConfig(source, camera, targets, tracker, pipeline, outputs, logging_config, resolved, mounting,
                     exposure)


# ---------------------------------------------------------------------------------------------- sections
def _source(data: Any, path: str) -> SourceConfig:
    cc.mapping(data, path, required=["uri"], optional=["options"])
    uri = cc.string(data, "uri", path)
    if ":" not in uri:
        raise cc.ConfigError(cc.join(path, "uri"), f"must be SCHEME:ARGUMENT (sim:, replay:DIR, aravis:, "
                                                    f"v4l2:/dev/videoN), got {uri!r}")
    options = data.get("options") or {}
    if not isinstance(options, Mapping):
        raise cc.ConfigError(cc.join(path, "options"), f"must be a mapping, got {options!r}")
    check_source(uri, options, path)  # as run would build it, so that dump-config and run agree
    return SourceConfig(uri, dict(options))


def _camera(data: Any, path: str, base_dir: Path) -> tuple[CameraModel | None, Any, CameraOptics | None]:
    """The camera, its resolved config text, and the fitted optics of a camera file (``optics``/``response``
    sections, see ``livetrack.camera.optics``) that the tracker then uses unless its own keys say otherwise."""
    if data is None:
        return None, None, None
    if isinstance(data, Mapping) and "file" in data:
        cc.mapping(data, path, required=["file"])
        file = _path(cc.string(data, "file", path), base_dir)
        camera, optics = load_camera_with_optics(file)
        return camera, {"file": str(file)}, optics
    return CameraModel.from_dict(data, path), data, None


def _targets(data: Any, path: str, base_dir: Path) -> tuple[list[TargetSpec] | None, Any]:
    if data is None:
        return None, None
    if isinstance(data, Mapping):
        cc.mapping(data, path, required=["file"])
        file = _path(cc.string(data, "file", path), base_dir)
        return load_targets(file), {"file": str(file)}
    if not isinstance(data, list):
        raise cc.ConfigError(path, f"must be null, {{file: PATH}} or a list of targets, got {data!r}")
    specs = [TargetSpec.from_dict(item, f"{path}[{i}]") for i, item in enumerate(data)]
    ids = [s.id for s in specs]
    if len(set(ids)) != len(ids):
        raise cc.ConfigError(path, f"duplicate target ids in {ids}")
    return specs, data


def _tracker(data: Any, path: str, defaults: TrackerOptions) -> TrackerOptions:
    """``defaults``: TrackerOptions with the camera file's optics; a null optics key keeps them."""
    fields = [f.name for f in dataclasses.fields(TrackerOptions) if f.name != "camera_std"]
    cc.mapping(data, path, optional=[*fields, "propagate_camera_uncertainty"])  # camera_std: from the camera file
    noise = data.get("noise_model")
    if noise is not None:
        values = cc.number_list(data, "noise_model", path, length=2)
        if not (0 <= values[0] <= MAX_DN**2 and 0 < values[1] <= MAX_DN):
            raise cc.ConfigError(cc.join(path, "noise_model"), f"must be [read variance in [0, {MAX_DN}^2] DN^2, "
                                                                f"DN per electron in (0, {MAX_DN}]], got {values}")
        noise = (values[0], values[1])
    return TrackerOptions(
        compensate_exposure=cc.boolean(data, "compensate_exposure", path, default=defaults.compensate_exposure),
        keep_delta_across_frames=cc.boolean(data, "keep_delta_across_frames", path,
                                            default=defaults.keep_delta_across_frames),
        edge_spacing_px=cc.number(data, "edge_spacing_px", path, default=defaults.edge_spacing_px, gt=0,
                                  le=MAX_PX),
        max_points_per_circle=cc.integer(data, "max_points_per_circle", path,
                                         default=defaults.max_points_per_circle, ge=24, le=MAX_POINTS_PER_CIRCLE),
        min_level_radius_px=cc.number(data, "min_level_radius_px", path, default=defaults.min_level_radius_px,
                                      ge=0, le=MAX_IMAGE_PX),
        edge_half_width_px=cc.number(data, "edge_half_width_px", path, default=defaults.edge_half_width_px, gt=0,
                                     le=MAX_PX),
        noise_model=noise,
        tracking=cc.boolean(data, "tracking", path, default=defaults.tracking),
        tracking_margin=cc.number(data, "tracking_margin", path, default=defaults.tracking_margin, gt=0,
                                  le=MAX_TRACKING_MARGIN),
        tracking_verify_every=cc.integer(data, "tracking_verify_every", path,
                                         default=defaults.tracking_verify_every, ge=1, le=MAX_EVERY_N),
        tracking_full_search_every=cc.integer(data, "tracking_full_search_every", path,
                                              default=defaults.tracking_full_search_every, ge=1, le=MAX_EVERY_N),
        psf_sigma_px=(defaults.psf_sigma_px if data.get("psf_sigma_px") is None
                      else cc.number(data, "psf_sigma_px", path, gt=0, le=MAX_PX)),
        psf_halo=_halo(data, path, defaults.psf_halo),
        clip_margin_dn=(defaults.clip_margin_dn if data.get("clip_margin_dn") is None
                        else cc.number(data, "clip_margin_dn", path, ge=0, le=MAX_DN)),
        clipped_shared_contrast=cc.boolean(data, "clipped_shared_contrast", path,
                                           default=defaults.clipped_shared_contrast),
        predict_motion=cc.boolean(data, "predict_motion", path, default=defaults.predict_motion),
        edge_bias_floor_px=cc.number(data, "edge_bias_floor_px", path, default=defaults.edge_bias_floor_px, ge=0,
                                     le=MAX_PX),
        outer_share_sd=cc.number(data, "outer_share_sd", path, default=defaults.outer_share_sd, ge=0, le=10),
        fit_target_model=(None if data.get("fit_target_model") is None  # auto (TrackerOptions)
                          else cc.boolean(data, "fit_target_model", path, default=False)),
        track_target_model=cc.boolean(data, "track_target_model", path, default=defaults.track_target_model),
    )


def _camera_uncertainty(data: Mapping, path: str, tracker: TrackerOptions, camera: Any) -> TrackerOptions:
    """``tracker.propagate_camera_uncertainty: true``: the camera file's ``uncertainty`` section (written by
    ``livetrack calibrate``) goes into every pose's covariance (``TrackerOptions.camera_std``); it needs
    ``camera: {file: PATH}`` and that section."""
    if not cc.boolean(data, "propagate_camera_uncertainty", path, default=False):
        return tracker
    key = cc.join(path, "propagate_camera_uncertainty")
    if not (isinstance(camera, Mapping) and "file" in camera):
        raise cc.ConfigError(key, "needs camera: {file: PATH}, a camera file with an uncertainty section "
                                  "(livetrack calibrate writes one)")
    uncertainty = load_camera_uncertainty(camera["file"])
    if uncertainty is None:
        raise cc.ConfigError(key, f"the camera file {camera['file']} has no uncertainty section (livetrack "
                                  "calibrate writes one)")
    return dataclasses.replace(tracker, camera_std=(uncertainty.fx, uncertainty.fy, uncertainty.cx, uncertainty.cy,
                                                    *uncertainty.dist))


def _halo(data: Mapping, path: str, default: tuple[float, float] | None) -> tuple[float, float] | None:
    if data.get("psf_halo") is None:
        return default
    fraction, sigma_px = cc.number_list(data, "psf_halo", path, length=2)
    if not (0 <= fraction < 1 and 0 < sigma_px <= MAX_IMAGE_PX):
        raise cc.ConfigError(cc.join(path, "psf_halo"), f"must be [fraction in [0, 1), sigma_px in "
                                                         f"(0, {MAX_IMAGE_PX}]], got {[fraction, sigma_px]}")
    return (fraction, sigma_px) if fraction > 0 else None


def _pipeline(data: Any, path: str) -> PipelineConfig:
    cc.mapping(data, path, required=PIPELINE_KEYS)
    lossless = data.get("lossless")
    if lossless is not None and not isinstance(lossless, bool):
        raise cc.ConfigError(cc.join(path, "lossless"), f"must be null, true or false, got {lossless!r}")
    worker = data["search_worker"]
    if isinstance(worker, bool):  # YAML 1.1 reads a bare on / off as true / false
        worker = "on" if worker else "off"
    if not isinstance(worker, str) or worker not in SEARCH_WORKER_VALUES:
        raise cc.ConfigError(cc.join(path, "search_worker"), f"must be auto, on or off, got {data['search_worker']!r}")
    return PipelineConfig(
        max_frames=_optional_int(data, "max_frames", path, ge=1, le=MAX_FRAMES), lossless=lossless,
        slot_size=cc.integer(data, "slot_size", path, ge=1, le=MAX_QUEUE),
        read_timeout_s=cc.number(data, "read_timeout_s", path, gt=0, le=60),
        sink_queue_size=cc.integer(data, "sink_queue_size", path, ge=1, le=MAX_QUEUE),
        sink_close_timeout_s=cc.number(data, "sink_close_timeout_s", path, gt=0, le=MAX_TIMEOUT_S),
        search_worker=SEARCH_WORKER_VALUES[worker],
    )


def _outputs(data: Any, path: str, base_dir: Path) -> OutputsConfig:
    cc.mapping(data, path, required=["rerun", "udp", "zmq", "record"], optional=["mavlink"])
    mavlink = data.get("mavlink", default_config_data()["outputs"]["mavlink"])
    return OutputsConfig(_rerun(data["rerun"], cc.join(path, "rerun"), base_dir),
                         _udp(data["udp"], cc.join(path, "udp")),
                         _zmq(data["zmq"], cc.join(path, "zmq")),
                         _record(data["record"], cc.join(path, "record"), base_dir),
                         _mavlink(mavlink, cc.join(path, "mavlink")))


def _rerun(data: Any, path: str, base_dir: Path) -> RerunConfig:
    keys = ["mode", "serve_bind", "serve_port", "spawn_port", "server_memory_limit", "image_every_n", "queue_size"]
    cc.mapping(data, path, required=keys)
    raw_mode = data["mode"]
    if raw_mode is False or raw_mode is None:  # YAML 1.1 reads an unquoted off as false
        raw_mode = "off"
    if not isinstance(raw_mode, str):
        raise cc.ConfigError(cc.join(path, "mode"), f"must be a string, got {raw_mode!r}")
    try:
        mode, argument = parse_mode(raw_mode)
    except ValueError as exc:
        raise cc.ConfigError(cc.join(path, "mode"), str(exc)) from None
    if mode == "save" and argument is not None:
        argument = str(_path(argument, base_dir))
    memory_limit = cc.string(data, "server_memory_limit", path)
    if not re.fullmatch(r"\d+(\.\d+)?\s*([KMGT]i?B|B|%)?", memory_limit.strip()):
        raise cc.ConfigError(cc.join(path, "server_memory_limit"), f"must be a size like 1GiB, 512MB or 25%, got "
                                                                   f"{memory_limit!r}")
    serve_bind = cc.string(data, "serve_bind", path)
    if not serve_bind.strip() or any(c.isspace() for c in serve_bind):
        raise cc.ConfigError(cc.join(path, "serve_bind"), f"must be an interface address, got {serve_bind!r}")
    return RerunConfig(
        mode=mode, argument=argument, serve_bind=serve_bind,
        serve_port=_port(data, "serve_port", path), spawn_port=_port(data, "spawn_port", path),
        server_memory_limit=memory_limit,
        image_every_n=cc.integer(data, "image_every_n", path, ge=1, le=MAX_EVERY_N),
        queue_size=cc.integer(data, "queue_size", path, ge=1, le=MAX_QUEUE),
    )


def _rerun_mode_text(config: RerunConfig) -> str:
    return config.mode if config.argument is None else f"{config.mode}:{config.argument}"


def _udp(data: Any, path: str) -> UdpConfig:
    cc.mapping(data, path, required=["destination", "encoding", "queue_size"])
    destination = None
    if data.get("destination") is not None:
        text = cc.string(data, "destination", path)
        try:
            destination = parse_host_port(text, "destination")
        except ValueError as exc:
            raise cc.ConfigError(cc.join(path, "destination"), str(exc)) from None
    return UdpConfig(destination, cc.string(data, "encoding", path, choices=ENCODINGS),
                     cc.integer(data, "queue_size", path, ge=1, le=MAX_QUEUE))


def _zmq(data: Any, path: str) -> ZmqConfig:
    cc.mapping(data, path, required=["endpoint", "encoding", "sndhwm", "queue_size"])
    endpoint = None
    if data.get("endpoint") is not None:
        endpoint = normalise_zmq_endpoint(cc.string(data, "endpoint", path), cc.join(path, "endpoint"))
    return ZmqConfig(endpoint, cc.string(data, "encoding", path, choices=ENCODINGS),
                     cc.integer(data, "sndhwm", path, ge=1, le=MAX_SNDHWM),
                     cc.integer(data, "queue_size", path, ge=1, le=MAX_QUEUE))


def normalise_zmq_endpoint(text: str, path: str) -> str:
    """``tcp://HOST:PORT``, ``ipc://PATH`` or ``inproc://NAME``; a bare ``HOST:PORT`` means tcp."""
    if "://" not in text:
        text = f"tcp://{text}"
    scheme = text.split("://", 1)[0]
    if scheme not in ("tcp", "ipc", "inproc"):
        raise cc.ConfigError(path, f"must be tcp://HOST:PORT, ipc://PATH or inproc://NAME, got {text!r}")
    if scheme == "tcp":
        try:
            parse_host_port(text[len("tcp://"):], "endpoint")
        except ValueError as exc:
            raise cc.ConfigError(path, str(exc)) from None
    return text


def _mavlink(data: Any, path: str) -> MavlinkConfig:
    keys = ["connection", "system_id", "component_id", "max_rate_hz", "vision_position_estimate", "queue_size"]
    cc.mapping(data, path, required=keys)
    connection = None
    if data.get("connection") is not None:
        connection = cc.string(data, "connection", path)
        try:
            parse_mavlink_connection(connection)
        except ValueError as exc:
            raise cc.ConfigError(cc.join(path, "connection"), str(exc)) from None
    return MavlinkConfig(connection, cc.integer(data, "system_id", path, ge=1, le=255),
                         cc.integer(data, "component_id", path, ge=1, le=255),
                         cc.number(data, "max_rate_hz", path, gt=0, le=MAX_RATE_HZ),
                         cc.boolean(data, "vision_position_estimate", path, default=False),
                         cc.integer(data, "queue_size", path, ge=1, le=MAX_QUEUE))


def _mounting(data: Any, path: str) -> Mounting | None:
    cc.mapping(data, path, required=["camera_to_body", "targets_in_world"])
    world = data["targets_in_world"] if data["targets_in_world"] is not None else {}
    wpath = cc.join(path, "targets_in_world")
    if not isinstance(world, Mapping):
        raise cc.ConfigError(wpath, f"must be a mapping of target id -> placement, got {type(world).__name__}")
    placements: dict[int, TargetPlacement] = {}
    for key, value in world.items():
        if isinstance(key, bool) or not isinstance(key, int) or not 0 <= key < 2**31:
            raise cc.ConfigError(cc.join(wpath, str(key)), "a target id must be an integer in [0, 2^31)")
        item_path = cc.join(wpath, key)
        cc.mapping(value, item_path, required=["position_ned_m", "heading_deg"])
        position = cc.number_list(value, "position_ned_m", item_path, length=3)
        if max(abs(v) for v in position) > MAX_WORLD_M:
            raise cc.ConfigError(cc.join(item_path, "position_ned_m"), f"must be within {MAX_WORLD_M:g} m, got "
                                                                        f"{position}")
        placements[key] = TargetPlacement((position[0], position[1], position[2]),
                                          cc.number(value, "heading_deg", item_path, ge=-360, le=360))
    mount = data["camera_to_body"]
    if mount is None:
        if placements:
            raise cc.ConfigError(wpath, "needs mounting.camera_to_body (the vehicle's pose comes through it)")
        return None
    mpath = cc.join(path, "camera_to_body")
    cc.mapping(mount, mpath, required=["rotation_rpy_deg", "translation_m"])
    rpy = cc.number_list(mount, "rotation_rpy_deg", mpath, length=3)
    if max(abs(v) for v in rpy) > 360:
        raise cc.ConfigError(cc.join(mpath, "rotation_rpy_deg"), f"angles must be within +-360 degrees, got {rpy}")
    offset = cc.number_list(mount, "translation_m", mpath, length=3)
    if max(abs(v) for v in offset) > MAX_MOUNT_OFFSET_M:
        raise cc.ConfigError(cc.join(mpath, "translation_m"), f"must be within {MAX_MOUNT_OFFSET_M:g} m, got "
                                                               f"{offset}")
    return Mounting((rpy[0], rpy[1], rpy[2]), (offset[0], offset[1], offset[2]), placements)


def _exposure_control(data: Any, path: str) -> ExposureControlOptions | None:
    keys = ["enabled", "white_goal", "black_min", "scene_goal", "max_step", "deadband", "min_exposure_us",
            "max_exposure_us"]
    cc.mapping(data, path, required=keys)
    options = ExposureControlOptions(
        white_goal=cc.number(data, "white_goal", path, gt=0, lt=1),
        black_min=cc.number(data, "black_min", path, ge=0, lt=1),
        scene_goal=cc.number(data, "scene_goal", path, gt=0, lt=1),
        max_step=cc.number(data, "max_step", path, gt=1, le=1000),
        deadband=cc.number(data, "deadband", path, gt=1, le=10),
        min_exposure_us=cc.number(data, "min_exposure_us", path, gt=0, le=1e9),
        max_exposure_us=cc.number(data, "max_exposure_us", path, gt=0, le=1e9))
    if options.min_exposure_us > options.max_exposure_us:
        raise cc.ConfigError(cc.join(path, "min_exposure_us"), f"must be <= max_exposure_us "
                                                                f"({options.max_exposure_us}), got "
                                                                f"{options.min_exposure_us}")
    if options.black_min >= options.white_goal:
        raise cc.ConfigError(cc.join(path, "black_min"), f"must be < white_goal ({options.white_goal}), got "
                                                          f"{options.black_min}")
    return options if cc.boolean(data, "enabled", path, default=False) else None


def _record(data: Any, path: str, base_dir: Path) -> RecordConfig:
    keys = ["dir", "overwrite", "png_compression", "fsync_every_n_frames", "queue_size"]
    cc.mapping(data, path, required=keys)
    folder = None
    if data.get("dir") is not None:
        folder = _path(cc.string(data, "dir", path), base_dir)
    compression = cc.integer(data, "png_compression", path, choices=range(10))
    return RecordConfig(folder, cc.boolean(data, "overwrite", path, default=False), compression,
                        cc.integer(data, "fsync_every_n_frames", path, ge=0, le=MAX_EVERY_N),
                        cc.integer(data, "queue_size", path, ge=1, le=MAX_QUEUE))


def _logging(data: Any, path: str) -> LoggingConfig:
    cc.mapping(data, path, required=["level", "print_every_s"])
    level = None
    if data.get("level") is not None:
        level = cc.string(data, "level", path, choices=LOG_LEVELS)
    return LoggingConfig(level, cc.number(data, "print_every_s", path, ge=0, le=MAX_TIMEOUT_S))


# ---------------------------------------------------------------------------------------------- helpers
def _optional_int(data: Mapping, key: str, path: str, ge: int, le: int) -> int | None:
    if data.get(key) is None:
        return None
    return cc.integer(data, key, path, ge=ge, le=le)


def _port(data: Mapping, key: str, path: str) -> int:
    port = cc.integer(data, key, path, ge=1)
    if port > 65535:
        raise cc.ConfigError(cc.join(path, key), f"must be <= 65535, got {port}")
    return port


def _path(text: str, base_dir: Path) -> Path:
    p = Path(text).expanduser()
    return p if p.is_absolute() else (base_dir / p).resolve()


def _scheme(uri: str) -> str:
    return uri.partition(":")[0]


def resolved_config_path(output: Path) -> Path:
    """Where the resolved config is saved beside an output file (``run.rrd`` -> ``run.config.yaml``)."""
    return output.with_name(output.stem + RESOLVED_CONFIG_SUFFIX)
