"""``livetrack detect`` on image files: images without a camera, several images with bad ones among them, float and
16-bit data. The images are rendered by the simulator (seeded) and saved without EXIF."""

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from livetrack.cli import main
from livetrack.sim.scenario import Scenario

WIDTH, HEIGHT, F_PX = 960, 600, 900.0
TARGETS_YAML = "targets:\n  - id: 3\n    outer_radius_m: 0.125\n"
RUNNER = "import sys, livetrack.cli as cli; sys.exit(cli.main(sys.argv[1:]))"


def _scenario(bit_depth: int) -> Scenario:
    return Scenario.from_dict({
        "name": "detect-cli", "seed": 4,
        "camera": {"width": WIDTH, "height": HEIGHT, "fx": F_PX, "fy": F_PX, "cx": (WIDTH - 1) / 2,
                   "cy": (HEIGHT - 1) / 2, "bit_depth": bit_depth},
        "targets": [{"id": 3, "outer_radius_m": 0.125}],
        "poses": [{"target_id": 3, "t_m": [0.15, -0.1, 2.2], "tilt_deg": 20, "tilt_axis_deg": 30}],
        "exposure": {"nominal_us": "auto", "factors": [1]},
    })


@pytest.fixture(scope="module")
def rendered():
    """The same pose rendered at 8 and at 12 bits: (image, truth pose) per bit depth."""
    out = {}
    for bits in (8, 12):
        frame = _scenario(bits).render_frame(0)
        out[bits] = (frame.image, frame.truth[3])
    return out


@pytest.fixture()
def files(tmp_path):
    targets = tmp_path / "targets.yaml"
    targets.write_text(TARGETS_YAML)
    camera = tmp_path / "camera12.yaml"
    camera.write_text(f"camera: {{width: {WIDTH}, height: {HEIGHT}, fx: {F_PX}, fy: {F_PX}, cx: {(WIDTH - 1) / 2}, "
                      f"cy: {(HEIGHT - 1) / 2}, bit_depth: 12}}\n")
    return tmp_path, targets, camera


def _detect(*argv) -> tuple[int, dict | None]:
    *_, out = argv
    code = main(["detect", *map(str, argv[:-1]), "--json", str(out)])
    return code, json.loads(out.read_text()) if out.exists() else None


def test_a_png_without_exif_gives_ids_levels_and_ellipses_and_an_explicit_null_pose(rendered, files, capsys):
    tmp, targets, _ = files
    image, truth = rendered[8]
    png = tmp / "screenshot.png"
    assert cv2.imwrite(str(png), image)
    code, data = _detect(png, "--targets", targets, tmp / "out.json")
    assert code == 0
    [entry] = data["frames"]
    assert entry["camera"] is None and "error" not in entry
    [target] = entry["targets"]
    assert target["target_id"] == 3 and target["levels"][0] == 0
    assert target["pose"] is None and "no camera: give --camera or --focal-px" in target["pose_reason"]
    outer = target["ellipses"][0]["outer"]
    centre_true = truth.t[:2] / truth.t[2] * F_PX + [(WIDTH - 1) / 2, (HEIGHT - 1) / 2]
    assert np.linalg.norm(np.array(outer["centre_px"]) - centre_true) < 1.5  # projected centre vs ellipse centre
    assert outer["semi_axes_px"][0] == pytest.approx(0.125 / 2.2 * F_PX, rel=0.05)
    assert "no pose (no camera" in capsys.readouterr().out


def test_focal_px_gives_the_pose_of_an_image_without_exif(rendered, files):
    tmp, targets, _ = files
    image, truth = rendered[8]
    png = tmp / "frame.png"
    assert cv2.imwrite(str(png), image)
    code, data = _detect(png, "--targets", targets, "--focal-px", F_PX, tmp / "out.json")
    assert code == 0
    entry = data["frames"][0]
    assert entry["camera"] == "focal_px" and entry["failures"] == []
    [target] = entry["targets"]
    assert target["ok"] and target["target_id"] == 3
    assert target["distance_m"] == pytest.approx(truth.distance_m, rel=1e-3)
    assert main(["detect", str(png), "--targets", str(targets), "--focal-px", "-3", "--json", str(tmp / "x")]) == 2


def test_several_images_bad_ones_are_reported_and_skipped_the_rest_processed(rendered, files):
    """A wrong-size image, a corrupt file and a missing one among good ones: each is an error in the JSON and on
    stderr, the good ones keep their poses, exit 0. With only bad inputs the exit status is 1."""
    tmp, targets, camera = files
    image12, truth = rendered[12]
    good_a, good_b, small, corrupt = tmp / "a.png", tmp / "b.png", tmp / "small.png", tmp / "corrupt.png"
    assert cv2.imwrite(str(good_a), image12) and cv2.imwrite(str(good_b), image12)
    assert cv2.imwrite(str(small), image12[:300, :480])
    corrupt.write_bytes(b"\x89PNG\r\n\x1a\nnot really")
    out = tmp / "out.json"
    cmd = [sys.executable, "-c", RUNNER, "detect", str(good_a), str(small), str(corrupt), str(tmp / "missing.png"),
           str(good_b), "--targets", str(targets), "--camera", str(camera), "--json", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    frames = json.loads(out.read_text())["frames"]
    assert [("error" in f) for f in frames] == [False, True, True, True, False]
    assert "480x300 but the camera is 960x600" in frames[1]["error"]
    for f in (frames[0], frames[4]):
        assert f["targets"][0]["ok"] and f["targets"][0]["distance_m"] == pytest.approx(truth.distance_m, rel=1e-3)
    for name in ("small.png", "corrupt.png", "missing.png"):
        assert name in proc.stderr
    assert "3 of 5 inputs skipped" in proc.stdout

    code, data = _detect(small, corrupt, "--targets", targets, "--camera", camera, tmp / "bad.json")
    assert code == 1 and all("error" in f for f in data["frames"])


def test_a_float_tiff_is_detected_like_the_integer_image(rendered, files):
    """A float32 TIFF in [0, 1] (another tool's output) is scaled to the camera's full scale: same target, same
    distance as the 12-bit PNG within 0.05 %; one holding NaN is refused with the reason."""
    tmp, targets, camera = files
    image12, truth = rendered[12]
    tiff, png = tmp / "float.tiff", tmp / "int.png"
    assert cv2.imwrite(str(tiff), image12.astype(np.float32) / 4095.0)
    assert cv2.imread(str(tiff), cv2.IMREAD_UNCHANGED).dtype == np.float32
    assert cv2.imwrite(str(png), image12)
    code, data = _detect(tiff, png, "--targets", targets, "--camera", camera, tmp / "out.json")
    assert code == 0
    from_float, from_int = (f["targets"][0] for f in data["frames"])
    assert from_float["ok"] and from_float["target_id"] == 3
    assert from_float["distance_m"] == pytest.approx(from_int["distance_m"], rel=5e-4)
    bad = image12.astype(np.float32) / 4095.0
    bad[0, 0] = np.nan
    assert cv2.imwrite(str(tiff), bad)
    code, data = _detect(tiff, "--targets", targets, "--camera", camera, tmp / "nan.json")
    assert code == 1 and "non-finite" in data["frames"][0]["error"]


def test_16_bit_values_above_the_cameras_bit_depth_are_warned_about(rendered, files, caplog):
    """12-bit data stored MSB-aligned (x16) with a 12-bit camera file: a warning in the JSON and the log; an
    LSB-aligned image gives none."""
    tmp, targets, camera = files
    image12, _ = rendered[12]
    msb, lsb = tmp / "msb.png", tmp / "lsb.png"
    assert cv2.imwrite(str(msb), (image12.astype(np.uint16) << 4)) and cv2.imwrite(str(lsb), image12)
    code, data = _detect(msb, lsb, "--targets", targets, "--camera", camera, tmp / "out.json")
    assert code == 0
    warned, clean = data["frames"]
    assert clean["warnings"] == []
    [warning] = warned["warnings"]
    assert "above the camera's 12-bit maximum 4095" in warning
    assert any("12-bit maximum" in r.getMessage() and r.levelname == "WARNING" for r in caplog.records)


@pytest.fixture(scope="module")
def over_exposed_12bit():
    """The same pose, 12-bit, at x8 of nominal (the paper clipped at 4095): (image, truth pose)."""
    scenario = _scenario(12)
    data = {"name": "detect-cli-x8", "seed": 4, "camera": scenario.camera.to_dict(),
            "targets": [{"id": 3, "outer_radius_m": 0.125}],
            "poses": [{"target_id": 3, "t_m": [0.15, -0.1, 2.2], "tilt_deg": 20, "tilt_axis_deg": 30}],
            "exposure": {"nominal_us": "auto", "factors": [8]}}
    frame = Scenario.from_dict(data).render_frame(0)
    assert frame.image.max() == 4095
    return frame.image, frame.truth[3]


def test_bit_depth_of_16_bit_words_is_taken_from_the_data_unless_stated(over_exposed_12bit, files):
    """A 12-bit camera's over-exposed frame saved LSB-aligned in a 16-bit PNG, without a camera file: taken as
    12-bit (clipped at 4095), the pose is exact. Stating 16 bits made the clipped paper look unclipped (0.047 %
    against 0.013 %, session 36); since session 37 the clip at 4095 is read off the frame (``clip_level``) and a wrong
    stated depth costs nothing."""
    tmp, targets, camera12 = files
    image, truth = over_exposed_12bit
    png = tmp / "x8.png"
    assert cv2.imwrite(str(png), image)
    errors = {}
    for name, extra in (("data", []), ("stated16", ["--bit-depth", "16"]), ("file", ["--camera", camera12])):
        focal = [] if name == "file" else ["--focal-px", F_PX]
        code, data = _detect(png, "--targets", targets, *focal, *extra, tmp / f"{name}.json")
        assert code == 0
        [entry] = data["frames"]
        assert (entry["bit_depth"], entry["bit_depth_from"]) == {"data": (12, "data"), "stated16": (16, "stated"),
                                                                 "file": (12, "stated")}[name]
        [target] = entry["targets"]
        errors[name] = abs(target["distance_m"] / truth.distance_m - 1.0)
    assert errors["data"] < 2e-4 and errors["file"] < 2e-4
    assert errors["data"] == pytest.approx(errors["file"], abs=1e-9)
    assert errors["stated16"] < 2e-4  # 0.047 % before the clip was read off the frame


def test_a_camera_file_without_bit_depth_takes_it_from_the_data(over_exposed_12bit, files):
    tmp, targets, _ = files
    image, truth = over_exposed_12bit
    png = tmp / "x8.png"
    assert cv2.imwrite(str(png), image)
    camera = tmp / "camera.yaml"
    camera.write_text(f"camera: {{width: {WIDTH}, height: {HEIGHT}, fx: {F_PX}, fy: {F_PX}, cx: {(WIDTH - 1) / 2}, "
                      f"cy: {(HEIGHT - 1) / 2}}}\n")
    code, data = _detect(png, "--targets", targets, "--camera", camera, tmp / "out.json")
    assert code == 0
    [entry] = data["frames"]
    assert (entry["bit_depth"], entry["bit_depth_from"], entry["warnings"]) == (12, "data", [])
    [target] = entry["targets"]
    assert abs(target["distance_m"] / truth.distance_m - 1.0) < 2e-4
