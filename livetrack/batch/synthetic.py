"""Small simulated recording archives for the batch tests and ``livetrack bench-batch``.

Each recording shows one ring target at a few poses and exposures, rendered by the simulator at a low resolution
and written with ``RecordingWriter``; the rendered images are written again in a cycle up to ``frames`` frames, so
a long recording costs only a few renders.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from livetrack.recording import RecordingWriter
from livetrack.sim.scenario import Scenario


def archive_scenario(seed: int, width_px: int = 320, height_px: int = 200, poses: int = 4) -> Scenario:
    """A small scenario: ``poses`` poses spread over the image, 3 exposures each (x0.5, x1, x4)."""
    focal = 0.95 * width_px
    data: dict[str, Any] = {
        "name": f"archive-{seed}", "seed": seed,
        "camera": {"width": width_px, "height": height_px, "fx": focal, "fy": focal,
                   "cx": (width_px - 1) / 2, "cy": (height_px - 1) / 2, "bit_depth": 12},
        "sensor": {"full_well_e": 10000, "read_noise_e": 5, "black_level_dn": 0},
        "optics": {"psf_sigma_px": 0.8},
        "scene": {"white_reflectance": 0.85, "black_reflectance": 0.04, "background_reflectance": 0.2},
        "targets": [{"id": 3, "outer_radius_m": 0.125}],
        "trajectory": {"kind": "spread", "count": poses, "distance_m": [0.9, 1.4], "tilt_deg": [0, 35],
                       "margin_px": 10},
        "exposure": {"nominal_us": "auto", "white_fraction_of_full_well": 0.55, "factors": [0.5, 1, 4],
                     "gain_db": 0},
        "timing": {"fps": 60},
    }
    return Scenario.from_dict(data)


def write_archive(folder: str | Path, recordings: int, frames: int, width_px: int = 320, height_px: int = 200,
                  poses: int = 4) -> list[Path]:
    """``recordings`` recordings of ``frames`` frames each in ``folder`` (``rec-000``, ``rec-001``, ...)."""
    folder = Path(folder)
    out = []
    for n in range(recordings):
        scenario = archive_scenario(seed=n, width_px=width_px, height_px=height_px, poses=poses)
        rendered = list(scenario.frames())
        path = folder / f"rec-{n:03d}"
        with RecordingWriter(path, scenario.camera, scenario.targets,
                             meta={"source": "livetrack.batch.synthetic", "scenario": scenario.name}) as writer:
            for k in range(frames):
                frame = rendered[k % len(rendered)]
                writer.write_frame(frame.image, timestamp_ns=int(k * 1e9 / scenario.fps),
                                   exposure_us=frame.exposure_us, gain_db=frame.gain_db, truth=frame.truth)
        out.append(path)
    return out
