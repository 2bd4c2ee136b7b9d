"""Frame sources behind one protocol (``base.FrameSource``), chosen by URI.

=====================  ==========================================================================================
``sim:`` / ``sim:default`` / ``sim:FILE.yaml``  the simulated camera (``sim_source.SimSource``)
``replay:DIR``         a recording (format v1), at the recorded pace or as fast as possible (``replay.ReplaySource``)
``aravis:`` / ``aravis:DEVICE``  a GigE Vision / USB3 Vision camera through Aravis 0.8 (``aravis_source.AravisSource``)
``v4l2:/dev/videoN``   a V4L2 webcam through OpenCV (``v4l2_source.V4L2Source``)
=====================  ==========================================================================================

``open_source(uri, options)`` builds the source and opens it; options are validated here (unknown keys are
rejected with their name). docs/cameras.md lists every option with its unit and default.

Also here, shared by the live sources: ``LatestSlot`` (the bounded hand-off from an acquisition thread: one frame,
the newest; an unread frame is dropped, not queued) and ``Backoff`` (reconnect delays).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from livetrack.camera import CameraModel
from livetrack.config import checks as cc
from livetrack.sources.base import Frame, FrameSource, SourceError
from livetrack.targets.spec import TargetSpec

log = logging.getLogger(__name__)

SCHEMES = ("sim", "replay", "aravis", "v4l2")


def open_source(uri: str, options: Mapping[str, Any] | None = None) -> FrameSource:
    """Build and open the source named by ``uri`` (see the module docstring) with ``options``.

    Raises ``ConfigError`` for a malformed URI or a bad option (naming it), ``SourceError`` when the source cannot
    be opened (missing file, no camera, missing system package).
    """
    source = make_source(uri, options)
    source.open()
    return source


def check_source(uri: str, options: Mapping[str, Any] | None, path: str = "source") -> None:
    """Validate ``uri`` and ``options`` exactly as ``make_source`` does (scheme, every option's key and value),
    without opening anything, so that a config is refused at load (``dump-config`` as well as ``run``).

    Raises ``ConfigError``; what only opening can tell (a camera that is not there) is left to ``open``.
    """
    try:
        make_source(uri, options)
    except SourceError as exc:  # e.g. sim:FILE that does not exist
        raise cc.ConfigError(cc.join(path, "uri"), str(exc)) from None
    except OSError as exc:  # e.g. sim:NAME with a name too long for the file system
        shown = uri if len(uri) <= 80 else uri[:77] + "..."
        raise cc.ConfigError(cc.join(path, "uri"), f"cannot use {shown!r}: {exc.strerror or exc}") from None
    except cc.ConfigError as exc:  # the sources name "source" (the URI) and "source.KEY" (an option)
        if exc.path == "source":
            raise cc.ConfigError(cc.join(path, "uri"), exc.problem) from None
        if exc.path.startswith("source."):
            raise cc.ConfigError(f"{cc.join(path, 'options')}{exc.path[len('source'):]}", exc.problem) from None
        raise


def make_source(uri: str, options: Mapping[str, Any] | None = None) -> FrameSource:
    """Like ``open_source`` but does not open the source (``open()`` is the caller's)."""
    if not isinstance(uri, str) or ":" not in uri:
        raise cc.ConfigError("source", f"must be a URI SCHEME:ARGUMENT with SCHEME in {list(SCHEMES)}, got {uri!r}")
    scheme, _, argument = uri.partition(":")
    options = dict(options or {})
    if scheme == "sim":
        from livetrack.sources.sim_source import SimSource

        return SimSource.from_options(argument, options)
    if scheme == "replay":
        from livetrack.sources.replay import ReplaySource

        return ReplaySource.from_options(argument, options)
    if scheme == "aravis":
        from livetrack.sources.aravis_source import AravisSource

        return AravisSource.from_options(argument, options)
    if scheme == "v4l2":
        from livetrack.sources.v4l2_source import V4L2Source

        return V4L2Source.from_options(argument, options)
    raise cc.ConfigError("source", f"unknown scheme {scheme!r} in {uri!r} (known: {', '.join(SCHEMES)})")


# ---------------------------------------------------------------------------------------------- option helpers
def camera_option(options: Mapping[str, Any], key: str = "camera", path: str = "source") -> CameraModel | None:
    """A ``CameraModel`` given as such or as the path of a camera YAML file (``livetrack.camera.io.load_camera``)."""
    value = options.get(key)
    if value is None or isinstance(value, CameraModel):
        return value
    if isinstance(value, (str, Path)):
        from livetrack.camera.io import load_camera

        return load_camera(value)
    raise cc.ConfigError(cc.join(path, key), f"must be a camera file path or a CameraModel, got {value!r}")


def targets_option(options: Mapping[str, Any], key: str = "targets", path: str = "source") -> list[TargetSpec]:
    """Target specs given as a list of ``TargetSpec`` / plain dicts, or as the path of a targets YAML file."""
    value = options.get(key)
    if value is None:
        return []
    if isinstance(value, (str, Path)):
        from livetrack.targets.spec import load_targets

        return load_targets(value)
    if isinstance(value, (list, tuple)):
        return [item if isinstance(item, TargetSpec) else TargetSpec.from_dict(item, f"{cc.join(path, key)}[{i}]")
                for i, item in enumerate(value)]
    raise cc.ConfigError(cc.join(path, key), f"must be a targets file path or a list of targets, got {value!r}")


# ---------------------------------------------------------------------------------------------- live hand-off
class LatestSlot:
    """A one-frame hand-off between an acquisition thread and the reader: ``put`` replaces an unread frame
    (counted in ``dropped``) rather than queueing it, so the reader always gets the newest frame."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._frame: Frame | None = None
        self._closed = False
        self.dropped = 0

    def put(self, frame: Frame) -> None:
        with self._cond:
            if self._frame is not None:
                self.dropped += 1
            self._frame = frame
            self._cond.notify_all()

    def get(self, timeout_s: float) -> Frame | None:
        """The newest unread frame, waiting up to ``timeout_s``; None on timeout or once closed and empty."""
        deadline = time.monotonic() + max(0.0, timeout_s)
        with self._cond:
            while self._frame is None and not self._closed:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return None
                self._cond.wait(remaining)
            frame, self._frame = self._frame, None
            return frame

    def close(self) -> None:
        """Wake the reader; ``get`` returns what is left, then None at once."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    @property
    def closed(self) -> bool:
        return self._closed


class Backoff:
    """Exponential reconnect delays: ``initial_s``, doubled after each failure, capped at ``max_s``."""

    def __init__(self, initial_s: float = 0.5, max_s: float = 8.0) -> None:
        self.initial_s = initial_s
        self.max_s = max_s
        self.attempts = 0

    def next_delay_s(self) -> float:
        delay = min(self.max_s, self.initial_s * (2.0 ** self.attempts))
        self.attempts += 1
        return delay

    def reset(self) -> None:
        self.attempts = 0


__all__ = ["Backoff", "Frame", "FrameSource", "LatestSlot", "SourceError", "camera_option", "check_source",
           "make_source", "open_source", "targets_option"]
