"""What a live calibration (``livetrack calibrate --source``) shows as it collects views: the console always, and
Rerun with ``--rerun MODE`` (``spawn | connect[:URL] | serve | save:PATH.rrd``, the syntax of ``run --rerun``).
This module is the output edge of the calibration command (rerun imported only when asked for).

Rerun entities (timeline ``view``: the number of views collected; ``frame``: the source's frame id):

- ``calibration/image``: the last accepted frame (8 bit for display), ``calibration/image/features`` its feature
  points, ``calibration/image/all`` every feature point so far (the coverage, point by point);
- ``calibration/coverage``: the 8x6 cells as an image the size of the frame, grey where empty, green where hit
  (brighter with more points), the corner cells outlined in red until hit;
- ``series/coverage``: fraction of cells hit, and ``series/threshold/coverage``;
- ``series/std_over_limit/<fx|cx|cy|k1>``: each parameter's relative 1-sigma divided by its threshold (the
  collection stops when all are at most 1 and the coverage is reached);
- ``status``: a TextLog line per view and per check.

Pixel centres: livetrack's are on integers, Rerun's at +0.5 (shifted here, as in ``livetrack.sinks.rerun_sink``).
"""

from __future__ import annotations

import logging
import subprocess
import time
from pathlib import Path

import numpy as np
import numpy.typing as npt

from livetrack.calibration.live import Progress, StopRule
from livetrack.calibration.report import COVERAGE_CELLS, coverage_map

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]


class ConsoleView:
    """Progress lines on stdout; the base of the Rerun view (which prints them too)."""

    def view_added(self, image: npt.NDArray, frame_id: int, points_px: list[FloatArray], total: int,
                   bit_depth: int) -> None:
        cov = coverage_map(points_px, image.shape[1], image.shape[0], COVERAGE_CELLS)
        print(f"view {len(points_px)}/{total} (frame {frame_id}): {cov.text()}", flush=True)

    def checked(self, progress: Progress, rule: StopRule) -> None:
        line = f"check: {progress.text()}"
        if progress.unmet:
            line += " -- not yet: " + "; ".join(progress.unmet)
        print(line, flush=True)

    def message(self, text: str) -> None:
        print(text, flush=True)

    def close(self) -> None:
        pass


class RerunView(ConsoleView):
    """The console lines, and the collection in a Rerun recording (entities in the module docstring)."""

    def __init__(self, mode_text: str, serve_bind: str = "127.0.0.1", port: int = 9876):
        import rerun as rr

        from livetrack.sinks.rerun_mode import parse_mode
        from livetrack.sinks.rerun_sink import APPLICATION_ID, port_open, viewer_command, viewer_executable

        mode, argument = parse_mode(mode_text)
        layout = blueprint()
        self._rr = rr
        self._rec = rr.RecordingStream(APPLICATION_ID + "-calibrate")
        self.uri: str | None = None
        if mode == "save":
            path = Path(argument or "calibration.rrd")
            path.parent.mkdir(parents=True, exist_ok=True)
            self._rec.save(path, default_blueprint=layout)
            self.uri = str(path)
        elif mode == "serve":
            server = rr.GrpcServerSink(serve_bind, port)
            self._rec.set_sinks(server, default_blueprint=layout)
            self.uri = server.uri
            print(f"rerun: viewer URL {self.uri}  (open it with: rerun {self.uri})", flush=True)
        elif mode in ("spawn", "connect"):
            url = argument if mode == "connect" else f"rerun+http://127.0.0.1:{port}/proxy"
            if mode == "spawn" and not port_open("127.0.0.1", port):
                # as the run sink: a viewer bound to loopback (rerun's spawn() would listen on 0.0.0.0)
                subprocess.Popen(viewer_command(viewer_executable(), port, serve_bind), stdin=subprocess.DEVNULL,
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
                for _ in range(100):
                    if port_open("127.0.0.1", port, timeout_s=0.2):
                        break
                    time.sleep(0.1)
            if not port_open(*_host_port(url)):
                raise ConnectionError(f"no Rerun viewer at {url}")
            self._rec.connect_grpc(url, default_blueprint=layout)
            self.uri = url
        else:  # "off" never gets here (the command makes a ConsoleView)
            raise ValueError(f"rerun mode {mode_text!r}")
        self._logged_static = False
        log.info("calibration viewer (rerun %s): %s", mode, self.uri)

    def view_added(self, image, frame_id, points_px, total, bit_depth):
        super().view_added(image, frame_id, points_px, total, bit_depth)
        from livetrack.sinks.rerun_sink import RERUN_PIXEL_OFFSET, _display_image

        rr, rec = self._rr, self._rec
        height, width = image.shape[:2]
        rec.set_time("view", sequence=len(points_px))
        rec.set_time("frame", sequence=int(frame_id))
        rec.log("calibration/image", rr.Image(_display_image(image, bit_depth)))
        rec.log("calibration/image/features", rr.Points2D(points_px[-1] + RERUN_PIXEL_OFFSET,
                                                          colors=[(40, 220, 80)], radii=[1.5]))
        rec.log("calibration/image/all", rr.Points2D(np.concatenate(points_px) + RERUN_PIXEL_OFFSET,
                                                     colors=[(250, 200, 40)], radii=[0.7]))
        cov = coverage_map(points_px, width, height, COVERAGE_CELLS)
        rec.log("calibration/coverage", rr.Image(coverage_image(cov.counts, width, height)))
        rec.log("series/coverage", rr.Scalars([cov.covered_fraction]))
        rec.log("status", rr.TextLog(f"view {len(points_px)} (frame {frame_id}): coverage "
                                     f"{cov.covered_fraction:.0%}"))

    def checked(self, progress, rule):
        super().checked(progress, rule)
        rr, rec = self._rr, self._rec
        rec.log("series/threshold/coverage", rr.Scalars([rule.coverage]))
        if progress.relative_std is not None:
            limits = {"fx": rule.fx_rel, "cx": rule.cx_rel, "cy": rule.cy_rel, "k1": rule.k1_rel}
            for name, value in progress.relative_std.items():
                rec.log(f"series/std_over_limit/{name}", rr.Scalars([value / limits[name]]))
        rec.log("status", rr.TextLog(progress.text() + ("" if progress.done else
                                                        " -- not yet: " + "; ".join(progress.unmet)),
                                     level="INFO" if progress.done else "DEBUG"))

    def message(self, text):
        super().message(text)
        self._rec.log("status", self._rr.TextLog(text, level="WARN"))

    def close(self):
        try:
            self._rec.flush(timeout_sec=2.0)
        except RuntimeError as exc:
            log.warning("rerun: could not flush the calibration view: %s", exc)
        self._rec.disconnect()


def blueprint():
    """The frame with its features and the coverage cells side by side; the series and the status below."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(rrb.Vertical(
        rrb.Horizontal(rrb.Spatial2DView(name="views", origin="calibration/image"),
                       rrb.Spatial2DView(name="coverage ({}x{} cells)".format(*COVERAGE_CELLS),
                                         origin="calibration/coverage")),
        rrb.Horizontal(rrb.TimeSeriesView(name="coverage", origin="series", contents=["series/coverage",
                                                                                       "series/threshold/**"]),
                       rrb.TimeSeriesView(name="1-sigma / threshold (stop at <= 1)", origin="series/std_over_limit"),
                       rrb.TextLogView(name="status", origin="status")),
        row_shares=[3, 2]), collapse_panels=True)


def coverage_image(counts: npt.NDArray[np.int64], width: int, height: int) -> npt.NDArray[np.uint8]:
    """(height, width, 3) uint8: each cell grey when empty, green when hit (brighter with more points, log
    scale); the empty corner cells outlined in red."""
    rows, cols = counts.shape
    level = np.log1p(counts) / max(np.log1p(counts.max()), 1e-9)
    cells = np.zeros((rows, cols, 3), dtype=np.uint8)
    cells[...] = (70, 70, 70)
    hit = counts > 0
    cells[hit] = np.stack([40 + 0 * level[hit], 100 + 150 * level[hit], 60 + 0 * level[hit]], axis=1).astype(
        np.uint8)
    ys = np.minimum((np.arange(height) * rows) // height, rows - 1)
    xs = np.minimum((np.arange(width) * cols) // width, cols - 1)
    out = cells[ys[:, None], xs[None, :]]
    out[np.diff(ys, prepend=-1) != 0, :] = 0  # cell borders
    out[:, np.diff(xs, prepend=-1) != 0] = 0
    ch, cw = height / rows, width / cols
    for i in (0, rows - 1):
        for j in (0, cols - 1):
            if counts[i, j] == 0:
                y0, y1, x0, x1 = int(i * ch), int((i + 1) * ch) - 1, int(j * cw), int((j + 1) * cw) - 1
                out[y0:y1 + 1, [x0, x1]] = (230, 40, 40)
                out[[y0, y1], x0:x1 + 1] = (230, 40, 40)
    return np.ascontiguousarray(out)


def _host_port(url: str) -> tuple[str, int]:
    from urllib.parse import urlsplit

    parts = urlsplit(url.replace("rerun+", "", 1))
    return parts.hostname or "127.0.0.1", parts.port or 9876


def make_view(rerun_mode: str | None) -> ConsoleView:
    """ConsoleView for None/"off", else a RerunView."""
    if rerun_mode in (None, "off"):
        return ConsoleView()
    return RerunView(rerun_mode)
