"""Every compiled (numba) kernel of the package, compiled or loaded from numba's cache before the first frame.

A kernel compiles (seconds) or loads from numba's on-disk cache (milliseconds) at its first call in a process; left
to the first frame, that frame pays it: ~0.2 s of loading on a paper-lab frame, and 5-50 s of compiling on a fresh
install. :func:`warm_up` calls each kernel of :data:`KERNEL_MODULES` once on a tiny input of the types the frames use
(``scripts/install.sh`` runs it, so that the install writes the cache; ``livetrack run`` and the live pipeline run
it before acquisition starts, so that the first frame neither compiles nor loads). ``tests/test_warm_up.py`` lists the
package's compiled functions and checks that this warm-up reaches each one, and that a tracked sequence with
searches afterwards compiles nothing more."""

from __future__ import annotations

import importlib
import time

import numpy as np

KERNEL_MODULES = (
    "livetrack.estimator.edge_kernels",
    "livetrack.estimator.clip_level",
    "livetrack.estimator.edge_glue_kernels",
    "livetrack.estimator.pose_kernels",
    "livetrack.estimator.surround_kernels",
    "livetrack.estimator.lut_kernel",
    "livetrack.estimator.target_map_kernel",
    "livetrack.estimator.target_model_kernel",
    "livetrack.estimator.detect.upsample_kernel",
    "livetrack.estimator.detect.blur_kernel",
    "livetrack.estimator.detect.pyramid_kernel",
    "livetrack.estimator.detect.sqrt_kernel",
    "livetrack.estimator.detect.hole_kernel",
    "livetrack.estimator.detect.levels_kernel",
    "livetrack.estimator.detect.window_kernel",
    "livetrack.estimator.detect.noise_kernel",
    "livetrack.estimator.detect.fit_kernel",
    "livetrack.estimator.detect.blob_kernel",
    "livetrack.estimator.detect.outline_kernel",
    "livetrack.modelcheck.reading_kernel",
)
"""The modules that define compiled kernels (a new one must be added here, and its kernels to :func:`warm_up`:
the test fails otherwise)."""


def is_kernel(obj) -> bool:
    """Whether ``obj`` is a numba dispatcher (a compiled function)."""
    return hasattr(obj, "targetoptions") and hasattr(obj, "py_func")


def kernels() -> list:
    """The compiled functions defined in :data:`KERNEL_MODULES` (empty without numba)."""
    out = []
    for name in KERNEL_MODULES:
        module = importlib.import_module(name)
        out += [obj for obj in vars(module).values() if is_kernel(obj) and obj.__module__ == name]
    return out


def _warm_detector() -> None:
    """The detector's kernels, on the types a detection passes them: the 16-to-8-bit table look-up, alone and with
    the pyramid's first level in its pass, and the same with the map computed (``sqrt_kernel``), on a whole frame
    and on a search window's crop (a strided view), of writeable or read-only images; the 4x upsampled
    threshold (with and without the full-resolution blur inside it, checked against OpenCV's blur:
    ``blur_kernel.kernel_taps``, at the default options) and the hole test on the detector's own (C-contiguous)
    work images, and with a closing on a crop (a view) or a copy; the coarse thresholds' arithmetic with their
    checks against OpenCV's (``window_kernel.exact``, at the default options, and ``clipped_exact``); the noise
    figures; an ellipse fit's residuals and a contour's hull area (``fit_kernel``); the map of target points to
    pixels for sampling (``target_map_kernel``); the top-level blobs of a contour hierarchy
    (``blob_kernel``); a blob's outline against its level image (``outline_kernel``)."""
    from livetrack.estimator import lut_kernel, target_map_kernel
    from livetrack.estimator.conics import Ellipse
    from livetrack.estimator.detect import (
        arcs,
        blob_kernel,
        blur_kernel,
        fit_kernel,
        hole_kernel,
        hole_pairs,
        levels,
        levels_kernel,
        noise_kernel,
        outline_edges,
        outline_kernel,
        pyramid_kernel,
        small_blobs,
        sqrt_kernel,
        threshold,
        upsample_kernel,
        window_kernel,
    )
    from livetrack.estimator.detect.options import DetectOptions

    if lut_kernel.numba is not None:  # an encoded camera's frames linearised (``camera.encoding.linearise``)
        for dtype, size in ((np.uint8, 256), (np.uint16, 65536)):
            to16 = np.zeros(size, np.uint16)
            to16.flags.writeable = False
            frame = np.zeros((8, 8), dtype)
            for src in (frame, frame[1:5, 2:6]):
                for writeable in (True, False):
                    view = src.view()
                    view.flags.writeable = writeable
                    lut_kernel.lut_to16(view, to16, np.empty(view.shape, np.uint16))
    if lut_kernel.numba is not None:
        table = np.zeros(65536, np.uint8)
        table.flags.writeable = False  # as threshold._sqrt_table's
        frame = np.zeros((8, 8), np.uint16)
        for src in (frame, frame[1:5, 2:6]):
            for writeable in (True, False):
                view = src.view()
                view.flags.writeable = writeable
                lut_kernel.lut16(view, table, np.empty(view.shape, np.uint8))
                if pyramid_kernel.numba is not None:
                    pyramid_kernel.lut16_halved(view, table, np.empty(view.shape, np.uint8),
                                                np.empty(((view.shape[0] + 1) // 2, (view.shape[1] + 1) // 2),
                                                         np.uint8))
                    # the map computed (``sqrt_kernel``), alone and with the first level
                    sqrt_kernel.sqrt16(view, np.float32(1.0), np.empty(view.shape, np.uint8))
                    sqrt_kernel.sqrt16_halved(view, np.float32(1.0), np.empty(view.shape, np.uint8),
                                              np.empty(((view.shape[0] + 1) // 2, (view.shape[1] + 1) // 2),
                                                       np.uint8))
    if upsample_kernel.numba is not None:
        img8 = np.zeros((8, 8), np.uint8)
        upsample_kernel.dark_by_upsampled_threshold(img8, np.zeros((2, 2), np.uint8), np.empty((8, 8), np.uint8))
        taps = blur_kernel.kernel_taps(DetectOptions().level0_blur_px)  # compiles and checks the blur
        if taps is not None:
            blurred = threshold._blurred_for_noise((img8, *taps), np.empty((8, 8), np.uint8))
            upsample_kernel.dark_and_box(blurred, np.zeros((2, 2), np.uint8), np.empty((8, 8), np.uint8),
                                         (img8, *taps))
    if hole_kernel.numba is not None:  # the hole test; a pair from a hole: its ring's samples, its outline
        hole_kernel.has_hole(np.zeros((3, 3), np.uint8))
        work = np.zeros((6, 6), np.uint8)
        for crop in (work, work[1:, 1:]):  # a closing with its hole test: a blob's own pixels, a retry's crop (a view)
            hole_kernel.closed_with_hole(crop, threshold._DISK5)
        hole_kernel.dark_on_bands(np.zeros((3, 3), np.uint8), Ellipse(np.zeros(2), np.ones(2), 0.0), (1.0,),
                                  np.zeros(1))
        contour = np.zeros((6, 1, 2), np.int32)
        hole_pairs._ring_on_outline((contour, contour), np.array([[-1, -1, 1, -1], [-1, -1, -1, 0]], np.int32), 0,
                                    1, Ellipse(np.zeros(2), np.ones(2), 0.0), 0.5, {})
        hole_kernel.directions_seen(np.zeros(1), 16.0 / np.pi)  # a ring's directions on the outline
        small_blobs._probes(np.zeros((3, 3), np.uint8), (0, 0, 2, 2))  # a small blob's probes, a ring's cheap test
        arcs._ring_around_middle(np.zeros((3, 3), np.uint8), 0, 0, 2, 2)
    if blob_kernel.numba is not None:  # the blobs a pairing examines, from cv2.findContours' hierarchy
        blob_kernel.top_blobs(np.array([[-1, -1, -1, -1]], np.int32), np.zeros(1, np.int64), 12, True)
    if outline_kernel.numba is not None:  # a blob's outline against the level image (a halo's test)
        outline_edges.outline_edge_share(np.zeros((3, 3), np.uint8), np.zeros((8, 1, 2), np.int32), 8.0)
    if levels_kernel.numba is not None:  # the level choice's readings, on its cached (read-only) patterns
        samples = np.zeros(16)
        levels_kernel.verdict(np.zeros((3, 8)), np.zeros(8), samples[8:], levels._code_values("10000000"), None,
                              0.0, 1.0, levels.PARENT_MIN_CONTRAST)
        r, t, _, _, white_cols, far = levels._ray_pattern(2.0)
        levels_kernel.disk_edges(np.zeros((len(t), len(r))), r, white_cols, far, 0.0)
    if window_kernel.numba is not None:  # the coarse thresholds' arithmetic, checked against OpenCV's (cached)
        window_kernel.exact(DetectOptions().relative_offset, threshold.SATURATED_RELATIVE_OFFSET)
        window_kernel.clipped_exact(threshold.CLIPPED_RELATIVE_OFFSET)  # a clipped frame's saturated windows
    if noise_kernel.numba is not None:  # the noise figures, on a work image
        threshold._noise(np.zeros((40, 40), np.uint8))
    if fit_kernel.numba is not None:  # an ellipse fit's residuals, on a contour as cv2.findContours gives it
        fit_kernel.fit_distances(np.zeros((6, 1, 2), np.int32), 0.0, 0.0, 1.0, 0.0, 2.0, 1.0)
        fit_kernel.hull_area(np.zeros((6, 1, 2), np.int32))  # and the solidity test's hull area
        fit_kernel.near_count(np.zeros((6, 2)), 0.0, 0.0, 1.0, 0.0, 2.0, 1.0, 1.0)  # a large edge pair's samples
    if target_map_kernel.numba is not None:  # target points to pixels, fresh or cached (read-only) points
        fresh, cached = np.zeros(2), np.zeros(2)
        cached.flags.writeable = False
        for tx in (fresh, cached):
            for ty in (fresh, cached):
                target_map_kernel.map_points(np.eye(3), tx, ty, 4, 4, np.empty((2, 2), np.float32),
                                             np.empty(2, np.bool_))


def warm_up() -> float:
    """Compile (or load from numba's cache) every kernel of :data:`KERNEL_MODULES` that this process will use: the
    edge, pose and surround kernels when ``LIVETRACK_KERNELS`` selects numba (:func:`edge_kernels.kernels`), the
    detector's whenever numba is installed. Returns the seconds it took. Idempotent: later calls cost
    microseconds."""
    from livetrack.estimator import edge_kernels, pose_kernels
    from livetrack.modelcheck import reading_kernel

    t0 = time.perf_counter()
    if edge_kernels.kernels() == "numba":
        edge_kernels.warm_up()  # with edge_glue_kernels and surround_kernels
        pose_kernels.warm_up()
        one = np.ones((1, 1))
        edge_kernels.response_rows(one, np.ones(1), np.ones(1), np.zeros(1))  # only the tests call it
        from livetrack.estimator import target_model_kernel  # a search's whole-target model (x32 with a halo)

        grid = np.zeros((2, 2))
        target_model_kernel.white_kernel(grid, grid, grid, np.eye(3), np.eye(3), np.zeros((1, 4)), True)
    _warm_detector()
    _warm_clip_level()
    if reading_kernel.numba is not None:  # ``livetrack model``'s (not tracking's: loading it costs milliseconds)
        reading_kernel.expected_clipped(np.zeros(1), 1.0, 1.0, 1.0, np.empty(1))
    return time.perf_counter() - t0


def _warm_clip_level() -> None:
    """``clip_level``'s passes on the frames a tracker gives them: 8 and 16-bit, whole frames (writeable or read-only,
    and a strided view: a search window's crop) and a target's box (a C-contiguous copy)."""
    from livetrack.estimator import clip_level

    if clip_level.numba is None:
        return
    for dtype, top in ((np.uint8, 255.0), (np.uint16, 4095.0)):
        frame = np.zeros((4, 6), dtype)
        frame[0, 0] = 1
        for writeable in (True, False):
            frame.flags.writeable = writeable
            for image in (frame, frame[:, 1:]):
                clip_level.frame_saturation_dn(image, top, 0.01 * top)


def cache_stats() -> dict[str, int]:
    """Numba's cache hits and misses (compilations) of every kernel in this process: ``{"hits": .., "misses": ..}``."""
    from livetrack.estimator.edge_kernels import cache_stats_of

    return cache_stats_of(kernels())
