"""The estimator on real phone photos of printed targets (no calibration: the camera comes from EXIF): the tracker's
result and its detection, from one ``tracked_photo`` run per photo (this module runs in one pytest-xdist worker with
``--dist loadfile``, so each photo is tracked once)."""

import dataclasses
import re

import cv2
import numpy as np
import pytest

from livetrack.camera.encoding import linearise
from livetrack.estimator.detect import detect
from livetrack.estimator.tracker import Tracker
from livetrack.targets.spec import load_targets
from tests.realdata import photo_camera, read_photo, realdata_dir, target_photos, tracked_photo
from tests.test_detect import angle_diff_deg

DATA = realdata_dir()
PHOTOS = target_photos()
needs_photos = pytest.mark.skipif(not PHOTOS,
                                  reason="../shared/realdata/target-photos not present (set LIVETRACK_REALDATA)")


@pytest.mark.skipif(not PHOTOS, reason="../shared/realdata/target-photos not present (set LIVETRACK_REALDATA)")
@pytest.mark.parametrize("photo", PHOTOS, ids=lambda p: p.stem)
def test_every_printed_target_is_found_with_its_id_and_a_plausible_pose(photo):
    """The tracker on the photo (its frame linearised from sRGB): one target, its id, and a pose. The detection
    itself (level, code margin, heading): ``tests/test_detect.py`` on the same run (``tracked_photo``)."""
    expected_id = int(re.match(r"cible(\d+)_", photo.name).group(1))
    result = tracked_photo(photo)
    assert [t.target_id for t in result.targets] == [expected_id]
    target = result.targets[0]
    fit = target.fit
    assert fit.ok
    assert target.n_edge_points > 300
    # A phone JPEG (sharpened, uncalibrated lens) fits the edge model to a pixel or two, not better.
    assert fit.residual_rms_px < 3.0
    assert 0.15 < fit.pose.distance_m < 4.0  # photos taken from about 0.3 to 3 m
    assert fit.pose.normal_cam @ fit.pose.t > 0  # the printed face looks at the camera
    assert np.all(np.isfinite(fit.pose_covariance))
    assert target.heading_known == (expected_id != 1)  # "11111111" gives no heading


@pytest.mark.skipif(not PHOTOS, reason="../shared/realdata/target-photos not present (set LIVETRACK_REALDATA)")
def test_a_phone_jpeg_is_read_as_srgb_and_fits_the_edge_model_better_so():
    """EXIF ColorSpace 1 (sRGB) gives a camera whose frames the tracker linearises. On cible01_05 (target 1 at 0.76
    m) the edge residuals fall 1.11 -> 0.80 px and the white's growth 1.81 -> 0.47 px: much of the bias read as
    over-exposure was the encoding; the distance moves by 0.02 % (the compensation had absorbed it). All 14 photos
    on 2026-12-06: residuals lower in 13, |delta| lower in 12, distances within 0.08 %."""
    photo = next(p for p in PHOTOS if p.stem == "cible01_05")
    targets = load_targets(DATA / "target-photos" / "targets.yaml")
    camera = photo_camera(photo)
    assert camera.encoding == "srgb"
    [srgb] = tracked_photo(photo).targets
    [linear] = Tracker(dataclasses.replace(camera, encoding="linear"), targets).process(read_photo(photo)).targets
    assert srgb.fit.ok and linear.fit.ok
    assert srgb.fit.residual_rms_px < 0.85 * linear.fit.residual_rms_px
    assert abs(srgb.fit.delta_px) < 0.5 * abs(linear.fit.delta_px)
    assert srgb.fit.pose.distance_m == pytest.approx(linear.fit.pose.distance_m, rel=1e-3)


@needs_photos
@pytest.mark.parametrize("path", PHOTOS, ids=lambda p: p.stem)
def test_real_photos_full_resolution(path):
    """The detection in the tracker's run on the photo (``tracked_photo``, shared with ``test_real_photos.py``:
    the frame linearised from sRGB, as ``livetrack detect`` reads a phone JPEG): one candidate, level 0."""
    expected = int(path.stem[5:7])
    result = tracked_photo(path)
    assert result.failures == []
    cands = [t.candidate for t in result.targets]
    assert [(c.target_id, c.level) for c in cands] == [(expected, 0)]
    c = cands[0]
    assert c.outer.a > 50 and c.code_margin > 1.5
    assert (c.heading_rad is None) == (c.spec.code.bits == "11111111")
    assert (c.rotation_slots is None) == (c.heading_rad is None)


@needs_photos
@pytest.mark.parametrize("path", PHOTOS[::3], ids=lambda p: p.stem)
def test_real_photos_downscaled_agree(path):
    """A quarter-size copy of the linearised photo gives the same id, heading (within a few degrees) and ellipse
    (scaled) as the full-size one."""
    specs = load_targets(DATA / "target-photos" / "targets.yaml")
    linear = linearise(read_photo(path), "srgb", 8)
    small = cv2.resize(linear, None, fx=0.25, fy=0.25, interpolation=cv2.INTER_AREA)
    [full] = [t.candidate for t in tracked_photo(path).targets]
    quarter, = detect(small, specs)
    assert full.target_id == quarter.target_id
    assert quarter.outer.a * 4 == pytest.approx(full.outer.a, rel=0.02)
    # INTER_AREA: quarter-size pixel i covers full-size pixels 4i .. 4i + 3, centre 4i + 1.5.
    assert np.linalg.norm(quarter.outer.centre_px * 4 + 1.5 - full.outer.centre_px) < 4.0
    if full.heading_rad is not None:
        assert angle_diff_deg(full.heading_rad, quarter.heading_rad) < 5.0
