"""``sim:`` -- the simulated camera: a scenario rendered frame after frame, looped, with its truth poses.

``sim:`` or ``sim:default`` is the built-in scenario, ``sim:PATH.yaml`` a scenario file
(``livetrack.sim.scenario``). Global frame i shows scenario frame ``i % len(scenario)`` (its pose and exposure);
``frame_id = i`` and ``timestamp_ns = start_ns + i / fps`` keep increasing across loops, and the noise differs
from loop to loop (seeded by the scenario seed and i, so a run is reproducible).

Realtime (default): a named thread renders one frame ahead and publishes frame i at ``t0 + i / fps`` into a
one-frame slot (``live = True``: an unread frame is replaced, counted in ``stats["dropped"]``). When rendering is
slower than the frame period the frame is published late, the schedule restarts from now (no burst to catch up),
``stats["late"]`` counts it and a warning gives the render time against the period (at most every 5 s).
Not realtime: each ``read`` renders the next frame at once (``live = False``, lossless, as fast as possible).
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from livetrack.camera import CameraModel
from livetrack.config import checks as cc
from livetrack.sim.scenario import Scenario
from livetrack.sources import LatestSlot
from livetrack.sources.base import Frame, SourceError
from livetrack.targets.spec import TargetSpec

log = logging.getLogger(__name__)

OPTIONS = ["realtime", "max_frames", "seed", "noise", "cache_mb", "prerender"]
LATE_WARNING_INTERVAL_S = 5.0


class SimSource:
    """The simulated camera (module docstring).

    Parameters
    ----------
    scenario : what to render.
    realtime : pace frames at ``scenario.fps`` in a render thread (True, live) or render on each read (False).
    max_frames : frames to deliver before ``read`` raises EOFError; None = loop forever.
    noise : sensor shot and read noise (False: the rounded expected image, for exact tests).
    cache_mb : memory for the per-pose optical images (the expensive part: ~0.16 s for 960x600, reused by all
        exposures and loops of that pose); least recently used ones are recomputed beyond it. Default 512.
    prerender : render the frames of one loop of the scenario at ``open`` and deliver copies of them in every
        loop (the noise then repeats from loop to loop): a camera as cheap as a real one, for measuring the
        pipeline at frame rates the renderer cannot reach. An exposure override (``set_exposure``) renders anew.
    """

    def __init__(self, scenario: Scenario, *, realtime: bool = True, max_frames: int | None = None,
                 noise: bool = True, cache_mb: float = 512.0, prerender: bool = False):
        self.scenario = scenario
        self.camera: CameraModel = scenario.camera_stating_encoding  # (sRGB or gamma-encoded output: stated)
        self.targets: list[TargetSpec] = list(scenario.targets)
        self.realtime = realtime
        self.live = realtime
        self.max_frames = max_frames
        self.noise = noise
        self.cache_bytes = int(cache_mb * 1e6)
        self.prerender = prerender
        self._prerendered: list[npt.NDArray[np.unsignedinteger]] = []
        self._optical: OrderedDict[int, npt.NDArray[np.float32]] = OrderedDict()
        self._lock = threading.Lock()
        self._exposure_override: tuple[float | None, float | None] = (None, None)
        self._next = 0
        self._slot = LatestSlot()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._opened = False
        self._counts = {"frames": 0, "late": 0}
        self._error: BaseException | None = None

    @classmethod
    def from_options(cls, argument: str, options: Mapping[str, Any]) -> SimSource:
        cc.mapping(options, "source", optional=OPTIONS)
        seed = cc.integer(options, "seed", "source", ge=0) if options.get("seed") is not None else None
        if argument in ("", "default"):
            scenario = Scenario.default(seed=seed)
        else:
            if not Path(argument).is_file():
                raise SourceError(f"sim:{argument}: no such scenario file")
            scenario = Scenario.from_file(argument, seed=seed)
        max_frames = (cc.integer(options, "max_frames", "source", ge=0)
                      if options.get("max_frames") is not None else None)
        return cls(scenario, realtime=cc.boolean(options, "realtime", "source", default=True),
                   max_frames=max_frames, noise=cc.boolean(options, "noise", "source", default=True),
                   cache_mb=cc.number(options, "cache_mb", "source", default=512.0, ge=0),
                   prerender=cc.boolean(options, "prerender", "source", default=False))

    # ------------------------------------------------------------------ protocol
    def open(self) -> None:
        if self._opened:
            raise SourceError("sim source is already open")
        self._opened = True
        log.info("sim: scenario %r, %d frames per loop at %g fps, %s, max_frames %s", self.scenario.name,
                 len(self.scenario), self.scenario.fps, "realtime" if self.realtime else "as fast as possible",
                 self.max_frames)
        if self.prerender:
            started = time.perf_counter()
            self._prerendered = [self._render(k).image for k in range(len(self.scenario))]
            log.info("sim: pre-rendered %d frames in %.1f s", len(self._prerendered), time.perf_counter() - started)
        if self.realtime:
            self._thread = threading.Thread(target=self._run, name="sim-render", daemon=True)
            self._thread.start()

    def read(self, timeout_s: float = 1.0) -> Frame | None:
        if not self._opened:
            raise SourceError("sim source is not open")
        if not self.realtime:
            if self._exhausted(self._next):
                raise EOFError("sim: max_frames reached")
            frame = self._render(self._next)
            self._next += 1
            self._counts["frames"] += 1
            return frame
        frame = self._slot.get(timeout_s)
        if frame is None and self._slot.closed:
            if self._error is not None:
                raise SourceError(f"sim: rendering failed: {self._error}") from self._error
            raise EOFError("sim: max_frames reached")
        return frame

    def close(self) -> None:
        self._stop.set()
        self._slot.close()
        if self._thread is not None:
            self._thread.join()
            self._thread = None

    def __enter__(self) -> SimSource:
        if not self._opened:
            self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def stats(self) -> dict[str, int]:
        return {**self._counts, "dropped": self._slot.dropped}

    # ------------------------------------------------------------------ exposure control
    def set_exposure(self, exposure_us: float | None = None, gain_db: float | None = None) -> tuple[float, float]:
        """Render from the next frame on at this exposure / gain instead of the scenario's (None keeps the
        current override or the scenario value). Returns the values that will be used."""
        with self._lock:
            old_exp, old_gain = self._exposure_override
            self._exposure_override = (old_exp if exposure_us is None else float(exposure_us),
                                       old_gain if gain_db is None else float(gain_db))
            exp, gain = self._exposure_override
        return (exp if exp is not None else self.scenario.nominal_exposure_us,
                gain if gain is not None else self.scenario.gain_db)

    # ------------------------------------------------------------------ rendering
    def _exhausted(self, i: int) -> bool:
        return self.max_frames is not None and i >= self.max_frames

    def _optical_image(self, k: int) -> npt.NDArray[np.float32]:
        step = self.scenario.pose_index(k)
        optical = self._optical.get(step)
        if optical is None:
            optical = self.scenario.formation.optical_image(self.scenario.placements_for(k))
            self._optical[step] = optical
            while len(self._optical) > 1 and sum(o.nbytes for o in self._optical.values()) > self.cache_bytes:
                self._optical.popitem(last=False)
        else:
            self._optical.move_to_end(step)
        return optical

    def _render(self, i: int) -> Frame:
        scenario = self.scenario
        k = i % len(scenario)
        factor = scenario.exposure_factors[k % len(scenario.exposure_factors)]
        with self._lock:
            override_exp, override_gain = self._exposure_override
        exposure_us = scenario.nominal_exposure_us * factor if override_exp is None else override_exp
        gain_db = scenario.gain_db if override_gain is None else override_gain
        if self._prerendered and override_exp is None and override_gain is None:
            image = self._prerendered[k].copy()
        else:
            rng = np.random.default_rng(np.random.SeedSequence([scenario.seed, 3, i]))
            image = scenario.formation.render_from_optical(self._optical_image(k), exposure_us, gain_db, rng,
                                                           self.noise)
        return Frame(image=image, frame_id=i, timestamp_ns=scenario.start_ns + round(i * 1e9 / scenario.fps),
                     host_timestamp_ns=time.time_ns(), exposure_us=float(exposure_us), gain_db=float(gain_db),
                     truth=scenario.truth_for(k),
                     meta={"scenario_frame": k, "pose_index": scenario.pose_index(k),
                           "exposure_factor": factor if override_exp is None else None})

    def _run(self) -> None:
        period_s = 1.0 / self.scenario.fps
        due = time.monotonic()
        last_warning = -LATE_WARNING_INTERVAL_S
        i = 0
        try:
            while not self._stop.is_set() and not self._exhausted(i):
                started = time.perf_counter()
                frame = self._render(i)
                render_s = time.perf_counter() - started
                now = time.monotonic()
                if now < due:
                    if self._stop.wait(due - now):
                        break
                elif now - due > period_s:
                    self._counts["late"] += 1
                    if now - last_warning >= LATE_WARNING_INTERVAL_S:
                        log.warning("sim: rendering is slower than %g fps: frame %d took %.0f ms for a %.0f ms "
                                    "period (%d late frames so far)", self.scenario.fps, i, render_s * 1e3,
                                    period_s * 1e3, self._counts["late"])
                        last_warning = now
                    due = now
                self._slot.put(dataclasses.replace(frame, host_timestamp_ns=time.time_ns()))
                self._counts["frames"] += 1
                due += period_s
                i += 1
        except Exception as exc:  # reported by read() as SourceError
            log.exception("sim: rendering failed at frame %d", i)
            self._error = exc
        finally:
            self._slot.close()
