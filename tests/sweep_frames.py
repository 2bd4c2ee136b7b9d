"""Frames of the detection sweep's seeded cases (``livetrack.evaluation.detection.build_cases``), for tests that
pin a case the sweep once missed."""

from __future__ import annotations

import numpy as np

from livetrack.evaluation.detection import build_cases
from livetrack.sim.scenario import Scenario


def sweep_frame(seed: int, name: str, exposure: float) -> tuple[Scenario, np.ndarray]:
    """The scenario of case ``name`` of the sweep of ``seed`` and its frame at ``exposure`` (x nominal)."""
    case = next(c for c in build_cases(seed) if c.name == name)
    scenario = Scenario.from_dict(case.scenario)
    optical = scenario.formation.optical_image(scenario.placements_for(0))
    frame = scenario.render_frame(case.scenario["exposure"]["factors"].index(exposure), optical=optical)
    assert frame.exposure_factor == exposure
    return scenario, frame.image
