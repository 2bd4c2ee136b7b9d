"""The pose stream message (schema ``livetrack.pose`` version 1): one message per target per processed frame.

Two encodings of the same fields, specified byte by byte in docs/pose-stream.md:

- binary: 320 bytes, little-endian, no padding, starting with the magic ``b"LTPS"`` and the version (u16);
- JSON: one UTF-8 object with ``"schema": "livetrack.pose"`` and ``"version": 1``; non-finite numbers are null.

``decode`` accepts either (it looks at the first byte). Used by the UDP and ZeroMQ sinks and ``livetrack listen``.
"""

from __future__ import annotations

import json
import math
import struct
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from livetrack.estimator.tracker import TargetResult

if TYPE_CHECKING:
    from livetrack.sinks.base import TrackedFrame

SCHEMA = "livetrack.pose"
VERSION = 1
MAGIC = b"LTPS"
FLAG_OK = 1 << 0
FLAG_HEADING_KNOWN = 1 << 1

# magic, version, flags, sequence, frame_id, device_timestamp_ns, host_timestamp_ns, target_id, n_targets,
# target_index, t_m (3), q_xyzw (4), covariance upper triangle (21), delta_px, delta_std_px, exposure_us,
# residual_rms_px, latency_ms, n_edge_points, reserved
BINARY_STRUCT = struct.Struct("<4sHHQqqqiHH3d4d21d5dII")
BINARY_SIZE = BINARY_STRUCT.size  # 320
_TRIU = np.triu_indices(6)

Encoding = Literal["binary", "json"]


class MessageError(ValueError):
    """Bytes that are not a valid pose message of a supported version."""


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
    exposure_us: float
    residual_rms_px: float
    latency_ms: float
    n_edge_points: int
    ok: bool
    heading_known: bool

    @classmethod
    def from_result(cls, result: TargetResult, *, sequence: int, frame_id: int, device_timestamp_ns: int,
                    host_timestamp_ns: int, n_targets: int, target_index: int, exposure_us: float,
                    latency_ms: float) -> PoseMessage:
        fit = result.fit
        cov = np.asarray(fit.pose_covariance, dtype=np.float64)
        var_delta = float(fit.covariance[6, 6]) if np.shape(fit.covariance) == (7, 7) else math.nan
        return cls(
            sequence=sequence, frame_id=frame_id, device_timestamp_ns=device_timestamp_ns,
            host_timestamp_ns=host_timestamp_ns, target_id=result.target_id, n_targets=n_targets,
            target_index=target_index,
            t_m=tuple(float(v) for v in fit.pose.t),  # type: ignore[arg-type]
            q_xyzw=tuple(float(v) for v in fit.pose.quaternion),  # type: ignore[arg-type]
            covariance_upper=tuple(float(v) for v in cov[_TRIU]),
            delta_px=float(fit.delta_px),
            delta_std_px=math.sqrt(var_delta) if math.isfinite(var_delta) and var_delta >= 0 else math.nan,
            exposure_us=float(exposure_us), residual_rms_px=float(fit.residual_rms_px),
            latency_ms=float(latency_ms), n_edge_points=int(result.n_edge_points), ok=bool(fit.ok),
            heading_known=bool(result.heading_known),
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
            MAGIC, VERSION, flags, self.sequence, self.frame_id, self.device_timestamp_ns, self.host_timestamp_ns,
            self.target_id, self.n_targets, self.target_index, *self.t_m, *self.q_xyzw, *self.covariance_upper,
            self.delta_px, self.delta_std_px, self.exposure_us, self.residual_rms_px, self.latency_ms,
            self.n_edge_points, 0,
        )

    def to_json(self) -> bytes:
        data: dict[str, Any] = {"schema": SCHEMA, "version": VERSION}
        for key, value in asdict(self).items():
            data[key] = _json_safe(value)
        return json.dumps(data, separators=(",", ":"), allow_nan=False).encode("utf-8")


def decode(data: bytes) -> PoseMessage:
    """Parse one message in either encoding; raises MessageError naming the problem."""
    if data[:1] == b"{":
        return _from_json(data)
    if len(data) < 6 or data[:4] != MAGIC:
        raise MessageError(f"not a livetrack pose message (magic {data[:4]!r}, {len(data)} bytes)")
    version = struct.unpack_from("<H", data, 4)[0]
    if version != VERSION:
        raise MessageError(f"unsupported binary version {version} (this reader knows {VERSION})")
    if len(data) != BINARY_SIZE:
        raise MessageError(f"binary version {VERSION} message must be {BINARY_SIZE} bytes, got {len(data)}")
    v = BINARY_STRUCT.unpack(data)
    flags = v[2]
    return PoseMessage(
        sequence=v[3], frame_id=v[4], device_timestamp_ns=v[5], host_timestamp_ns=v[6], target_id=v[7],
        n_targets=v[8], target_index=v[9], t_m=tuple(v[10:13]), q_xyzw=tuple(v[13:17]),
        covariance_upper=tuple(v[17:38]), delta_px=v[38], delta_std_px=v[39], exposure_us=v[40],
        residual_rms_px=v[41], latency_ms=v[42], n_edge_points=v[43], ok=bool(flags & FLAG_OK),
        heading_known=bool(flags & FLAG_HEADING_KNOWN),
    )


def _from_json(data: bytes) -> PoseMessage:
    try:
        obj = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MessageError(f"invalid JSON: {exc}") from None
    if not isinstance(obj, dict) or obj.get("schema") != SCHEMA:
        raise MessageError(f"not a {SCHEMA} JSON message")
    if obj.get("version") != VERSION:
        raise MessageError(f"unsupported JSON version {obj.get('version')!r} (this reader knows {VERSION})")
    try:
        return PoseMessage(
            sequence=int(obj["sequence"]), frame_id=int(obj["frame_id"]),
            device_timestamp_ns=int(obj["device_timestamp_ns"]), host_timestamp_ns=int(obj["host_timestamp_ns"]),
            target_id=int(obj["target_id"]), n_targets=int(obj["n_targets"]),
            target_index=int(obj["target_index"]), t_m=_floats(obj["t_m"], 3), q_xyzw=_floats(obj["q_xyzw"], 4),
            covariance_upper=_floats(obj["covariance_upper"], 21), delta_px=_float(obj["delta_px"]),
            delta_std_px=_float(obj["delta_std_px"]), exposure_us=_float(obj["exposure_us"]),
            residual_rms_px=_float(obj["residual_rms_px"]), latency_ms=_float(obj["latency_ms"]),
            n_edge_points=int(obj["n_edge_points"]), ok=bool(obj["ok"]), heading_known=bool(obj["heading_known"]),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise MessageError(f"malformed {SCHEMA} JSON message: {exc!r}") from None


def _json_safe(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, (tuple, list)):
        return [_json_safe(v) for v in value]
    return value


def _float(value: Any) -> float:
    return math.nan if value is None else float(value)


def _floats(values: Any, n: int) -> tuple[float, ...]:
    if not isinstance(values, list) or len(values) != n:
        raise ValueError(f"expected a list of {n} numbers, got {values!r}")
    return tuple(_float(v) for v in values)


def messages_for_frame(results: list[TargetResult], *, first_sequence: int, frame_id: int,
                       device_timestamp_ns: int, host_timestamp_ns: int, exposure_us: float,
                       latency_ms: float) -> list[PoseMessage]:
    """One message per target result of a frame, with consecutive sequence numbers from ``first_sequence``."""
    n = len(results)
    return [PoseMessage.from_result(r, sequence=first_sequence + i, frame_id=frame_id,
                                    device_timestamp_ns=device_timestamp_ns, host_timestamp_ns=host_timestamp_ns,
                                    n_targets=n, target_index=i, exposure_us=exposure_us, latency_ms=latency_ms)
            for i, r in enumerate(results)]


def messages_for_tracked_frame(item: TrackedFrame, first_sequence: int) -> list[PoseMessage]:
    """``messages_for_frame`` for a pipeline item (its frame's ids, timestamps, exposure and latency)."""
    frame = item.frame
    return messages_for_frame(item.result.targets, first_sequence=first_sequence, frame_id=frame.frame_id,
                              device_timestamp_ns=frame.timestamp_ns, host_timestamp_ns=frame.host_timestamp_ns,
                              exposure_us=frame.exposure_us, latency_ms=item.latency_ms)
