"""PNG figures of a ``ModelReport`` (matplotlib, Agg backend; every figure is closed after saving).

Files written by ``write_plots(report, folder)`` (returned as a list):
bias_curve.png, residual_maps.png, residuals_binned.png, edge_profiles.png, levels.png, heldout.png.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from livetrack.modelcheck.analysis import ModelReport  # noqa: E402

COLOURS = {"measured": "k", "baseline": "tab:red", "extended": "tab:blue"}


def _label(rep: ModelReport, key: str) -> str:
    if key == "extended":
        return "chosen: " + (" + ".join(rep.chosen) or "baseline")
    return key


def write_plots(rep: ModelReport, folder: str | os.PathLike) -> list[str]:
    return save_figures(rep, folder, (("bias_curve.png", _bias), ("residual_maps.png", _maps),
                                      ("residuals_binned.png", _binned), ("edge_profiles.png", _profiles),
                                      ("levels.png", _levels), ("heldout.png", _heldout)))


def save_figures(rep: Any, folder: str | os.PathLike,
                 figures: Sequence[tuple[str, Callable[[Any], plt.Figure]]]) -> list[str]:
    """Each (file name, figure of ``rep``) saved as a PNG in ``folder`` (made if needed); the paths written."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    files = []
    for name, fn in figures:
        fig = fn(rep)
        try:
            fig.savefig(folder / name, dpi=110)
        finally:
            plt.close(fig)
        files.append(str(folder / name))
    return files


def _bias(rep: ModelReport) -> plt.Figure:
    t = rep.series.exposure_ms
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2))
    for k in ("measured", "baseline", "extended"):
        ax[0].plot(t, rep.bias[k], "o" if k == "measured" else "-", color=COLOURS[k], label=_label(rep, k))
    ax[0].set_xscale("log")
    ax[0].set_xlabel("exposure (ms)")
    ax[0].set_ylabel("50 %-threshold disk radius (px)")
    ax[0].set_title("exposure bias: measured vs predicted")
    ax[0].legend()
    c = rep.compensated
    ax[1].plot(t, c["radius_raw_px"] - np.nanmean(c["radius_raw_px"]), "o-", color="k",
               label=f"raw (std {c['spread_raw_px']:.3f} px)")
    for k in ("baseline", "extended"):
        v = c[f"radius_compensated_{k}_px"]
        ax[1].plot(t, v - np.nanmean(v), "o-", color=COLOURS[k],
                   label=f"compensated, {_label(rep, k)} (std {c[f'spread_{k}_px']:.3f} px)")
    ax[1].set_xscale("log")
    ax[1].set_xlabel("exposure (ms)")
    ax[1].set_ylabel("radius - mean (px)")
    ax[1].set_title("apparent radius after compensation")
    ax[1].legend(fontsize=8)
    fig.tight_layout()
    return fig


def _assemble(rep: ModelReport, arrays: list[np.ndarray]) -> np.ndarray:
    s = rep.series
    out = np.full((s.height, s.width), np.nan)
    for g, a in zip(s.grids, arrays, strict=True):
        out[g.y0::g.step, g.x0::g.step][: a.shape[0], : a.shape[1]] = a
    return out


def _first_middle_last(n_frames: int) -> list[int]:
    """Indices of the shortest, middle and longest exposure (frames are in exposure order)."""
    return sorted({0, n_frames // 2, n_frames - 1})


def _maps(rep: ModelReport) -> plt.Figure:
    s = rep.series
    pick = _first_middle_last(s.n_frames)
    fig, ax = plt.subplots(2, len(pick), figsize=(4.2 * len(pick), 7), squeeze=False)
    for col, i in enumerate(pick):
        for row, k in enumerate(("baseline", "extended")):
            res = [np.where(rep.check.layout.roi[g], (rep.predicted[k][i][g] - s.images[i][g]) / rep.check.sd[i][g],
                            np.nan) for g in range(len(s.grids))]
            img = _assemble(rep, res)
            if s.grids[0].step > 1:  # Bayer: fill the other sites for display
                img = _fill(img)
            im = ax[row, col].imshow(img, cmap="RdBu_r", vmin=-4, vmax=4, interpolation="nearest")
            ax[row, col].set_title(f"{_label(rep, k)}\n{s.exposure_ms[i]:g} ms", fontsize=9)
            ax[row, col].set_xticks([])
            ax[row, col].set_yticks([])
    fig.colorbar(im, ax=ax, shrink=0.7, label="(predicted - measured) / sd")
    fig.suptitle("residual maps")
    return fig


def _fill(img: np.ndarray) -> np.ndarray:
    out = img.copy()
    bad = np.isnan(out)
    for dy, dx in ((0, 1), (1, 0), (0, -1), (-1, 0), (1, 1), (-1, -1)):
        shifted = np.roll(img, (dy, dx), axis=(0, 1))
        fill = bad & ~np.isnan(shifted)
        out[fill] = shifted[fill]
        bad &= ~fill
    return out


def _binned(rep: ModelReport) -> plt.Figure:
    views = [("orientation", "angle_deg", "edge direction from disk centre (deg)"),
             ("intensity", "predicted_fraction_of_saturation", "predicted DN / saturation"),
             ("position", "distance_from_centre_over_half_diagonal", "distance from image centre / half-diagonal")]
    fig, ax = plt.subplots(2, 3, figsize=(14, 6.5))
    for col, (view, key, xlabel) in enumerate(views):
        for k in ("baseline", "extended"):
            b = rep.binned[k].get(view)
            if b is None:
                continue
            ax[0, col].plot(b[key], b["mean"], "o-", color=COLOURS[k], label=_label(rep, k))
            ax[1, col].plot(b[key], b["rms"], "o-", color=COLOURS[k], label=_label(rep, k))
        ax[0, col].axhline(0, color="0.6", lw=0.8)
        ax[1, col].axhline(1, color="0.6", lw=0.8)
        ax[0, col].set_title(view + (" (over-exposed frames, edge pixels)" if view == "orientation" else ""),
                             fontsize=9)
        ax[1, col].set_xlabel(xlabel)
    ax[0, 0].set_ylabel("mean normalised residual")
    ax[1, 0].set_ylabel("RMS normalised residual")
    ax[0, 0].legend(fontsize=8)
    fig.tight_layout()
    return fig


def _profiles(rep: ModelReport) -> plt.Figure:
    s = rep.series
    pick = _first_middle_last(s.n_frames)
    fig, ax = plt.subplots(1, len(pick), figsize=(4.6 * len(pick), 4), squeeze=False)
    dp = rep.disk_pixels["extended"]
    for col, i in enumerate(pick):
        off = np.concatenate([o[d >= 0] for o, d in zip(dp.offset_px, dp.disk, strict=True)])
        sel = np.abs(off) < 8
        edges = np.linspace(-8, 8, 65)
        meas = np.concatenate([im[d >= 0] for im, d in zip(s.images[i], dp.disk, strict=True)])
        a = ax[0, col]
        a.plot(off[sel][::7], meas[sel][::7], ".", ms=1.5, color="0.6", label="measured pixels")
        for k in ("measured", "baseline", "extended"):
            src = s.images[i] if k == "measured" else rep.predicted[k][i]
            v = np.concatenate([im[d >= 0] for im, d in zip(src, dp.disk, strict=True)])
            idx = np.digitize(off, edges) - 1
            ok = (idx >= 0) & (idx < 64)
            m = np.bincount(idx[ok], v[ok], 64) / np.maximum(np.bincount(idx[ok], minlength=64), 1)
            a.plot(0.5 * (edges[1:] + edges[:-1]), m, "-" if k != "measured" else "--", color=COLOURS[k],
                   label=_label(rep, k) + (" (binned)" if k == "measured" else ""))
        a.axhline(s.saturation_dn, color="0.3", lw=0.6, ls=":")
        a.set_title(f"{s.exposure_ms[i]:g} ms", fontsize=9)
        a.set_xlabel("distance from fitted disk edge (px, + outside)")
    ax[0, 0].set_ylabel("DN")
    ax[0, 0].legend(fontsize=7)
    fig.suptitle("edge profiles of all disks")
    fig.tight_layout()
    return fig


def _levels(rep: ModelReport) -> plt.Figure:
    t = rep.series.exposure_ms
    fig, ax = plt.subplots(figsize=(6, 4.2))
    for k in ("measured", "baseline", "extended"):
        v = rep.levels[k]
        st = "o" if k == "measured" else "-"
        ax.plot(t, v[:, 1], st, color=COLOURS[k], label=f"white, {_label(rep, k)}")
        ax.plot(t, np.maximum(v[:, 0], 0.1), st, color=COLOURS[k], alpha=0.5, label=f"black, {_label(rep, k)}")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.axhline(rep.series.saturation_dn, color="0.3", lw=0.6, ls=":")
    ax.set_xlabel("exposure (ms)")
    ax.set_ylabel("DN (disk centre / paper between disks)")
    ax.legend(fontsize=7)
    ax.set_title("black and white levels")
    fig.tight_layout()
    return fig


def _heldout(rep: ModelReport) -> plt.Figure:
    names = ["baseline"] + ["+".join(c.effects) for c in rep.singles] + [
        "+".join(c.effects) for c in rep.path if len(c.effects) > 1]
    vals = [rep.baseline_heldout.heldout_rms] + [c.heldout_rms for c in rep.singles] + [
        c.heldout_rms for c in rep.path if len(c.effects) > 1]
    fig, ax = plt.subplots(figsize=(7, 0.35 * len(names) + 1.5))
    colours = ["tab:red"] + ["tab:blue" if "+".join(rep.chosen) == n else "0.6" for n in names[1:]]
    ax.barh(range(len(names)), vals, color=colours)
    ax.set_yticks(range(len(names)))
    ax.set_yticklabels(names, fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("held-out RMS normalised error (lower is better)")
    ax.set_xlim(0.9 * min(vals), max(vals) * 1.02)
    ax.set_title("model extensions, judged on exposures not fitted")
    fig.tight_layout()
    return fig
