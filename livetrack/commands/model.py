"""``livetrack model``: fit the image-formation model to an exposure series, compare with the measurement and
choose model extensions by held-out prediction error (see docs/model-check.md)."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from livetrack.batch.executor import add_executor_arguments
from livetrack.config.checks import ConfigError

NAME = "model"
HELP = ("model versus measurement: fit the baseline image-formation model to an exposure series of a static "
        "disk grid, test the catalogue of extensions on held-out exposures, report the cause of the misfit")

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", type=Path, nargs="+", metavar="INPUT",
                        help="a recording (v1) of livetrack ring targets at three or more exposures (static or moving, "
                             "e.g. from livetrack record-sweep), a recording of a static disk grid (meta: pattern: "
                             "disk_grid, pitch_m), or the real folder exposure-series-disks (then --filter)")
    parser.add_argument("--filter", default=None, metavar="NM",
                        help="narrowband filter of the real exposure-series-disks folder, any present in it (e.g. "
                             "550nm; a wrong one lists those there), or 'all': every filter, each model also chosen "
                             "by leave-one-filter-out")
    parser.add_argument("--json", type=Path, default=None, metavar="OUT", help="write the JSON report here")
    parser.add_argument("--plots", type=Path, default=None, metavar="DIR", help="write PNG plots into this folder")
    parser.add_argument("--camera-out", type=Path, default=None, metavar="FILE",
                        help="write a camera file with the fitted PSF (core, halo) and saturated-pixel noise, and the "
                             "intrinsics of a recording input (for detect --camera, evaluate --fitted-camera)")
    parser.add_argument("--json-dir", type=Path, default=None, metavar="DIR",
                        help="many inputs (livetrack model SWEEPS/* --json-dir OUT/): one report each in DIR, one "
                             "task per input over --workers or a --scheduler (livetrack.batch; docs/batch.md)")
    add_executor_arguments(parser)


def load_series(path: Path, filter_nm: str | None):
    from livetrack.modelcheck.series import available_filters, from_exposure_series_disks, from_recording

    if (path / "recording.yaml").is_file():
        return from_recording(path)
    if (path / "frames").is_dir() and (path / "dark_frames").is_dir():
        if filter_nm is None:
            raise ConfigError("--filter", "required for the exposure-series-disks folder; filters there: "
                              + ", ".join(available_filters(path)))
        return from_exposure_series_disks(path, filter_nm)
    raise ConfigError("INPUT", f"{path}: neither a recording nor an exposure-series-disks folder")


def run(args: argparse.Namespace) -> int:
    from livetrack.modelcheck.analysis import analyse
    from livetrack.modelcheck.plots import write_plots
    from livetrack.modelcheck.rings_input import is_ring_recording

    if args.json_dir is not None:
        return _run_batch(args)
    if len(args.input) > 1:
        raise ConfigError("INPUT", "several inputs need --json-dir DIR (one report each)")
    args.input = args.input[0]
    if is_ring_recording(args.input):
        return _run_rings(args)
    if args.filter == "all":
        return _run_all_filters(args)
    try:
        series = load_series(args.input, args.filter)
    except ValueError as exc:
        print(f"livetrack model: error: {exc}", file=sys.stderr)
        return 2
    report = analyse(series)

    def camera_file(out: Path) -> dict:
        from livetrack.modelcheck.export import recording_camera, write_fitted_camera

        return write_fitted_camera(report, out, recording_camera(args.input))

    return _write_outputs(args, report, write_plots, camera_file)


def _run_batch(args: argparse.Namespace) -> int:
    """``--json-dir``: one task per input (livetrack.batch.model); one report JSON per input, a summary table."""
    from livetrack.batch.detect import output_names
    from livetrack.batch.executor import make_executor
    from livetrack.batch.model import model_inputs

    if args.plots is not None or args.camera_out is not None or args.json is not None:
        raise ConfigError("--json-dir", "writes one report per input; --json, --plots and --camera-out are for one "
                                        "input")
    try:
        names = output_names(args.input)
    except ValueError as exc:
        raise ConfigError("INPUT", str(exc)) from None
    with make_executor(args.workers, args.scheduler, args.retries) as executor:
        print(f"livetrack model: {len(args.input)} inputs on {executor.description}", file=sys.stderr)
        results = model_inputs(args.input, executor, args.filter, progress=not args.no_progress)
    args.json_dir.mkdir(parents=True, exist_ok=True)
    lines = [f"{'input':32s} result", "-" * 72]
    for result, name in zip(results, names, strict=True):
        if "report" in result:
            (args.json_dir / name).write_text(json.dumps(result["report"], indent=1))
            chosen = result["report"].get("heldout", {}).get("chosen")
            lines.append(f"{name[:-5][:32]:32s} chosen: {', '.join(chosen) if chosen else 'baseline'}")
        else:
            lines.append(f"{name[:-5][:32]:32s} FAILED: {result['error'].splitlines()[0]}")
            print(f"FAILED {result['input']}: {result['error']}", file=sys.stderr)
    failed = sum("report" not in r for r in results)
    lines += ["-" * 72, f"{len(results)} inputs, {len(results) - failed} reports, {failed} failed -> {args.json_dir}"]
    print("\n".join(lines))
    return 1 if failed else 0


def _write_outputs(args: argparse.Namespace, report, write_plots, camera_file) -> int:
    """The report's JSON (``--json``), plots (``--plots``) and camera file (``--camera-out``), then its summary."""
    data = report.to_json()
    if args.plots is not None:
        data["plots"] = write_plots(report, args.plots)
    if args.camera_out is not None:
        data["camera_file"] = camera_file(args.camera_out)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(data, indent=1))
    print(report.summary())
    if args.plots is not None:
        print("plots: " + ", ".join(Path(p).name for p in data["plots"]))
    if args.camera_out is not None:
        print(f"camera file: {args.camera_out} ({data['camera_file']['optics']})")
    return 0


def _run_rings(args: argparse.Namespace) -> int:
    """A recording of livetrack ring targets (``livetrack.modelcheck.rings``)."""
    from livetrack.modelcheck.rings import analyse_rings
    from livetrack.modelcheck.rings_input import ring_series_from_recording
    from livetrack.modelcheck.rings_plots import write_ring_camera, write_ring_plots

    try:
        report = analyse_rings(ring_series_from_recording(args.input))
    except ValueError as exc:
        print(f"livetrack model: error: {exc}", file=sys.stderr)
        return 2
    return _write_outputs(args, report, write_ring_plots, lambda out: write_ring_camera(report, out))


def _run_all_filters(args: argparse.Namespace) -> int:
    """``--filter all``: every filter of the real folder, each model also chosen by leave-one-filter-out; one JSON
    (filter -> report), plots in DIR/FILTER/."""
    from livetrack.modelcheck.analysis import analyse_filters
    from livetrack.modelcheck.plots import write_plots
    from livetrack.modelcheck.series import available_filters

    try:
        series = {f: load_series(args.input, f) for f in available_filters(args.input)}
    except ValueError as exc:
        print(f"livetrack model: error: {exc}", file=sys.stderr)
        return 2
    reports = analyse_filters(series)
    data = {f: r.to_json() for f, r in reports.items()}
    for f, r in reports.items():
        if args.plots is not None:
            data[f]["plots"] = write_plots(r, args.plots / f)
        print(f"=== {f}\n{r.summary()}")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(data, indent=1))
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m livetrack.commands.model ...`` (until the command is registered in ``livetrack.cli``)."""
    parser = argparse.ArgumentParser(prog="livetrack model", description=HELP)
    add_arguments(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        return run(args)
    except ConfigError as exc:
        print(f"livetrack model: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
