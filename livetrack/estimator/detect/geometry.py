"""The configured targets grouped by geometry (what the code reading needs)."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from livetrack.estimator.target_map import sample_target_points
from livetrack.targets.spec import TargetSpec

FloatArray = npt.NDArray[np.float64]


# ---------------------------------------------------------------------- target geometry groups
@dataclass(frozen=True)
class _Geometry:
    """The shape of a level in units of its outer radius (what the sampling needs)."""

    ratio: float  # r / R
    ring: float  # code ring radius / R
    dot: float  # code dot radius / R
    slots: int


@dataclass(frozen=True)
class _Entry:
    """One configured level: the top-level id, the level, its spec and its parent's spec (None at level 0)."""

    target_id: int
    level: int
    spec: TargetSpec
    parent: TargetSpec | None


def _geometry_groups(targets: list[TargetSpec]) -> dict[_Geometry, list[_Entry]]:
    groups: dict[_Geometry, list[_Entry]] = {}
    for top in targets:
        parent = None
        for level, spec in top.levels():
            if spec.code is not None:
                R = spec.outer_radius_m
                geom = _Geometry(round(spec.radius_ratio, 6), round(spec.code.ring_radius_m / R, 6),
                                 round(spec.code.dot_radius_m / R, 6), spec.code.slots)
                groups.setdefault(geom, []).append(_Entry(top.id, level, spec, parent))
            parent = spec
    return groups


def _hole(entries: list[_Entry]) -> float:
    """Radius (units of R) inside the inner disk that may hold something dark (child, centre dot, its text)."""
    worst = 0.0
    for e in entries:
        s = e.spec
        dark = max(3.0 * s.centre_dot_radius_m, s.child.outer_radius_m if s.child else 0.0, 0.3 * s.inner_radius_m)
        worst = max(worst, dark / s.outer_radius_m)
    return worst


def _slots(img: np.ndarray, H0: FloatArray, ring: float, dot: float, n: int,
           phase: float, brightest: bool = False) -> tuple[FloatArray, FloatArray]:
    """Image values (N,) at the N slots (angle ``phase + 2 pi j / N`` on the circle of radius ``ring``, units
    of R, through ``H0``: the mean of a cluster with radial and tangential offsets of 0.4 dot radius, or its
    brightest value with ``brightest``) and at the N gaps half-way between them. NaN where outside the image."""
    radius, cluster_t, grid_t = _slot_pattern(ring, dot, n)
    slot_t = phase + grid_t
    angle = np.concatenate([(slot_t[:, None] + cluster_t).ravel(), slot_t + np.pi / n])
    # ``sample_target(img, H0, radius, angle)``'s own arithmetic, without its wrapper
    vals = sample_target_points(img, H0, radius * np.cos(angle), radius * np.sin(angle))
    cluster = vals[: 5 * n].reshape(n, 5)
    return (np.max(cluster, axis=1) if brightest else cluster.sum(axis=1) / 5), vals[5 * n :]


@functools.lru_cache(maxsize=256)
def _slot_pattern(ring: float, dot: float, n: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """For ``_slots`` (read-only, cached): the radii of the N 5-point clusters then of the N gaps, the angular
    offsets (5,) within a cluster, and the slot angles 2 pi j / N."""
    dr = 0.4 * dot
    dt = dr / ring
    cluster_r = ring + np.array([0.0, dr, -dr, 0.0, 0.0])
    radius = np.concatenate([np.tile(cluster_r, n), np.full(n, ring)])
    cluster_t = np.array([0.0, 0.0, 0.0, dt, -dt])
    grid_t = 2.0 * np.pi * np.arange(n) / n
    for a in (radius, cluster_t, grid_t):
        a.flags.writeable = False
    return radius, cluster_t, grid_t
