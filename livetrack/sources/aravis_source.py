"""``aravis:DEVICE`` -- a GigE Vision / USB3 Vision camera through Aravis 0.8 (PyGObject).

DEVICE is the id Aravis gives the camera (``arv-tool-0.8`` lists them, e.g. ``Basler-21234567`` or
``Aravis-Fake-GV01``), a GigE camera's IP address, or empty for the first camera found.

At open the camera is configured (pixel format, ROI, frame rate, exposure and gain with auto modes off) and the
values in force are read back; a named acquisition thread then pops each buffer, copies the image out, pushes the
buffer back at once and hands the frame over in a one-frame slot (``live = True``: an unread frame is replaced,
``stats["dropped"]``).

Per frame ``exposure_us`` / ``gain_db`` are the camera's chunk data (ChunkExposureTime, ChunkGain) where it sends
them (``meta["exposure_source"] == "chunk"``), else the values read back from the camera after the last change
(``"readback"``; ``meta["frames_since_change"]`` is 0 for the first frame after a change, which may still have
been exposed with the previous value -- at most the frames already in flight, one at 200 fps on the fake camera).
Feature names differ: SFNC cameras have ExposureTime (us) and Gain (dB); older ones, and Aravis's fake camera,
ExposureTimeAbs (us) and GainRaw (vendor units, reported as is with ``meta["gain_unit"] == "raw"``). Both are
tried.

Device frame ids are 16-bit on GigE Vision 1.x (1..65535, 0 skipped): ``FrameIdUnwrapper`` turns them into a
monotonic ``frame_id``; gaps count as ``stats["lost_frames"]``, buffers that arrive incomplete (missing packets,
timeout) as ``stats["incomplete"]``.

When the camera disappears -- no complete buffer for ``stall_timeout_s`` (nothing arrives, or only broken
buffers), or Aravis's control-lost signal (heartbeat) -- the source logs a warning, drops the camera and reopens
it with exponential backoff (``reconnect_initial_s`` doubling up to ``reconnect_max_s``), re-applying the
settings; ``read`` returns None meanwhile; ``stats["reconnects"]`` counts successful reopenings.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from livetrack.camera import CameraModel
from livetrack.config import checks as cc
from livetrack.sources import Backoff, LatestSlot, camera_option, targets_option
from livetrack.sources.aravis_gi import copy_image
from livetrack.sources.base import Frame, SourceError, ThreadedCameraSource
from livetrack.targets.spec import TargetSpec

log = logging.getLogger(__name__)

OPTIONS = ["exposure_us", "gain_db", "pixel_format", "frame_rate_hz", "roi", "camera", "targets", "n_buffers",
           "stall_timeout_s", "reconnect_initial_s", "reconnect_max_s", "chunks", "packet_size", "packet_resend"]

PIXEL_FORMATS = {"Mono8": (np.uint8, 8), "Mono10": (np.uint16, 10), "Mono12": (np.uint16, 12),
                 "Mono16": (np.uint16, 16)}
"""Supported pixel formats: numpy dtype and bits (LSB-aligned). Packed formats (Mono12Packed...) are refused."""

PFNC_CODES = {0x01080001: "Mono8", 0x01100003: "Mono10", 0x01100005: "Mono12", 0x01100007: "Mono16"}
"""GenICam PFNC codes of the formats above (as in buffers)."""

EXPOSURE_FEATURES = ("ExposureTime", "ExposureTimeAbs")
GAIN_FEATURES = ("Gain", "GainRaw")
POLL_S = 0.1
OPEN_ATTEMPTS = 3
"""Attempts to open a camera that times out (a busy link or host, a camera still booting), ``reconnect_initial_s``
apart, doubling; any other error fails at once."""
"""Longest wait for one buffer in the acquisition thread (checks for close and stalls in between)."""
STREAM_COUNTERS = {"n_missing_packets": "missing_packets", "n_resent_packets": "resent_packets",
                   "n_underruns": "underruns"}


class FrameIdUnwrapper:
    """Device frame ids -> a monotonically increasing counter.

    16-bit GigE Vision 1.x ids run 1..65535 and wrap to 1 (0 is reserved); if a device does send 0 the period
    becomes 65536. Ids above 65535 (GigE Vision 2 extended ids, USB3 Vision) are taken as 64-bit, never wrapping.
    ``rebase()`` (after a reconnect, when the device counter restarts) makes the next id follow the last one.
    ``lost`` counts the ids skipped.
    """

    def __init__(self) -> None:
        self.last_raw: int | None = None
        self.last: int = -1
        self.lost = 0
        self._period = 65535
        self._wide = False

    def __call__(self, raw: int) -> int:
        raw = int(raw)
        if raw == 0:
            self._period = 65536
        if raw > 0xFFFF:
            self._wide = True
        if self.last_raw is None:
            step = 1
        elif self._wide:
            step = raw - self.last_raw
        else:
            step = (raw - self.last_raw) % self._period
        if step <= 0:  # a repeated or older id (should not happen): keep the counter monotonic
            step = 1
        self.lost += step - 1
        self.last += step
        self.last_raw = raw
        return self.last

    def rebase(self) -> None:
        self.last_raw = None


@dataclasses.dataclass(frozen=True)
class AravisSettings:
    """What the source asks of the camera. None leaves the camera's own value."""

    exposure_us: float | None = None
    gain_db: float | None = None
    pixel_format: str = "Mono8"
    frame_rate_hz: float | None = None
    roi: tuple[int, int, int, int] | None = None  # x, y, width, height in sensor pixels
    n_buffers: int = 8
    chunks: bool = True
    packet_size: int | None = None
    packet_resend: bool = True


class AravisSource(ThreadedCameraSource):
    """A GenICam camera through Aravis (module docstring).

    Parameters
    ----------
    device_id : Aravis device id or IP address; "" = the first camera.
    settings : exposure, gain, pixel format, frame rate, ROI, buffers (``AravisSettings``).
    camera : intrinsics for the image as delivered (ROI size) or for the full sensor (then shifted by the ROI
        offset); None = an uncalibrated placeholder (f = the larger image side, centred), with a warning.
    targets : the targets to track (passed through to the pipeline).
    stall_timeout_s : no complete buffer for this long = the camera is lost. Default 2 s (raise it for frame rates
        below 1 Hz or long exposures).
    reconnect_initial_s, reconnect_max_s : backoff between reopening attempts (each attempt itself blocks ~1-3 s
        in Aravis's discovery when the camera is absent).
    """

    live = True

    def __init__(self, device_id: str = "", settings: AravisSettings | None = None, *,
                 camera: CameraModel | None = None, targets: Sequence[TargetSpec] = (),
                 stall_timeout_s: float = 2.0, reconnect_initial_s: float = 0.5, reconnect_max_s: float = 8.0):
        self.device_id = device_id
        self.settings = settings or AravisSettings()
        if self.settings.pixel_format not in PIXEL_FORMATS:
            raise cc.ConfigError("source.pixel_format",
                                 f"must be one of {list(PIXEL_FORMATS)}, got {self.settings.pixel_format!r}")
        self._given_camera = camera
        self.camera: CameraModel = camera  # type: ignore[assignment]  # set at open
        self.targets: list[TargetSpec] = list(targets)
        self.stall_timeout_s = stall_timeout_s
        self._backoff = Backoff(reconnect_initial_s, reconnect_max_s)
        self._want_exposure_us = self.settings.exposure_us
        self._want_gain_db = self.settings.gain_db
        self._Aravis: Any = None
        self._GLib: Any = None
        self._cam: Any = None
        self._stream: Any = None
        self._chunk_parser: Any = None
        self._lost_handler: int | None = None
        self._control_lost = threading.Event()
        self._cam_lock = threading.RLock()
        self._slot = LatestSlot()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self._unwrap = FrameIdUnwrapper()
        self._dtype: Any = np.uint8
        self._exposure_feature = ""
        self._gain_feature = ""
        self._exposure_us: float | None = None  # read back; None: unknown (the camera has no exposure feature)
        self._gain_db: float | None = None
        self._frames_since_change = 0
        self._counts = {"frames": 0, "incomplete": 0, "reconnects": 0, "lost_events": 0,
                        **{name: 0 for name in STREAM_COUNTERS.values()}}
        self._stream_base = dict.fromkeys(STREAM_COUNTERS.values(), 0)

    @classmethod
    def from_options(cls, argument: str, options: Mapping[str, Any]) -> AravisSource:
        path = "source"
        cc.mapping(options, path, optional=OPTIONS)
        roi = None
        if options.get("roi") is not None:
            values = cc.number_list(options, "roi", path, length=4)
            if any(v != int(v) or v < 0 for v in values) or values[2] < 1 or values[3] < 1:
                raise cc.ConfigError(cc.join(path, "roi"), f"must be [x, y, width, height] in whole pixels, got "
                                                            f"{options['roi']}")
            roi = tuple(int(v) for v in values)

        def optional_number(key: str, **bounds: float) -> float | None:
            return cc.number(options, key, path, **bounds) if options.get(key) is not None else None

        packet_size = (cc.integer(options, "packet_size", path, ge=576)
                       if options.get("packet_size") is not None else None)
        settings = AravisSettings(
            exposure_us=optional_number("exposure_us", gt=0),
            gain_db=optional_number("gain_db"),
            pixel_format=cc.string(options, "pixel_format", path, default="Mono8", choices=list(PIXEL_FORMATS)),
            frame_rate_hz=optional_number("frame_rate_hz", gt=0),
            roi=roi,  # type: ignore[arg-type]
            n_buffers=cc.integer(options, "n_buffers", path, default=8, ge=2),
            chunks=cc.boolean(options, "chunks", path, default=True),
            packet_size=packet_size,
            packet_resend=cc.boolean(options, "packet_resend", path, default=True),
        )
        return cls(argument, settings, camera=camera_option(options, path=path),
                   targets=targets_option(options, path=path),
                   stall_timeout_s=cc.number(options, "stall_timeout_s", path, default=2.0, gt=0),
                   reconnect_initial_s=cc.number(options, "reconnect_initial_s", path, default=0.5, gt=0),
                   reconnect_max_s=cc.number(options, "reconnect_max_s", path, default=8.0, gt=0))

    @property
    def name(self) -> str:
        return f"aravis:{self.device_id}"

    # ------------------------------------------------------------------ protocol
    def open(self) -> None:
        """Load Aravis, open and configure the camera, start acquiring. SourceError if any of it fails."""
        if self._thread is not None:
            raise SourceError(f"{self.name}: already open")
        from livetrack.sources.aravis_gi import AravisUnavailable, load_aravis

        try:
            self._Aravis, self._GLib = load_aravis()
        except AravisUnavailable as exc:
            raise SourceError(f"{self.name}: {exc}") from exc
        for attempt in range(1, OPEN_ATTEMPTS + 1):
            try:
                self._connect()
                break
            except self._GLib.Error as exc:
                self._teardown()
                if attempt == OPEN_ATTEMPTS or "timeout" not in exc.message.lower():
                    raise SourceError(f"{self.name}: cannot open the camera: {exc.message}") from exc
                delay = self._backoff.initial_s * 2 ** (attempt - 1)
                log.warning("%s: the camera did not answer (%s); attempt %d of %d in %.1f s", self.name, exc.message,
                            attempt + 1, OPEN_ATTEMPTS, delay)
                time.sleep(delay)
            except Exception:
                self._teardown()
                raise
        self._thread = threading.Thread(target=self._run, name="aravis-acquire", daemon=True)
        self._thread.start()

    def _release(self) -> None:
        self._teardown()

    @property
    def stats(self) -> dict[str, int]:
        return {**self._counts, "lost_frames": self._unwrap.lost, "dropped": self._slot.dropped}

    @property
    def connected(self) -> bool:
        return self._cam is not None

    # ------------------------------------------------------------------ exposure control
    def set_exposure(self, exposure_us: float | None = None,
                     gain_db: float | None = None) -> tuple[float | None, float | None] | None:
        """Ask for a new exposure and/or gain (None keeps it). Returns the values read back from the camera (each
        None when the camera has no such feature), or None while it is disconnected (they are applied when it is
        back)."""
        if exposure_us is not None:
            self._want_exposure_us = float(exposure_us)
        if gain_db is not None:
            self._want_gain_db = float(gain_db)
        with self._cam_lock:
            if self._cam is None:
                return None
            try:
                self._apply_exposure(exposure_us, gain_db)
            except self._GLib.Error as exc:
                log.warning("%s: setting exposure failed: %s", self.name, exc.message)
                return None
            return self._exposure_us, self._gain_db

    def _apply_exposure(self, exposure_us: float | None, gain_db: float | None) -> None:
        """Write exposure / gain (under ``_cam_lock``), read both back, restart ``frames_since_change``."""
        cam = self._cam
        if exposure_us is not None and self._exposure_feature:
            cam.set_float(self._exposure_feature, float(exposure_us))
        if gain_db is not None and self._gain_feature:
            if self._gain_feature == "GainRaw":
                cam.set_integer("GainRaw", round(gain_db))
            else:
                cam.set_float(self._gain_feature, float(gain_db))
        self._exposure_us = cam.get_float(self._exposure_feature) if self._exposure_feature else None
        if self._gain_feature == "GainRaw":
            self._gain_db = float(cam.get_integer("GainRaw"))
        elif self._gain_feature:
            self._gain_db = cam.get_float(self._gain_feature)
        self._frames_since_change = 0
        log.info("%s: exposure %s us, gain %s %s (read back)", self.name, _known(self._exposure_us, ".1f"),
                 _known(self._gain_db, ".2f"), "raw" if self._gain_feature == "GainRaw" else "dB")

    # ------------------------------------------------------------------ connection
    def _available(self, feature: str) -> bool:
        try:
            return bool(self._cam.is_feature_available(feature))
        except self._GLib.Error:
            return False

    def _connect(self) -> None:
        """Open, configure and start the camera (raises GLib.Error / SourceError)."""
        Aravis = self._Aravis
        s = self.settings
        with self._cam_lock:
            cam = Aravis.Camera.new(self.device_id or None)
            self._cam = cam
            device_name = f"{cam.get_vendor_name()} {cam.get_model_name()} {cam.get_device_serial_number()}"
            available = cam.dup_available_pixel_formats_as_strings()
            if s.pixel_format not in available:
                raise SourceError(f"{self.name}: pixel format {s.pixel_format} not offered by {device_name} "
                                  f"(it offers {', '.join(available)})")
            cam.set_pixel_format_from_string(s.pixel_format)
            if s.roi is not None:
                cam.set_region(*s.roi)
            if s.frame_rate_hz is not None and cam.is_frame_rate_available():
                cam.set_frame_rate(s.frame_rate_hz)
            for auto in ("ExposureAuto", "GainAuto"):
                if self._available(auto):
                    cam.set_string(auto, "Off")
            self._exposure_feature = next((f for f in EXPOSURE_FEATURES if self._available(f)), "")
            self._gain_feature = next((f for f in GAIN_FEATURES if self._available(f)), "")
            if not self._exposure_feature:
                log.warning("%s: %s has neither of %s: exposure unknown", self.name, device_name,
                            EXPOSURE_FEATURES)
            self._apply_exposure(self._want_exposure_us, self._want_gain_db)
            self._setup_chunks(cam)
            if cam.is_gv_device() and s.packet_size is not None:
                cam.gv_set_packet_size(s.packet_size)
            region = cam.get_region()
            x, y, width, height = int(region.x), int(region.y), int(region.width), int(region.height)
            pixel_format = cam.get_pixel_format_as_string()
            self._dtype, bits = PIXEL_FORMATS[pixel_format]
            self._set_camera_model(cam, x, y, width, height, bits)
            rate = cam.get_frame_rate() if cam.is_frame_rate_available() else float("nan")
            payload = cam.get_payload()
            stream = cam.create_stream(None, None)
            if stream is None:
                raise SourceError(f"{self.name}: cannot create a stream")
            if cam.is_gv_device() and not s.packet_resend:
                stream.set_property("packet-resend", Aravis.GvStreamPacketResend.NEVER)
            for _ in range(s.n_buffers):
                stream.push_buffer(Aravis.Buffer.new_allocate(payload))
            self._stream = stream
            self._stream_base = dict.fromkeys(STREAM_COUNTERS.values(), 0)
            self._control_lost.clear()
            self._lost_handler = cam.get_device().connect("control-lost", self._on_control_lost)
            cam.start_acquisition()
            self._unwrap.rebase()
        log.info("%s: %s, %dx%d at (%d, %d), %s, %.3g fps, exposure %s us, gain %s, exposure metadata from %s",
                 self.name, device_name, width, height, x, y, pixel_format, rate, _known(self._exposure_us, ".1f"),
                 _known(self._gain_db, ".2f"),
                 "chunks" if self._chunk_parser is not None else "read-back")

    def _setup_chunks(self, cam: Any) -> None:
        self._chunk_parser = None
        if not self.settings.chunks or not self._available("ChunkModeActive"):
            return
        try:
            names = [n for n in ("ExposureTime", "Gain") if cam.is_enumeration_entry_available("ChunkSelector", n)]
            if "ExposureTime" not in names:
                return
            cam.set_chunks(",".join(names))
            self._chunk_parser = cam.create_chunk_parser()
        except self._GLib.Error as exc:
            log.warning("%s: chunk data unavailable (%s): using register read-back", self.name, exc.message)
            self._chunk_parser = None

    def _set_camera_model(self, cam: Any, x: int, y: int, width: int, height: int, bits: int) -> None:
        given = self._given_camera
        if given is None:
            if self.camera is None or (self.camera.width, self.camera.height) != (width, height):
                log.warning("%s: no camera file: using an uncalibrated placeholder model (f = %d px, centred); "
                            "poses will be wrong by the focal length error", self.name, max(width, height))
                self.camera = CameraModel(width=width, height=height, fx=float(max(width, height)),
                                          fy=float(max(width, height)), cx=(width - 1) / 2.0,
                                          cy=(height - 1) / 2.0, bit_depth=bits)
            return
        if (given.width, given.height) == (width, height):
            self.camera = dataclasses.replace(given, bit_depth=bits)
            return
        sensor_width, sensor_height = cam.get_sensor_size()
        if (given.width, given.height) == (sensor_width, sensor_height):
            self.camera = dataclasses.replace(given, width=width, height=height, cx=given.cx - x, cy=given.cy - y,
                                              bit_depth=bits)
            return
        raise SourceError(f"{self.name}: the camera file is for {given.width}x{given.height} images; the camera "
                          f"delivers {width}x{height} (sensor {sensor_width}x{sensor_height})")

    def _on_control_lost(self, device: Any) -> None:  # called from an Aravis thread
        self._control_lost.set()

    def _teardown(self) -> None:
        """Stop acquisition (errors ignored: the camera may be gone) and drop camera and stream."""
        with self._cam_lock:
            cam, stream = self._cam, self._stream
            self._cam = self._stream = self._chunk_parser = None
            if stream is not None:
                self._poll_stream_counters(stream)
            if cam is not None:
                if self._lost_handler is not None:
                    cam.get_device().disconnect(self._lost_handler)
                    self._lost_handler = None
                try:
                    cam.stop_acquisition()
                except self._GLib.Error as exc:
                    log.debug("%s: stop_acquisition: %s", self.name, exc.message)

    def _poll_stream_counters(self, stream: Any) -> None:
        for info, key in STREAM_COUNTERS.items():
            value = int(stream.get_info_uint64_by_name(info))
            self._counts[key] += value - self._stream_base[key]
            self._stream_base[key] = value

    # ------------------------------------------------------------------ acquisition thread
    def _run(self) -> None:
        last_buffer = time.monotonic()
        last_poll = last_buffer
        try:
            while not self._stop.is_set():
                if self._stream is None:
                    if self._reconnect():
                        last_buffer = last_poll = time.monotonic()
                    continue
                buffer = self._stream.timeout_pop_buffer(int(POLL_S * 1e6))
                now = time.monotonic()
                if buffer is not None and self._handle(buffer):
                    last_buffer = now
                if now - last_poll > 1.0:
                    self._poll_stream_counters(self._stream)
                    last_poll = now
                if self._control_lost.is_set():
                    self._lose("control lost (heartbeat)")
                elif now - last_buffer > self.stall_timeout_s:
                    self._lose(f"no complete buffer for {now - last_buffer:.1f} s")
        except Exception as exc:
            log.exception("%s: acquisition thread failed", self.name)
            self._error = exc
        finally:
            if self._error is not None:
                self._slot.close()

    def _lose(self, reason: str) -> None:
        log.warning("%s: camera lost (%s); reconnecting with backoff", self.name, reason)
        self._counts["lost_events"] += 1
        self._teardown()
        self._backoff.reset()

    def _reconnect(self) -> bool:
        delay = self._backoff.next_delay_s()
        if self._stop.wait(delay):
            return False
        try:
            self._connect()
        except (self._GLib.Error, SourceError) as exc:
            message = getattr(exc, "message", str(exc))
            log.info("%s: reconnect attempt %d failed (%s); next in %.1f s", self.name, self._backoff.attempts,
                     message, min(self._backoff.max_s, delay * 2))
            self._teardown()
            return False
        self._counts["reconnects"] += 1
        log.warning("%s: camera back after %d attempt(s)", self.name, self._backoff.attempts)
        self._backoff.reset()
        return True

    def _handle(self, buffer: Any) -> bool:
        """Copy the image and metadata out of ``buffer``, push it back, publish the frame; False if the buffer
        was incomplete or unusable."""
        Aravis = self._Aravis
        stream = self._stream
        host_ns = time.time_ns()
        try:
            if buffer.get_status() != Aravis.BufferStatus.SUCCESS:
                self._counts["incomplete"] += 1
                log.debug("%s: incomplete buffer (%s)", self.name, buffer.get_status().value_nick)
                return False
            raw_id = buffer.get_frame_id()
            width, height = buffer.get_image_width(), buffer.get_image_height()
            try:
                image = copy_image(buffer, width, height, self._dtype)
            except ValueError as exc:  # a short payload: count it like an incomplete buffer
                self._counts["incomplete"] += 1
                log.warning("%s: %s", self.name, exc)
                return False
            timestamp_ns = buffer.get_timestamp() or buffer.get_system_timestamp()
            with self._cam_lock:
                exposure_us, gain_db, since_change = self._exposure_us, self._gain_db, self._frames_since_change
                self._frames_since_change += 1
            origin = "readback"
            if self._chunk_parser is not None and buffer.has_chunks():
                try:
                    exposure_us = self._chunk_parser.get_float_value(buffer, "ChunkExposureTime")
                    if self._gain_feature == "Gain":
                        gain_db = self._chunk_parser.get_float_value(buffer, "ChunkGain")
                    origin = "chunk"
                except self._GLib.Error as exc:
                    log.warning("%s: chunk data unreadable (%s): using register read-back", self.name, exc.message)
                    self._chunk_parser = None
        finally:
            stream.push_buffer(buffer)
        frame_id = self._unwrap(raw_id)
        meta = {"device_frame_id": int(raw_id), "exposure_source": origin, "frames_since_change": since_change}
        if self._gain_feature == "GainRaw":
            meta["gain_unit"] = "raw"
        if image.shape != (self.camera.height, self.camera.width):
            self._counts["incomplete"] += 1
            log.warning("%s: %dx%d image, expected %dx%d: dropped", self.name, width, height, self.camera.width,
                        self.camera.height)
            return False
        self._counts["frames"] += 1
        self._slot.put(Frame(image=image, frame_id=frame_id, timestamp_ns=int(timestamp_ns),
                             host_timestamp_ns=host_ns, exposure_us=_optional_float(exposure_us),
                             gain_db=_optional_float(gain_db),
                             meta=meta))
        return True


def _optional_float(value: float | None) -> float | None:
    """A read-back or chunk value as a float; None (unknown) stays None."""
    return None if value is None else float(value)


def _known(value: float | None, spec: str) -> str:
    """``value`` formatted for a log line, or "unknown"."""
    return "unknown" if value is None else format(value, spec)
