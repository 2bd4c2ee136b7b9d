"""Code book of 8-slot ring codes, and decoding with heading.

A code is a string of N bits, bit k = '1' meaning a white dot in slot k (slot k at angle 2*pi*k/N from +x toward
+y in the target frame). The book holds the aperiodic patterns (each of its N rotations is distinct, so the code
also gives the heading) such that any two codes, and any code and its own non-trivial rotations, differ in at
least ``MIN_DISTANCE`` slots. Ids are the book's indices, in a fixed deterministic order.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

SLOTS = 8
MIN_DISTANCE = 2


def rotate(bits: str, k: int) -> str:
    """The code as read when the target is rotated by k slots: slot j of the result is slot j - k of ``bits``."""
    k %= len(bits)
    return bits[-k:] + bits[:-k] if k else bits


@lru_cache(maxsize=1024)
def is_symmetric(bits: str) -> bool:
    """True if some non-trivial rotation maps the code onto itself (the heading is then ambiguous; cached:
    ``decode`` asks it of every code it reads)."""
    return any(rotate(bits, k) == bits for k in range(1, len(bits)))


def _distance(a: str, b: str) -> int:
    return sum(x != y for x, y in zip(a, b, strict=True))


def rotation_distance(a: str, b: str) -> int:
    """Smallest Hamming distance between ``a`` and any rotation of ``b``."""
    return min(_distance(a, rotate(b, k)) for k in range(len(b)))


def self_distance(bits: str) -> int:
    """Smallest Hamming distance between a code and its non-trivial rotations (0 for symmetric codes)."""
    return min(_distance(bits, rotate(bits, k)) for k in range(1, len(bits)))


@lru_cache(maxsize=4)
def code_book(slots: int = SLOTS, min_distance: int = MIN_DISTANCE) -> tuple[str, ...]:
    """Deterministic greedy book: canonical (lexicographically smallest rotation) aperiodic codes with at
    least two dots and two gaps, added in increasing order when they keep the minimum distance."""
    book: list[str] = []
    for value in range(1 << slots):
        bits = format(value, f"0{slots}b")
        if min(rotate(bits, k) for k in range(slots)) != bits:
            continue  # not canonical
        ones = bits.count("1")
        if ones < 2 or ones > slots - 2:
            continue
        if self_distance(bits) < min_distance:
            continue
        if all(rotation_distance(bits, other) >= min_distance for other in book):
            book.append(bits)
    return tuple(book)


def bits_for_id(target_id: int, slots: int = SLOTS) -> str:
    book = code_book(slots)
    if not 0 <= target_id < len(book):
        raise ValueError(f"id {target_id} is not in the {slots}-slot code book (ids 0..{len(book) - 1})")
    return book[target_id]


@dataclass(frozen=True)
class Decoded:
    """Result of matching measured slot values against candidate codes.

    ``rotation_slots``: the measured pattern equals the candidate rotated by this many slots, i.e. the target's
    +x axis lies at ``rotation_slots * 2*pi/N`` from the reference direction used for sampling. ``None`` when the
    code is symmetric (heading unknown). ``margin`` is the distance gap to the second-best match, in slots.
    """

    index: int
    rotation_slots: int | None
    distance: float
    margin: float
    heading_known: bool

    def __bool__(self) -> bool:
        return self.index >= 0


NO_MATCH = Decoded(index=-1, rotation_slots=None, distance=float("inf"), margin=0.0, heading_known=False)


@lru_cache(maxsize=1024)
def _rotations(bits: str) -> np.ndarray:
    """(N, N) float64, row k = the code's bits (1.0 for "1") rolled by k slots, ``np.roll(ref, k)`` (read-only,
    cached)."""
    ref = np.array([b == "1" for b in bits], dtype=np.float64)
    n = ref.size
    out = ref[(np.arange(n)[None, :] - np.arange(n)[:, None]) % n]
    out.flags.writeable = False
    return out


def decode(measured: np.ndarray, candidates: list[str], max_distance: float = 0.5) -> Decoded:
    """Match soft slot values ``measured`` (N,) in [0, 1] (1 = white dot) against ``candidates``.

    Distance is the sum of |measured - bit| (a soft Hamming distance). The best candidate and rotation win if
    their distance is at most ``max_distance`` and no other candidate (at any rotation) is as close.
    """
    measured = np.asarray(measured, dtype=np.float64)
    n = measured.size
    best: list[tuple[float, int, int]] = []
    for index, bits in enumerate(candidates):
        if len(bits) != n:
            continue
        # row k: the code rolled by k slots (np.roll(ref, k)); each row's sum is numpy's pairwise sum of that
        # row, as np.abs(measured - np.roll(ref, k)).sum() gives it (tests/test_detect_glue.py holds them equal)
        distances = np.abs(measured - _rotations(bits)).sum(axis=1).tolist()
        best.extend((d, index, k) for k, d in enumerate(distances))
    if not best:
        return NO_MATCH
    best.sort()
    d0, index, k = best[0]
    symmetric = is_symmetric(candidates[index])
    # Second best among other candidates, or among other rotations of the same candidate if it has a heading.
    rivals = [d for d, i, kk in best[1:] if i != index or (not symmetric and kk != k)]
    if symmetric:
        rivals = [d for d, i, _ in best[1:] if i != index]
    d1 = rivals[0] if rivals else float(n)
    if d0 > max_distance or d1 <= d0:
        return NO_MATCH
    return Decoded(index=index, rotation_slots=None if symmetric else k, distance=d0, margin=d1 - d0,
                   heading_known=not symmetric)
