"""OpenCV's circle-grid calibration as a baseline, on a rendered grid: black disks on white paper drawn through
the full camera model (supersampled), blurred by a Gaussian PSF, exposed, with shot and read noise, clipped at
full scale. ``findCirclesGrid`` + ``calibrateCamera`` then see the same exposure bias a real grid would. Pure (no
I/O); used by the exposure comparison of ``livetrack.calibration.experiment``."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from livetrack.calibration.chessboard import ChessboardOptions, calibrate_points
from livetrack.calibration.report import CalibrationResult
from livetrack.camera import CameraModel
from livetrack.geometry import Pose

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class CircleGrid:
    """A symmetric grid of ``cols`` x ``rows`` black disks of ``radius_m``, centres ``spacing_m`` apart, on a white
    sheet reaching ``margin_m`` beyond the outer disks. Board frame: centred, z = 0."""

    cols: int = 7
    rows: int = 5
    spacing_m: float = 0.03
    radius_m: float = 0.009
    margin_m: float = 0.03

    def centres_m(self) -> FloatArray:
        """Disk centres (N, 3), row by row, in the order ``findCirclesGrid`` returns them."""
        x = (np.arange(self.cols) - (self.cols - 1) / 2) * self.spacing_m
        y = (np.arange(self.rows) - (self.rows - 1) / 2) * self.spacing_m
        xx, yy = np.meshgrid(x, y)
        return np.column_stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)])


def pixel_rays(camera: CameraModel, supersampling: int = 4) -> FloatArray:
    """Viewing rays (H * W * n * n, 3) of an n x n grid of sub-pixel points in every pixel (the same for every pose
    of one camera: compute once)."""
    n = supersampling
    sub = (np.arange(n) + 0.5) / n - 0.5
    ys, xs = np.mgrid[0:camera.height, 0:camera.width]
    shape = (camera.height, camera.width, n, n)
    px = np.broadcast_to(xs[..., None, None] + sub[None, None, None, :], shape).reshape(-1)
    py = np.broadcast_to(ys[..., None, None] + sub[None, None, :, None], shape).reshape(-1)
    return camera.unproject(np.column_stack([px, py]))


def optical_image(camera: CameraModel, grid: CircleGrid, pose: Pose, rays: FloatArray,
                  psf_sigma_px: float = 0.8) -> FloatArray:
    """Reflectance seen by each pixel (H, W) (paper 0.85, ink 0.04, background 0.2), area-integrated over the
    sub-pixel ``rays`` (:func:`pixel_rays`) and blurred by a Gaussian PSF."""
    n2 = rays.shape[0] // (camera.height * camera.width)
    normal = pose.R[:, 2]
    along = rays @ normal
    hit = along > 1e-9
    X = rays * ((normal @ pose.t) / np.where(hit, along, 1.0))[:, None]
    q = (X - pose.t) @ pose.R
    half_w = (grid.cols - 1) / 2 * grid.spacing_m + grid.margin_m
    half_h = (grid.rows - 1) / 2 * grid.spacing_m + grid.margin_m
    on_sheet = hit & (np.abs(q[:, 0]) <= half_w) & (np.abs(q[:, 1]) <= half_h)
    gx = np.round(q[:, 0] / grid.spacing_m + (grid.cols - 1) / 2)
    gy = np.round(q[:, 1] / grid.spacing_m + (grid.rows - 1) / 2)
    in_grid = (gx >= 0) & (gx < grid.cols) & (gy >= 0) & (gy < grid.rows)
    dx = q[:, 0] - (gx - (grid.cols - 1) / 2) * grid.spacing_m
    dy = q[:, 1] - (gy - (grid.rows - 1) / 2) * grid.spacing_m
    ink = on_sheet & in_grid & (dx * dx + dy * dy <= grid.radius_m ** 2)
    reflectance = np.where(ink, 0.04, np.where(on_sheet, 0.85, 0.2))
    image = reflectance.reshape(camera.height, camera.width, n2).mean(axis=2)
    return cv2.GaussianBlur(image, (0, 0), psf_sigma_px)


def expose(optical: FloatArray, exposure_factor: float, rng: np.random.Generator, bit_depth: int = 12,
           white_fraction: float = 0.55, full_well_e: float = 10000.0, read_noise_e: float = 5.0,
           noise: bool = True) -> npt.NDArray[np.uint16]:
    """Paper (0.85) at ``white_fraction`` of full well x ``exposure_factor``; shot and read noise (``noise``
    False: none, only the rounding to DN); clipped at full well and full scale; (H, W) uint16 of ``bit_depth``
    bits."""
    electrons = np.clip(optical / 0.85 * white_fraction * full_well_e * exposure_factor, 0, None)
    if noise:
        electrons = rng.poisson(electrons).astype(np.float64)
    electrons = np.minimum(electrons, full_well_e)
    if noise:
        electrons = electrons + rng.normal(0.0, read_noise_e, electrons.shape)
    top = (1 << bit_depth) - 1
    return np.clip(np.round(electrons / full_well_e * top), 0, top).astype(np.uint16)


def find_grid(image: npt.NDArray, grid: CircleGrid, bit_depth: int) -> FloatArray | None:
    """Disk centres (N, 2) found by ``cv2.findCirclesGrid`` (symmetric grid, its default blob detector) on the
    image scaled to 8 bits, or None."""
    gray = np.clip(np.asarray(image, dtype=np.float64) * (255.0 / ((1 << bit_depth) - 1)), 0, 255)
    found, centres = cv2.findCirclesGrid(gray.round().astype(np.uint8), (grid.cols, grid.rows),
                                         flags=cv2.CALIB_CB_SYMMETRIC_GRID)
    return centres.reshape(-1, 2).astype(np.float64) if found else None


def calibrate_grid(images: list[npt.NDArray], grid: CircleGrid, camera_size: tuple[int, int],
                   bit_depth: int, reject: bool = True) -> CalibrationResult | None:
    """OpenCV's calibration (5 coefficients, ``calibrateCameraExtended``) from the views where the grid is found,
    or None with fewer than 3. ``reject`` (default): views with outlying residuals are left out as in the chessboard
    mode (``calibrate_points``: RMS above 3 x the median and 1 px); findCirclesGrid sometimes takes a noise blob for
    a disk of an over-exposed view (a centre 12 px off: k1 +23 % with that view kept). False: every view found."""
    obj, img, names = [], [], []
    for k, image in enumerate(images):
        centres = find_grid(image, grid, bit_depth)
        if centres is not None:
            obj.append(grid.centres_m())
            img.append(centres)
            names.append(f"view{k}")
    if len(obj) < 3:
        return None
    width, height = camera_size
    options = ChessboardOptions(reject_factor=3.0 if reject else np.inf, reject_min_px=1.0 if reject else np.inf)
    return calibrate_points(obj, img, width, height, names, options, bit_depth)
