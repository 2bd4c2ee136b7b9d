"""The tracker: one call per frame, no I/O, no threads (``Tracker.process(image, exposure_us) -> FrameResult``).

Modules: ``tracker`` (the ``Tracker`` class: search, track, the per-target estimate and pose fit), ``options``
(``TrackerOptions`` and the constants tuning its steps), ``results`` (what it hands out, and their plain-JSON
views), ``checks`` (checks and corrections of a pose fit), ``windows`` (search windows, edge profile reach,
grouping detections), ``tracks`` (what tracking keeps of a target, its motion and prediction), ``contrast``
(the contrast shared by clipped edge profiles), ``target_model_pose`` (the 2-D target model's pose in a search
and in tracked frames), ``delta_cache`` (the exposure bias kept per exposure).
"""

from livetrack.estimator.tracker.checks import DOTS_SCALE_NOISE
from livetrack.estimator.tracker.delta_cache import DELTA_CACHE_REL_TOL, DELTA_CACHE_SIZE
from livetrack.estimator.tracker.options import CLIP_MARGIN_FRACTION, TrackerOptions
from livetrack.estimator.tracker.results import (
    FrameResult,
    SearchOutcome,
    TargetFailure,
    TargetResult,
    target_failure_to_dict,
    target_result_to_dict,
)
from livetrack.estimator.tracker.tracker import Tracker
from livetrack.estimator.tracker.windows import group_levels

__all__ = [
    "CLIP_MARGIN_FRACTION",
    "DELTA_CACHE_REL_TOL",
    "DELTA_CACHE_SIZE",
    "DOTS_SCALE_NOISE",
    "FrameResult",
    "SearchOutcome",
    "TargetFailure",
    "TargetResult",
    "Tracker",
    "TrackerOptions",
    "group_levels",
    "target_failure_to_dict",
    "target_result_to_dict",
]
