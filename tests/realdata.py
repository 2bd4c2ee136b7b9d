"""Where the real camera images live: ``$LIVETRACK_REALDATA`` or ``../shared/realdata`` beside the repository; and
the phone photos of printed targets, tracked once per test session (each 16 MP photo takes 3-14 s: the tests that
read them share one ``Tracker.process`` per photo)."""

from __future__ import annotations

import functools
import os
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
IMX519_PIXEL_PITCH_UM = 1.22
"""OnePlus 6 main sensor, which took the target photos (realdata README)."""


def realdata_dir() -> Path | None:
    folder = Path(os.environ.get("LIVETRACK_REALDATA", REPO.parent / "shared" / "realdata"))
    return folder if folder.is_dir() else None


def target_photos() -> list[Path]:
    """The phone photos ``cibleNN_MM.jpg`` of printed target NN (none without the real data)."""
    root = realdata_dir()
    return sorted((root / "target-photos" / "photos").glob("cible*.jpg")) if root else []


def read_photo(path: Path):
    """The photo as 8-bit grey, its pixels as stored (EXIF orientation ignored: the camera is the sensor's)."""
    import cv2

    return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)


def photo_camera(path: Path):
    """The photo's camera from its EXIF (focal length, size; sRGB encoding)."""
    from livetrack.camera.io import camera_from_exif

    image = read_photo(path)
    return camera_from_exif(path, image.shape[1], image.shape[0], IMX519_PIXEL_PITCH_UM)


@functools.cache
def tracked_photo(path: Path):
    """``Tracker.process`` of the photo with its EXIF camera and the photos' targets (cached for the session)."""
    from livetrack.estimator.tracker import Tracker
    from livetrack.targets.spec import load_targets

    targets = load_targets(realdata_dir() / "target-photos" / "targets.yaml")
    return Tracker(photo_camera(path), targets).process(read_photo(path))
