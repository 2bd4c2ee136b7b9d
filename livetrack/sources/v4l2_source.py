"""``v4l2:/dev/videoN`` -- a V4L2 webcam, through OpenCV's V4L2 backend.

The device is reached through the small ``V4L2Device`` protocol (open / grab / controls / close);
``OpenCVV4L2Device`` implements it with ``cv2.VideoCapture(path, cv2.CAP_V4L2)``. The source around it is the
same as for the GenICam cameras: a named acquisition thread grabs, converts to 8-bit grey and hands the newest
frame over in a one-frame slot (``live = True``), and a device that stops delivering (``fail_limit`` failed grabs
in a row, e.g. unplugged) is reported, closed and reopened with exponential backoff (``read`` returns None
meanwhile, ``stats["reconnects"]`` counts the reopenings).

Units: V4L2's ``exposure_time_absolute`` (``exposure_absolute`` on older kernels; OpenCV's CAP_PROP_EXPOSURE with
the V4L2 backend) counts **100 us** steps: ``exposure_us = 100 * value``, and a requested exposure is rounded to
the nearest 100 us. Manual exposure is V4L2 ``auto_exposure = 1`` (V4L2_EXPOSURE_MANUAL; 3 is aperture priority,
the usual default). Gain is in the device's own units (not dB): reported as is, ``meta["gain_unit"] == "raw"``.
Per frame ``exposure_us`` / ``gain_db`` are the values read back after the last change (webcams send no chunk
data); ``meta["frames_since_change"]`` is 0 on the first frame after a change, which may still have the old value.
``frame_id`` is the source's own counter; ``timestamp_ns`` the driver's buffer time (OpenCV CAP_PROP_POS_MSEC,
monotonic clock) when it gives one, else the host's monotonic time at the grab.

Not tested against a real device here (none on the build machine): the tests drive the source with a fake
``V4L2Device`` (frames, controls, unplugging); ``OpenCVV4L2Device`` is exercised only up to "no such device".
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any, Protocol

import cv2
import numpy as np
import numpy.typing as npt

from livetrack.camera import CameraModel
from livetrack.config import checks as cc
from livetrack.sources import Backoff, LatestSlot, camera_option, targets_option
from livetrack.sources.base import Frame, SourceError, ThreadedCameraSource
from livetrack.targets.spec import TargetSpec

log = logging.getLogger(__name__)

OPTIONS = ["exposure_us", "gain", "width", "height", "fps", "fourcc", "camera", "targets", "fail_limit",
           "reconnect_initial_s", "reconnect_max_s"]

EXPOSURE_UNIT_US = 100.0
"""One step of V4L2's exposure_time_absolute, in microseconds."""
AUTO_EXPOSURE_MANUAL = 1
"""V4L2_EXPOSURE_MANUAL, the value of the auto_exposure menu control for manual exposure."""

# Control names as v4l2-ctl lists them (kernel >= 5.x).
AUTO_EXPOSURE = "auto_exposure"
EXPOSURE_TIME_ABSOLUTE = "exposure_time_absolute"
GAIN = "gain"


class V4L2Device(Protocol):
    """The device access the source needs; ``OpenCVV4L2Device`` is the real one, tests use a fake."""

    path: str

    def open(self) -> None:
        """Open the device (and set the capture format); OSError if it is absent or busy."""

    def grab(self) -> tuple[npt.NDArray[np.uint8], int | None] | None:
        """Block for the next frame: (image (H, W) grey or (H, W, 3) BGR uint8, driver timestamp ns or None), or
        None when the grab failed (device gone, I/O error)."""

    def set_control(self, name: str, value: float) -> None:
        """Set a V4L2 control (raw device units); OSError if refused."""

    def get_control(self, name: str) -> float | None:
        """A V4L2 control's current value (raw units), None if the device does not have it."""

    def close(self) -> None: ...


class OpenCVV4L2Device:
    """``V4L2Device`` through ``cv2.VideoCapture(path, cv2.CAP_V4L2)``; OpenCV passes raw V4L2 control values."""

    PROPS = {AUTO_EXPOSURE: cv2.CAP_PROP_AUTO_EXPOSURE, EXPOSURE_TIME_ABSOLUTE: cv2.CAP_PROP_EXPOSURE,
             GAIN: cv2.CAP_PROP_GAIN}

    def __init__(self, path: str, width: int | None = None, height: int | None = None, fps: float | None = None,
                 fourcc: str | None = None):
        self.path = path
        self.width, self.height, self.fps, self.fourcc = width, height, fps, fourcc
        self._cap: Any = None

    def open(self) -> None:
        cap = cv2.VideoCapture(self.path, cv2.CAP_V4L2)
        if not cap.isOpened():
            cap.release()
            raise OSError(f"{self.path}: cannot open (no such V4L2 device, or busy)")
        if self.fourcc:
            cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*self.fourcc))
        if self.width:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.width)
        if self.height:
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
        if self.fps:
            cap.set(cv2.CAP_PROP_FPS, self.fps)
        self._cap = cap

    def grab(self) -> tuple[npt.NDArray[np.uint8], int | None] | None:
        ok, image = self._cap.read()
        if not ok or image is None:
            return None
        msec = self._cap.get(cv2.CAP_PROP_POS_MSEC)
        return image, (round(msec * 1e6) if msec > 0 else None)

    def set_control(self, name: str, value: float) -> None:
        if not self._cap.set(self.PROPS[name], float(value)):
            raise OSError(f"{self.path}: control {name} = {value} refused")

    def get_control(self, name: str) -> float | None:
        prop = self.PROPS.get(name)
        if prop is None:
            return None
        value = self._cap.get(prop)
        return None if value == -1 else float(value)

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None


class V4L2Source(ThreadedCameraSource):
    """A V4L2 webcam (module docstring).

    Parameters
    ----------
    device : the device (``OpenCVV4L2Device(path, ...)`` from ``from_options``).
    exposure_us : manual exposure (rounded to 100 us); None = leave the device's (auto) exposure alone.
    gain : gain in the device's raw units; None = leave it.
    camera, targets : intrinsics for the delivered image size (None = uncalibrated placeholder, warned), targets.
    fail_limit : failed grabs in a row that mean the device is gone (default 3).
    reconnect_initial_s, reconnect_max_s : backoff between reopening attempts.
    """

    live = True

    def __init__(self, device: V4L2Device, *, exposure_us: float | None = None, gain: float | None = None,
                 camera: CameraModel | None = None, targets: Sequence[TargetSpec] = (), fail_limit: int = 3,
                 reconnect_initial_s: float = 0.5, reconnect_max_s: float = 8.0):
        self.device = device
        self._given_camera = camera
        self.camera: CameraModel = camera  # type: ignore[assignment]  # checked at the first frame
        self.targets: list[TargetSpec] = list(targets)
        self.fail_limit = fail_limit
        self._want_exposure_us = exposure_us
        self._want_gain = gain
        self._backoff = Backoff(reconnect_initial_s, reconnect_max_s)
        self._lock = threading.RLock()
        self._connected = False
        self._slot = LatestSlot()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self._exposure_us: float | None = None  # read back; None: unknown (the device has no such control)
        self._gain: float | None = None
        self._frames_since_change = 0
        self._next_id = 0
        self._counts = {"frames": 0, "failed_grabs": 0, "reconnects": 0, "lost_events": 0}

    @classmethod
    def from_options(cls, argument: str, options: Mapping[str, Any]) -> V4L2Source:
        path = "source"
        cc.mapping(options, path, optional=OPTIONS)
        if not argument:
            raise cc.ConfigError("source", "v4l2 needs a device path: v4l2:/dev/videoN")

        def optional(key: str, kind: str = "number", **bounds: float) -> Any:
            if options.get(key) is None:
                return None
            return cc.integer(options, key, path, ge=1) if kind == "int" else cc.number(options, key, path, **bounds)

        fourcc = cc.string(options, "fourcc", path) if options.get("fourcc") is not None else None
        if fourcc is not None and len(fourcc) != 4:
            raise cc.ConfigError(cc.join(path, "fourcc"), f"must be 4 characters (e.g. MJPG, YUYV), got {fourcc!r}")
        device = OpenCVV4L2Device(argument, width=optional("width", "int"), height=optional("height", "int"),
                                  fps=optional("fps", gt=0), fourcc=fourcc)
        return cls(device, exposure_us=optional("exposure_us", gt=0), gain=optional("gain", ge=0),
                   camera=camera_option(options, path=path), targets=targets_option(options, path=path),
                   fail_limit=cc.integer(options, "fail_limit", path, default=3, ge=1),
                   reconnect_initial_s=cc.number(options, "reconnect_initial_s", path, default=0.5, gt=0),
                   reconnect_max_s=cc.number(options, "reconnect_max_s", path, default=8.0, gt=0))

    @property
    def name(self) -> str:
        return f"v4l2:{self.device.path}"

    # ------------------------------------------------------------------ protocol
    def open(self) -> None:
        if self._thread is not None:
            raise SourceError(f"{self.name}: already open")
        try:
            self._connect()
            with self._lock:  # the first frame sizes the camera model before open() returns
                grabbed = self.device.grab()
                host_ns, mono_ns = time.time_ns(), time.monotonic_ns()
                settings = self._settings_snapshot()
            if grabbed is None:
                raise OSError("opened, but delivers no frame")
            self._publish(*grabbed, host_ns, mono_ns, settings)
        except OSError as exc:
            self._disconnect()
            raise SourceError(f"{self.name}: {exc}") from exc
        except SourceError:
            self._disconnect()
            raise
        self._thread = threading.Thread(target=self._run, name="v4l2-acquire", daemon=True)
        self._thread.start()

    def _release(self) -> None:
        self._disconnect()

    @property
    def stats(self) -> dict[str, int]:
        return {**self._counts, "dropped": self._slot.dropped}

    # ------------------------------------------------------------------ exposure control
    def set_exposure(self, exposure_us: float | None = None,
                     gain_db: float | None = None) -> tuple[float | None, float | None] | None:
        """Ask for a manual exposure (rounded to 100 us) and/or gain (raw device units, despite the name shared
        with the other sources). Returns the values read back (each None when the device does not report it), or
        None while the device is away (applied when it is back). Waits for the grab in progress (at most a frame
        period)."""
        if exposure_us is not None:
            self._want_exposure_us = float(exposure_us)
        if gain_db is not None:
            self._want_gain = float(gain_db)
        with self._lock:
            if not self._connected:
                return None
            try:
                self._apply(exposure_us, gain_db)
            except OSError as exc:
                log.warning("%s: setting exposure failed: %s", self.name, exc)
                return None
            return self._exposure_us, self._gain

    def _apply(self, exposure_us: float | None, gain: float | None) -> None:
        device = self.device
        if exposure_us is not None:
            device.set_control(AUTO_EXPOSURE, AUTO_EXPOSURE_MANUAL)
            device.set_control(EXPOSURE_TIME_ABSOLUTE, max(1, round(exposure_us / EXPOSURE_UNIT_US)))
        if gain is not None:
            device.set_control(GAIN, gain)
        value = device.get_control(EXPOSURE_TIME_ABSOLUTE)
        self._exposure_us = None if value is None else float(value) * EXPOSURE_UNIT_US
        value = device.get_control(GAIN)
        self._gain = None if value is None else float(value)
        self._frames_since_change = 0
        log.info("%s: exposure %s us, gain %s (raw) read back", self.name,
                 "unknown" if self._exposure_us is None else f"{self._exposure_us:.0f}",
                 "unknown" if self._gain is None else f"{self._gain:g}")

    # ------------------------------------------------------------------ connection
    def _connect(self) -> None:
        with self._lock:
            self.device.open()
            try:
                self._apply(self._want_exposure_us, self._want_gain)
            except OSError:
                self.device.close()
                raise
            self._connected = True

    def _disconnect(self) -> None:
        with self._lock:
            if self._connected:
                self._connected = False
                self.device.close()

    def _run(self) -> None:
        failures = 0
        try:
            while not self._stop.is_set():
                if not self._connected:
                    self._reconnect()
                    failures = 0
                    continue
                with self._lock:
                    grabbed = self.device.grab()
                    host_ns, mono_ns = time.time_ns(), time.monotonic_ns()
                    settings = self._settings_snapshot()
                if grabbed is None:
                    failures += 1
                    self._counts["failed_grabs"] += 1
                    if failures >= self.fail_limit:
                        log.warning("%s: device lost (%d failed grabs in a row); reconnecting with backoff",
                                    self.name, failures)
                        self._counts["lost_events"] += 1
                        self._disconnect()
                        self._backoff.reset()
                    continue
                failures = 0
                self._publish(*grabbed, host_ns, mono_ns, settings)
        except Exception as exc:
            log.exception("%s: acquisition thread failed", self.name)
            self._error = exc
            self._slot.close()

    def _reconnect(self) -> None:
        delay = self._backoff.next_delay_s()
        if self._stop.wait(delay):
            return
        try:
            self._connect()
        except OSError as exc:
            log.info("%s: reconnect attempt %d failed (%s)", self.name, self._backoff.attempts, exc)
            return
        self._counts["reconnects"] += 1
        log.warning("%s: device back after %d attempt(s)", self.name, self._backoff.attempts)
        self._backoff.reset()

    def _settings_snapshot(self) -> tuple[float | None, float | None, int]:
        """(exposure_us, gain, frames_since_change) for the frame just grabbed (under ``_lock``)."""
        snapshot = (self._exposure_us, self._gain, self._frames_since_change)
        self._frames_since_change += 1
        return snapshot

    def _publish(self, image: npt.NDArray[np.uint8], timestamp_ns: int | None, host_ns: int, mono_ns: int,
                 settings: tuple[float | None, float | None, int]) -> None:
        exposure_us, gain, since_change = settings
        if image.ndim == 3:
            image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        else:
            image = np.array(image, dtype=np.uint8, copy=True)
        height, width = image.shape
        if self.camera is None or (self.camera.width, self.camera.height) != (width, height):
            self._set_camera_model(width, height)
        meta = {"exposure_source": "readback", "frames_since_change": since_change, "gain_unit": "raw"}
        frame = Frame(image=image, frame_id=self._next_id,
                      timestamp_ns=timestamp_ns if timestamp_ns is not None else mono_ns, host_timestamp_ns=host_ns,
                      exposure_us=exposure_us, gain_db=gain, meta=meta)
        self._next_id += 1
        self._counts["frames"] += 1
        self._slot.put(frame)

    def _set_camera_model(self, width: int, height: int) -> None:
        given = self._given_camera
        if given is not None:
            if (given.width, given.height) != (width, height):
                raise SourceError(f"{self.name}: the camera file is for {given.width}x{given.height} images, the "
                                  f"device delivers {width}x{height}")
            self.camera = given
            return
        log.warning("%s: no camera file: using an uncalibrated placeholder model (f = %d px, centred)", self.name,
                    max(width, height))
        self.camera = CameraModel(width=width, height=height, fx=float(max(width, height)),
                                  fy=float(max(width, height)), cx=(width - 1) / 2.0, cy=(height - 1) / 2.0)
