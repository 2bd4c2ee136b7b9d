"""Build the configured outputs. A disabled output is simply absent from the list (the pipeline has no
special case for it); rerun, zmq and mavlink are imported only when their output is on."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from livetrack.camera import CameraModel
from livetrack.sinks.base import Sink
from livetrack.targets.spec import TargetSpec

if TYPE_CHECKING:
    from livetrack.config.app import AppConfig

log = logging.getLogger(__name__)


def build_sinks(config: AppConfig, camera: CameraModel, targets: Sequence[TargetSpec], config_text: str,
                meta: dict[str, Any] | None = None, console: bool = True) -> tuple[list[Sink], dict[str, int]]:
    """(sinks, queue size per sink name) for the enabled outputs of ``config``."""
    out = config.outputs
    sinks: list[Sink] = []
    sizes: dict[str, int] = {}
    if console and config.logging.print_every_s > 0:
        from livetrack.sinks.console import ConsoleSink

        sinks.append(ConsoleSink(config.logging.print_every_s))
        sizes["console"] = 1
    if out.record.dir is not None:
        from livetrack.sinks.recording_sink import RecordingSink

        rec = out.record
        sinks.append(RecordingSink(rec.dir, camera, targets, meta=meta, overwrite=rec.overwrite,
                                   png_compression=rec.png_compression,
                                   fsync_every_n_frames=rec.fsync_every_n_frames, config_text=config_text))
        sizes["record"] = rec.queue_size
    if out.udp.destination is not None:
        from livetrack.sinks.udp import UdpSink

        host, port = out.udp.destination
        sinks.append(UdpSink(host, port, encoding=out.udp.encoding,  # type: ignore[arg-type]
                             mounting=config.mounting))
        sizes["udp"] = out.udp.queue_size
    if out.zmq.endpoint is not None:
        from livetrack.sinks.zmq_pub import ZmqPubSink

        sinks.append(ZmqPubSink(out.zmq.endpoint, encoding=out.zmq.encoding,  # type: ignore[arg-type]
                                sndhwm=out.zmq.sndhwm, mounting=config.mounting))
        sizes["zmq"] = out.zmq.queue_size
    if out.mavlink.connection is not None:
        from livetrack.sinks.mavlink import MavlinkSink

        mav = out.mavlink
        sinks.append(MavlinkSink(mav.connection, targets, config.mounting, system_id=mav.system_id,
                                 component_id=mav.component_id, max_rate_hz=mav.max_rate_hz,
                                 vision_position_estimate=mav.vision_position_estimate))
        sizes["mavlink"] = mav.queue_size
    if out.rerun.mode != "off":
        from livetrack.sinks.rerun_sink import RerunSink

        rr_cfg = out.rerun
        sinks.append(RerunSink(rr_cfg.mode, camera, targets, argument=rr_cfg.argument, serve_bind=rr_cfg.serve_bind,
                               serve_port=rr_cfg.serve_port, spawn_port=rr_cfg.spawn_port,
                               server_memory_limit=rr_cfg.server_memory_limit, image_every_n=rr_cfg.image_every_n,
                               config_text=config_text, mounting=config.mounting))
        sizes["rerun"] = rr_cfg.queue_size
    return sinks, sizes
