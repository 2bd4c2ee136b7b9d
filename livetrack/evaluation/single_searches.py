"""One search per frame: the distance error of single targets printed with and without a white sheet, over-exposed,
each frame posed by a fresh tracker (what a first frame, or a camera that never tracks, gets).

The detection sweep (``evaluation.detection``) runs one tracker over each scene's exposures in order, so its clipped
frames have the blur of the clean frames before them; here nothing is known beforehand. Scenes come from
``detection.make_case``: one target of 0.2, 1 or 5 % of the frame (tilted 0, 30 and 50 degrees), on grey, carpet,
gradient and foliage ground, on the two ordinary cameras of the sweep, each at x4, x8, x16 and x32 of the nominal
exposure. A target without a sheet has the ground on the bright side of its outer circle: how much of the white's
exposure bias that edge takes is what ``tracker.contrast._outer_bias_share`` and ``Tracker._dots_guided`` set."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass

import numpy as np

from livetrack.evaluation import detection
from livetrack.sim.scenario import Scenario

GROUNDS = ("grey", "carpet", "gradient", "foliage")
SIZES = ((0.002, 0.0), (0.01, 30.0), (0.05, 50.0))  # (share of the frame, tilt in degrees)
EXPOSURES = (4.0, 8.0, 16.0, 32.0)
CAMERAS = ("1920x1200-12bit", "1280x800-8bit")
SEED_BASE = 8000


@dataclass(frozen=True)
class SearchOutcome:
    """One frame: its scene and the found target's signed distance error (percent; None when not found)."""

    ground: str
    sheet: str
    seed: int
    area_fraction: float
    tilt_deg: float
    exposure_factor: float
    camera: str
    distance_error_pct: float | None


def run(grounds: Sequence[str] = GROUNDS, seeds: int = 4, sheets: Sequence[str] = ("none", "2.8"),
        exposures: Sequence[float] = EXPOSURES,
        progress: Callable[[str], None] | None = None) -> list[SearchOutcome]:
    """Every scene (ground x seed x size x sheet), each exposure searched by a fresh tracker."""
    out = []
    for sheet in sheets:
        for ground in grounds:
            for seed in range(seeds):
                camera = CAMERAS[seed % 2]
                for area, tilt in SIZES:
                    try:
                        case = detection.make_case("s", "single", ground, camera, [(area, tilt)], tuple(exposures),
                                                   SEED_BASE + seed, sheet="none" if sheet == "none" else float(sheet))
                    except ValueError:  # the target does not fit this camera's frame
                        continue
                    scenario = Scenario.from_dict(case.scenario)
                    ((target_id, truth),) = scenario.truth_for(0).items()
                    for k in range(len(scenario)):
                        frame = scenario.render_frame(k)
                        tracker = detection._tracker(scenario.camera, scenario.targets)
                        result = tracker.process(frame.image, frame.exposure_us)
                        errors = [100.0 * (t.pose.distance_m / truth.distance_m - 1.0) for t in result.targets
                                  if t.fit and t.target_id == target_id]
                        out.append(SearchOutcome(ground, sheet, seed, area, tilt, float(exposures[k]), camera,
                                                 errors[0] if errors else None))
                    if progress is not None:
                        progress(f"{sheet} {ground} seed {seed} area {area}")
    return out


def summary(rows: Sequence[SearchOutcome]) -> list[dict]:
    """Per (sheet, exposure): frames, found, mean / median |distance error| (percent) and mean signed error."""
    out = []
    for sheet in sorted({r.sheet for r in rows}):
        for exposure in sorted({r.exposure_factor for r in rows}):
            mine = [r for r in rows if r.sheet == sheet and r.exposure_factor == exposure]
            errors = np.array([r.distance_error_pct for r in mine if r.distance_error_pct is not None])
            out.append({"sheet": sheet, "exposure_factor": exposure, "frames": len(mine), "found": len(errors),
                        "mean_abs_error_pct": float(np.abs(errors).mean()) if len(errors) else math.nan,
                        "median_abs_error_pct": float(np.median(np.abs(errors))) if len(errors) else math.nan,
                        "mean_error_pct": float(errors.mean()) if len(errors) else math.nan})
    return out


def report(rows: Sequence[SearchOutcome]) -> dict:
    """The JSON report: the summary and every frame."""
    return {"summary": summary(rows), "frames": [asdict(r) for r in rows]}
