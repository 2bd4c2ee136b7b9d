"""For the tests of the detector's cost-only switches (``detector.SKIP_HALOS``, ``detector.SKIP_KNOWN``): one frame
detected with a switch on and off, the candidates compared to the last digit, the calls of a pairing function
counted."""

from __future__ import annotations

import numpy as np

from livetrack.estimator.detect import Detector
from livetrack.estimator.detect import detector as detector_module
from livetrack.estimator.detect import pairs as pairs_module


def candidate_key(found) -> list:
    """Every number a candidate carries that the tracker uses (ids, level, both ellipses, heading), exactly."""
    return [(c.target_id, c.level, c.outer.centre_px.tolist(), c.outer.semi_axes_px.tolist(), c.outer.angle_rad,
             c.inner.centre_px.tolist(), c.inner.semi_axes_px.tolist(), c.inner.angle_rad, c.heading_rad)
            for c in found]


def with_and_without(monkeypatch, switch: str, scenario, image: np.ndarray, counted: str | None = None):
    """``Detector.detect`` of ``image`` with ``detector.<switch>`` on, then off: (candidates on, candidates off,
    calls on, calls off), the calls those of ``pairs.<counted>`` (0 without ``counted``)."""
    calls = [0]
    if counted is not None:
        original = getattr(pairs_module, counted)

        def count(*args, **kwargs):
            calls[0] += 1
            return original(*args, **kwargs)

        monkeypatch.setattr(pairs_module, counted, count)
    saturation = float(scenario.camera.saturation_level)
    monkeypatch.setattr(detector_module, switch, True)
    found = Detector(scenario.targets).detect(image, saturation=saturation)
    calls_on, calls[0] = calls[0], 0
    monkeypatch.setattr(detector_module, switch, False)
    again = Detector(scenario.targets).detect(image, saturation=saturation)
    return candidate_key(found), candidate_key(again), calls_on, calls[0]
