"""Faster Python glue of the detector against the plain computations it replaced: equal bit for bit."""

import math

import numpy as np
import pytest

from livetrack.estimator.conics import Ellipse
from livetrack.targets import codebook


def _distances_by_roll(measured: np.ndarray, candidates: list[str]) -> list[tuple[float, int, int]]:
    """``codebook.decode``'s distances as it computed them before: one ``np.roll`` per rotation."""
    out = []
    for index, bits in enumerate(candidates):
        if len(bits) != measured.size:
            continue
        ref = np.array([b == "1" for b in bits], dtype=np.float64)
        for k in range(measured.size):
            out.append((float(np.abs(measured - np.roll(ref, k)).sum()), index, k))
    return out


def _decode_by_roll(measured: np.ndarray, candidates: list[str], max_distance: float) -> codebook.Decoded:
    best = sorted(_distances_by_roll(measured, candidates))
    if not best:
        return codebook.NO_MATCH
    d0, index, k = best[0]
    symmetric = codebook.is_symmetric(candidates[index])
    rivals = [d for d, i, kk in best[1:] if i != index or (not symmetric and kk != k)]
    if symmetric:
        rivals = [d for d, i, _ in best[1:] if i != index]
    d1 = rivals[0] if rivals else float(measured.size)
    if d0 > max_distance or d1 <= d0:
        return codebook.NO_MATCH
    return codebook.Decoded(index, None if symmetric else k, d0, d1 - d0, not symmetric)


@pytest.mark.parametrize("n", [3, 7, 8, 9, 16, 17])
def test_decode_distances_are_the_rolled_ones(n):
    """The rotations as one (N, N) array: every distance the same float as ``np.roll``'s (numpy's pairwise sum
    per row), so the sort, the winner and the margin are the same."""
    rng = np.random.default_rng(n)
    book = list(codebook.code_book(8)) if n == 8 else ["".join(rng.choice(["0", "1"], n)) for _ in range(5)]
    book += ["01" * (n // 2) + "0" * (n % 2)]  # a symmetric code (for even n)
    for t in range(600):
        m = rng.random(n)
        if t % 3 == 0:
            m = np.round(m * 4) / 4  # ties
        elif t % 3 == 1:
            m = np.clip(rng.normal(0.5, 0.7, n), 0.0, 1.0)
        cands = [book[i] for i in rng.choice(len(book), size=min(len(book), 1 + t % 3), replace=False)]
        want = _decode_by_roll(m, cands, 0.5 + (t % 4))
        assert codebook.decode(m, cands, 0.5 + (t % 4)) == want


def test_ellipse_normalisation_is_numpys():
    """``Ellipse``'s scalar arithmetic (``%`` for ``np.mod``, ``tolist`` for ``float``) stores the same numbers."""
    rng = np.random.default_rng(4)
    angles = np.concatenate([rng.normal(0.0, 10.0, 3000), np.arange(-8, 9) * np.pi, np.arange(-8, 9) * np.pi / 2,
                             [0.0, -0.0, 1e-300, -1e-300, 4e15, -4e15]])
    for k, angle in enumerate(angles.tolist()):
        a, b = float(rng.uniform(0.5, 100.0)), float(rng.uniform(0.5, 100.0))
        centre = rng.normal(500.0, 300.0, 2)
        e = Ellipse(centre, np.array([a, b]) if k % 2 else [a, b], angle)
        if b > a:
            a, b, angle = b, a, angle + np.pi / 2
        want = float(np.mod(angle, np.pi))
        assert e.angle_rad == want and math.copysign(1.0, e.angle_rad) == math.copysign(1.0, want)
        assert e.semi_axes_px.tolist() == [a, b] and e.semi_axes_px.dtype == np.float64
        assert e.centre_px is centre or np.array_equal(e.centre_px, centre)
    for bad in ((np.nan, 1.0, 0.0), (1.0, np.inf, 0.0), (2.0, 1.0, np.nan), (0.0, 1.0, 0.0), (-1.0, 1.0, 0.0)):
        with pytest.raises(ValueError):
            Ellipse(np.zeros(2), np.array(bad[:2]), bad[2])
    with pytest.raises(ValueError):
        Ellipse(np.array([np.nan, 0.0]), np.ones(2), 0.0)


def test_lut16_returns_the_top_of_its_input():
    """The compiled table look-up (and its numpy fallback) give ``table[src]`` and ``src.max()``, on whole images,
    strided crops and read-only ones; the detector's top 8-bit level, ``table[top]``, is then ``dst.max()`` for its
    non-decreasing table."""
    from livetrack.estimator import lut_kernel
    from livetrack.estimator.detect.threshold import _sqrt_table

    rng = np.random.default_rng(9)
    table = _sqrt_table(4095.0, 65536)
    for k in range(30):
        src = rng.integers(0, 1 << int(rng.integers(1, 17)), (int(rng.integers(1, 40)), int(rng.integers(1, 50))),
                           dtype=np.uint16)
        if k % 3 == 1:
            src = src[1:, ::2] if src.shape[0] > 1 else src[:, ::2]
        if k % 3 == 2:
            src.flags.writeable = False
        for fn in (lut_kernel.lut16, lut_kernel._lut16_python):
            dst = np.full(src.shape, 7, np.uint8)
            top = fn(src, table, dst)
            assert top == int(src.max()) and np.array_equal(dst, table[src])
            assert int(table[top]) == int(dst.max())
    assert lut_kernel.lut16(np.zeros((0, 3), np.uint16), table, np.zeros((0, 3), np.uint8)) == 0
