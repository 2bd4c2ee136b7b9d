"""Time the recording writer per frame: ``python -m livetrack.recording.bench [--width W --height H --frames N]``.

For each bit depth (8, 12 and 16: the last two as 16-bit PNG) and each fsync setting it writes N frames of a
synthetic sensor image (smooth shading plus 1 % noise: PNG compresses it about as much as a real frame) to a
temporary recording and prints the wall and CPU (thread) time per frame of:

- ``write_frame``: encode the PNG and write it (what the recorder did in its own thread before spooling);
- ``spool_frame``: write the raw values as PGM and the row (what ``run --record`` now does in the acquisition
  thread: the time acquisition spends per frame);
- ``convert``: encode the spooled frame's PNG and replace the PGM by it (the recorder's thread).

The sustainable rate of ``run --record`` is about 1000 / (convert ms) frames per second on one free core; a
camera faster than that fills the spool and acquisition waits. Wall times include the machine's load.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from livetrack.camera import CameraModel
from livetrack.recording import RecordingWriter


def synthetic_image(width: int, height: int, bit_depth: int, seed: int) -> np.ndarray:
    """Smooth shading over 20-60 % of full scale plus Gaussian noise of 1 % of full scale, LSB-aligned."""
    rng = np.random.default_rng(seed)
    full = 2**bit_depth - 1
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    base = (0.4 + 0.2 * np.sin(x / 50.0 + seed) * np.cos(y / 70.0)) * full
    image = np.clip(base + rng.normal(0.0, 0.01 * full, (height, width)), 0, full)
    return image.astype(np.uint8 if bit_depth == 8 else np.uint16)


def _timed(call: Callable[..., object], *args: object, **kwargs: object) -> tuple[object, float, float]:
    """(result, wall ms, this thread's CPU ms) of one call."""
    wall0, cpu0 = time.perf_counter_ns(), time.thread_time_ns()
    result = call(*args, **kwargs)
    return result, (time.perf_counter_ns() - wall0) / 1e6, (time.thread_time_ns() - cpu0) / 1e6


def bench(width: int, height: int, bit_depth: int, frames: int, fsync_every_n_frames: int,
          png_compression: int, folder: Path) -> dict[str, tuple[float, float]]:
    """Median (wall ms, CPU ms) per frame of write_frame, spool_frame and convert."""
    camera = CameraModel(width=width, height=height, fx=1000.0, fy=1000.0, cx=(width - 1) / 2,
                         cy=(height - 1) / 2, bit_depth=bit_depth)
    images = [synthetic_image(width, height, bit_depth, seed) for seed in range(frames)]
    times: dict[str, list[tuple[float, ...]]] = {"write_frame": [], "spool_frame": [], "convert": []}
    kwargs = {"fsync_every_n_frames": fsync_every_n_frames, "png_compression": png_compression}
    frame = {"exposure_us": 1000.0, "gain_db": 0.0}
    with RecordingWriter(folder / f"direct-{bit_depth}-{fsync_every_n_frames}", camera, [], **kwargs) as writer:
        for i, image in enumerate(images):
            times["write_frame"].append(_timed(writer.write_frame, image, timestamp_ns=i, **frame)[1:])
    with RecordingWriter(folder / f"spool-{bit_depth}-{fsync_every_n_frames}", camera, [], **kwargs) as writer:
        for i, image in enumerate(images):
            spooled, *spool_ms = _timed(writer.spool_frame, image, timestamp_ns=i, **frame)
            times["spool_frame"].append(tuple(spool_ms))
            times["convert"].append(_timed(writer.convert, spooled)[1:])
    return {name: (float(np.median([w for w, _ in t])), float(np.median([c for _, c in t])))
            for name, t in times.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--width", type=int, default=1920)
    parser.add_argument("--height", type=int, default=1200)
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--png-compression", type=int, default=1)
    parser.add_argument("--dir", type=Path, default=None, help="where to write (default: a temporary directory)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(dir=args.dir) as folder:
        print(f"{args.width}x{args.height}, {args.frames} frames, PNG level {args.png_compression}; "
              "median wall / CPU ms per frame")
        for bit_depth in (8, 12, 16):
            for fsync in (1, 0):
                result = bench(args.width, args.height, bit_depth, args.frames, fsync, args.png_compression,
                               Path(folder))
                print(f"  {bit_depth:2d}-bit fsync_every_n_frames={fsync}: "
                      + "; ".join(f"{name} {wall:.1f} / {cpu:.1f}" for name, (wall, cpu) in result.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
