"""Files of the ring check (the edge of ``livetrack.modelcheck.rings``): PNG figures (matplotlib, Agg) and the
fitted camera file.

``write_ring_plots(report, folder)`` writes bias_curve.png (left: the per-edge exposure bias of the 50 %-threshold
ring vs exposure, measured and predicted by the baseline and the chosen model, with the tracker's delta; right: the
ring thickness after compensation with each model), residuals_binned.png (by edge direction, predicted intensity,
image position) and heldout.png. ``write_ring_camera(report, file)`` writes the camera file (intrinsics of the
recording, ``optics``: core and halo of the chosen model, ``response``: read noise of saturated pixels).
"""

from __future__ import annotations

import os
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from livetrack.camera.io import write_camera_file  # noqa: E402
from livetrack.camera.optics import CameraOptics  # noqa: E402
from livetrack.modelcheck.plots import save_figures  # noqa: E402
from livetrack.modelcheck.rings import RingReport  # noqa: E402

COLOURS = {"measured": "k", "baseline": "tab:red", "extended": "tab:blue"}


def _label(rep: RingReport, key: str) -> str:
    return "chosen: " + (" + ".join(rep.chosen) or "baseline") if key == "extended" else key


def write_ring_plots(rep: RingReport, folder: str | os.PathLike) -> list[str]:
    return save_figures(rep, folder, (("bias_curve.png", _bias), ("residuals_binned.png", _binned),
                                      ("heldout.png", _heldout)))


def _bias(rep: RingReport) -> Any:
    items = rep.check.items
    t = np.array([it.exposure_us for it in items])
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    for k in ("measured", "baseline", "extended"):
        style = {"ls": "none", "marker": "o"} if k == "measured" else {"ls": "none", "marker": "x", "ms": 8}
        a.plot(t, rep.bias[k], color=COLOURS[k], label=_label(rep, k), **style)
    a.plot(t, [it.delta_px for it in items], ls="none", marker="+", color="tab:green", ms=9,
           label="tracker delta (fitted edges)")
    a.set_xscale("log")
    a.set_xlabel("exposure (us)")
    a.set_ylabel("exposure bias per edge (px, + = white grows)")
    a.set_title("50 %-threshold ring: bias vs exposure")
    a.axhline(0, color="0.7", lw=0.8)
    a.legend(fontsize=8)
    for k in ("baseline", "extended"):
        b.plot(t, -2.0 * rep.compensated[f"delta_compensated_{k}_px"], ls="none", marker="o", color=COLOURS[k],
               label=f"{_label(rep, k)} (spread {rep.compensated[f'spread_{k}_px']:.3f} px)")
    b.plot(t, -2.0 * rep.bias["measured"], ls="none", marker=".", color="k",
           label=f"raw (spread {rep.compensated['spread_raw_px']:.3f} px)")
    b.set_xscale("log")
    b.set_xlabel("exposure (us)")
    b.set_ylabel("ring thickness - printed (px)")
    b.set_title("after compensation with each model (flat is good)")
    b.axhline(0, color="0.7", lw=0.8)
    b.legend(fontsize=8)
    fig.tight_layout()
    return fig


def _binned(rep: RingReport) -> Any:
    fig, axes = plt.subplots(2, 3, figsize=(13, 6.5), sharex="col")
    views = (("orientation", "angle_deg", "edge normal direction (deg), over-exposed frames"),
             ("intensity", "predicted_fraction_of_saturation", "predicted intensity / saturation"),
             ("position", "distance_from_centre_over_half_diagonal", "distance from image centre / half-diagonal"))
    for col, (view, key, xlabel) in enumerate(views):
        for k in ("baseline", "extended"):
            data = rep.binned[k].get(view)
            if data is None:
                continue
            axes[0, col].plot(data[key], data["mean"], marker="o", color=COLOURS[k], label=_label(rep, k))
            axes[1, col].plot(data[key], data["rms"], marker="o", color=COLOURS[k], label=_label(rep, k))
        axes[1, col].set_xlabel(xlabel)
        axes[0, col].axhline(0, color="0.7", lw=0.8)
        axes[1, col].axhline(1, color="0.7", lw=0.8)
    axes[0, 0].set_ylabel("mean (pred - meas) / sd")
    axes[1, 0].set_ylabel("RMS (pred - meas) / sd")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle("residuals of the pixels around the target's edges")
    fig.tight_layout()
    return fig


def _heldout(rep: RingReport) -> Any:
    names = ["baseline"] + ["+".join(c.effects) for c in rep.singles] + ["path: " + "+".join(c.effects)
                                                                       for c in rep.path]
    values = [rep.baseline_heldout.heldout_rms] + [c.heldout_rms for c in rep.singles] + [c.heldout_rms
                                                                                          for c in rep.path]
    fig, ax = plt.subplots(figsize=(8, 0.35 * len(names) + 1.5))
    ax.barh(range(len(names)), values, color=["tab:red"] + ["0.6"] * len(rep.singles) + ["tab:blue"] * len(rep.path))
    ax.set_yticks(range(len(names)), names, fontsize=8)
    ax.invert_yaxis()
    ax.set_xscale("log")
    ax.axvline(1, color="k", lw=0.8)
    ax.set_xlabel("held-out RMS normalised error (1 = noise)")
    fig.tight_layout()
    return fig


def fitted_ring_optics(rep: RingReport) -> CameraOptics:
    """The chosen model's core and halo, and the saturated-pixel read noise."""
    p = rep.final.params
    halo = "halo" in rep.final.effects
    return CameraOptics(psf_sigma_px=float(p["sigma_px"]), halo_fraction=float(p["halo_fraction"]) if halo else 0.0,
                        halo_sigma_px=float(p["halo_sigma_px"]) if halo else None, read_noise_dn=rep.read_noise_dn)


def write_ring_camera(rep: RingReport, file: str | os.PathLike) -> dict[str, Any]:
    """Write the camera file (the recording's intrinsics, the fitted optics); return what was written."""
    optics = fitted_ring_optics(rep)
    left_out = [e for e in rep.final.effects if e != "halo"]
    lines = [f"livetrack model --camera-out: fitted on the ring recording {rep.series.name} "
             f"({len(set(rep.series.exposure_us.tolist()))} exposures)",
             f"chosen model: {' + '.join(rep.final.effects) or 'baseline (Gaussian PSF)'}"]
    if left_out:
        lines.append(f"not stored (the estimator does not model them): {', '.join(left_out)}")
    if optics.read_noise_dn is None:
        lines.append("no deeply saturated frame: response.read_noise_dn not measured")
    write_camera_file(file, rep.series.camera, optics, "\n".join(lines))
    return {"file": str(file), "optics": optics.to_sections(), "intrinsics": True, "not_exported": left_out}
