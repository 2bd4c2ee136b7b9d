"""Rerun viewer sink: image, detected ellipses, edge points and ids, camera and target poses in 3D, time series.

Modes (``outputs.rerun.mode`` / ``--rerun``): ``spawn`` (start a local viewer), ``connect`` or ``connect:URL``
(stream to a running viewer, default ``rerun+http://127.0.0.1:9876/proxy``), ``serve`` (host a gRPC server that
viewers connect to; binds ``serve_bind``, 127.0.0.1 unless configured), ``save:PATH`` (write an .rrd file),
``off`` (no sink is created at all).

Entity layout (the camera frame is the world frame: x right, y down, z forward):

- ``world`` ViewCoordinates RDF (static);
- ``world/camera/image``: Pinhole (static), Image (8 bit for display), and below it ``ellipses`` (LineStrips2D,
  outer and inner ellipse of each detected target), ``edges`` (Points2D, the edge points used), ``ids``
  (Points2D at the centres, labelled with id and distance);
- ``world/targets/<id>``: Transform3D target-to-camera (temporal), ``world/targets/<id>/geometry`` the printed
  circles of every level in the target frame (LineStrips3D, static);
- ``series/distance_m/<id>``, ``series/delta_px/<id>``, ``series/exposure_us``, ``series/latency_ms``: Scalars;
- ``config``: the resolved configuration (TextDocument, static).

Timelines: ``frame`` (the source's frame id) and ``host_time`` (host arrival time).
Rerun's image space has pixel centres at +0.5 (pixel (0, 0) covers [0, 1]); livetrack's at integers, so every 2D
position and the principal point are shifted by +0.5 here, where they leave livetrack.
"""

from __future__ import annotations

import logging
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from livetrack.camera import CameraModel
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
                 recording_id: str | None = None, name: str = "rerun"):
        if mode not in MODES:
            raise ValueError(f"rerun mode must be one of {MODES}, got {mode!r}")
        self.name = name
        self.mode = mode
        self.argument = argument
        self._camera = camera
        self._targets = list(targets)
        self._serve_bind = serve_bind
        self._serve_port = serve_port
        self._spawn_port = spawn_port
        self._memory_limit = server_memory_limit
        self._image_every_n = max(int(image_every_n), 1)
        self._config_text = config_text
        self._recording_id = recording_id or str(uuid.uuid4())
        self._rec: rr.RecordingStream | None = None
        self._logged = 0
        self.uri: str | None = None
        self.flush_error: str | None = None  # set at close if the data could not be delivered

    # ------------------------------------------------------------------ lifecycle
    def open(self) -> None:
        rec = rr.RecordingStream(APPLICATION_ID, recording_id=self._recording_id)
        self._rec = rec
        layout = blueprint()
        if self.mode == "save":
            path = Path(self.argument or "livetrack.rrd")
            path.parent.mkdir(parents=True, exist_ok=True)
            rec.save(path, default_blueprint=layout)
            self.uri = str(path)
        elif self.mode == "connect":
            self.uri = self.argument or DEFAULT_CONNECT_URL
            rec.connect_grpc(self.uri, default_blueprint=layout)
        elif self.mode == "serve":
            server = rr.GrpcServerSink(self._serve_bind, self._serve_port, server_memory_limit=self._memory_limit)
            rec.set_sinks(server, default_blueprint=layout)
            self.uri = server.uri
            print(f"rerun: viewer URL {self.uri}  (open it with: rerun {self.uri})", flush=True)
        else:
            rec.spawn(port=self._spawn_port, default_blueprint=layout)
            self.uri = f"spawned viewer on port {self._spawn_port}"
        log.info("rerun sink (%s): %s", self.mode, self.uri)
        self._log_static(rec)

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
        if self._config_text is not None:
            rec.log("config", rr.TextDocument(self._config_text, media_type="text/plain"), static=True)

    def close(self) -> None:
        rec, self._rec = self._rec, None
        if rec is None:
            return
        try:
            rec.flush(timeout_sec=2.0)
        except RuntimeError as exc:  # e.g. the viewer was never reachable
            self.flush_error = str(exc)
            log.warning("rerun (%s %s): could not flush: %s", self.mode, self.uri, exc)
        rec.disconnect()

    # ------------------------------------------------------------------ per frame
    def handle(self, item: TrackedFrame) -> None:
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
                rec.log(f"series/distance_m/{target.target_id}", rr.Scalars([distance]))
                rec.log(f"series/delta_px/{target.target_id}", rr.Scalars([target.fit.delta_px]))
        rec.log("world/camera/image/ellipses", rr.LineStrips2D(strips, colors=strip_colours or None))
        rec.log("world/camera/image/edges",
                rr.Points2D(np.vstack(edges) if edges else np.zeros((0, 2)),
                            colors=np.vstack(edge_colours) if edge_colours else None, radii=[0.8]))
        rec.log("world/camera/image/ids",
                rr.Points2D(np.vstack(centres) if centres else np.zeros((0, 2)), labels=labels or None,
                            radii=[2.0]))
        rec.log("series/exposure_us", rr.Scalars([frame.exposure_us]))
        rec.log("series/latency_ms", rr.Scalars([item.latency_ms]))
        self._logged += 1

    @property
    def stats(self) -> dict[str, Any]:
        out: dict[str, Any] = {"logged": self._logged, "uri": self.uri}
        if self.flush_error:
            out["flush_error"] = self.flush_error
        return out


def _display_image(image: np.ndarray, bit_depth: int) -> np.ndarray:
    """8-bit view of an LSB-aligned image (high bits kept): 2-4x less to send, and Rerun shows it full range."""
    if image.dtype == np.uint8:
        return image
    shift = max(int(bit_depth) - 8, 0)
    return (image >> shift).astype(np.uint8) if shift else np.minimum(image, 255).astype(np.uint8)
