"""Printable targets: exact 1:1 geometry in SVG, PDF and PNG, and the ``livetrack target`` command."""

from __future__ import annotations

import math
import re
import struct
import xml.etree.ElementTree as ET
from pathlib import Path

import cv2
import numpy as np
import pytest

from livetrack import cli
from livetrack.targets import artwork
from livetrack.targets.spec import TargetSpec, load_targets

REAL_TARGETS = Path("/work/shared/realdata/target-photos/targets.yaml")
SVG_NS = "{http://www.w3.org/2000/svg}"


def _real_spec(target_id: int) -> TargetSpec:
    if not REAL_TARGETS.exists():
        pytest.skip(f"{REAL_TARGETS} not present")
    return next(s for s in load_targets(REAL_TARGETS) if s.id == target_id)


def _expected_disks_mm(spec: TargetSpec) -> list[tuple[float, float, float, str]]:
    """(dx, dy, r, fill) relative to the target centre, in drawing order, straight from the spec."""
    out = []
    for _, level in spec.levels():
        out.append((0.0, 0.0, 1000 * level.outer_radius_m, "#000000"))
        out.append((0.0, 0.0, 1000 * level.inner_radius_m, "#ffffff"))
        if level.code is not None:
            for x, y in level.code.white_dot_centres_m():
                out.append((1000 * x, 1000 * y, 1000 * level.code.dot_radius_m, "#ffffff"))
        if level.centre_dot_radius_m > 0:
            out.append((0.0, 0.0, 1000 * level.centre_dot_radius_m, "#000000"))
    return out


# ---------------------------------------------------------------------------------------------------- layout
@pytest.mark.parametrize("diameter_mm", [20.0, 100.0, 250.0, 1000.0])
def test_layout_keeps_text_and_scale_bar_out_of_the_clear_zone(diameter_mm):
    spec = TargetSpec.default(3, diameter_mm / 2000.0)
    lay, items = artwork.page_items(spec)
    R = diameter_mm / 2
    assert lay.clear_margin_mm >= 0.1 * R
    assert lay.centre_x_mm == pytest.approx(lay.width_mm / 2)
    assert lay.centre_y_mm == pytest.approx(lay.height_mm / 2)
    assert lay.centre_x_mm - R - lay.clear_margin_mm >= -1e-9  # clear zone on the page
    assert lay.centre_y_mm - R - lay.clear_margin_mm >= -1e-9
    assert lay.scale_bar_mm + 2 * artwork.EDGE_MM <= lay.width_mm
    marks = [it for it in items[1:] if not isinstance(it, artwork.Disk)]
    assert len(marks) >= 5  # two text lines, bar, two ticks, bar label
    for it in marks:
        if isinstance(it, artwork.Text):
            x0, x1 = it.x_mm, it.x_mm + len(it.text) * artwork.TEXT_WIDTH_PER_CHAR_EM * it.size_mm
            y0, y1 = it.baseline_mm - it.size_mm, it.baseline_mm + 0.3 * it.size_mm
        else:
            x0, x1, y0, y1 = it.x_mm, it.x_mm + it.w_mm, it.y_mm, it.y_mm + it.h_mm
        assert 0 <= x0 and x1 <= lay.width_mm and 0 <= y0 and y1 <= lay.height_mm, it
        # Nearest point of the box to the target centre lies outside the clear zone.
        nx = min(max(lay.centre_x_mm, x0), x1)
        ny = min(max(lay.centre_y_mm, y0), y1)
        assert math.hypot(nx - lay.centre_x_mm, ny - lay.centre_y_mm) >= R + lay.clear_margin_mm, it


def test_scale_bar_ticks_are_exactly_the_stated_length_apart():
    lay, items = artwork.page_items(TargetSpec.default(8, 0.125))
    ticks = [it for it in items if isinstance(it, artwork.Rect) and it.h_mm == artwork.TICK_MM]
    assert len(ticks) == 2
    centres = sorted(t.x_mm + t.w_mm / 2 for t in ticks)
    assert centres[1] - centres[0] == pytest.approx(lay.scale_bar_mm, abs=1e-12)
    texts = [it.text for it in items if isinstance(it, artwork.Text)]
    assert any(f"{lay.scale_bar_mm:.0f} mm" in t for t in texts)


# ---------------------------------------------------------------------------------------------------- SVG
@pytest.mark.parametrize("which", ["default-2-levels", "real-id-8"])
def test_svg_is_mm_exact_and_matches_the_spec(tmp_path, which):
    spec = TargetSpec.default(8, 0.125, levels=2) if which.startswith("default") else _real_spec(8)
    out = artwork.write_target(spec, tmp_path / "t.svg")
    root = ET.parse(out).getroot()
    lay = artwork.page_layout(spec)
    assert root.tag == f"{SVG_NS}svg"
    assert root.get("width") == f"{lay.width_mm:g}mm" and root.get("height") == f"{lay.height_mm:g}mm"
    assert [float(v) for v in root.get("viewBox").split()] == [0.0, 0.0, lay.width_mm, lay.height_mm]
    circles = root.findall(f"{SVG_NS}circle")
    expected = _expected_disks_mm(spec)
    assert len(circles) == len(expected)
    for c, (dx, dy, r, fill) in zip(circles, expected, strict=True):
        assert float(c.get("r")) == pytest.approx(r, abs=1e-4)
        assert float(c.get("cx")) - lay.centre_x_mm == pytest.approx(dx, abs=1e-4)
        assert float(c.get("cy")) - lay.centre_y_mm == pytest.approx(dy, abs=1e-4)
        assert c.get("fill") == fill
    assert float(circles[0].get("r")) * 2 == pytest.approx(2000 * spec.outer_radius_m)
    texts = " ".join(t.text for t in root.findall(f"{SVG_NS}text"))
    assert f"id {spec.id}" in texts and "print at 100 %" in texts and "mm between tick centres" in texts
    # The white page comes first, under everything.
    first = root.find(f"{SVG_NS}rect")
    assert first.get("fill") == "#ffffff" and float(first.get("width")) == lay.width_mm


# ---------------------------------------------------------------------------------------------------- PDF
def _pdf_objects(data: bytes) -> dict[int, bytes]:
    """Objects found through the xref table (checks that every offset points at its object)."""
    start = int(re.search(rb"startxref\s+(\d+)\s+%%EOF", data).group(1))
    m = re.match(rb"xref\s+0 (\d+)\s+", data[start:])
    count = int(m.group(1))
    table = data[start + m.end(): start + m.end() + 20 * count]
    objects = {}
    for number in range(1, count):
        offset = int(table[20 * number: 20 * number + 10])
        head = f"{number} 0 obj".encode()
        assert data[offset: offset + len(head)] == head
        objects[number] = data[offset: data.index(b"endobj", offset)]
    return objects


@pytest.mark.parametrize("diameter_mm", [60.0, 250.0, 1000.0])
def test_pdf_page_size_in_points_matches_mm(tmp_path, diameter_mm):
    spec = TargetSpec.default(5, diameter_mm / 2000.0)
    data = artwork.write_target(spec, tmp_path / "t.pdf").read_bytes()
    assert data.startswith(b"%PDF-1.4") and data.rstrip().endswith(b"%%EOF")
    lay = artwork.page_layout(spec)
    box = [float(v) for v in re.search(rb"/MediaBox \[([-\d. ]+)\]", data).group(1).split()]
    assert box[:2] == [0.0, 0.0]
    assert box[2] == pytest.approx(lay.width_mm * 72 / 25.4, abs=0.01)
    assert box[3] == pytest.approx(lay.height_mm * 72 / 25.4, abs=0.01)
    objects = _pdf_objects(data)
    stream_obj = next(o for o in objects.values() if b"stream" in o)
    length = int(re.search(rb"/Length (\d+)", stream_obj).group(1))
    body = stream_obj[stream_obj.index(b"stream\n") + 7:]
    assert body[length:].startswith(b"endstream")
    # The first path after the page rectangle is the black outer disk: its start point is (cx + R, cy) in mm.
    m = re.search(rb"0 g\n([-\d.]+) ([-\d.]+) m", body)
    assert float(m.group(1)) == pytest.approx(lay.centre_x_mm + diameter_mm / 2, abs=1e-4)
    assert float(m.group(2)) == pytest.approx(lay.centre_y_mm, abs=1e-4)
    assert body.count(b" c\n") + body.count(b" c\nh f") >= 8 * len(_expected_disks_mm(spec))


def test_pdf_circle_arcs_stay_on_the_circle():
    r = 125.0
    path = artwork._pdf_circle(0.0, 0.0, r)
    numbers = [[float(v) for v in line.split()[:-1]] for line in path.splitlines() if line.endswith(" c")]
    assert len(numbers) == 8
    start = (r, 0.0)
    worst = 0.0
    for seg in numbers:
        p0, p1, p2, p3 = np.array(start), np.array(seg[0:2]), np.array(seg[2:4]), np.array(seg[4:6])
        t = np.linspace(0, 1, 101)[:, None]
        curve = (1 - t) ** 3 * p0 + 3 * (1 - t) ** 2 * t * p1 + 3 * (1 - t) * t**2 * p2 + t**3 * p3
        worst = max(worst, float(np.abs(np.hypot(curve[:, 0], curve[:, 1]) - r).max()))
        start = (seg[4], seg[5])
    assert start == pytest.approx((r, 0.0), abs=1e-4)
    assert worst < 1e-3  # mm


# ---------------------------------------------------------------------------------------------------- PNG
def _png_ppm(data: bytes) -> tuple[int, int, int]:
    pos = 8
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos: pos + 4])
        kind = data[pos + 4: pos + 8]
        if kind == b"pHYs":
            return struct.unpack(">IIB", data[pos + 8: pos + 8 + length])
        pos += 12 + length
    raise AssertionError("no pHYs chunk")


def _edge_span_px(darkness: np.ndarray) -> float:
    """Sub-pixel distance between the first and last dark edge of a 1-D profile (pixel k spans k +- 0.5)."""
    dark = np.flatnonzero(darkness > 0.5)
    first, last = int(dark[0]), int(dark[-1])
    left = first + 3.5 - darkness[first - 4: first + 4].sum()
    right = last - 3.5 + darkness[last - 3: last + 5].sum()
    return float(right - left)


@pytest.mark.parametrize(("which", "dpi"), [("default-2-levels", 200), ("real-id-8", 150), ("real-id-1", 96)])
def test_png_geometry_is_exact(tmp_path, which, dpi):
    spec = {"default-2-levels": lambda: TargetSpec.default(8, 0.05, levels=2),
            "real-id-8": lambda: _real_spec(8), "real-id-1": lambda: _real_spec(1)}[which]()
    out = artwork.write_target(spec, tmp_path / "t.png", dpi=dpi)
    data = out.read_bytes()
    ppm_x, ppm_y, unit = _png_ppm(data)
    assert unit == 1 and ppm_x == ppm_y == round(dpi / 0.0254)
    image = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    assert image.dtype == np.uint8 and image.ndim == 2
    assert image.shape[::-1] == artwork.png_size_px(spec, dpi)

    lay = artwork.page_layout(spec)
    px_per_m = dpi / 0.0254
    cx, cy = float(artwork.mm_to_px(lay.centre_x_mm, dpi)), float(artwork.mm_to_px(lay.centre_y_mm, dpi))
    R_px = spec.outer_radius_m * px_per_m
    darkness = 1.0 - image.astype(np.float64) / 255.0

    # Outer diameter along the centre row and column (x and y scale).
    expected_d = 2000 * spec.outer_radius_m / 25.4 * dpi
    half = round(R_px + 0.5 * lay.clear_margin_mm / 25.4 * dpi)  # inside the clear zone: no text, no bar
    row = darkness[round(cy), round(cx) - half: round(cx) + half]
    column = darkness[round(cy) - half: round(cy) + half, round(cx)]
    assert _edge_span_px(row) == pytest.approx(expected_d, abs=1.0)
    assert _edge_span_px(column) == pytest.approx(expected_d, abs=1.0)

    # Black area fraction inside the target against the analytic dark area.
    yy, xx = np.mgrid[0: image.shape[0], 0: image.shape[1]]
    dist = np.hypot(xx - cx, yy - cy)
    inside = dist <= R_px + 1.5
    fraction = darkness[inside].sum() / (math.pi * R_px**2)
    expected_fraction = spec.dark_area_m2() / (math.pi * spec.outer_radius_m**2)
    assert fraction == pytest.approx(expected_fraction, rel=0.01)

    # White clear zone around the black disk.
    ring = (dist > R_px + 1.5) & (dist < R_px + lay.clear_margin_mm / 25.4 * dpi - 1.0)
    assert ring.sum() > 0 and image[ring].min() == 255

    # Code dots at the right angles (slot k at 2 pi k / N from +x toward +y, y down in the image).
    checked = 0
    for _, level in spec.levels():
        for (x_m, y_m), bit in zip(level.code.dot_centres_m(), level.code.bits, strict=True):
            value = image[round(cy + y_m * px_per_m), round(cx + x_m * px_per_m)]
            assert (value > 200) if bit == "1" else (value < 55), (level.id, x_m, y_m, bit, value)
            checked += 1
    assert checked == 8 * sum(1 for _ in spec.levels())


def test_png_has_text_and_scale_bar_outside_the_target(tmp_path):
    spec = TargetSpec.default(2, 0.04, levels=1)
    dpi = 150
    image = artwork.rasterize(spec, dpi)
    lay = artwork.page_layout(spec)
    top = image[: int((lay.centre_y_mm - 40 - lay.clear_margin_mm) / 25.4 * dpi)]
    bottom = image[int((lay.centre_y_mm + 40 + lay.clear_margin_mm) / 25.4 * dpi):]
    assert (top < 128).sum() > 200  # the id text
    # Scale bar: its dark columns span the bar length.
    cols = np.flatnonzero((bottom < 128).sum(axis=0) > 0)
    span_mm = (cols[-1] - cols[0] + 1) * 25.4 / dpi
    assert span_mm == pytest.approx(lay.scale_bar_mm + artwork.STROKE_MM, abs=2 * 25.4 / dpi)


def test_unknown_suffix_and_bad_dpi_are_value_errors(tmp_path):
    spec = TargetSpec.default(0, 0.05)
    with pytest.raises(ValueError, match="unknown output format"):
        artwork.write_target(spec, tmp_path / "t.jpg")
    with pytest.raises(ValueError, match="dpi"):
        artwork.write_target(spec, tmp_path / "t.png", dpi=0)
    assert not (tmp_path / "t.jpg").exists()


# ---------------------------------------------------------------------------------------------------- CLI
@pytest.fixture
def target_cli(monkeypatch):
    """The real CLI entry point with only this command registered (other commands are tested elsewhere)."""
    monkeypatch.setattr(cli, "COMMAND_MODULES", ["livetrack.commands.target"])
    return cli.main


@pytest.mark.parametrize("suffix", [".svg", ".pdf", ".png"])
def test_cli_writes_the_file(tmp_path, capsys, target_cli, suffix):
    out = tmp_path / "sub" / f"t{suffix}"
    code = target_cli(["target", "--id", "8", "--diameter-mm", "80", "--out", str(out), "--dpi", "100"])
    assert code == 0 and out.exists() and out.stat().st_size > 500
    text = capsys.readouterr().out
    bits = TargetSpec.default(8, 0.04).code.bits
    assert str(out) in text and "id 8" in text and "80.0 mm" in text and f"bits: {bits}" in text
    assert "heading: from the code" in text


def test_cli_reports_a_symmetric_code_from_a_spec_file(tmp_path, capsys, target_cli):
    _real_spec(1)
    out = tmp_path / "t.svg"
    code = target_cli(["target", "--spec", str(REAL_TARGETS), "--id", "1", "--out", str(out)])
    assert code == 0
    text = capsys.readouterr().out
    assert "bits: 11111111" in text and "heading: none (symmetric code)" in text and "160.0 mm" in text
    radii = [float(c.get("r")) for c in ET.parse(out).getroot().findall(f"{SVG_NS}circle")]
    assert radii[:2] == [80.0, 32.0] and radii[-1] == 1.0  # outer, inner, ..., centre dot


def test_cli_levels_one_draws_a_single_level(tmp_path, target_cli, capsys):
    out = tmp_path / "t.svg"
    argv = ["target", "--id", "3", "--diameter-mm", "100", "--levels", "1", "--out", str(out)]
    assert target_cli(argv) == 0
    capsys.readouterr()
    circles = ET.parse(out).getroot().findall(f"{SVG_NS}circle")
    assert len(circles) == len(_expected_disks_mm(TargetSpec.default(3, 0.05, levels=1)))


@pytest.mark.parametrize(("argv", "message"), [
    (["--id", "99", "--diameter-mm", "100"], "id 99"),
    (["--id", "3"], "--diameter-mm"),
    (["--id", "3", "--diameter-mm", "-5"], "must be > 0"),
    (["--id", "5", "--spec", str(REAL_TARGETS)], "no target with id 5"),
    (["--id", "8", "--spec", str(REAL_TARGETS), "--diameter-mm", "250"], "disagrees"),
    (["--id", "8", "--spec", str(REAL_TARGETS), "--levels", "1"], "--levels"),
])
def test_cli_errors_are_clear(tmp_path, capsys, target_cli, argv, message):
    if "--spec" in argv and not REAL_TARGETS.exists():
        pytest.skip(f"{REAL_TARGETS} not present")
    out = tmp_path / "t.svg"
    assert target_cli(["target", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and err.startswith("livetrack target: error:")
    assert not out.exists()


def test_cli_unknown_format_is_a_clear_error(tmp_path, capsys, target_cli):
    assert target_cli(["target", "--id", "3", "--diameter-mm", "50", "--out", str(tmp_path / "t.jpg")]) == 2
    assert "unknown format '.jpg'" in capsys.readouterr().err
