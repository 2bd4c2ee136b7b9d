"""Frames of the detection sweep's seeded cases (``livetrack.evaluation.detection.build_cases``), for tests that
pin a case the sweep once missed, and of paper-lab at chosen exposures."""

from __future__ import annotations

from pathlib import Path

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


def paper_lab_frames(pose_index: int, factors: list[float]) -> tuple[Scenario, list]:
    """Paper-lab (config/scenarios/paper-lab.yaml: a 3 % halo of 6 px, 4 % ink) at ``factors`` x nominal, at 10 fps
    (an x32 exposure is longer than a 30 fps frame): the scenario and the frames of pose ``pose_index``."""
    from livetrack.config import checks as cc

    data = cc.load_yaml(Path(__file__).resolve().parents[1] / "config" / "scenarios" / "paper-lab.yaml")
    data["exposure"]["factors"] = list(factors)
    data["timing"]["fps"] = 10
    scenario = Scenario.from_dict(data)
    return scenario, [scenario.render_frame(k) for k in range(len(scenario)) if scenario.pose_index(k) == pose_index]
