"""MAVLink output for PX4 / ArduPilot vehicles (docs/vehicle.md), encoded by pymavlink (MAVLink 2, common).

As a companion component (``MAV_TYPE_ONBOARD_CONTROLLER``, ids configurable) it sends:

- ``HEARTBEAT`` at 1 Hz (its own small thread, from open to close, frames or not);
- ``LANDING_TARGET`` per tracked target with a converged fit: angle_x / angle_y of the target centre in the image
  (camera frame: ``atan2(x, z)``, ``atan2(y, z)``), distance (camera centre to target centre, m), size_x / size_y
  (the target's angular diameter, ``2 atan(outer_radius_m / distance)``, rad), and ``position_valid = 1`` with
  x, y, z and the quaternion (w, x, y, z) of the target in ``MAV_FRAME_BODY_FRD`` (camera -> body through
  ``mounting.camera_to_body``);
- optionally ``VISION_POSITION_ESTIMATE``: the vehicle in local NED from a target with a known placement
  (``mounting.targets_in_world``), roll / pitch / yaw, and the estimator's covariance carried through the frames
  (upper triangle of (x, y, z, roll, pitch, yaw), m^2 / rad^2); not from a target whose heading is unknown (a
  symmetric code: its rotation about its normal, hence the vehicle's position around it, is arbitrary).

``time_usec`` is the frame's capture time on the host clock in microseconds since the Unix epoch: the device
timestamp when the source's clock is the host's (the pipeline's ``device_latency_ms`` is set), else the host
arrival time. Each target is sent at most ``max_rate_hz`` times per second on average (by capture time; a
quarter period of jitter is allowed, so frames at exactly that rate all pass).

pymavlink picks MAVLink 2 and its dialect from environment variables read when ``mavutil`` is first imported:
``import_mavutil`` sets ``MAVLINK20=1`` (if unset) before importing it, and the connection uses the ``common``
dialect (LANDING_TARGET's x/y/z/q extension fields exist only in MAVLink 2).
"""

from __future__ import annotations

import logging
import math
import os
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from livetrack.frames import Mounting, rpy_covariance, rpy_from_rotation, upper_triangle, vehicle_poses
from livetrack.sinks.base import TrackedFrame
from livetrack.sinks.udp import parse_host_port
from livetrack.targets.spec import TargetSpec

log = logging.getLogger(__name__)

DIALECT = "common"
HEARTBEAT_PERIOD_S = 1.0
MAX_BAUD = 10_000_000


@dataclass(frozen=True)
class MavlinkConnection:
    """A parsed ``--mavlink`` argument: ``udpout:HOST:PORT`` or ``serial:DEVICE:BAUD``."""

    kind: Literal["udpout", "serial"]
    address: str  # HOST or DEVICE
    port_or_baud: int

    @property
    def mavutil_device(self) -> str:
        return f"udpout:{self.address}:{self.port_or_baud}" if self.kind == "udpout" else self.address

    def __str__(self) -> str:
        return f"{self.kind}:{self.address}:{self.port_or_baud}"


def parse_connection(text: str) -> MavlinkConnection:
    """``udpout:HOST:PORT`` or ``serial:/dev/ttyX:BAUD``; ValueError naming the problem."""
    kind, sep, rest = text.partition(":")
    if not sep or kind not in ("udpout", "serial"):
        raise ValueError(f"must be udpout:HOST:PORT or serial:/dev/ttyX:BAUD, got {text!r}")
    if kind == "udpout":
        host, port = parse_host_port(rest, "udpout")
        return MavlinkConnection("udpout", host, port)
    device, sep, baud_text = rest.rpartition(":")
    if not sep or not device:
        raise ValueError(f"serial must be serial:DEVICE:BAUD, got {text!r}")
    try:
        baud = int(baud_text)
    except ValueError:
        raise ValueError(f"serial: baud rate must be an integer, got {baud_text!r}") from None
    if not 1 <= baud <= MAX_BAUD:
        raise ValueError(f"serial: baud rate must be in 1..{MAX_BAUD}, got {baud}")
    return MavlinkConnection("serial", device, baud)


def import_mavutil() -> Any:
    """pymavlink's mavutil, MAVLink 2: ``MAVLINK20=1`` must be in the environment before its first import."""
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil

    return mavutil


def capture_time_host_ns(item: TrackedFrame) -> int:
    """The frame's capture time on the host clock (Unix ns): the device timestamp when the device clock is the
    host's, else the host arrival time."""
    frame = item.frame
    return int(frame.timestamp_ns) if item.device_latency_ms is not None else int(frame.host_timestamp_ns)


@dataclass(frozen=True)
class LandingTargetFields:
    """LANDING_TARGET's values for one target (before float32 encoding). Units in the MAVLink spec's."""

    angle_x_rad: float
    angle_y_rad: float
    distance_m: float
    size_x_rad: float
    size_y_rad: float
    xyz_body_m: tuple[float, float, float]
    q_wxyz: tuple[float, float, float, float]


def landing_target_fields(mounting: Mounting, target_id: int, R_cam_target: np.ndarray,
                          t_cam_target_m: np.ndarray, outer_radius_m: float | None) -> LandingTargetFields:
    t = np.asarray(t_cam_target_m, dtype=np.float64)
    distance = float(np.linalg.norm(t))
    size = 2.0 * math.atan(outer_radius_m / distance) if outer_radius_m and distance > 0 else 0.0
    poses = vehicle_poses(mounting, target_id, R_cam_target, t, np.zeros((6, 6)))
    qx, qy, qz, qw = (float(v) for v in poses.body_from_target.quaternion_xyzw)
    return LandingTargetFields(
        angle_x_rad=math.atan2(float(t[0]), float(t[2])), angle_y_rad=math.atan2(float(t[1]), float(t[2])),
        distance_m=distance, size_x_rad=size, size_y_rad=size,
        xyz_body_m=tuple(float(v) for v in poses.body_from_target.t),  # type: ignore[arg-type]
        q_wxyz=(qw, qx, qy, qz))


class MavlinkSink:
    """Sends HEARTBEAT, LANDING_TARGET and optionally VISION_POSITION_ESTIMATE (module docstring)."""

    consumes: Literal["results"] = "results"

    def __init__(self, connection: str | MavlinkConnection, targets: Sequence[TargetSpec],
                 mounting: Mounting | None = None, *, system_id: int = 1, component_id: int = 191,
                 max_rate_hz: float = 30.0, vision_position_estimate: bool = False, name: str = "mavlink"):
        self.name = name
        self.connection = connection if isinstance(connection, MavlinkConnection) else parse_connection(connection)
        self.radius_m = {t.id: float(t.outer_radius_m) for t in targets}
        if mounting is None:
            log.warning("MAVLink: mounting.camera_to_body is not set: LANDING_TARGET assumes a forward-looking "
                        "camera at the body origin")
            mounting = Mounting()
        self.mounting = mounting
        self.system_id = system_id
        self.component_id = component_id
        self.min_period_ns = int(round(1e9 / max_rate_hz)) if max_rate_hz > 0 else 0
        self.vision_position_estimate = vision_position_estimate
        self._master: Any = None
        self._mavlink: Any = None
        self._lock = threading.Lock()  # the connection (its sequence numbers) is shared with the heartbeat thread
        self._stop = threading.Event()
        self._heartbeat_thread: threading.Thread | None = None
        self._next_due_ns: dict[int, int] = {}
        self._counts = {"heartbeat": 0, "landing_target": 0, "vision_position_estimate": 0, "rate_limited": 0,
                        "not_ok": 0, "heading_unknown": 0}
        self._errors = 0

    def open(self) -> None:
        mavutil = import_mavutil()
        c = self.connection
        kwargs: dict[str, Any] = {"source_system": self.system_id, "source_component": self.component_id,
                                  "dialect": DIALECT, "autoreconnect": False}
        if c.kind == "serial":
            kwargs["baud"] = c.port_or_baud
        self._master = mavutil.mavlink_connection(c.mavutil_device, **kwargs)
        self._mavlink = mavutil.mavlink
        self._heartbeat_thread = threading.Thread(target=self._heartbeats, name="livetrack-mavlink-heartbeat",
                                                  daemon=True)
        self._heartbeat_thread.start()
        log.info("MAVLink to %s as system %d component %d", c, self.system_id, self.component_id)

    def _heartbeats(self) -> None:
        m = self._mavlink
        while not self._stop.is_set():
            self._send(m.MAVLink_heartbeat_message(m.MAV_TYPE_ONBOARD_CONTROLLER, m.MAV_AUTOPILOT_INVALID, 0, 0,
                                                   m.MAV_STATE_ACTIVE, 3), "heartbeat")
            self._stop.wait(HEARTBEAT_PERIOD_S)

    def _send(self, message: Any, kind: str) -> None:
        try:
            with self._lock:
                if self._master is None:
                    return
                self._master.mav.send(message)
            self._counts[kind] += 1
        except OSError as exc:  # serial unplugged, ...; pymavlink's UDP write already swallows socket errors
            self._errors += 1
            if self._errors in (1, 10, 100, 1000):
                log.warning("MAVLink %s: %s (%d send errors so far)", self.connection, exc, self._errors)

    def handle(self, item: TrackedFrame) -> None:
        m = self._mavlink
        capture_ns = capture_time_host_ns(item)
        time_usec = capture_ns // 1000
        for target in item.result.targets:
            fit = target.fit
            if not fit.ok:
                self._counts["not_ok"] += 1
                continue
            if not self._due(target.target_id, capture_ns):
                self._counts["rate_limited"] += 1
                continue
            R, t = fit.pose.R, fit.pose.t
            f = landing_target_fields(self.mounting, target.target_id, R, t, self.radius_m.get(target.target_id))
            self._send(m.MAVLink_landing_target_message(
                time_usec, target.target_id % 256, m.MAV_FRAME_BODY_FRD, f.angle_x_rad, f.angle_y_rad, f.distance_m,
                f.size_x_rad, f.size_y_rad, *f.xyz_body_m, list(f.q_wxyz), m.LANDING_TARGET_TYPE_VISION_FIDUCIAL, 1),
                "landing_target")
            if not self.vision_position_estimate or target.target_id not in self.mounting.targets_in_world:
                continue
            if not target.heading_known:  # its rotation about its normal is arbitrary, so is the vehicle's pose
                self._counts["heading_unknown"] += 1
                continue
            poses = vehicle_poses(self.mounting, target.target_id, R, t, fit.pose_covariance)
            assert poses.ned_from_body is not None and poses.ned_covariance is not None
            roll, pitch, yaw = rpy_from_rotation(poses.ned_from_body.R)
            cov = upper_triangle(rpy_covariance(poses.ned_covariance, poses.ned_from_body.R))
            x, y, z = (float(v) for v in poses.ned_from_body.t)
            self._send(m.MAVLink_vision_position_estimate_message(time_usec, x, y, z, roll, pitch, yaw, cov, 0),
                       "vision_position_estimate")

    def _due(self, target_id: int, capture_ns: int) -> bool:
        """Rate limit per target on a grid of ``1 / max_rate_hz`` by capture time, a quarter period of timing
        jitter allowed (frames at exactly the maximum rate all pass); a clock that goes back restarts the grid."""
        period, tolerance = self.min_period_ns, self.min_period_ns // 4
        due = self._next_due_ns.get(target_id)
        if due is not None and due - capture_ns > 2 * period:
            due = None
        if due is not None and capture_ns < due - tolerance:
            return False
        self._next_due_ns[target_id] = (capture_ns if due is None else max(due, capture_ns - tolerance)) + period
        return True

    def close(self) -> None:
        self._stop.set()
        if self._heartbeat_thread is not None:
            self._heartbeat_thread.join(2.0)
        with self._lock:
            master, self._master = self._master, None
        if master is not None:
            master.close()

    @property
    def stats(self) -> dict[str, Any]:
        skipped = ("rate_limited", "not_ok", "heading_unknown")
        return {**{f"sent_{k}": v for k, v in self._counts.items() if k not in skipped},
                **{k: self._counts[k] for k in skipped}, "errors": self._errors}
