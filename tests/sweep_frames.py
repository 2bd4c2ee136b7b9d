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


def family_apart(monkeypatch, family: str, scenes_name: str, draw_name: str, seed: int = 3) -> list:
    """The cases of the sweep's drawn ``family`` for ``seed``, after checking that it has its own random stream:
    with the family cut to its least (``scenes_name`` set to 0) and drawing nothing (``draw_name`` a no-op), every
    other family's scenes are the ones they were (names and scenarios)."""
    from livetrack.evaluation import detection

    with_family = build_cases(seed)
    monkeypatch.setattr(detection, scenes_name, 0)
    monkeypatch.setattr(detection, draw_name, lambda data, rng: None)
    others = [c for c in with_family if c.family != family]
    without = [c for c in build_cases(seed) if c.family != family]
    assert [c.name for c in others] == [c.name for c in without]
    assert all(a.scenario == b.scenario for a, b in zip(others, without, strict=True))
    return [c for c in with_family if c.family == family]
