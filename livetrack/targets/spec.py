"""Target geometry: a black disk (radius R) with a white inner disk (radius r), white code dots on a circle in
the black annulus, an optional small black centre dot, and optionally a nested target (the fractal level)
inside the white inner disk.

Target frame: origin at the centre, printed face in z = 0, x right and y down as seen from the front, z away
from the viewer. Code slot k of N sits at angle 2*pi*k/N from +x toward +y.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from livetrack.config import checks as cc
from livetrack.targets import codebook

FloatArray = npt.NDArray[np.float64]

# Default design, as fractions of the outer radius R.
DEFAULT_INNER_RATIO = 0.4
DEFAULT_RING_RATIO = 0.7
DEFAULT_DOT_RATIO = 0.1
DEFAULT_CHILD_SCALE = 0.2


@dataclass(frozen=True)
class CodeSpec:
    slots: int
    ring_radius_m: float
    dot_radius_m: float
    bits: str

    @property
    def symmetric(self) -> bool:
        """True if the code gives no heading."""
        return codebook.is_symmetric(self.bits)

    def dot_centres_m(self) -> FloatArray:
        """(N, 2) target-plane centres of all N slots (white dot or not)."""
        angles = 2.0 * np.pi * np.arange(self.slots) / self.slots
        return self.ring_radius_m * np.column_stack([np.cos(angles), np.sin(angles)])

    def white_dot_centres_m(self) -> FloatArray:
        centres = self.dot_centres_m()
        return centres[[b == "1" for b in self.bits]]


@dataclass(frozen=True)
class TargetSpec:
    id: int
    outer_radius_m: float
    inner_radius_m: float
    code: CodeSpec | None = None
    centre_dot_radius_m: float = 0.0
    child: TargetSpec | None = None

    # ------------------------------------------------------------------ construction
    @classmethod
    def default(cls, target_id: int, outer_radius_m: float, levels: int = 2) -> TargetSpec:
        """The default design: r = 0.4 R, 8 slots on 0.7 R, dots of 0.1 R, a child at 1/5 scale."""
        R = float(outer_radius_m)
        child = cls.default(target_id, R * DEFAULT_CHILD_SCALE, levels - 1) if levels > 1 else None
        return cls(
            id=target_id,
            outer_radius_m=R,
            inner_radius_m=DEFAULT_INNER_RATIO * R,
            code=CodeSpec(codebook.SLOTS, DEFAULT_RING_RATIO * R, DEFAULT_DOT_RATIO * R,
                          codebook.bits_for_id(target_id)),
            child=child,
        )

    @classmethod
    def from_dict(cls, data: Any, path: str = "target") -> TargetSpec:
        cc.mapping(data, path, required=["id", "outer_radius_m"],
                   optional=["inner_radius_m", "code", "centre_dot_radius_m", "child", "levels"])
        target_id = cc.integer(data, "id", path, ge=0)
        R = cc.number(data, "outer_radius_m", path, gt=0)
        if "inner_radius_m" not in data and "code" not in data and "child" not in data:
            # Short form: the default design of this id at this size.
            levels = cc.integer(data, "levels", path, default=2, ge=1)
            try:
                return cls.default(target_id, R, levels)
            except ValueError as exc:
                raise cc.ConfigError(cc.join(path, "id"), str(exc)) from None
        if "levels" in data:
            raise cc.ConfigError(cc.join(path, "levels"), "only allowed in the short form (id + outer_radius_m)")
        r = cc.number(data, "inner_radius_m", path, gt=0, lt=R)
        centre_dot = cc.number(data, "centre_dot_radius_m", path, default=0.0, ge=0, lt=r)
        code = None
        if data.get("code") is not None:
            code = _code_from_dict(data["code"], cc.join(path, "code"), r, R)
        child = None
        if data.get("child") is not None:
            child_path = cc.join(path, "child")
            child_data = dict(data["child"])
            child_data.setdefault("id", target_id)
            child = cls.from_dict(child_data, child_path)
            if child.outer_radius_m >= r:
                raise cc.ConfigError(cc.join(child_path, "outer_radius_m"),
                                     f"child ({child.outer_radius_m} m) must fit inside the inner disk ({r} m)")
            if centre_dot > 0:
                raise cc.ConfigError(cc.join(path, "centre_dot_radius_m"), "a centre dot and a child exclude "
                                     "each other")
        return cls(id=target_id, outer_radius_m=R, inner_radius_m=r, code=code, centre_dot_radius_m=centre_dot,
                   child=child)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"id": self.id, "outer_radius_m": self.outer_radius_m,
                               "inner_radius_m": self.inner_radius_m}
        if self.centre_dot_radius_m:
            out["centre_dot_radius_m"] = self.centre_dot_radius_m
        if self.code is not None:
            out["code"] = {"slots": self.code.slots, "ring_radius_m": self.code.ring_radius_m,
                           "dot_radius_m": self.code.dot_radius_m, "bits": self.code.bits}
        if self.child is not None:
            out["child"] = self.child.to_dict()
        return out

    # ------------------------------------------------------------------ geometry
    @property
    def radius_ratio(self) -> float:
        """r / R, the ratio the detector looks for between concentric ellipses."""
        return self.inner_radius_m / self.outer_radius_m

    def levels(self) -> Iterator[tuple[int, TargetSpec]]:
        """(level, spec) from the outermost (level 0) inward."""
        level, spec = 0, self
        while spec is not None:
            yield level, spec
            spec, level = spec.child, level + 1

    def dark_area_m2(self) -> float:
        """Analytic area of all black in the target (every level), in square metres."""
        area = np.pi * (self.outer_radius_m**2 - self.inner_radius_m**2)
        if self.code is not None:
            area -= np.pi * self.code.dot_radius_m**2 * self.code.bits.count("1")
        area += np.pi * self.centre_dot_radius_m**2
        if self.child is not None:
            area += self.child.dark_area_m2()
        return float(area)

    def reflectance(self, x_m: FloatArray, y_m: FloatArray) -> FloatArray:
        """1.0 where the target plane point is white, 0.0 where black; white outside R (the sheet).

        Vectorised over arrays of any shape; ``x_m``, ``y_m`` in the target frame.
        """
        x_m = np.asarray(x_m, dtype=np.float64)
        y_m = np.asarray(y_m, dtype=np.float64)
        r2 = x_m * x_m + y_m * y_m
        black = (r2 <= self.outer_radius_m**2) & (r2 > self.inner_radius_m**2)
        if self.code is not None and self.code.bits.count("1"):
            rho2 = self.code.dot_radius_m**2
            for cx, cy in self.code.white_dot_centres_m():
                black &= (x_m - cx) ** 2 + (y_m - cy) ** 2 > rho2
        if self.centre_dot_radius_m > 0:
            black |= r2 <= self.centre_dot_radius_m**2
        out = np.where(black, 0.0, 1.0)
        if self.child is not None:
            inside = r2 <= self.child.outer_radius_m**2
            if np.any(inside):
                out[inside] = self.child.reflectance(x_m[inside], y_m[inside])
        return out


def _code_from_dict(data: Any, path: str, r: float, R: float) -> CodeSpec:
    cc.mapping(data, path, required=["slots", "ring_radius_m", "dot_radius_m", "bits"])
    slots = cc.integer(data, "slots", path, ge=2)
    ring = cc.number(data, "ring_radius_m", path, gt=r, lt=R)
    dot = cc.number(data, "dot_radius_m", path, gt=0)
    bits = data["bits"]
    if isinstance(bits, int) and not isinstance(bits, bool):
        bits = str(bits).zfill(slots)  # YAML reads 01001111 unquoted as an int
    if not isinstance(bits, str) or len(bits) != slots or set(bits) - {"0", "1"}:
        raise cc.ConfigError(cc.join(path, "bits"), f"must be a string of {slots} '0'/'1', got {bits!r}")
    if ring - dot <= r or ring + dot >= R:
        raise cc.ConfigError(cc.join(path, "dot_radius_m"), "dots must lie inside the black annulus")
    if dot >= ring * np.sin(np.pi / slots):
        raise cc.ConfigError(cc.join(path, "dot_radius_m"), "neighbouring dots would overlap")
    return CodeSpec(slots=slots, ring_radius_m=ring, dot_radius_m=dot, bits=bits)


def load_targets(file: str | Path) -> list[TargetSpec]:
    """Read a targets file: a mapping with a ``targets`` list (other top-level keys are allowed and ignored,
    e.g. ``other-markers`` in the real-data file), or a bare list."""
    data = cc.load_yaml(file)
    items = data.get("targets") if isinstance(data, dict) else data
    if not isinstance(items, list):
        raise cc.ConfigError(f"{file}: targets", "must be a list of target specs")
    specs = [TargetSpec.from_dict(item, f"{file}: targets[{i}]") for i, item in enumerate(items)]
    ids = [s.id for s in specs]
    if len(set(ids)) != len(ids):
        raise cc.ConfigError(f"{file}: targets", f"duplicate ids in {ids}")
    return specs
