"""The live pipeline's threads and hand-offs, with a fake source and a fake tracker (fast, deterministic counts).

Real sources and the real tracker are exercised in test_run_cli.py and test_sinks.py.
"""

from __future__ import annotations

import threading
import time
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from livetrack.camera import CameraModel
from livetrack.estimator.tracker import FrameResult, SearchOutcome
from livetrack.pipeline import Pipeline, PipelineOptions
from livetrack.sinks.runner import DropSlot, SlotClosed
from livetrack.sources.base import Frame, SourceError
from livetrack.targets.spec import TargetSpec

CAMERA = CameraModel(width=64, height=48, fx=60.0, fy=60.0, cx=31.5, cy=23.5)
TARGETS = [TargetSpec.default(3, 0.1)]
RUN_TIMEOUT_S = 30.0


class FakeSource:
    """``n`` frames (None: endless); live sources produce a frame every ``period_s`` whether read or not."""

    def __init__(self, n: int | None = 20, live: bool = False, period_s: float = 0.0, fail_at: int | None = None,
                 timestamp_ns: int | None = None):
        self.camera = CAMERA
        self.targets = TARGETS
        self.live = live
        self.n = n
        self.period_s = period_s
        self.fail_at = fail_at
        self.device_start_ns = timestamp_ns
        self.next_id = 0
        self.closed = False
        self._t0 = time.monotonic()

    def open(self) -> None:
        pass

    def read(self, timeout_s: float = 1.0) -> Frame | None:
        if self.n is not None and self.next_id >= self.n:
            raise EOFError
        if self.fail_at is not None and self.next_id >= self.fail_at:
            raise SourceError("camera unplugged")
        if self.live and self.period_s > 0:
            due = self._t0 + self.next_id * self.period_s
            wait = due - time.monotonic()
            if wait > timeout_s:
                time.sleep(timeout_s)
                return None
            time.sleep(max(wait, 0.0))
        i = self.next_id
        self.next_id += 1
        now = time.time_ns()
        device = now if self.device_start_ns is None else self.device_start_ns + i * 1000
        return Frame(image=np.full((48, 64), i % 256, np.uint8), frame_id=i, timestamp_ns=device,
                     host_timestamp_ns=now, exposure_us=100.0 + i, gain_db=0.0)

    def close(self) -> None:
        self.closed = True

    @property
    def stats(self) -> dict[str, int]:
        return {"frames": self.next_id}


class FakeTracker:
    """Returns an empty result after ``delay_s``; records the frames it saw (by their first pixel)."""

    def __init__(self, delay_s: float = 0.0, fail_on: set[int] | None = None):
        self.delay_s = delay_s
        self.fail_on = fail_on or set()
        self.seen: list[int] = []

    def process(self, image: np.ndarray, exposure_us: float | None = None) -> FrameResult:
        value = int(image[0, 0])
        self.seen.append(value)
        if value in self.fail_on:
            raise RuntimeError("estimator bug")
        if self.delay_s:
            time.sleep(self.delay_s)
        return FrameResult([], {"detect_ms": 0.1, "pose_ms": 0.2, "total_ms": 0.3})


class ListSink:
    """Collects what it is given, optionally slowly or failing."""

    def __init__(self, name: str = "list", consumes: str = "results", delay_s: float = 0.0, fail: bool = False,
                 fail_open: bool = False):
        self.name = name
        self.consumes = consumes
        self.delay_s = delay_s
        self.fail = fail
        self.fail_open = fail_open
        self.items: list[Any] = []
        self.opened_in: str | None = None
        self.closed = False

    def open(self) -> None:
        self.opened_in = threading.current_thread().name
        if self.fail_open:
            raise OSError("port in use")

    def handle(self, item: Any) -> None:
        if self.delay_s:
            time.sleep(self.delay_s)
        if self.fail:
            raise ValueError("sink bug")
        self.items.append(item)

    def close(self) -> None:
        self.closed = True

    @property
    def stats(self) -> dict[str, Any]:
        return {"items": len(self.items)}


def run_bounded(pipeline: Pipeline, timeout_s: float = RUN_TIMEOUT_S):
    pipeline.start()
    done = pipeline.wait(timeout_s)
    summary = pipeline.close()
    assert done, "pipeline did not finish in time"
    return summary


# ---------------------------------------------------------------------------------------------- DropSlot
def test_drop_slot_drops_oldest_and_counts():
    slot: DropSlot[int] = DropSlot(2)
    for i in range(5):
        assert slot.put(i)
    assert slot.dropped == 3
    assert [slot.get(0.1), slot.get(0.1)] == [3, 4]
    assert slot.get(0.01) is None
    slot.close()
    assert not slot.put(9)
    with pytest.raises(SlotClosed):
        slot.get(0.1)


def test_lossless_slot_blocks_until_read_and_can_be_aborted():
    slot: DropSlot[int] = DropSlot(1, lossless=True)
    slot.put(0)
    done = threading.Event()

    def producer() -> None:
        slot.put(1)
        done.set()

    thread = threading.Thread(target=producer)
    thread.start()
    assert not done.wait(0.2)  # blocked: the slot is full
    assert slot.get(1.0) == 0
    assert done.wait(5.0)
    thread.join(5.0)
    assert slot.get(1.0) == 1 and slot.dropped == 0
    slot.put(2)
    abort = threading.Event()
    abort.set()
    assert slot.put(3, abort=abort) is False  # full and aborted: gives up instead of waiting


def test_slot_close_wakes_waiting_reader():
    slot: DropSlot[int] = DropSlot(1)
    result: list[Any] = []

    def reader() -> None:
        try:
            slot.get(10.0)
        except SlotClosed:
            result.append("closed")

    thread = threading.Thread(target=reader)
    thread.start()
    time.sleep(0.05)
    slot.close()
    thread.join(5.0)
    assert result == ["closed"]


# ---------------------------------------------------------------------------------------------- pipeline
def test_replay_like_source_is_lossless_and_in_order():
    tracker = FakeTracker(delay_s=0.002)
    sink = ListSink()
    pipeline = Pipeline(FakeSource(n=30), tracker, [sink], PipelineOptions(sink_queue_size=100))
    assert pipeline.lossless
    summary = run_bounded(pipeline)
    assert summary.frames_processed == summary.frames_acquired == 30
    assert summary.dropped_before_processing == 0
    assert tracker.seen == list(range(30))
    assert [t.frame.frame_id for t in sink.items] == list(range(30))
    assert [t.sequence for t in sink.items] == list(range(30))
    assert summary.stopped_by == "end of source"
    assert sink.opened_in == "livetrack-sink-list" and sink.closed
    assert pipeline.source.closed
    assert all(t.latency_ms >= 0 for t in sink.items)
    assert summary.latency_ms["p50"] is not None and summary.stage_ms["track_ms"]["p50"] is not None


def test_live_source_drops_oldest_when_tracking_is_slow():
    source = FakeSource(n=40, live=True, period_s=0.002)
    tracker = FakeTracker(delay_s=0.03)
    pipeline = Pipeline(source, tracker, [], PipelineOptions())
    assert not pipeline.lossless
    summary = run_bounded(pipeline)
    assert summary.frames_acquired == 40
    assert summary.frames_processed < 40
    assert summary.dropped_before_processing == 40 - summary.frames_processed
    assert tracker.seen == sorted(tracker.seen)  # newest-first never goes backwards
    assert tracker.seen[-1] == 39  # the last frame is processed, older ones were dropped


def test_max_frames_bounds_an_endless_live_source():
    summary = run_bounded(Pipeline(FakeSource(n=None, live=True, period_s=0.001), FakeTracker(),
                                   [], PipelineOptions(max_frames=7)))
    assert summary.frames_processed == 7
    assert summary.stopped_by == "max_frames"


def test_max_frames_lossless_reads_only_what_it_processes():
    source = FakeSource(n=None)
    summary = run_bounded(Pipeline(source, FakeTracker(), [], PipelineOptions(max_frames=5)))
    assert summary.frames_processed == 5 and summary.frames_acquired == 5


def test_slow_sink_never_blocks_tracking():
    slow = ListSink("slow", delay_s=0.2)
    fast = ListSink("fast")
    pipeline = Pipeline(FakeSource(n=50), FakeTracker(), [slow, fast], PipelineOptions(sink_queue_size=2),
                        sink_queue_sizes={"fast": 100})
    pipeline.start()
    assert pipeline.wait(RUN_TIMEOUT_S)
    handled_by_slow_then = len(slow.items)
    summary = pipeline.close()
    # every frame was tracked and reached the fast sink, while the slow one had handled only a few
    assert summary.frames_processed == 50 and len(fast.items) == 50
    assert handled_by_slow_then < 50
    assert summary.sinks["slow"]["dropped"] > 0
    assert summary.sinks["slow"]["dropped"] + summary.sinks["slow"]["handled"] == 50
    assert summary.sinks["fast"]["dropped"] == 0


def test_failing_sink_is_counted_and_the_run_goes_on():
    bad = ListSink("bad", fail=True)
    summary = run_bounded(Pipeline(FakeSource(n=10), FakeTracker(), [bad], PipelineOptions(sink_queue_size=20)))
    assert summary.frames_processed == 10
    assert summary.sinks["bad"]["errors"] == 10 and bad.closed


def test_sink_that_cannot_open_fails_start_and_closes_everything():
    good = ListSink("good")
    source = FakeSource(n=10)
    pipeline = Pipeline(source, FakeTracker(), [good, ListSink("bad", fail_open=True)])
    with pytest.raises(OSError, match="port in use"):
        pipeline.start()
    assert good.closed and source.closed


def test_tracker_exception_skips_the_frame():
    summary = run_bounded(Pipeline(FakeSource(n=6), FakeTracker(fail_on={2, 4}), [], PipelineOptions()))
    assert summary.frames_processed == 4 and summary.process_errors == 2


def test_source_error_ends_the_run_and_is_reported():
    summary = run_bounded(Pipeline(FakeSource(n=None, fail_at=3), FakeTracker(), [], PipelineOptions()))
    assert summary.frames_processed == 3
    assert "camera unplugged" in (summary.source_error or "")
    assert summary.stopped_by == "source error"


def test_stop_from_another_thread_ends_an_endless_run():
    pipeline = Pipeline(FakeSource(n=None, live=True, period_s=0.005), FakeTracker(), [ListSink()])
    pipeline.start()
    threading.Timer(0.3, pipeline.stop, args=("test",)).start()
    assert pipeline.wait(RUN_TIMEOUT_S)
    summary = pipeline.close()
    assert summary.stopped_by == "test" and summary.frames_processed > 0
    assert not any(t.name.startswith("livetrack-") for t in threading.enumerate())


def test_frame_sinks_get_every_acquired_frame_even_when_processing_drops():
    recorder = ListSink("rec", consumes="frames")
    source = FakeSource(n=30, live=True, period_s=0.002)
    summary = run_bounded(Pipeline(source, FakeTracker(delay_s=0.02), [recorder],
                                   PipelineOptions(), sink_queue_sizes={"rec": 100}))
    assert summary.frames_processed < 30
    assert [f.frame_id for f in recorder.items] == list(range(30))


def test_device_latency_only_when_device_clock_is_the_host_clock():
    host_clock = ListSink("a")
    run_bounded(Pipeline(FakeSource(n=3), FakeTracker(), [host_clock]))
    assert all(t.device_latency_ms is not None and t.device_latency_ms >= 0 for t in host_clock.items)
    other_clock = ListSink("b")
    summary = run_bounded(Pipeline(FakeSource(n=3, timestamp_ns=5_000), FakeTracker(), [other_clock]))
    assert all(t.device_latency_ms is None for t in other_clock.items)
    assert summary.device_latency_ms["p50"] is None


def test_summary_format_names_every_stage_and_drop():
    summary = run_bounded(Pipeline(FakeSource(n=5), FakeTracker(), [ListSink("out")]))
    text = summary.format()
    for word in ("5 frames processed", "drops:", "sink out", "latency", "detect_ms", "pose_ms", "outside_track_ms"):
        assert word in text



def test_kernels_are_warmed_up_before_acquisition_and_the_first_frames_are_reported(monkeypatch):
    """``start`` loads the compiled kernels (``estimator.warm``) before the first frame is read; the summary gives how
    long that took and the first frame's latency, first search and first tracked frame."""
    from livetrack.estimator import warm

    events: list[str] = []
    monkeypatch.setattr(warm, "warm_up", lambda: events.append("warm") or 0.25)

    class Source(FakeSource):
        def read(self, timeout_s: float = 1.0) -> Frame | None:
            events.append("read")
            return super().read(timeout_s)

    tracker = FakeTrackingTracker(search_s=0.0, first_search_s=0.05, track_s=0.001)
    summary = run_bounded(Pipeline(Source(n=30, live=True, period_s=0.005), tracker, [],
                                   PipelineOptions(search_worker=True)))
    assert events[0] == "warm" and events.count("warm") == 1
    assert summary.warm_up_s == 0.25
    first = summary.first_frames_ms
    assert first["search"] >= 50.0 and first["latency"] >= 50.0 and 0.0 < first["tracked"] < 50.0
    assert "compiled kernels ready in 0.25 s" in summary.format()
    single = run_bounded(Pipeline(FakeSource(n=3), FakeTracker(), []))  # every result has detect_ms: searches
    assert single.first_frames_ms["search"] is not None and single.first_frames_ms["tracked"] is None


# ---------------------------------------------------------------------------------------------- search worker
class FakeTrackingTracker:
    """A tracker in tracking mode: ``search`` takes ``search_s`` (``first_search_s`` the first time), ``track``
    takes ``track_s`` and loses the target on the frames in ``lose_on`` (by first pixel); a verify search is due
    every ``verify_every`` tracked frames. Records which thread ran what."""

    def __init__(self, search_s: float = 0.0, first_search_s: float | None = None, track_s: float = 0.0,
                 verify_every: int = 5, lose_on: set[int] | None = None):
        self.options = SimpleNamespace(tracking=True)
        self.search_s, self.first_search_s, self.track_s = search_s, first_search_s, track_s
        self.verify_every = verify_every
        self.lose_on = lose_on or set()
        self.kept = False
        self.since_search = 0
        self.searched: list[int] = []
        self.tracked: list[int] = []
        self.threads: dict[str, set[str]] = {"track": set(), "search": set(), "adopt": set()}

    @staticmethod
    def _result(value: int, kind: str) -> FrameResult:
        target = SimpleNamespace(target_id=1, fit=SimpleNamespace(ok=True), frame=value, kind=kind)
        return FrameResult([target], {"detect_ms": 0.0, "pose_ms": 0.0, "total_ms": 0.0})

    @property
    def search_due(self) -> bool:
        return not self.kept or self.since_search + 1 >= self.verify_every

    def track(self, image: np.ndarray, exposure_us: float | None = None) -> FrameResult | None:
        self.threads["track"].add(threading.current_thread().name)
        value = int(image[0, 0])
        if not self.kept or value in self.lose_on:
            return None
        time.sleep(self.track_s)
        self.tracked.append(value)
        self.since_search += 1
        return self._result(value, "tracked")

    def search(self, image: np.ndarray, exposure_us: float | None = None) -> SearchOutcome:
        self.threads["search"].add(threading.current_thread().name)
        value = int(image[0, 0])
        delay = self.first_search_s if (self.first_search_s is not None and not self.searched) else self.search_s
        self.searched.append(value)
        time.sleep(delay)
        return SearchOutcome(self._result(value, "searched"), [], image.shape)

    def adopt(self, found: SearchOutcome, *, keep_current: bool = False, with_motion: bool = True) -> None:
        self.threads["adopt"].add(threading.current_thread().name)
        self.kept = True
        self.since_search = 0

    def process(self, image: np.ndarray, exposure_us: float | None = None) -> FrameResult:
        raise AssertionError("with a search worker the pipeline never calls process()")


def test_search_worker_is_on_for_a_live_tracking_source_only():
    assert Pipeline(FakeSource(live=True), FakeTrackingTracker(), []).search_worker
    assert not Pipeline(FakeSource(live=False), FakeTrackingTracker(), []).search_worker  # replay: reproducible
    assert not Pipeline(FakeSource(live=True), FakeTracker(), []).search_worker  # no track()/search()
    assert Pipeline(FakeSource(live=False), FakeTrackingTracker(), [],
                    PipelineOptions(search_worker=True)).search_worker


def test_a_slow_search_does_not_delay_the_tracked_frames_behind_it():
    # frames every 10 ms; each verify search (one in 5 tracked frames) takes 300 ms, a tracked frame 1 ms
    source = FakeSource(n=80, live=True, period_s=0.01)
    tracker = FakeTrackingTracker(search_s=0.3, first_search_s=0.0, track_s=0.001, verify_every=5)
    sink = ListSink()
    summary = run_bounded(Pipeline(source, tracker, [sink], PipelineOptions(sink_queue_size=1000)))
    assert tracker.threads["search"] == {"livetrack-search"}
    assert tracker.threads["track"] == tracker.threads["adopt"] == {"livetrack-process"}
    tracked = [t for t in sink.items if t.result.targets and t.result.targets[0].kind == "tracked"]
    assert len(tracked) >= 40 and summary.searches["run"] >= 2
    # a tracked frame waits for no search: far below the 300 ms one takes (generous for a loaded machine)
    assert max(t.latency_ms for t in tracked) < 150.0, [(t.frame.frame_id, t.stage_ms) for t in tracked
                                                        if t.latency_ms >= 150.0]
    assert summary.searches["merged"] >= 1  # the first frame (nothing tracked yet) went out with its search
    ids = [t.frame.frame_id for t in sink.items]
    assert ids == sorted(set(ids))
    assert [t.sequence for t in sink.items] == list(range(len(sink.items)))


@pytest.mark.parametrize("search_s", [0.0, 0.004])
def test_with_a_search_worker_a_finite_source_loses_no_frame_and_keeps_frame_order(search_s):
    # lossless: every frame goes out exactly once, in order; frames whose target was lost wait for their search
    source = FakeSource(n=120)
    tracker = FakeTrackingTracker(search_s=search_s, track_s=0.0005, verify_every=4,
                                  lose_on=set(range(7, 120, 9)))
    sink = ListSink()
    pipeline = Pipeline(source, tracker, [sink], PipelineOptions(sink_queue_size=1000, search_worker=True))
    summary = run_bounded(pipeline)
    assert [t.frame.frame_id for t in sink.items] == list(range(120))
    assert [t.sequence for t in sink.items] == list(range(120))
    assert summary.frames_processed == summary.frames_acquired == 120
    poses = [t.frame.frame_id for t in sink.items for _ in t.result.targets]
    assert poses == sorted(set(poses))  # each target's pose in frame order, once per frame
    lost = [t for t in sink.items if t.frame.frame_id in tracker.lose_on]
    assert all(t.result.targets and t.result.targets[0].kind == "searched" for t in lost)  # waited for it
    counts = summary.searches
    assert counts["requested"] == counts["run"] + counts["replaced"] and counts["errors"] == 0
    assert counts["merged"] + counts["late"] <= counts["requested"]


def test_search_worker_stops_at_max_frames_and_joins():
    pipeline = Pipeline(FakeSource(n=None, live=True, period_s=0.002),
                        FakeTrackingTracker(search_s=0.05, track_s=0.0005), [], PipelineOptions(max_frames=25))
    summary = run_bounded(pipeline)
    assert summary.frames_processed == 25 and summary.stopped_by == "max_frames"
    assert not pipeline._search.is_alive()


def test_a_hung_search_neither_holds_tracked_frames_nor_hangs_shutdown():
    """The first search is quick, then every search hangs 3 s: tracked frames go on, the run ends in time.

    What the hang must not do is told apart from what CPU load does on a shared machine: a live source's frame
    that the processing thread has not taken before the next one arrives is replaced in the acquisition slot
    (counted there; on a loaded machine 13 of 30 frames were, every 5 ms). A frame held by the hung search would
    instead wait in the reorder buffer (``search_wait_ms``, then be dropped unprocessed: a tracked frame missing
    from the output), or stall the processing thread (a gap in the hand-offs, and a run past its bound)."""
    wait_ms = 100.0
    tracker = FakeTrackingTracker(search_s=3.0, first_search_s=0.0, track_s=0.0005, verify_every=3)
    sink = ListSink()
    pipeline = Pipeline(FakeSource(n=30, live=True, period_s=0.005), tracker, [sink],
                        PipelineOptions(sink_queue_size=1000, search_wait_ms=wait_ms, sink_close_timeout_s=0.3))
    t0 = time.monotonic()
    summary = run_bounded(pipeline)
    assert time.monotonic() - t0 < 2.5
    ids = [t.frame.frame_id for t in sink.items]
    assert ids == sorted(set(ids)) and summary.frames_processed == len(ids)
    assert len(tracker.searched) == 2  # the quick first search, then the hung one (still running at the end)
    hung = tracker.searched[1]
    after = [t for t in sink.items if t.frame.frame_id > hung]
    assert len(after) >= 5 and all(t.result.targets[0].kind == "tracked" for t in after)
    # every tracked frame went out, none waited for the hung search, and the processing thread never stalled as
    # long as a held frame would have waited
    assert set(tracker.tracked) <= set(ids)
    assert all(t.stage_ms["reorder_wait_ms"] < wait_ms for t in after)
    assert (np.diff([t.handoff_ns for t in after]) / 1e6).max() < wait_ms
    # the others were replaced unprocessed in the acquisition slot (load), or had no pose (before the first
    # search was adopted)
    assert len(ids) + pipeline._slot.dropped + pipeline._dropped_unprocessed == summary.frames_acquired == 30


class ScenarioSource:
    """The frames of a simulated scenario, one every ``period_s`` at most (a finite, lossless source like a replay
    at its recorded pace)."""

    live = False

    def __init__(self, scenario: Any, period_s: float = 0.0):
        self.camera, self.targets = scenario.camera, list(scenario.targets)
        self.frames = list(scenario.frames())
        self.period_s = period_s
        self.next_id = 0

    def read(self, timeout_s: float = 1.0) -> Frame | None:
        if self.next_id >= len(self.frames):
            raise EOFError
        time.sleep(self.period_s)
        sim = self.frames[self.next_id]
        now = time.time_ns()
        frame = Frame(image=sim.image, frame_id=self.next_id, timestamp_ns=now, host_timestamp_ns=now,
                      exposure_us=sim.exposure_us, gain_db=0.0)
        self.next_id += 1
        return frame

    def close(self) -> None:
        pass

    @property
    def stats(self) -> dict[str, int]:
        return {"frames": self.next_id}


def test_with_a_search_worker_a_lost_target_leaves_the_others_tracked_and_is_found_again():
    """The real tracker, two targets, one occluded for 4 frames (``test_tracker.occlusion_scene``), a frame every
    30 ms: every frame goes out once, in order, with target 3; 5 is absent while occluded and tracked again at the
    end (found by a window search after it is back: one in 3 frames when the search thread is idle)."""
    from livetrack.estimator.tracker import Tracker, TrackerOptions
    from tests.test_tracker import occlusion_scene

    source = ScenarioSource(occlusion_scene(n_back=14), period_s=0.03)
    tracker = Tracker(source.camera, source.targets, TrackerOptions(tracking=True, tracking_verify_every=3))
    sink = ListSink()
    summary = run_bounded(Pipeline(source, tracker, [sink], PipelineOptions(sink_queue_size=1000,
                                                                              search_worker=True)))
    assert [t.frame.frame_id for t in sink.items] == list(range(21)) and summary.frames_processed == 21
    ids = [sorted(t.target_id for t in item.result.targets) for item in sink.items]
    print("ids:", ids, summary.searches)
    assert all(3 in frame_ids for frame_ids in ids)
    assert all(ids[k] == [3] for k in range(3, 7)) and ids[-1] == [3, 5]


class LosingTracker(FakeTrackingTracker):
    """``FakeTrackingTracker`` whose kept target 2 is lost (target 1 stays tracked) on the frames ``lose_two_on``:
    ``track`` returns target 1 alone, and a lost-only search is due until one is adopted."""

    def __init__(self, lose_two_on: set[int], **kwargs: Any):
        super().__init__(**kwargs)
        self.lose_two_on = lose_two_on
        self.lost_pending = False
        self.requests: list[tuple[int, bool]] = []  # (frame, lost_only) of each search

    @property
    def search_due(self) -> bool:
        return self.lost_pending or super().search_due

    @property
    def lost_search_due(self) -> bool:
        return self.lost_pending and not super().search_due

    def track(self, image: np.ndarray, exposure_us: float | None = None) -> FrameResult | None:
        result = super().track(image, exposure_us)
        if result is not None and int(image[0, 0]) in self.lose_two_on:
            self.lost_pending = True
        return result

    def search(self, image: np.ndarray, exposure_us: float | None = None, *, lost_only: bool = False
               ) -> SearchOutcome:
        self.requests.append((int(image[0, 0]), lost_only))
        return super().search(image, exposure_us)

    def adopt(self, found: SearchOutcome, *, keep_current: bool = False, with_motion: bool = True) -> None:
        super().adopt(found, keep_current=keep_current, with_motion=with_motion)
        self.lost_pending = False


def test_a_target_lost_while_others_are_tracked_gets_a_lost_only_search_and_its_frame_goes_out_at_once():
    # lossless, searches instant: each frame where a target is lost goes out tracked, and the search asked for
    # next (its frame's, or a later one's when the worker was busy) looks for the lost target only
    tracker = LosingTracker(lose_two_on={6, 17, 31}, track_s=0.0005, verify_every=8)
    sink = ListSink()
    summary = run_bounded(Pipeline(FakeSource(n=40), tracker, [sink],
                                   PipelineOptions(sink_queue_size=1000, search_worker=True)))
    assert [t.frame.frame_id for t in sink.items] == list(range(40)) and summary.frames_processed == 40
    kinds = {t.frame.frame_id: t.result.targets[0].kind for t in sink.items}
    assert all(kinds[k] == "tracked" for k in tracker.lose_two_on)
    lost_only = [frame for frame, only in tracker.requests if only]
    assert lost_only, tracker.requests  # (the worker may be busy with a verify search when a target is lost)
    assert min(lost_only) >= min(tracker.lose_two_on), tracker.requests  # none before a target was lost
