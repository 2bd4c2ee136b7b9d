"""The evaluations as batch tasks (``livetrack evaluate ... --workers N | --scheduler ADDRESS``).

``exposure-sweep``: the pose steps are cut into ranges of ``range_poses``; one task runs every method over one range
with fresh estimators (as ``run_sweep(first_step=..., max_steps=...)``), so a range starts with a search and the
trackers' state (windows, delta per exposure) is carried within it. The serial run (``workers=0``) runs the same
ranges here: the same report whatever the number of workers (only the measured ``seconds`` differ; the command's
``--no-timings`` leaves them out). A task gets the scenario file, seed and pose count, and builds the scenario
itself (seeded: the same poses and noise everywhere); ``poses`` sets a ``trajectory`` scenario's ``count`` for
Monte-Carlo sweeps of many poses.

``detection``: one task per scene (``Case``: its scenario is plain data); each scene has its own tracker, so the
report is the one of ``run_detection_sweep`` whatever the executor. The frames without targets and the photos run
here after the scenes (they share one random generator, in order).
"""

from __future__ import annotations

import functools
import time
from collections.abc import Sequence
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np

from livetrack.batch.executor import Executor, Outcome, Task
from livetrack.config.checks import ConfigError

DEFAULT_RANGE_POSES = 5
"""Pose steps per exposure-sweep task (each step: every method at every exposure, ~seconds)."""


class BatchFailed(RuntimeError):
    """Tasks failed after their retries; ``failures`` lists ``"label: error"``. An evaluation needs them all."""

    def __init__(self, failures: list[str]):
        super().__init__(f"{len(failures)} task(s) failed: " + "; ".join(failures))
        self.failures = failures


# --------------------------------------------------------------------------------------------- exposure sweep
def load_sweep_scenario(file: str, seed: int | None = None, poses: int | None = None) -> Any:
    """The scenario of ``file`` (``seed`` overrides its seed); ``poses`` replaces its trajectory's ``count``."""
    return _load_sweep_scenario(str(Path(file).resolve()), seed, poses)


@functools.lru_cache(maxsize=4)
def _load_sweep_scenario(file: str, seed: int | None, poses: int | None) -> Any:
    from livetrack.config import checks as cc
    from livetrack.sim.scenario import Scenario

    data = cc.load_yaml(file)
    if poses is not None:
        if not isinstance(data, dict) or not isinstance(data.get("trajectory"), dict):
            raise ConfigError("--poses", f"{file} has explicit poses; --poses needs a scenario with a trajectory")
        data = {**data, "trajectory": {**data["trajectory"], "count": int(poses)}}
    return Scenario.from_dict(data, seed=seed, path="", base_dir=Path(file).parent)


def sweep_range(file: str, seed: int | None, poses: int | None, start: int, stop: int,
                settings: dict[str, Any]) -> dict[str, Any]:
    """Task: pose steps ``start`` to ``stop - 1`` of the sweep. ``settings``: ``methods``, ``with_crb``,
    ``fitted_camera`` (file or None), ``clipped_shared_contrast``. Returns the observations (dicts) and the
    Cramer-Rao bounds per step."""
    from livetrack.estimator.tracker import TrackerOptions
    from livetrack.evaluation.exposure_sweep import run_sweep

    scenario = load_sweep_scenario(file, seed, poses)
    fitted = None
    if settings["fitted_camera"]:
        from livetrack.camera.io import load_optics

        fitted = load_optics(Path(settings["fitted_camera"]))
    result = run_sweep(scenario, settings["methods"], max_steps=stop, with_crb=settings["with_crb"],
                       fitted_optics=fitted, first_step=start,
                       tracker_options=TrackerOptions(clipped_shared_contrast=settings["clipped_shared_contrast"],
                                                      fit_target_model=settings.get("fit_target_model", False)))
    return {"observations": [dict(o.__dict__) for o in result.observations],
            "crb_distance_rel": {int(k): [float(x) for x in v] for k, v in result.crb_distance_rel.items()}}


def pose_ranges(count: int, range_poses: int) -> list[tuple[int, int]]:
    if range_poses < 1:
        raise ValueError(f"range_poses must be >= 1, got {range_poses}")
    return [(a, min(a + range_poses, count)) for a in range(0, count, range_poses)]


def run_sweep_batch(file: str | Path, executor: Executor, settings: dict[str, Any], seed: int | None = None,
                    poses: int | None = None, max_steps: int | None = None, range_poses: int = DEFAULT_RANGE_POSES,
                    progress: bool = False) -> Any:
    """The exposure sweep of scenario ``file`` over ``executor``: a ``SweepResult`` as ``run_sweep`` gives,
    the observations in step order. Raises ``BatchFailed`` naming the failed pose ranges."""
    from livetrack.evaluation.exposure_sweep import Observation, SweepResult

    scenario = load_sweep_scenario(str(file), seed, poses)
    n_steps = len(scenario.steps) if max_steps is None else min(max_steps, len(scenario.steps))
    path = str(Path(file).resolve())
    tasks = [Task(sweep_range, (path, seed, poses, a, b, settings), f"{Path(file).name} poses {a}-{b - 1}",
                  weight=b - a) for a, b in pose_ranges(n_steps, range_poses)]
    outcomes = executor.run(tasks, progress="poses" if progress else None)
    _raise_failures(outcomes)
    result = SweepResult(scenario=scenario.name, exposure_factors=list(scenario.exposure_factors))
    for outcome in outcomes:
        result.observations += [Observation(**o) for o in outcome.value["observations"]]
        result.crb_distance_rel.update({int(k): v for k, v in outcome.value["crb_distance_rel"].items()})
    return result


# -------------------------------------------------------------------------------------------------- detection
def detection_case(case: dict[str, Any], explain: bool = False, encoding_known: bool = False) -> dict[str, Any]:
    """Task: one scene of the detection evaluation (``Case`` as a dict). Returns its target outcomes and
    spurious reports as plain data."""
    from livetrack.evaluation.detection import Case, DetectionResult, run_case

    result = DetectionResult()
    run_case(Case(**case), result, explain, encoding_known)
    return {"targets": [asdict(t) for t in result.targets], "spurious": result.spurious}


def run_detection_batch(executor: Executor, seed: int = 0, scale: float = 1.0, quick: bool = False,
                        photos: Sequence[tuple[str, Any]] = (), background_files: Sequence[str] = (),
                        cases: Sequence[Any] | None = None, progress: bool = False, explain: bool = False,
                        encoding_known: bool = False) -> Any:
    """``run_detection_sweep`` with the scenes as tasks on ``executor``; the same ``DetectionResult``."""
    from livetrack.evaluation import detection as d
    from livetrack.targets.spec import TargetSpec

    t0 = time.perf_counter()
    cases = d.build_cases(seed, scale, quick) if cases is None else list(cases)
    cases += d.photo_cases(background_files, seed, quick)
    tasks = [Task(detection_case, (asdict(c), explain, encoding_known), f"scene {c.name} ({c.background}, {c.camera})",
                  weight=len(c.scenario["exposure"]["factors"])) for c in cases]
    outcomes = executor.run(tasks, progress="scene frames" if progress else None)
    _raise_failures(outcomes)
    result = d.DetectionResult()
    for outcome in outcomes:
        result.targets += [d.TargetOutcome(**t) for t in outcome.value["targets"]]
        result.spurious += outcome.value["spurious"]
    rng = np.random.default_rng(np.random.SeedSequence([seed, 202]))
    d.run_no_target(cases, result, d.QUICK_EXPOSURES if quick else (0.25, 1.0, 4.0, 16.0), rng)
    d.run_photos(photos, result, [TargetSpec.default(i, d.OUTER_RADIUS_M) for i in d.POOL_IDS])
    return replace(result, seconds=time.perf_counter() - t0)


def _raise_failures(outcomes: Sequence[Outcome]) -> None:
    failures = [f"{o.task.label}: {o.error}" for o in outcomes if not o.ok]
    if failures:
        raise BatchFailed(failures)
