"""Printable target artwork at exact 1:1 scale: SVG, PDF and PNG.

The page is a list of simple shapes in millimetres (page frame: origin at the top-left corner, x right,
y down), built once by :func:`page_items` and written by one small writer per format, so the three outputs
agree:

* SVG: ``width``/``height`` in mm and a ``viewBox`` in mm (1 user unit = 1 mm); circles are ``<circle>``.
* PDF (written by hand): MediaBox in points (1 pt = 25.4/72 mm exactly); the content stream scales to mm with
  y down; each circle is 8 cubic Bezier arcs (radial error < 5e-6 of the radius, 0.6 um for R = 125 mm).
* PNG (written by hand): 8-bit grey, the DPI stored in the pHYs chunk (pixels per metre, rounded as the format
  requires); disks are anti-aliased by an analytic edge coverage, so edges sit within a small fraction of a
  pixel of the true geometry. Array index [i, j] is the pixel whose centre lies at page
  ((j + 0.5), (i + 0.5)) * 25.4 / dpi mm; in livetrack's pixel-centres-on-integers convention that is
  :func:`mm_to_px`.

Drawing order (painter's): white page, then per level the black outer disk, white inner disk, white code dots,
black centre dot, then the child level inside the white inner disk. The id, the code and a scale bar are
printed outside a white clear zone around the black disk (the detector needs white around it).
"""

from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import escape

import cv2
import numpy as np
import numpy.typing as npt

from livetrack.targets.spec import TargetSpec

MM_PER_INCH = 25.4
PT_PER_MM = 72.0 / MM_PER_INCH

# Page layout, millimetres.
CLEAR_MARGIN_RATIO = 0.25  # white clear zone around the black disk, fraction of R (the detector needs >= 0.1)
CLEAR_MARGIN_MIN_MM = 10.0  # ... and at least this much
EDGE_MM = 8.0  # page edge to text and scale bar (most printers cannot print the outer ~5 mm)
FONT_MM = 4.0  # text size (em); Helvetica's capitals are ~0.72 of this
LINE_MM = 6.0  # baseline to baseline
BAND_MM = 20.0  # height of the text band above and the scale-bar band below the clear zone
SCALE_BAR_CHOICES_MM = (100.0, 50.0, 20.0, 10.0)  # the longest that fits the page is used
STROKE_MM = 0.4  # scale bar line and tick thickness
TICK_MM = 4.0  # scale bar tick height
TEXT_WIDTH_PER_CHAR_EM = 0.6  # generous average Helvetica advance, for sizing the page

FORMATS = (".svg", ".pdf", ".png")
MAX_PNG_SIDE_PX = 30000  # refuse larger rasters (memory: ~4 bytes per pixel while drawing)

BLACK = 0.0
WHITE = 1.0


@dataclass(frozen=True)
class Disk:
    cx_mm: float
    cy_mm: float
    r_mm: float
    grey: float  # 0 black .. 1 white


@dataclass(frozen=True)
class Rect:
    x_mm: float
    y_mm: float
    w_mm: float
    h_mm: float
    grey: float


@dataclass(frozen=True)
class Text:
    x_mm: float  # left end of the baseline
    baseline_mm: float
    size_mm: float
    text: str


Item = Disk | Rect | Text


@dataclass(frozen=True)
class PageLayout:
    width_mm: float
    height_mm: float
    centre_x_mm: float  # target centre on the page
    centre_y_mm: float
    clear_margin_mm: float  # white around the black disk, free of text and marks
    scale_bar_mm: float


# ---------------------------------------------------------------------------------------------------- layout
def label_lines(spec: TargetSpec) -> list[str]:
    """The text printed above the target."""
    levels = sum(1 for _ in spec.levels())
    code = f"code {spec.code.bits}" if spec.code is not None else "no code"
    if spec.code is not None and spec.code.symmetric:
        code += " (symmetric: no heading)"
    return [
        f"livetrack target id {spec.id} \u2014 {code} \u2014 {levels} level{'s' if levels > 1 else ''}",
        f"outer diameter {2000.0 * spec.outer_radius_m:.1f} mm \u2014 print at 100 %",
    ]


def page_layout(spec: TargetSpec) -> PageLayout:
    """Page size (whole mm) with the target centred, its clear zone, and room for the text and scale bar."""
    R_mm = 1000.0 * spec.outer_radius_m
    margin = max(CLEAR_MARGIN_RATIO * R_mm, CLEAR_MARGIN_MIN_MM)
    text_mm = max(len(line) for line in label_lines(spec)) * TEXT_WIDTH_PER_CHAR_EM * FONT_MM
    width = max(2.0 * (R_mm + margin), 2.0 * EDGE_MM + text_mm, 2.0 * EDGE_MM + SCALE_BAR_CHOICES_MM[-1])
    width = float(math.ceil(width - 1e-9))
    height = float(math.ceil(2.0 * (R_mm + margin + BAND_MM) - 1e-9))
    bar = next(b for b in SCALE_BAR_CHOICES_MM if b + STROKE_MM <= width - 2.0 * EDGE_MM)
    return PageLayout(width_mm=width, height_mm=height, centre_x_mm=width / 2.0, centre_y_mm=height / 2.0,
                      clear_margin_mm=margin, scale_bar_mm=bar)


def target_disks(spec: TargetSpec, centre_x_mm: float, centre_y_mm: float) -> list[Disk]:
    """All disks of the target (every level) in drawing order. Target frame y down = page y down."""
    disks: list[Disk] = []
    for _, level in spec.levels():
        disks.append(Disk(centre_x_mm, centre_y_mm, 1000.0 * level.outer_radius_m, BLACK))
        disks.append(Disk(centre_x_mm, centre_y_mm, 1000.0 * level.inner_radius_m, WHITE))
        if level.code is not None:
            r_dot = 1000.0 * level.code.dot_radius_m
            for x_m, y_m in level.code.white_dot_centres_m():
                disks.append(Disk(centre_x_mm + 1000.0 * x_m, centre_y_mm + 1000.0 * y_m, r_dot, WHITE))
        if level.centre_dot_radius_m > 0:
            disks.append(Disk(centre_x_mm, centre_y_mm, 1000.0 * level.centre_dot_radius_m, BLACK))
    return disks


def page_items(spec: TargetSpec) -> tuple[PageLayout, list[Item]]:
    """The page as shapes in mm, in drawing order."""
    lay = page_layout(spec)
    items: list[Item] = [Rect(0.0, 0.0, lay.width_mm, lay.height_mm, WHITE)]
    items += target_disks(spec, lay.centre_x_mm, lay.centre_y_mm)
    for i, line in enumerate(label_lines(spec)):
        items.append(Text(EDGE_MM, EDGE_MM + FONT_MM + i * LINE_MM, FONT_MM, line))
    # Scale bar: |-----| with the tick centre lines exactly scale_bar_mm apart, label below it.
    label_baseline = lay.height_mm - EDGE_MM
    tick_bottom = label_baseline - FONT_MM - 2.0
    bar_y = tick_bottom - TICK_MM / 2.0
    x0 = EDGE_MM + STROKE_MM / 2.0  # left tick centre
    x1 = x0 + lay.scale_bar_mm
    items.append(Rect(x0, bar_y - STROKE_MM / 2.0, lay.scale_bar_mm, STROKE_MM, BLACK))
    for x in (x0, x1):
        items.append(Rect(x - STROKE_MM / 2.0, tick_bottom - TICK_MM, STROKE_MM, TICK_MM, BLACK))
    items.append(Text(EDGE_MM, label_baseline, FONT_MM,
                      f"scale bar: {lay.scale_bar_mm:.0f} mm between tick centres"))
    return lay, items


# ---------------------------------------------------------------------------------------------------- writers
def write_target(spec: TargetSpec, out: Path, dpi: int = 300) -> Path:
    """Write the target page to ``out``; the format comes from the suffix (.svg, .pdf, .png). ``dpi`` is used
    for PNG only. Returns ``out``. Raises ValueError for an unknown suffix or a non-positive or too large
    raster."""
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in FORMATS:
        raise ValueError(f"{out}: unknown output format {out.suffix!r} (use one of {', '.join(FORMATS)})")
    if suffix == ".svg":
        out.write_text(svg_text(spec), encoding="utf-8")
    elif suffix == ".pdf":
        out.write_bytes(pdf_bytes(spec))
    else:
        out.write_bytes(png_bytes(rasterize(spec, dpi), dpi))
    return out


def _num(value: float) -> str:
    text = f"{value:.4f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def _svg_grey(grey: float) -> str:
    level = int(round(255 * grey))
    return f"#{level:02x}{level:02x}{level:02x}"


def svg_text(spec: TargetSpec) -> str:
    lay, items = page_items(spec)
    w, h = _num(lay.width_mm), _num(lay.height_mm)
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        f'<svg xmlns="http://www.w3.org/2000/svg" version="1.1" width="{w}mm" height="{h}mm" '
        f'viewBox="0 0 {w} {h}">',
        f"<title>livetrack target id {spec.id}</title>",
    ]
    for item in items:
        if isinstance(item, Disk):
            lines.append(f'<circle cx="{_num(item.cx_mm)}" cy="{_num(item.cy_mm)}" r="{_num(item.r_mm)}" '
                         f'fill="{_svg_grey(item.grey)}"/>')
        elif isinstance(item, Rect):
            lines.append(f'<rect x="{_num(item.x_mm)}" y="{_num(item.y_mm)}" width="{_num(item.w_mm)}" '
                         f'height="{_num(item.h_mm)}" fill="{_svg_grey(item.grey)}"/>')
        else:
            lines.append(f'<text x="{_num(item.x_mm)}" y="{_num(item.baseline_mm)}" '
                         f'font-family="Helvetica, Arial, sans-serif" font-size="{_num(item.size_mm)}" '
                         f'fill="#000000">{escape(item.text)}</text>')
    lines.append("</svg>")
    return "\n".join(lines) + "\n"


def _pdf_circle(cx: float, cy: float, r: float, arcs: int = 8) -> str:
    """Closed path of ``arcs`` cubic Bezier arcs; control length 4/3 tan(theta/4) r for arc angle theta."""
    step = 2.0 * math.pi / arcs
    k = 4.0 / 3.0 * math.tan(step / 4.0) * r
    ops = [f"{_num(cx + r)} {_num(cy)} m"]
    for i in range(arcs):
        a0, a1 = i * step, (i + 1) * step
        x0, y0 = cx + r * math.cos(a0), cy + r * math.sin(a0)
        x3, y3 = cx + r * math.cos(a1), cy + r * math.sin(a1)
        x1, y1 = x0 - k * math.sin(a0), y0 + k * math.cos(a0)
        x2, y2 = x3 + k * math.sin(a1), y3 - k * math.cos(a1)
        ops.append(" ".join(_num(v) for v in (x1, y1, x2, y2, x3, y3)) + " c")
    return "\n".join(ops) + "\nh f"


def _pdf_string(text: str) -> bytes:
    raw = text.encode("cp1252", errors="replace")  # WinAnsiEncoding (the em dash is 0x97)
    return b"(" + raw.replace(b"\\", b"\\\\").replace(b"(", b"\\(").replace(b")", b"\\)") + b")"


def pdf_bytes(spec: TargetSpec) -> bytes:
    """A one-page PDF 1.4; MediaBox in points, content drawn in mm with y down."""
    lay, items = page_items(spec)
    w_pt, h_pt = lay.width_mm * PT_PER_MM, lay.height_mm * PT_PER_MM
    content: list[bytes] = [f"{PT_PER_MM:.10f} 0 0 {-PT_PER_MM:.10f} 0 {h_pt:.6f} cm".encode()]
    for item in items:
        if isinstance(item, Disk):
            content.append(f"{_num(item.grey)} g\n{_pdf_circle(item.cx_mm, item.cy_mm, item.r_mm)}".encode())
        elif isinstance(item, Rect):
            content.append(f"{_num(item.grey)} g {_num(item.x_mm)} {_num(item.y_mm)} {_num(item.w_mm)} "
                           f"{_num(item.h_mm)} re f".encode())
        else:
            # The text matrix flips y back, so glyphs stand upright on the y-down user space.
            content.append(f"0 g BT /F1 {_num(item.size_mm)} Tf 1 0 0 -1 {_num(item.x_mm)} "
                           f"{_num(item.baseline_mm)} Tm ".encode() + _pdf_string(item.text) + b" Tj ET")
    stream = b"\n".join(content) + b"\n"
    objects = [
        b"<< /Type /Catalog /Pages 2 0 R >>",
        b"<< /Type /Pages /Kids [3 0 R] /Count 1 >>",
        f"<< /Type /Page /Parent 2 0 R /MediaBox [0 0 {w_pt:.4f} {h_pt:.4f}] /Contents 4 0 R "
        f"/Resources << /Font << /F1 5 0 R >> >> >>".encode(),
        f"<< /Length {len(stream)} >>\nstream\n".encode() + stream + b"endstream",
        b"<< /Type /Font /Subtype /Type1 /BaseFont /Helvetica /Encoding /WinAnsiEncoding >>",
        f"<< /Title {_pdf_string(f'livetrack target id {spec.id}').decode('latin-1')} "
        f"/Creator (livetrack) >>".encode("latin-1"),
    ]
    out = bytearray(b"%PDF-1.4\n%\xe2\xe3\xcf\xd3\n")
    offsets = []
    for number, body in enumerate(objects, start=1):
        offsets.append(len(out))
        out += f"{number} 0 obj\n".encode() + body + b"\nendobj\n"
    xref = len(out)
    out += f"xref\n0 {len(objects) + 1}\n".encode() + b"0000000000 65535 f \n"
    out += b"".join(f"{off:010d} 00000 n \n".encode() for off in offsets)
    out += (f"trailer\n<< /Size {len(objects) + 1} /Root 1 0 R /Info {len(objects)} 0 R >>\n"
            f"startxref\n{xref}\n%%EOF\n").encode()
    return bytes(out)


# ---------------------------------------------------------------------------------------------------- raster
def mm_to_px(value_mm: float | npt.ArrayLike, dpi: float) -> float | npt.NDArray[np.float64]:
    """Page mm -> PNG pixel coordinate with pixel centres on integers (pixel 0 spans -0.5..0.5)."""
    return np.asarray(value_mm, dtype=np.float64) * dpi / MM_PER_INCH - 0.5


def png_size_px(spec: TargetSpec, dpi: float) -> tuple[int, int]:
    """(width, height) of the PNG in pixels: the page rounded up to whole pixels (the extra is white)."""
    lay = page_layout(spec)
    return (math.ceil(lay.width_mm * dpi / MM_PER_INCH - 1e-9),
            math.ceil(lay.height_mm * dpi / MM_PER_INCH - 1e-9))


def _paint(canvas: npt.NDArray[np.float32], coverage: npt.NDArray[np.float64], grey: float,
           rows: slice, cols: slice) -> None:
    region = canvas[rows, cols]
    region += (coverage * (grey - region)).astype(np.float32)


def _paint_disk(canvas: npt.NDArray[np.float32], disk: Disk, px_per_mm: float) -> None:
    """Anti-aliased disk: coverage = clip(r - d + 1/2, 0, 1) with d the distance of the pixel centre from the
    disk centre (exact for a straight edge along a pixel axis; total area error well below a pixel)."""
    cx, cy, r = disk.cx_mm * px_per_mm - 0.5, disk.cy_mm * px_per_mm - 0.5, disk.r_mm * px_per_mm
    h, w = canvas.shape
    i0, i1 = max(int(math.floor(cy - r - 1)), 0), min(int(math.ceil(cy + r + 1)) + 1, h)
    j0, j1 = max(int(math.floor(cx - r - 1)), 0), min(int(math.ceil(cx + r + 1)) + 1, w)
    if i0 >= i1 or j0 >= j1:
        return
    yy = (np.arange(i0, i1, dtype=np.float64) - cy)[:, None]
    xx = (np.arange(j0, j1, dtype=np.float64) - cx)[None, :]
    coverage = np.clip(r - np.sqrt(xx * xx + yy * yy) + 0.5, 0.0, 1.0)
    if r < 2.0 and coverage.sum() > 0:  # tiny disk: the linear edge model overestimates; keep the true area
        coverage = np.clip(coverage * (math.pi * r * r / coverage.sum()), 0.0, 1.0)
    _paint(canvas, coverage, disk.grey, slice(i0, i1), slice(j0, j1))


def _overlap_1d(lo: float, hi: float, n: int) -> tuple[int, npt.NDArray[np.float64]]:
    """First index and per-pixel overlap of [lo, hi] (page px, pixel k spans k..k+1) with pixels 0..n-1."""
    k0, k1 = max(int(math.floor(lo)), 0), min(int(math.ceil(hi)), n)
    k = np.arange(k0, max(k1, k0), dtype=np.float64)
    return k0, np.clip(np.minimum(k + 1.0, hi) - np.maximum(k, lo), 0.0, 1.0)


def _paint_rect(canvas: npt.NDArray[np.float32], rect: Rect, px_per_mm: float) -> None:
    h, w = canvas.shape
    i0, fy = _overlap_1d(rect.y_mm * px_per_mm, (rect.y_mm + rect.h_mm) * px_per_mm, h)
    j0, fx = _overlap_1d(rect.x_mm * px_per_mm, (rect.x_mm + rect.w_mm) * px_per_mm, w)
    if fy.size and fx.size:
        _paint(canvas, fy[:, None] * fx[None, :], rect.grey, slice(i0, i0 + fy.size), slice(j0, j0 + fx.size))


def _paint_text(canvas: npt.NDArray[np.float32], text: Text, px_per_mm: float) -> None:
    """Hershey font (ASCII only), cap height ~0.72 em like Helvetica, shrunk if it would leave the page."""
    font = cv2.FONT_HERSHEY_SIMPLEX
    scale = 0.72 * text.size_mm * px_per_mm / 21.0  # Hershey simplex capitals are ~21 px at scale 1
    thickness = max(1, int(round(scale * 1.6)))
    ascii_text = text.text.replace("\u2014", "-").encode("ascii", errors="replace").decode("ascii")
    h, w = canvas.shape
    x, y = int(round(text.x_mm * px_per_mm)), int(round(text.baseline_mm * px_per_mm))
    (width, _), _ = cv2.getTextSize(ascii_text, font, scale, thickness)
    if x + width > w - x:
        scale *= (w - 2 * x) / width
    mask = np.zeros((h, w), np.uint8)
    cv2.putText(mask, ascii_text, (x, y), font, scale, 255, thickness, cv2.LINE_AA)
    rows = np.flatnonzero(mask.any(axis=1))
    if rows.size:
        band = slice(rows[0], rows[-1] + 1)
        _paint(canvas[band], mask[band] / 255.0, BLACK, slice(None), slice(None))


def rasterize(spec: TargetSpec, dpi: float) -> npt.NDArray[np.uint8]:
    """(H, W) uint8 grey page (0 black, 255 white) at ``dpi``; see :func:`mm_to_px` for pixel coordinates."""
    if not dpi > 0:
        raise ValueError(f"dpi must be > 0, got {dpi}")
    w, h = png_size_px(spec, dpi)
    if max(w, h) > MAX_PNG_SIDE_PX:
        raise ValueError(f"a {w} x {h} px PNG is too large (max {MAX_PNG_SIDE_PX} px a side): lower --dpi "
                         "or use SVG/PDF")
    px_per_mm = dpi / MM_PER_INCH
    canvas = np.ones((h, w), np.float32)
    for item in page_items(spec)[1]:
        if isinstance(item, Disk):
            _paint_disk(canvas, item, px_per_mm)
        elif isinstance(item, Rect):
            _paint_rect(canvas, item, px_per_mm)
        else:
            _paint_text(canvas, item, px_per_mm)
    return np.clip(np.rint(canvas * 255.0), 0, 255).astype(np.uint8)


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    crc = zlib.crc32(kind + data) & 0xFFFFFFFF
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)


def png_bytes(image: npt.NDArray[np.uint8], dpi: float) -> bytes:
    """8-bit greyscale PNG with the resolution in pHYs (pixels per metre, an integer by the format)."""
    h, w = image.shape
    ppm = int(round(dpi / MM_PER_INCH * 1000.0))
    rows = np.hstack([np.zeros((h, 1), np.uint8), np.ascontiguousarray(image, np.uint8)])  # filter 0 per row
    return b"".join([
        b"\x89PNG\r\n\x1a\n",
        _png_chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0)),
        _png_chunk(b"pHYs", struct.pack(">IIB", ppm, ppm, 1)),
        _png_chunk(b"IDAT", zlib.compress(rows.tobytes(), 6)),
        _png_chunk(b"IEND", b""),
    ])
