"""Console sink: one line per printed frame (frame id, then id, distance, delta, latency per target), at most
one frame every ``every_s`` seconds. It is a sink like the others, so a slow terminal never stalls tracking."""

from __future__ import annotations

import sys
import time
from typing import IO, Any, Literal

from livetrack.sinks.base import TrackedFrame


def format_line(item: TrackedFrame) -> str:
    frame = item.frame
    exposure = "unknown" if frame.exposure_us is None else f"{frame.exposure_us:8.1f} us"
    parts = [f"frame {frame.frame_id:6d}", f"exp {exposure}", f"latency {item.latency_ms:6.1f} ms"]
    unfitted = [f for f in item.result.failures if f.stage != "pose_fit"]  # failed fits are among the targets
    if not item.result.targets and not unfitted:
        parts.append("no target")
    for t in item.result.targets:
        state = "" if t.fit.ok else f" FAILED ({t.fit.reason})"
        parts.append(f"id {t.target_id}: {t.fit.pose.distance_m:7.4f} m delta {t.fit.delta_px:+6.3f} px{state}")
    for f in unfitted:
        parts.append(f"id {f.target_id}: no pose ({f.stage}: {f.reason})")
    return "  ".join(parts)


class ConsoleSink:
    consumes: Literal["results"] = "results"

    def __init__(self, every_s: float = 0.5, stream: IO[str] | None = None, name: str = "console"):
        self.name = name
        self.every_s = every_s
        self._stream = stream
        self._next_ns = 0
        self._printed = 0

    def open(self) -> None:
        pass

    def handle(self, item: TrackedFrame) -> None:
        now = time.monotonic_ns()
        if now < self._next_ns:
            return
        self._next_ns = now + int(self.every_s * 1e9)
        print(format_line(item), file=self._stream or sys.stdout, flush=True)
        self._printed += 1

    def close(self) -> None:
        pass

    @property
    def stats(self) -> dict[str, Any]:
        return {"printed": self._printed}
