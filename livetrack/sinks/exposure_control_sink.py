"""Auto-exposure as an output (config ``exposure_control``, off by default): on its own thread, fed the newest
processed frame (queue of 1), it runs ``livetrack.exposure_control.ExposureController`` and writes the exposure
to the source (``set_exposure``: sim, Aravis, V4L2; thread-safe in each). The tracker never waits for it."""

from __future__ import annotations

import logging
import math
from typing import Any, Literal

from livetrack.camera.encoding import linear_dn
from livetrack.exposure_control import ExposureController, ExposureControlOptions
from livetrack.sinks.base import TrackedFrame

log = logging.getLogger(__name__)


class ExposureControlSink:
    consumes: Literal["results"] = "results"

    def __init__(self, source: Any, full_scale_dn: float, options: ExposureControlOptions,
                 name: str = "exposure_control", encoding: str = "linear"):
        if not callable(getattr(source, "set_exposure", None)):
            raise ValueError(f"exposure_control: the source {type(source).__name__} cannot set its exposure")
        self.name = name
        self.source = source
        # an encoded camera (sRGB, a gamma): metered in linear light, as exposure scales it
        self.controller = ExposureController(full_scale_dn, options,
                                             linear_dn(encoding, round(math.log2(full_scale_dn + 1))))
        self._set = 0
        self._last_us: float | None = None

    def open(self) -> None:
        pass

    def handle(self, item: TrackedFrame) -> None:
        new = self.controller.update(item.frame.image, item.result, item.frame.exposure_us)
        if new is None:
            return
        applied = self.source.set_exposure(exposure_us=new)
        self._set += 1
        if applied and applied[0] is not None:  # the camera's rounding: wait for what it really uses
            self.controller.applied(float(applied[0]))
            new = float(applied[0])
        self._last_us = new
        log.debug("exposure_control: exposure %.1f us", new)

    def close(self) -> None:
        pass

    @property
    def stats(self) -> dict[str, Any]:
        return {"exposure_changes": self._set, "last_exposure_us": self._last_us}
