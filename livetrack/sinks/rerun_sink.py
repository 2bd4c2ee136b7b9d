"""Rerun viewer sink: image, detected ellipses, edge points and ids, camera and target poses in 3D, time series.

Modes (``outputs.rerun.mode`` / ``--rerun``): ``spawn`` (start a local viewer), ``connect`` or ``connect:URL``
(stream to a running viewer, default ``rerun+http://127.0.0.1:9876/proxy``), ``serve`` (host a gRPC server that
viewers connect to), ``save:PATH`` (write an .rrd file), ``off`` (no sink is created at all).

Every server livetrack starts binds ``serve_bind`` (``outputs.rerun.serve_bind``), 127.0.0.1 unless configured:
the ``serve`` gRPC server, and the viewer that ``spawn`` starts. Rerun's own ``spawn()`` (0.41) cannot pass a bind
address and its viewer listens on 0.0.0.0 (the viewer's ``--bind`` default), so this sink starts the viewer
itself (``viewer_command``: ``rerun --port P --bind ADDRESS ...``), waits until it listens, then connects to it.

Delivery (connect, spawn): before connecting, the viewer's port is probed (TCP, ``PROBE_TIMEOUT_S``): Rerun's
``connect_grpc`` to nothing blocks 5 s and its shutdown 5 s more. With no viewer there, a warning is logged once,
the items are counted as ``undelivered`` (in ``dropped`` and the summary) and the probe is repeated every
``RECONNECT_EVERY_S``: a viewer started later receives from then on. While connected, a flush every
``CHECK_EVERY_S`` (bounded by ``CHECK_TIMEOUT_S``) confirms delivery; a viewer that vanished or stalls is warned
about once, what was logged since the last confirmed flush is counted undelivered, and the sink goes back to
probing. ``close()`` flushes for at most ``CLOSE_FLUSH_TIMEOUT_S``: shutdown is never held up by a viewer.

Entity layout (the camera frame is the world frame: x right, y down, z forward):

- ``world`` ViewCoordinates RDF (static);
- ``world/camera/image``: Pinhole (static), Image (8 bit for display), and below it ``ellipses`` (LineStrips2D,
  outer and inner ellipse of each detected target), ``edges`` (Points2D, the edge points used), ``ids``
  (Points2D at the centres, labelled with id and distance);
- ``world/targets/<id>``: Transform3D target-to-camera (temporal), ``world/targets/<id>/geometry`` the printed
  circles of every level in the target frame (LineStrips3D, static);
- with ``mounting.camera_to_body`` configured: ``world/vehicle`` (static Transform3D body-to-camera) with
  ``world/vehicle/axes`` (Arrows3D forward, right, down, 0.3 m); for each target placed in the world
  (``mounting.targets_in_world``) ``world/targets/<id>/pad`` (static: the pad's square outline, 3 x the target's
  diameter, and an arrow along its heading, the target's +x) and ``world/ned`` (the local NED frame seen from the
  camera through the last placed target's pose, temporal) with ``world/ned/axes`` (north, east, down, 1 m);
- ``series/distance_m/<id>``, ``series/delta_px/<id>``, ``series/exposure_us``, ``series/latency_ms``: Scalars;
- ``config``: the resolved configuration (TextDocument, static).

Timelines: ``frame`` (the source's frame id) and ``host_time`` (host arrival time).
Rerun's image space has pixel centres at +0.5 (pixel (0, 0) covers [0, 1]); livetrack's at integers, so every 2D
position and the principal point are shifted by +0.5 here, where they leave livetrack.
"""

from __future__ import annotations

import contextlib
import importlib.util
import logging
import os
import shutil
import socket
import subprocess
import threading
import time
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal
from urllib.parse import urlsplit

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from livetrack.camera import CameraModel
from livetrack.frames import Mounting, Transform, compose
from livetrack.sinks.base import TrackedFrame
from livetrack.sinks.rerun_mode import DEFAULT_CONNECT_URL, MODES
from livetrack.targets.spec import TargetSpec

log = logging.getLogger(__name__)

APPLICATION_ID = "livetrack"
RERUN_PIXEL_OFFSET = 0.5  # livetrack pixel centre (0, 0) -> Rerun image coordinates (0.5, 0.5)
_ELLIPSE_SAMPLES = 72
_CIRCLE_SAMPLES = 96
_OK_COLOUR = (40, 220, 80)
_FAILED_COLOUR = (240, 60, 40)
_AXIS_COLOURS = [(230, 50, 50), (50, 200, 50), (60, 110, 240)]  # x, y, z
PROBE_TIMEOUT_S = 0.5  # TCP connect to the viewer's port before connecting to it
RECONNECT_EVERY_S = 2.0  # probe again this often while no viewer is there (items meanwhile undelivered)
CHECK_EVERY_S = 1.0  # confirm delivery (flush) this often while connected
CHECK_TIMEOUT_S = 0.5  # a flush not done by then means the viewer stalls or is gone
CLOSE_FLUSH_TIMEOUT_S = 1.5  # the last flush at close (shutdown waits at most this for the viewer)
SPAWN_READY_TIMEOUT_S = 10.0  # a spawned viewer must listen within this
VIEWER_MEMORY_LIMIT = "75%"  # as rerun's spawn()
_SPAWNED: list[subprocess.Popen] = []  # viewers started here outlive the run (the user closes them); kept here


def viewer_executable() -> str:
    """The ``rerun`` viewer binary: the one of the installed rerun-sdk (rerun_cli package), else ``rerun`` on PATH."""
    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin is not None:
        binary = Path(spec.origin).parent / ("rerun.exe" if os.name == "nt" else "rerun")
        if binary.is_file():
            return str(binary)
    found = shutil.which("rerun")
    if found is None:
        raise FileNotFoundError("no rerun viewer binary found (it comes with the rerun-sdk package)")
    return found


def viewer_command(executable: str, port: int, bind: str, memory_limit: str = VIEWER_MEMORY_LIMIT,
                   server_memory_limit: str = "1GiB") -> list[str]:
    """The command line of a viewer listening on ``bind:port`` (what rerun's spawn() runs, plus ``--bind``)."""
    return [executable, "--port", str(int(port)), "--bind", bind, "--memory-limit", memory_limit,
            "--server-memory-limit", server_memory_limit, "--expect-data-soon"]


def _connect_address(host: str) -> str:
    """Where to reach a server bound to ``host`` from this machine (an unspecified address: loopback)."""
    return {"0.0.0.0": "127.0.0.1", "::": "::1", "": "127.0.0.1"}.get(host, host)


def port_open(host: str, port: int, timeout_s: float = PROBE_TIMEOUT_S) -> bool:
    """True if a TCP connection to ``host:port`` succeeds within ``timeout_s``."""
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            return True
    except OSError:
        return False


def blueprint() -> rrb.Blueprint:
    """Image with overlays on the left; 3D scene and time series on the right."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial2DView(name="image", origin="world/camera/image"),
            rrb.Vertical(
                rrb.Spatial3DView(name="camera and targets", origin="world"),
                rrb.TimeSeriesView(name="distance (m)", origin="series/distance_m"),
                rrb.TimeSeriesView(name="exposure bias delta (px)", origin="series/delta_px"),
                rrb.Horizontal(
                    rrb.TimeSeriesView(name="exposure (us)", origin="series/exposure_us"),
                    rrb.TimeSeriesView(name="latency (ms)", origin="series/latency_ms"),
                ),
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


class RerunSink:
    """Logs each TrackedFrame to a Rerun recording stream owned by the sink's thread."""

    consumes: Literal["results"] = "results"
    # connect/spawn wait up to 5 s for a viewer; the pipeline does not wait that long (frames drop meanwhile)
    open_timeout_s = 2.0

    def __init__(self, mode: str, camera: CameraModel, targets: Sequence[TargetSpec], *, argument: str | None = None,
                 serve_bind: str = "127.0.0.1", serve_port: int = 9876, spawn_port: int = 9876,
                 server_memory_limit: str = "1GiB", image_every_n: int = 1, config_text: str | None = None,
                 recording_id: str | None = None, name: str = "rerun", viewer: str | None = None,
                 mounting: Mounting | None = None, reconnect_every_s: float = RECONNECT_EVERY_S):
        if mode not in MODES:
            raise ValueError(f"rerun mode must be one of {MODES}, got {mode!r}")
        self.reconnect_every_s = float(reconnect_every_s)
        self.name = name
        self.mode = mode
        self.argument = argument
        self._camera = camera
        self._targets = list(targets)
        self._mounting = mounting
        self._serve_bind = serve_bind
        self._serve_port = serve_port
        self._spawn_port = spawn_port
        self._memory_limit = server_memory_limit
        self._image_every_n = max(int(image_every_n), 1)
        self._config_text = config_text
        self._recording_id = recording_id or str(uuid.uuid4())
        self._viewer = viewer  # the viewer binary for spawn (None: viewer_executable())
        self._rec: rr.RecordingStream | None = None
        self._layout: rrb.Blueprint | None = None
        self._logged = 0
        self.uri: str | None = None
        # the last failed delivery's error while no later delivery succeeded (connect, spawn), or the close's flush's:
        # set at close when the data could not be delivered (a viewer lost mid-run and found again clears it: a
        # gRPC flush that failed right after a late viewer came up, under load, had stayed set)
        self.flush_error: str | None = None
        # delivery (connect, spawn): connected to a viewer, items confirmed delivered / counted undelivered
        self._connected = False
        self._delivered = 0
        self.undelivered = 0
        self._delivery_failures = 0
        self._next_probe = 0.0
        self._next_check = 0.0
        self.viewer_pid: int | None = None
        self.viewer_command: list[str] | None = None
        self._dropping: threading.Thread | None = None

    # ------------------------------------------------------------------ lifecycle
    def open(self) -> None:
        # Rerun's exit handler flushes every stream without a time limit: with a stalled viewer the process never
        # exits (measured: 12 min, until the viewer was resumed). close() flushes with a bound; the handler goes.
        rr.unregister_shutdown()
        rec = rr.RecordingStream(APPLICATION_ID, recording_id=self._recording_id)
        self._rec = rec
        layout = self._layout = blueprint()
        if self.mode == "save":
            path = Path(self.argument or "livetrack.rrd")
            path.parent.mkdir(parents=True, exist_ok=True)
            rec.save(path, default_blueprint=layout)
            self.uri = str(path)
        elif self.mode == "serve":
            server = rr.GrpcServerSink(self._serve_bind, self._serve_port, server_memory_limit=self._memory_limit)
            rec.set_sinks(server, default_blueprint=layout)
            self.uri = server.uri
            print(f"rerun: viewer URL {self.uri}  (open it with: rerun {self.uri})", flush=True)
        else:
            if self.mode == "spawn":
                self.uri = self._spawn_viewer()
            else:
                self.uri = self.argument or DEFAULT_CONNECT_URL
            if not self._try_connect():
                self._delivery_failures += 1
                log.warning("rerun (%s): no viewer at %s; nothing is delivered (counted as undelivered) until one "
                            "listens there (checked every %.0f s)", self.mode, self.uri, self.reconnect_every_s)
            log.info("rerun sink (%s): %s", self.mode, self.uri)
            return
        log.info("rerun sink (%s): %s", self.mode, self.uri)
        self._log_static(rec)

    def _spawn_viewer(self) -> str:
        """Start a viewer listening on serve_bind:spawn_port (unless one already listens there) and wait until it
        listens; its gRPC URL. Rerun's spawn() cannot choose the bind address (module docstring)."""
        host, port = _connect_address(self._serve_bind), self._spawn_port
        url = f"rerun+http://{'[' + host + ']' if ':' in host else host}:{port}/proxy"
        if port_open(host, port):
            log.info("rerun: a viewer already listens on port %d; using it", port)
            return url
        self.viewer_command = viewer_command(self._viewer or viewer_executable(), port, self._serve_bind,
                                             server_memory_limit=self._memory_limit)
        proc = subprocess.Popen(self.viewer_command, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, start_new_session=True,  # outlives the run
                                env={**os.environ, "RERUN_APP_ONLY": "true"})
        _SPAWNED.append(proc)
        self.viewer_pid = proc.pid
        deadline = time.monotonic() + SPAWN_READY_TIMEOUT_S
        while not port_open(host, port, timeout_s=0.2):
            if proc.poll() is not None:
                raise RuntimeError(f"the rerun viewer exited with status {proc.returncode} before listening "
                                   f"({' '.join(self.viewer_command)}); no display?")
            if time.monotonic() > deadline:
                raise RuntimeError(f"the rerun viewer does not listen on {host}:{port} after "
                                   f"{SPAWN_READY_TIMEOUT_S:.0f} s")
            time.sleep(0.1)
        log.info("rerun: spawned viewer (pid %d) listening on %s:%d", proc.pid, self._serve_bind, port)
        return url

    def _try_connect(self) -> bool:
        """Connect to the viewer at ``self.uri`` if its port answers (no blocking connect to nothing)."""
        assert self._rec is not None and self.uri is not None
        parts = urlsplit(self.uri.replace("rerun+", "", 1))
        host, port = parts.hostname or "127.0.0.1", parts.port or 9876
        self._next_probe = time.monotonic() + self.reconnect_every_s
        if not port_open(host, port):
            return False
        self._rec.connect_grpc(self.uri, default_blueprint=self._layout)
        self._log_static(self._rec)
        self._connected = True
        self._delivered = self._logged
        self._next_check = time.monotonic() + CHECK_EVERY_S
        return True

    def _check_delivery(self, timeout_s: float) -> bool:
        """Flush to the viewer within ``timeout_s``; on failure count what was not confirmed as undelivered, warn
        (first time) and drop the connection (probed again later). True if delivered."""
        assert self._rec is not None
        self._next_check = time.monotonic() + CHECK_EVERY_S
        try:
            self._rec.flush(timeout_sec=timeout_s)
        except RuntimeError as exc:
            self.flush_error = str(exc)
            self.undelivered += self._logged - self._delivered
            self._delivered = self._logged
            self._connected = False
            self._delivery_failures += 1
            if self._delivery_failures in (1, 10, 100):
                log.warning("rerun (%s): the viewer at %s does not receive (%s); %d items undelivered so far, "
                            "checking again every %.0f s", self.mode, self.uri, exc, self.undelivered,
                            self.reconnect_every_s)
            self._drop_connection()
            return False
        self._delivered = self._logged
        self.flush_error = None  # delivered since: what was lost is counted in ``undelivered``
        return True

    def _drop_connection(self) -> None:
        """Stop streaming to a viewer that does not receive, without waiting on it: Rerun's disconnect waits up
        to 5 s for a connection that never comes, so it runs in a daemon thread, given 0.2 s."""
        rec = self._rec
        assert rec is not None
        thread = threading.Thread(target=_quietly_disconnect, args=(rec,), name="livetrack-rerun-disconnect",
                                  daemon=True)
        thread.start()
        thread.join(0.2)
        self._dropping = thread
        self._rec = rr.RecordingStream(APPLICATION_ID, recording_id=self._recording_id)  # for a later viewer

    def _still_dropping(self) -> bool:
        """True while the last dropped connection has not let go (a stalled viewer): no new connection until
        then, so that a viewer that stalls for long costs one thread and one stream, not one per retry."""
        return self._dropping is not None and self._dropping.is_alive()

    def _log_static(self, rec: rr.RecordingStream) -> None:
        cam = self._camera
        rec.log("world", rr.ViewCoordinates.RDF, static=True)
        rec.log("world/camera/image", rr.Pinhole(focal_length=[cam.fx, cam.fy],
                                                 principal_point=[cam.cx + RERUN_PIXEL_OFFSET,
                                                                  cam.cy + RERUN_PIXEL_OFFSET],
                                                 width=cam.width, height=cam.height,
                                                 camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.3),
                static=True)
        angles = np.linspace(0.0, 2.0 * np.pi, _CIRCLE_SAMPLES + 1)
        unit = np.column_stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)])
        for spec in self._targets:
            strips = []
            for _, level in spec.levels():
                strips += [unit * level.outer_radius_m, unit * level.inner_radius_m]
            rec.log(f"world/targets/{spec.id}/geometry",
                    rr.LineStrips3D(strips, colors=[(230, 230, 230)], labels=[f"target {spec.id}"] + [""] * (
                        len(strips) - 1)), static=True)
        if self._mounting is not None:
            self._log_vehicle(rec, self._mounting)
        if self._config_text is not None:
            rec.log("config", rr.TextDocument(self._config_text, media_type="text/plain"), static=True)

    def _log_vehicle(self, rec: rr.RecordingStream, mounting: Mounting) -> None:
        """The vehicle's body frame (rigid to the camera) and the pads of the targets placed in the world."""
        camera_from_body = mounting.body_from_camera.inverse()
        rec.log("world/vehicle", rr.Transform3D(translation=camera_from_body.t, mat3x3=camera_from_body.R),
                static=True)
        rec.log("world/vehicle/axes", rr.Arrows3D(vectors=np.eye(3) * 0.3, colors=_AXIS_COLOURS,
                                                  labels=["forward", "right", "down"]), static=True)
        radius = {spec.id: spec.outer_radius_m for spec in self._targets}
        for target_id in mounting.targets_in_world:
            half = 3.0 * radius.get(target_id, 0.25)
            square = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0], [-1, -1, 0]], dtype=np.float64) * half
            rec.log(f"world/targets/{target_id}/pad",
                    rr.LineStrips3D([square], colors=[(250, 200, 40)], labels=[f"pad {target_id}"]), static=True)
            rec.log(f"world/targets/{target_id}/pad/heading",
                    rr.Arrows3D(vectors=[[half, 0.0, 0.0]], colors=[(250, 200, 40)], labels=["heading"]),
                    static=True)
        if mounting.targets_in_world:
            rec.log("world/ned/axes", rr.Arrows3D(vectors=np.eye(3), colors=_AXIS_COLOURS,
                                                  labels=["north", "east", "down"]), static=True)

    def close(self) -> None:
        if self._rec is None:
            return
        if self.mode in ("connect", "spawn"):
            if self._connected:
                self._check_delivery(CLOSE_FLUSH_TIMEOUT_S)
            if not self._connected:  # never connected, or just lost: nothing to wait for
                self._rec = None
                if self.undelivered:
                    log.warning("rerun (%s): %d items not delivered to %s", self.mode, self.undelivered, self.uri)
                return
        rec, self._rec = self._rec, None
        try:
            rec.flush(timeout_sec=CLOSE_FLUSH_TIMEOUT_S)
        except RuntimeError as exc:
            self.flush_error = str(exc)
            log.warning("rerun (%s %s): could not flush: %s", self.mode, self.uri, exc)
        rec.disconnect()

    # ------------------------------------------------------------------ per frame
    def handle(self, item: TrackedFrame) -> None:
        if self.mode in ("connect", "spawn"):
            now = time.monotonic()
            if (not self._connected and now >= self._next_probe and not self._still_dropping()
                    and self._try_connect()):
                log.info("rerun (%s): viewer at %s now reachable; streaming", self.mode, self.uri)
            if not self._connected:
                self.undelivered += 1
                return
            if now >= self._next_check and not self._check_delivery(CHECK_TIMEOUT_S):
                self.undelivered += 1
                return
        rec = self._rec
        assert rec is not None
        frame = item.frame
        rec.set_time("frame", sequence=frame.frame_id)
        rec.set_time("host_time", timestamp=np.datetime64(frame.host_timestamp_ns, "ns"))
        if item.sequence % self._image_every_n == 0:
            rec.log("world/camera/image", rr.Image(_display_image(frame.image, self._camera.bit_depth)))
        targets = item.result.targets
        strips, strip_colours, edges, edge_colours, centres, labels = [], [], [], [], [], []
        angles = np.linspace(0.0, 2.0 * np.pi, _ELLIPSE_SAMPLES + 1)
        for target in targets:
            colour = _OK_COLOUR if target.fit.ok else _FAILED_COLOUR
            cand = target.candidate
            for ellipse in (cand.outer, cand.inner):
                strips.append(np.asarray(ellipse.points(angles)) + RERUN_PIXEL_OFFSET)
                strip_colours.append(colour)
            pts = np.asarray(target.edge_points_px, dtype=np.float64).reshape(-1, 2)
            edges.append(pts + RERUN_PIXEL_OFFSET)
            edge_colours.append(np.tile(np.array(colour, dtype=np.uint8), (len(pts), 1)))
            centres.append(np.asarray(cand.outer.centre_px, dtype=np.float64) + RERUN_PIXEL_OFFSET)
            distance = target.fit.pose.distance_m
            labels.append(f"{target.target_id}: {distance:.3f} m, delta {target.fit.delta_px:+.2f} px"
                          + ("" if target.fit.ok else " (failed)"))
            if target.fit.ok:
                pose = target.fit.pose
                rec.log(f"world/targets/{target.target_id}",
                        rr.Transform3D(translation=pose.t, quaternion=rr.Quaternion(xyzw=pose.quaternion)))
                placement = None if self._mounting is None else self._mounting.targets_in_world.get(
                    target.target_id)
                if placement is not None:  # the local NED frame in the camera, through this target
                    camera_from_ned = compose(Transform(pose.R, pose.t), placement.ned_from_target.inverse())
                    rec.log("world/ned", rr.Transform3D(translation=camera_from_ned.t, mat3x3=camera_from_ned.R))
                rec.log(f"series/distance_m/{target.target_id}", rr.Scalars([distance]))
                rec.log(f"series/delta_px/{target.target_id}", rr.Scalars([target.fit.delta_px]))
        rec.log("world/camera/image/ellipses", rr.LineStrips2D(strips, colors=strip_colours or None))
        rec.log("world/camera/image/edges",
                rr.Points2D(np.vstack(edges) if edges else np.zeros((0, 2)),
                            colors=np.vstack(edge_colours) if edge_colours else None, radii=[0.8]))
        rec.log("world/camera/image/ids",
                rr.Points2D(np.vstack(centres) if centres else np.zeros((0, 2)), labels=labels or None,
                            radii=[2.0]))
        if frame.exposure_us is not None:  # unknown: no point
            rec.log("series/exposure_us", rr.Scalars([frame.exposure_us]))
        rec.log("series/latency_ms", rr.Scalars([item.latency_ms]))
        self._logged += 1

    @property
    def stats(self) -> dict[str, Any]:
        out: dict[str, Any] = {"logged": self._logged, "uri": self.uri}
        if self.mode in ("connect", "spawn"):
            # undelivered items count as drops, failed connections / deliveries as errors (added to the runner's)
            out.update(undelivered=self.undelivered, dropped=self.undelivered, errors=self._delivery_failures)
        if self.flush_error:
            out["flush_error"] = self.flush_error
        if self.viewer_pid is not None:
            out["viewer_pid"] = self.viewer_pid
        return out


def _quietly_disconnect(rec: rr.RecordingStream) -> None:
    with contextlib.suppress(Exception):
        rec.disconnect()


def _display_image(image: np.ndarray, bit_depth: int) -> np.ndarray:
    """8-bit view of an LSB-aligned image (high bits kept): 2-4x less to send, and Rerun shows it full range."""
    if image.dtype == np.uint8:
        return image
    shift = max(int(bit_depth) - 8, 0)
    return (image >> shift).astype(np.uint8) if shift else np.minimum(image, 255).astype(np.uint8)
