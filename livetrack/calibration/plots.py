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


def coverage_figure(result: CalibrationResult) -> plt.Figure:
    """The coverage heat map: points per cell of the coverage grid (``report.COVERAGE_CELLS``, the grid of the
    printed coverage and of the live stop rule), each cell's count written in it, empty corner cells outlined in
    red; the title is the printed coverage line."""
    cam = result.camera
    cov = result.coverage()
    cols, rows = cov.cells
    fig, ax = plt.subplots(figsize=(8, 8 * cam.height / cam.width + 0.6))
    im = ax.imshow(cov.counts, extent=(-0.5, cam.width - 0.5, cam.height - 0.5, -0.5), cmap="magma",
                   interpolation="nearest")
    fig.colorbar(im, ax=ax, label="points per cell")
    top = max(int(cov.counts.max()), 1)
    for i in range(rows):
        for j in range(cols):
            n = int(cov.counts[i, j])
            ax.text(-0.5 + (j + 0.5) * cov.cell_width_px, -0.5 + (i + 0.5) * cov.cell_height_px, str(n),
                    ha="center", va="center", fontsize=8, color="black" if n > 0.6 * top else "white")
            if n == 0 and i in (0, rows - 1) and j in (0, cols - 1):
                ax.add_patch(plt.Rectangle((-0.5 + j * cov.cell_width_px, -0.5 + i * cov.cell_height_px),
                                           cov.cell_width_px, cov.cell_height_px, fill=False, edgecolor="red",
                                           linewidth=2))
    ax.set_title(f"{cov.text()}; {len(result.view_names)} views")
    ax.set_xlabel("x (px)")
    ax.set_ylabel("y (px)")
    fig.tight_layout()
    return fig


def _coverage(result: CalibrationResult, file: Path) -> Path:
    fig = coverage_figure(result)
    fig.savefig(file, dpi=100)
    plt.close(fig)
    return file
