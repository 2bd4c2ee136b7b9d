"""PNG figures of a calibration (the edge of ``livetrack.calibration``; matplotlib, Agg): the residual quiver and
the coverage heat map. Every figure is closed after saving."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from livetrack.calibration.report import CalibrationResult  # noqa: E402


def write_plots(result: CalibrationResult, folder: str | Path) -> list[Path]:
    """Write ``residuals.png`` and ``coverage.png`` into ``folder``; returns their paths."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    return [_residual_quiver(result, folder / "residuals.png"), _coverage(result, folder / "coverage.png")]


def _residual_quiver(result: CalibrationResult, file: Path) -> Path:
    cam = result.camera
    points = np.concatenate([p.reshape(-1, 2) for p in result.points_px]) if result.points_px else np.zeros((0, 2))
    res = np.concatenate([r.reshape(-1, 2) for r in result.residuals_px]) if result.residuals_px else points
    norm = np.linalg.norm(res, axis=1)
    scale_px = max(float(np.percentile(norm, 95)) if len(norm) else 1.0, 1e-6)
    arrow_len_px = 0.04 * max(cam.width, cam.height)
    fig, ax = plt.subplots(figsize=(8, 8 * cam.height / cam.width + 0.6))
    q = ax.quiver(points[:, 0], points[:, 1], res[:, 0], res[:, 1], norm, angles="xy", scale_units="xy",
                  scale=scale_px / arrow_len_px, cmap="viridis", width=0.002)
    fig.colorbar(q, ax=ax, label="residual (px)")
    ax.set_xlim(-0.5, cam.width - 0.5)
    ax.set_ylim(cam.height - 0.5, -0.5)
    ax.set_aspect("equal")
    ax.set_title(f"residuals (measured - model), x{arrow_len_px / scale_px:.0f}; RMS {result.rms_px:.3f} px")
    ax.set_xlabel("x (px)")
    ax.set_ylabel("y (px)")
    fig.tight_layout()
    fig.savefig(file, dpi=100)
    plt.close(fig)
    return file


def _coverage(result: CalibrationResult, file: Path) -> Path:
    cam = result.camera
    cov = result.coverage((16, 12))
    fig, ax = plt.subplots(figsize=(8, 8 * cam.height / cam.width + 0.6))
    im = ax.imshow(cov.counts, extent=(-0.5, cam.width - 0.5, cam.height - 0.5, -0.5), cmap="magma",
                   interpolation="nearest")
    fig.colorbar(im, ax=ax, label="points per cell")
    ax.set_title(f"coverage: {cov.covered_fraction:.0%} of {cov.counts.size} cells, {len(result.view_names)} views")
    ax.set_xlabel("x (px)")
    ax.set_ylabel("y (px)")
    fig.tight_layout()
    fig.savefig(file, dpi=100)
    plt.close(fig)
    return file
