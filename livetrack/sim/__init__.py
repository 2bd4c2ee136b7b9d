"""Image-formation simulator: exact geometric coverage of printed sheets, then optics and sensor."""

from livetrack.sim.coverage import Placement, corner_map, render_reflectance
from livetrack.sim.texture import EdgeTexture, ImageTexture, PlanarTexture, TargetTexture

__all__ = [
    "EdgeTexture",
    "ImageTexture",
    "Placement",
    "PlanarTexture",
    "TargetTexture",
    "corner_map",
    "render_reflectance",
]
