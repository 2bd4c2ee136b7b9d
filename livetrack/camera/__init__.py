"""The camera: its intrinsics and distortion (``model``: ``CameraModel``), its YAML file with the optional fitted
optics and calibration uncertainty (``io``), and those optics as estimator options (``optics``)."""

from livetrack.camera.model import CameraModel

__all__ = ["CameraModel"]
