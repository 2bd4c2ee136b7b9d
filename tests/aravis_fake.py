"""An in-process GigE Vision camera for tests: Aravis's fake camera on the loopback interface, drawing the
simulator's target at the exposure its ExposureTimeAbs register holds.

``Aravis.GvFakeCamera.new("lo", serial)`` serves GVCP on 127.0.0.1:3956 and streams GVSP from a thread of its
own; dropping the last reference stops it (its finalizer joins that thread), which is how the tests pull the
camera's plug. Only one can run at a time (the GVCP port is fixed).

The image comes from a fill-pattern callback. PyGObject cannot pass a Python callable there (the callback outlives
the call), so it is installed with ctypes: ``arv_fake_camera_set_fill_pattern`` on the C pointer of the inner
ArvFakeCamera, with a CFUNCTYPE callback this object keeps alive. The callback copies a cached render of
``Scenario.default()`` (pose step ``pose_index``, noise-free, 12 bit shifted to 8 bit, rendered once per exposure)
into the buffer, cropped to the ROI; it only supports Mono8 (the fake camera sizes its buffers as width x height).
"""

from __future__ import annotations

import ctypes
import dataclasses
import gc
import threading

import numpy as np
import numpy.typing as npt

from livetrack.camera import CameraModel
from livetrack.sim.scenario import Scenario
from livetrack.sources.aravis_gi import gobject_pointer, libaravis, load_aravis

FILL_PATTERN = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32,
                                ctypes.c_uint32)
"""void (*ArvFakeCameraFillPattern) (ArvBuffer *, void *user_data, guint32 exposure_time_us, guint32 gain,
ArvPixelFormat)."""
MONO8 = 0x01080001
ADDRESS = "127.0.0.1"


class FakeGigECamera:
    """Start with ``start()``, pull the plug with ``stop()``; ``errors`` collects exceptions of the callback."""

    def __init__(self, serial: str = "LT01", pose_index: int = 0):
        self.serial = serial
        self.scenario = Scenario.default()
        frame = pose_index * len(self.scenario.exposure_factors)
        self.optical = self.scenario.formation.optical_image(self.scenario.placements_for(frame))
        self._images: dict[int, npt.NDArray[np.uint8]] = {}
        self._lock = threading.Lock()
        self.errors: list[BaseException] = []
        self.fills = 0
        self._gv = None
        self._callback = FILL_PATTERN(self._fill)
        lib = libaravis()
        lib.arv_fake_camera_set_fill_pattern.restype = None
        lib.arv_fake_camera_set_fill_pattern.argtypes = [ctypes.c_void_p, FILL_PATTERN, ctypes.c_void_p]
        self._lib = lib

    @property
    def device_id(self) -> str:
        """The id Aravis discovers the camera under."""
        return f"Aravis-Fake-{self.serial}"

    @property
    def camera_model(self) -> CameraModel:
        """The scenario's camera as delivered by this fake (8 bit)."""
        return dataclasses.replace(self.scenario.camera, bit_depth=8)

    @property
    def nominal_exposure_us(self) -> float:
        return self.scenario.nominal_exposure_us

    def image_at(self, exposure_us: int) -> npt.NDArray[np.uint8]:
        """The full (600, 960) 8-bit image the fake camera sends at this exposure."""
        with self._lock:
            image = self._images.get(exposure_us)
            if image is None:
                image12 = self.scenario.formation.render_from_optical(self.optical, float(exposure_us), 0.0,
                                                                      None, noise=False)
                image = (image12 >> 4).astype(np.uint8)
                self._images[exposure_us] = image
            return image

    def start(self) -> None:
        Aravis, _ = load_aravis()
        self._gv = Aravis.GvFakeCamera.new("lo", self.serial)
        if not self._gv.is_running():
            self._gv = None
            raise RuntimeError("the fake GigE Vision camera could not bind 127.0.0.1:3956 (port in use?)")
        fake = self._gv.get_fake_camera()
        self._lib.arv_fake_camera_set_fill_pattern(gobject_pointer(fake), self._callback, None)
        del fake

    def stop(self) -> None:
        """Stop serving (as if the camera's cable were pulled)."""
        self._gv = None
        gc.collect()

    @property
    def running(self) -> bool:
        return self._gv is not None

    def _fill(self, buffer: int, _data: int, exposure_us: int, _gain: int, pixel_format: int) -> None:
        try:
            lib = self._lib
            width, height = lib.arv_buffer_get_image_width(buffer), lib.arv_buffer_get_image_height(buffer)
            if pixel_format != MONO8 or width <= 0 or height <= 0:
                return
            source = self.image_at(int(exposure_us))
            out = np.zeros((height, width), np.uint8)
            h, w = min(height, source.shape[0]), min(width, source.shape[1])
            out[:h, :w] = source[:h, :w]
            data = lib.arv_buffer_get_data(buffer, None)
            ctypes.memmove(data, out.ctypes.data, out.nbytes)
            self.fills += 1
        except Exception as exc:  # never let an exception cross into C
            self.errors.append(exc)

    def __enter__(self) -> FakeGigECamera:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
