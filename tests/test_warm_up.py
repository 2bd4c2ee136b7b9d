"""The warm-up (``livetrack.estimator.warm``) reaches every compiled kernel of the package, on the types the frames
use: a kernel added later without a warm-up fails here, and so does one that a frame would compile again for
another array type (seconds of compiling in the middle of a run)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "livetrack"

_PROBE = """
import json
from livetrack.estimator import warm

warm.warm_up()
kernels = warm.kernels()
helpers = set()
for k in kernels:  # a kernel another one calls is compiled into its caller (its own signature list stays empty)
    helpers |= {n for n in k.py_func.__code__.co_names if n != k.__name__}
after_warm = {f"{k.__module__}.{k.__name__}": [str(s) for s in k.signatures] for k in kernels}
called = {f"{k.__module__}.{k.__name__}": k.__name__ in helpers for k in kernels}
{frames}
after_frames = {f"{k.__module__}.{k.__name__}": [str(s) for s in k.signatures] for k in kernels}
print(json.dumps({"warm": after_warm, "called": called, "frames": after_frames}))
"""

_FRAMES = """
from livetrack.estimator.tracker import Tracker, TrackerOptions
from tests.test_tracker import _small_scene

for bits in (12, 8):  # 16-bit and 8-bit images; nominal and 4x over-exposed; searches, window searches, tracking
    scene = _small_scene(bits, 9.0, [1.0, 4.0])
    frames = [scene.render_frame(i) for i in (0, 1)]
    tracker = Tracker(scene.camera, list(scene.targets), TrackerOptions(tracking=True))
    for k in range(24):
        frame = frames[k // 12]
        tracker.process(frame.image, frame.exposure_us)
"""


def _probe(frames: str = "") -> dict:
    env = {**os.environ, "LIVETRACK_KERNELS": "numba"}
    out = subprocess.run([sys.executable, "-c", _PROBE.replace("{frames}", frames)], env=env, cwd=PACKAGE.parent,
                         capture_output=True, text=True, timeout=600, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_every_module_with_compiled_functions_is_warmed():
    """Each source file that compiles a function (``numba.njit``, ``jit_kernel``) is in ``KERNEL_MODULES``."""
    from livetrack.estimator import warm

    defining = set()
    for path in PACKAGE.rglob("*.py"):
        text = path.read_text(encoding="utf-8")
        if re.search(r"^\s*@(numba\.)?(njit|jit|jit_kernel)\b", text, re.MULTILINE) or "numba.njit(" in text:
            defining.add(".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts))
    assert defining == set(warm.KERNEL_MODULES) | {"livetrack.estimator.edge_kernels"}, defining


@pytest.mark.skipif(__import__("importlib").util.find_spec("numba") is None, reason="numba not installed")
def test_the_warm_up_compiles_every_kernel_and_the_frames_compile_nothing_more():
    """In a fresh process: after ``warm_up`` every kernel has a compiled signature (or is a helper compiled into the
    kernels that call it), and tracking small 16-bit and 8-bit targets, nominal and 4x over-exposed, with searches,
    window searches and the surround model, adds no signature to any kernel."""
    got = _probe(_FRAMES)
    assert len(got["warm"]) >= 30
    cold = [name for name, sigs in got["warm"].items() if not sigs and not got["called"][name]]
    assert not cold, f"not warmed up: {cold}"
    grown = {name: sorted(set(got["frames"][name]) - set(sigs)) for name, sigs in got["warm"].items()
             if set(got["frames"][name]) - set(sigs)}
    assert not grown, f"compiled again during the frames (types the warm-up does not cover): {grown}"
