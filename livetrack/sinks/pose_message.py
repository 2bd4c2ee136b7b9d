"""The pose stream message (schema ``livetrack.pose`` versions 1 and 2): one message per target per processed frame.

Two encodings of the same fields, specified byte by byte in docs/pose-stream.md:

- binary: 320 bytes (version 1), little-endian, no padding, starting with the magic ``b"LTPS"`` and the version
  (u16); version 2 is version 1 followed by the 456-byte frames block (776 bytes);
- JSON: one UTF-8 object with ``"schema": "livetrack.pose"`` and ``"version": 1``; non-finite numbers are null;
  version 2 adds the object ``"frames"``.

Version 2 (the pose in the vehicle's frames: target in body FRD, vehicle in local NED, ``livetrack.frames``) is
sent only when ``mounting.camera_to_body`` is configured; without it the stream is version 1, unchanged.

``decode`` accepts either (it looks at the first byte). Used by the UDP and ZeroMQ sinks and ``livetrack listen``.
"""

from __future__ import annotations

import json
import math
import struct
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

if TYPE_CHECKING:  # only for annotations: decoding needs no estimator (listen, receivers, fuzzing)
    from livetrack.estimator.tracker import TargetResult
    from livetrack.frames import Mounting
    from livetrack.sinks.base import TrackedFrame

SCHEMA = "livetrack.pose"
VERSION = 1  # without the frames block
VERSION_FRAMES = 2  # with it
VERSIONS = (VERSION, VERSION_FRAMES)
MAGIC = b"LTPS"
FLAG_OK = 1 << 0
FLAG_HEADING_KNOWN = 1 << 1

# magic, version, flags, sequence, frame_id, device_timestamp_ns, host_timestamp_ns, target_id, n_targets,
# target_index, t_m (3), q_xyzw (4), covariance upper triangle (21), delta_px, delta_std_px, exposure_us,
# residual_rms_px, latency_ms, n_edge_points, reserved
BINARY_STRUCT = struct.Struct("<4sHHQqqqiHH3d4d21d5dII")
BINARY_SIZE = BINARY_STRUCT.size  # 320
# version 2's frames block: flags (bit 0: vehicle_in_ned present), reserved, then target_in_body and
# vehicle_in_ned, each t_m (3), q_xyzw (4), covariance upper triangle (21); vehicle_in_ned all NaN when absent
FRAMES_STRUCT = struct.Struct("<II3d4d21d3d4d21d")
FRAMES_SIZE = FRAMES_STRUCT.size  # 456
BINARY_SIZE_FRAMES = BINARY_SIZE + FRAMES_SIZE  # 776
FRAMES_FLAG_VEHICLE_IN_NED = 1 << 0
BINARY_SIZES = {VERSION: BINARY_SIZE, VERSION_FRAMES: BINARY_SIZE_FRAMES}
_TRIU = np.triu_indices(6)

Encoding = Literal["binary", "json"]


class MessageError(ValueError):
    """Bytes that are not a valid pose message of a supported version.

    ``reason`` is a short category for counting rejections (``REJECT_REASONS``); ``str()`` says what is wrong.
    """

    def __init__(self, problem: str, reason: str = "malformed"):
        self.reason = reason
        super().__init__(problem)


# Why ``decode`` rejects a message: the categories of ``MessageError.reason``.
REJECT_REASONS = ("not-a-message", "version", "size", "json-syntax", "schema", "malformed")
MAX_JSON_BYTES = 65536  # a version-1 JSON message is about 1.5 kB (version 2 about 3.5 kB); anything beyond is not one

# JSON field -> (low, high) inclusive, from the binary layout's integer types (docs/pose-stream.md)
_U16, _U32, _U64 = (0, 2**16 - 1), (0, 2**32 - 1), (0, 2**64 - 1)
_I32, _I64 = (-(2**31), 2**31 - 1), (-(2**63), 2**63 - 1)
JSON_INT_FIELDS = {"sequence": _U64, "frame_id": _I64, "device_timestamp_ns": _I64, "host_timestamp_ns": _I64,
                   "target_id": _I32, "n_targets": _U16, "target_index": _U16, "n_edge_points": _U32}
JSON_FLOAT_FIELDS = ("delta_px", "delta_std_px", "exposure_us", "residual_rms_px", "latency_ms")
JSON_VECTOR_FIELDS = {"t_m": 3, "q_xyzw": 4, "covariance_upper": 21}
JSON_BOOL_FIELDS = ("ok", "heading_known")
JSON_FIELDS = frozenset(["schema", "version", *JSON_INT_FIELDS, *JSON_FLOAT_FIELDS, *JSON_VECTOR_FIELDS,
                         *JSON_BOOL_FIELDS])
JSON_FIELDS_FRAMES = JSON_FIELDS | {"frames"}  # version 2
JSON_FRAME_NAMES = ("target_in_body", "vehicle_in_ned")  # the keys of "frames"; vehicle_in_ned may be null
JSON_FRAME_POSE_FIELDS = {"t_m": 3, "q_xyzw": 4, "covariance_upper": 21}


@dataclass(frozen=True)
class FramePose:
    """A pose in one of the vehicle's frames: translation m, rotation (qx, qy, qz, qw), and the upper triangle
    of its 6x6 covariance (t m, rotation vector rad applied on the left, in that frame), row by row."""

    t_m: tuple[float, float, float]
    q_xyzw: tuple[float, float, float, float]
    covariance_upper: tuple[float, ...]

    def values(self) -> tuple[float, ...]:
        return (*self.t_m, *self.q_xyzw, *self.covariance_upper)

    @classmethod
    def from_values(cls, v: tuple[float, ...]) -> FramePose:
        return cls(t_m=tuple(v[0:3]), q_xyzw=tuple(v[3:7]), covariance_upper=tuple(v[7:28]))  # type: ignore[arg-type]


@dataclass(frozen=True)
class PoseFrames:
    """Version 2's frames block. target_in_body: the target in body FRD (``X_body = R X_target + t``).
    vehicle_in_ned: the vehicle (body) in local NED (``X_ned = R X_body + t``) from the target's known placement;
    None when the target has none (``mounting.targets_in_world``)."""

    target_in_body: FramePose
    vehicle_in_ned: FramePose | None = None


@dataclass(frozen=True)
class PoseMessage:
    """One target's pose in one frame, as streamed. Field meanings and units: docs/pose-stream.md."""

    sequence: int
    frame_id: int
    device_timestamp_ns: int
    host_timestamp_ns: int
    target_id: int
    n_targets: int
    target_index: int
    t_m: tuple[float, float, float]
    q_xyzw: tuple[float, float, float, float]
    covariance_upper: tuple[float, ...]  # 21 values: upper triangle of the 6x6 (t_m, rotvec_rad), row-major
    delta_px: float
    delta_std_px: float
    exposure_us: float | None  # None: unknown (NaN in binary, null in JSON)
    residual_rms_px: float
    latency_ms: float
    n_edge_points: int
    ok: bool
    heading_known: bool
    frames: PoseFrames | None = None  # version 2 only (None: version 1)

    @property
    def version(self) -> int:
        return VERSION if self.frames is None else VERSION_FRAMES

    @classmethod
    def from_result(cls, result: TargetResult, *, sequence: int, frame_id: int, device_timestamp_ns: int,
                    host_timestamp_ns: int, n_targets: int, target_index: int, exposure_us: float | None,
                    latency_ms: float, mounting: Mounting | None = None) -> PoseMessage:
        fit = result.fit
        cov = np.asarray(fit.pose_covariance, dtype=np.float64)
        var_delta = float(fit.covariance[6, 6]) if np.shape(fit.covariance) == (7, 7) else math.nan
        frames = None if mounting is None else pose_frames(mounting, result.target_id, fit.pose.R, fit.pose.t, cov)
        return cls(
            sequence=sequence, frame_id=frame_id, device_timestamp_ns=device_timestamp_ns,
            host_timestamp_ns=host_timestamp_ns, target_id=result.target_id, n_targets=n_targets,
            target_index=target_index,
            t_m=tuple(float(v) for v in fit.pose.t),  # type: ignore[arg-type]
            q_xyzw=tuple(float(v) for v in fit.pose.quaternion),  # type: ignore[arg-type]
            covariance_upper=tuple(float(v) for v in cov[_TRIU]),
            delta_px=float(fit.delta_px),
            delta_std_px=math.sqrt(var_delta) if math.isfinite(var_delta) and var_delta >= 0 else math.nan,
            exposure_us=_known(exposure_us), residual_rms_px=float(fit.residual_rms_px),
            latency_ms=float(latency_ms), n_edge_points=int(result.n_edge_points), ok=bool(fit.ok),
            heading_known=bool(result.heading_known), frames=frames,
        )

    @property
    def covariance(self) -> np.ndarray:
        """The full symmetric (6, 6) covariance of (t_m, rotation vector rad)."""
        out = np.zeros((6, 6))
        out[_TRIU] = self.covariance_upper
        return out + np.triu(out, 1).T

    @property
    def distance_m(self) -> float:
        return math.sqrt(sum(v * v for v in self.t_m))

    # ------------------------------------------------------------------ encodings
    def encode(self, encoding: Encoding = "binary") -> bytes:
        return self.to_binary() if encoding == "binary" else self.to_json()

    def to_binary(self) -> bytes:
        flags = (FLAG_OK if self.ok else 0) | (FLAG_HEADING_KNOWN if self.heading_known else 0)
        return BINARY_STRUCT.pack(
            MAGIC, self.version, flags, self.sequence, self.frame_id, self.device_timestamp_ns, self.host_timestamp_ns,
            self.target_id, self.n_targets, self.target_index, *self.t_m, *self.q_xyzw, *self.covariance_upper,
            self.delta_px, self.delta_std_px, math.nan if self.exposure_us is None else self.exposure_us,
            self.residual_rms_px, self.latency_ms,
            self.n_edge_points, 0,
        ) + (b"" if self.frames is None else _frames_to_binary(self.frames))

    def to_json(self) -> bytes:
        data: dict[str, Any] = {"schema": SCHEMA, "version": self.version}
        for key, value in asdict(self).items():
            if key != "frames":
                data[key] = _json_safe(value)
        if self.frames is not None:
            data["frames"] = {name: None if pose is None else {k: _json_safe(v) for k, v in asdict(pose).items()}
                              for name, pose in ((n, getattr(self.frames, n)) for n in JSON_FRAME_NAMES)}
        return json.dumps(data, separators=(",", ":"), allow_nan=False).encode("utf-8")


def pose_frames(mounting: Mounting, target_id: int, R_cam_target: np.ndarray, t_cam_target_m: np.ndarray,
                cov_cam: np.ndarray) -> PoseFrames:
    """The frames block of one target's pose (``livetrack.frames.vehicle_poses``)."""
    from livetrack.frames import upper_triangle, vehicle_poses

    poses = vehicle_poses(mounting, target_id, R_cam_target, t_cam_target_m, cov_cam)

    def frame_pose(transform: Any, cov: np.ndarray) -> FramePose:
        return FramePose(tuple(float(v) for v in transform.t), tuple(float(v) for v in transform.quaternion_xyzw),
                         tuple(upper_triangle(cov)))  # type: ignore[arg-type]

    vehicle = None
    if poses.ned_from_body is not None and poses.ned_covariance is not None:
        vehicle = frame_pose(poses.ned_from_body, poses.ned_covariance)
    return PoseFrames(frame_pose(poses.body_from_target, poses.body_covariance), vehicle)


def _frames_to_binary(frames: PoseFrames) -> bytes:
    vehicle = frames.vehicle_in_ned
    flags = 0 if vehicle is None else FRAMES_FLAG_VEHICLE_IN_NED
    return FRAMES_STRUCT.pack(flags, 0, *frames.target_in_body.values(),
                              *((math.nan,) * 28 if vehicle is None else vehicle.values()))


def decode(data: bytes) -> PoseMessage:
    """Parse one message in either encoding.

    Raises ``MessageError`` (with a ``reason`` category) for anything that is not a valid message of a known
    version, and nothing else, whatever the bytes: JSON fields are checked strictly (integers must be JSON
    integers within their binary type's range, floats numbers or null, flags true or false, no unknown or
    duplicate keys, no NaN/Infinity literals).
    """
    try:
        data = bytes(data)
    except (TypeError, ValueError):
        raise MessageError(f"not bytes: {type(data).__name__}", "not-a-message") from None
    if data[:1] == b"{":
        return _from_json(data)
    if len(data) < 6 or data[:4] != MAGIC:
        raise MessageError(f"not a livetrack pose message (magic {data[:4]!r}, {len(data)} bytes)", "not-a-message")
    version = struct.unpack_from("<H", data, 4)[0]
    if version not in VERSIONS:
        raise MessageError(f"unsupported binary version {version} (this reader knows {VERSION}, {VERSION_FRAMES})",
                           "version")
    if len(data) != BINARY_SIZES[version]:
        raise MessageError(f"binary version {version} message must be {BINARY_SIZES[version]} bytes, got "
                           f"{len(data)}", "size")
    v = BINARY_STRUCT.unpack_from(data)
    frames = None
    if version == VERSION_FRAMES:
        f = FRAMES_STRUCT.unpack_from(data, BINARY_SIZE)
        frames = PoseFrames(FramePose.from_values(f[2:30]),
                            FramePose.from_values(f[30:58]) if f[0] & FRAMES_FLAG_VEHICLE_IN_NED else None)
    flags = v[2]
    return _checked(PoseMessage(
        sequence=v[3], frame_id=v[4], device_timestamp_ns=v[5], host_timestamp_ns=v[6], target_id=v[7],
        n_targets=v[8], target_index=v[9], t_m=tuple(v[10:13]), q_xyzw=tuple(v[13:17]),
        covariance_upper=tuple(v[17:38]), delta_px=v[38], delta_std_px=v[39], exposure_us=_known(v[40]),
        residual_rms_px=v[41], latency_ms=v[42], n_edge_points=v[43], ok=bool(flags & FLAG_OK),
        heading_known=bool(flags & FLAG_HEADING_KNOWN), frames=frames,
    ))


def _checked(message: PoseMessage) -> PoseMessage:
    """Cross-field checks common to both encodings."""
    if message.target_index >= message.n_targets:
        raise MessageError(f"target_index {message.target_index} must be < n_targets {message.n_targets}",
                           "malformed")
    return message


def _from_json(data: bytes) -> PoseMessage:
    if len(data) > MAX_JSON_BYTES:
        raise MessageError(f"JSON message of {len(data)} bytes (at most {MAX_JSON_BYTES})", "size")
    try:
        obj = json.loads(data.decode("utf-8"), parse_constant=_no_constant, object_pairs_hook=_unique_keys)
    except UnicodeDecodeError as exc:
        raise MessageError(f"invalid JSON: not UTF-8 ({exc.reason} at byte {exc.start})", "json-syntax") from None
    except RecursionError:
        raise MessageError("invalid JSON: nested too deeply", "json-syntax") from None
    except ValueError as exc:  # JSONDecodeError, an integer literal of more than 4300 digits, NaN/Infinity
        raise MessageError(f"invalid JSON: {_short(str(exc))}", "json-syntax") from None
    if not isinstance(obj, dict) or obj.get("schema") != SCHEMA:
        raise MessageError(f"not a {SCHEMA} JSON message", "schema")
    version = obj.get("version")
    if type(version) is not int or version not in VERSIONS:
        raise MessageError(f"unsupported JSON version {_describe(version)} (this reader knows {VERSION}, "
                           f"{VERSION_FRAMES})", "version")
    fields = JSON_FIELDS if version == VERSION else JSON_FIELDS_FRAMES
    unknown = sorted(set(obj) - fields)
    missing = sorted(fields - set(obj))
    if unknown or missing:
        what = (f"unknown field(s) {_short(repr(unknown))}" if unknown else "") + (
            f"{'; ' if unknown else ''}missing field(s) {missing}" if missing else "")
        raise MessageError(f"malformed {SCHEMA} JSON message: {what}", "malformed")
    values: dict[str, Any] = {}
    for name, (low, high) in JSON_INT_FIELDS.items():
        value = obj[name]
        if type(value) is not int:
            raise _field_error(name, value, "an integer")
        if not low <= value <= high:
            raise _field_error(name, value, f"an integer in [{low}, {high}]")
        values[name] = value
    for name in JSON_FLOAT_FIELDS:
        values[name] = _float(obj[name], name)
    values["exposure_us"] = _known(values["exposure_us"])
    for name, n in JSON_VECTOR_FIELDS.items():
        items = obj[name]
        if type(items) is not list or len(items) != n:
            raise _field_error(name, items, f"a list of {n} numbers")
        values[name] = tuple(_float(item, f"{name}[{i}]") for i, item in enumerate(items))
    for name in JSON_BOOL_FIELDS:
        if type(obj[name]) is not bool:
            raise _field_error(name, obj[name], "true or false")
        values[name] = obj[name]
    if version == VERSION_FRAMES:
        values["frames"] = _frames_from_json(obj["frames"])
    return _checked(PoseMessage(**values))


def _frames_from_json(obj: Any) -> PoseFrames:
    if type(obj) is not dict or set(obj) != set(JSON_FRAME_NAMES):
        raise _field_error("frames", obj, f"an object with exactly {list(JSON_FRAME_NAMES)}")
    poses: dict[str, FramePose | None] = {}
    for name in JSON_FRAME_NAMES:
        item = obj[name]
        if item is None and name == "vehicle_in_ned":
            poses[name] = None
            continue
        if type(item) is not dict or set(item) != set(JSON_FRAME_POSE_FIELDS):
            raise _field_error(f"frames.{name}", item, f"an object with exactly {list(JSON_FRAME_POSE_FIELDS)}")
        vectors = {}
        for key, n in JSON_FRAME_POSE_FIELDS.items():
            values = item[key]
            if type(values) is not list or len(values) != n:
                raise _field_error(f"frames.{name}.{key}", values, f"a list of {n} numbers")
            vectors[key] = tuple(_float(v, f"frames.{name}.{key}[{i}]") for i, v in enumerate(values))
        poses[name] = FramePose(**vectors)
    target_in_body = poses["target_in_body"]
    assert target_in_body is not None
    return PoseFrames(target_in_body, poses["vehicle_in_ned"])


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not JSON (non-finite numbers are null)")


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out = dict(pairs)
    if len(out) != len(pairs):
        raise ValueError("duplicate key in an object")
    return out


def _short(text: str, limit: int = 80) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _describe(value: Any) -> str:
    """A short description of a decoded JSON value (containers by size: their repr may be huge or deep)."""
    if isinstance(value, (list, dict)):
        return f"a {type(value).__name__} of {len(value)} items"
    return _short(repr(value))


def _field_error(name: str, value: Any, expected: str) -> MessageError:
    return MessageError(f"malformed {SCHEMA} JSON message: {name} must be {expected}, got {_describe(value)}",
                        "malformed")


def _float(value: Any, name: str) -> float:
    """A JSON number as a float; null is NaN (how non-finite values travel). Beyond float range: rejected."""
    if value is None:
        return math.nan
    if type(value) is float:
        if not math.isfinite(value):  # 1e400 parses as inf
            raise _field_error(name, value, "a finite number or null")
        return value
    if type(value) is int:
        try:
            return float(value)
        except OverflowError:
            raise _field_error(name, value, "a number within float range") from None
    raise _field_error(name, value, "a number or null")


def _known(exposure_us: float | None) -> float | None:
    """An exposure as a float; None and NaN (unknown, as it travels) are None."""
    return None if exposure_us is None or math.isnan(exposure_us) else float(exposure_us)


def _json_safe(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, (tuple, list)):
        return [_json_safe(v) for v in value]
    return value


def messages_for_frame(results: list[TargetResult], *, first_sequence: int, frame_id: int,
                       device_timestamp_ns: int, host_timestamp_ns: int, exposure_us: float,
                       latency_ms: float, mounting: Mounting | None = None) -> list[PoseMessage]:
    """One message per target result of a frame, with consecutive sequence numbers from ``first_sequence``;
    with ``mounting``, version 2 messages (the frames block)."""
    n = len(results)
    return [PoseMessage.from_result(r, sequence=first_sequence + i, frame_id=frame_id,
                                    device_timestamp_ns=device_timestamp_ns, host_timestamp_ns=host_timestamp_ns,
                                    n_targets=n, target_index=i, exposure_us=exposure_us, latency_ms=latency_ms,
                                    mounting=mounting)
            for i, r in enumerate(results)]


def messages_for_tracked_frame(item: TrackedFrame, first_sequence: int,
                               mounting: Mounting | None = None) -> list[PoseMessage]:
    """``messages_for_frame`` for a pipeline item (its frame's ids, timestamps, exposure and latency)."""
    frame = item.frame
    return messages_for_frame(item.result.targets, first_sequence=first_sequence, frame_id=frame.frame_id,
                              device_timestamp_ns=frame.timestamp_ns, host_timestamp_ns=frame.host_timestamp_ns,
                              exposure_us=frame.exposure_us, latency_ms=item.latency_ms, mounting=mounting)
