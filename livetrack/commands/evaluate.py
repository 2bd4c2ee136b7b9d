"""``livetrack evaluate exposure-sweep``: the paper's experiment in simulation, every method side by side.
``livetrack evaluate detection``: the detection rate among visible targets in varied simulated scenes, false
positives on frames without targets (``livetrack.evaluation.detection``).
``livetrack evaluate single-searches``: one search per over-exposed frame of single targets with and without a white
sheet (``livetrack.evaluation.single_searches``)."""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from livetrack.batch.evaluate import load_sweep_scenario
from livetrack.batch.executor import add_executor_arguments, check_executor_args, make_executor
from livetrack.config.checks import ConfigError
from livetrack.estimator.tracker import TrackerOptions
from livetrack.evaluation.exposure_sweep import ALL_METHODS, FITTED_METHOD, SweepResult, run_sweep

NAME = "evaluate"
HELP = "experiments on simulated ground truth (exposure-sweep, detection, single-searches)"

DEFAULT_SCENARIO = Path(__file__).resolve().parents[2] / "config" / "scenarios" / "paper-lab.yaml"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("experiment", choices=["exposure-sweep", "detection", "single-searches"],
                        help="which experiment")
    parser.add_argument("--scenario", type=Path, default=None,
                        help="scenario YAML with one target (default: config/scenarios/paper-lab.yaml)")
    parser.add_argument("--methods", default=None,
                        help=f"comma-separated subset of {','.join(ALL_METHODS + (FITTED_METHOD,))} (default: all; "
                             f"{FITTED_METHOD} only with --fitted-camera)")
    parser.add_argument("--fitted-camera", type=Path, default=None, metavar="FILE",
                        help=f"camera file with fitted optics (livetrack model --camera-out): adds the method "
                             f"{FITTED_METHOD}, livetrack told the PSF core, halo and saturated-pixel noise (only the "
                             f"optics are used; the intrinsics are the scenario's)")
    parser.add_argument("--per-point-contrast", action="store_true",
                        help="the livetrack methods fit each clipped edge profile with its own contrast (the default "
                             "shares one per target: TrackerOptions.clipped_shared_contrast)")
    parser.add_argument("--fit-target-model", action=argparse.BooleanOptionalAction,
                        default=TrackerOptions.fit_target_model,
                        help="exposure-sweep: the livetrack methods model a target whose edges a lens halo clips in "
                             "2-D, halo included (TrackerOptions.fit_target_model; ~1-5 s per such frame; default "
                             "on)")
    parser.add_argument("--max-steps", type=int, default=None, help="use only the first N poses (quick runs)")
    parser.add_argument("--no-crb", action="store_true", help="skip the Cramer-Rao bound (saves ~3 s per pose)")
    parser.add_argument("--seed", type=int, default=None, help="override the scenario's seed (detection: the sweep's "
                        "seed, default 0; single-searches: the number of seeds per ground, default 4)")
    parser.add_argument("--quick", action="store_true", help="detection: half the scenes, 4 exposures (~1/4 the time)")
    parser.add_argument("--encoding-known", action="store_true",
                        help="detection: the tracker's camera states each scene's output encoding (the encoded "
                             "family's sRGB or gamma), as a user who knows it would; default: linear, as a camera "
                             "file that says nothing")
    parser.add_argument("--explain", action="store_true",
                        help="detection: for each visible target missed, the stage that lost it (a traced detection "
                             "of its frame: no blob, blob, pair, code, identified, or the tracker's failure); "
                             "printed per miss and counted, and in the JSON ('explain')")
    parser.add_argument("--scale", type=float, default=1.0,
                        help="detection: multiply the number of scenes (default 1: 35 scenes x 8 exposures)")
    parser.add_argument("--photos", type=Path, nargs="*", default=None, metavar="IMAGE",
                        help="detection: real photos with none of our targets (default: other-markers/*.png and "
                             "chessboard/*.jpg of $LIVETRACK_REALDATA or ../shared/realdata, when present)")
    parser.add_argument("--json", type=Path, required=True, help="report file")
    parser.add_argument("--plot", type=Path, default=None, help="PNG: distance error vs exposure per method")
    parser.add_argument("--poses", type=int, default=None, metavar="N",
                        help="exposure-sweep: N poses from the scenario's trajectory (its count replaced; Monte-Carlo "
                             "sweeps with --workers or --scheduler)")
    parser.add_argument("--range-poses", type=int, default=None, metavar="N",
                        help="exposure-sweep with --workers/--scheduler: poses per task, each range with fresh "
                             "estimators (default 5)")
    parser.add_argument("--no-timings", action="store_true",
                        help="leave the measured seconds out of the report (identical reports across runs)")
    add_executor_arguments(parser, default_hint="none: one process, as before; give N for a local cluster")


def run(args: argparse.Namespace) -> int:
    check_executor_args(args.workers, args.scheduler)
    if args.poses is not None and (args.experiment != "exposure-sweep" or args.poses < 1):
        raise ConfigError("--poses", "is for exposure-sweep, and must be >= 1")
    if args.experiment == "detection":
        return run_detection(args)
    if args.experiment == "single-searches":
        return run_single_searches(args)
    scenario_file = args.scenario or DEFAULT_SCENARIO
    scenario = load_sweep_scenario(str(scenario_file), seed=args.seed, poses=args.poses)
    fitted = None
    if args.fitted_camera is not None:
        from livetrack.camera.io import load_optics

        try:
            fitted = load_optics(args.fitted_camera)
        except ConfigError as exc:
            print(f"livetrack evaluate: error: {exc}", file=sys.stderr)
            return 2
    if args.methods is None:
        methods = list(ALL_METHODS) + ([FITTED_METHOD] if fitted else [])
    else:
        methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    known = ALL_METHODS + (FITTED_METHOD,)
    unknown = sorted(set(methods) - set(known))
    if unknown:
        print(f"livetrack evaluate: error: unknown methods {unknown} (choose from {', '.join(known)})",
              file=sys.stderr)
        return 2
    if FITTED_METHOD in methods and fitted is None:
        print(f"livetrack evaluate: error: method {FITTED_METHOD} needs --fitted-camera FILE", file=sys.stderr)
        return 2
    if _batch(args):
        from livetrack.batch.evaluate import DEFAULT_RANGE_POSES, run_sweep_batch

        settings = {"methods": methods, "with_crb": not args.no_crb,
                    "clipped_shared_contrast": not args.per_point_contrast,
                    "fit_target_model": args.fit_target_model,
                    "fitted_camera": str(args.fitted_camera.resolve()) if args.fitted_camera else None}
        range_poses = DEFAULT_RANGE_POSES if args.range_poses is None else args.range_poses
        if range_poses < 1:
            raise ConfigError("--range-poses", f"must be >= 1, got {range_poses}")
        result = _on_executor(args, f"ranges of {range_poses} poses", lambda executor: run_sweep_batch(
            scenario_file, executor, settings, seed=args.seed, poses=args.poses, max_steps=args.max_steps,
            range_poses=range_poses, progress=not args.no_progress))
        if result is None:
            return 1
    else:
        result = run_sweep(scenario, methods, max_steps=args.max_steps, with_crb=not args.no_crb,
                           progress=lambda msg: print(f"  {msg}", file=sys.stderr, flush=True), fitted_optics=fitted,
                           tracker_options=TrackerOptions(clipped_shared_contrast=not args.per_point_contrast,
                                                          fit_target_model=args.fit_target_model))
    summary = result.summary()
    report = {
        "experiment": "exposure-sweep",
        "scenario": str(scenario_file),
        "tracker_options": {"clipped_shared_contrast": not args.per_point_contrast,
                            "fit_target_model": args.fit_target_model},
        "fitted_camera": None if fitted is None else {"file": str(args.fitted_camera), **fitted.to_sections()},
        "exposure_factors": result.exposure_factors,
        "summary": summary,
        "ratios_vs_best_square_marker": _ratios(summary),
        "curves": {m: dict(zip(["exposure_factor", "median_error_pct", "median_abs_error_pct"],
                               result.error_curve(m), strict=True)) for m in summary},
        "observations": [o.__dict__ for o in result.observations],
        "crb_distance_rel": {str(k): v for k, v in result.crb_distance_rel.items()},
    }
    if _batch(args) or args.poses is not None:
        report["poses"] = len(scenario.steps)
    if _batch(args):
        report["range_poses"] = range_poses
    if args.no_timings:
        report = _without_timings(report)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=1))
    print(format_table(summary))
    ratios = report["ratios_vs_best_square_marker"]
    if ratios:
        print(f"\nlivetrack vs the better of ArUco/AprilTag: precision x{ratios['precision']:.1f}, "
              f"accuracy x{ratios['accuracy']:.1f}")
    if args.plot:
        plot_curves(result, args.plot)
        print(f"plot: {args.plot}")
    print(f"report: {args.json}")
    return 0


def _batch(args: argparse.Namespace) -> bool:
    """Tasks on livetrack.batch (--workers N, 0 included, or --scheduler); otherwise one run_sweep, as before."""
    return args.workers is not None or args.scheduler is not None


def _without_timings(report: dict) -> dict:
    """--no-timings: a copy of the report without the measured seconds (per observation, per method, the run)."""
    report = json.loads(json.dumps(report))
    for obs in report.get("observations", []):
        obs.pop("seconds", None)
    for method in report.get("summary", {}).values():
        if isinstance(method, dict):
            method.pop("median_seconds_per_frame", None)
    report.pop("seconds", None)
    report.get("summary", {}).pop("seconds", None)
    return report


def _ratios(summary: dict) -> dict[str, float]:
    ours = summary.get("livetrack")
    markers = [summary[m] for m in ("aruco", "apriltag") if m in summary]
    if not ours or not markers:
        return {}
    out = {}
    for key, name in (("precision_spread_across_exposures_pct", "precision"),
                      ("accuracy_mean_abs_distance_error_pct", "accuracy")):
        values = [m[key] for m in markers if m[key] is not None]
        if values and ours[key]:
            out[name] = min(values) / ours[key]
    return out


def format_table(summary: dict) -> str:
    head = (f"{'method':26s} {'found':>6s} {'|dist err|':>10s} {'signed':>8s} {'spread':>8s} {'normal':>7s} "
            f"{'CRB':>8s} {'spread/CRB':>10s} {'s/frame':>8s}")
    lines = [head, "-" * len(head)]

    def f(v, fmt):
        return format(v, fmt) if v is not None else "-"

    for method, s in summary.items():
        lines.append(f"{method:26s} {s['detection_rate'] * 100:5.0f}% "
                     f"{f(s['accuracy_mean_abs_distance_error_pct'], '9.3f')}% "
                     f"{f(s['mean_signed_distance_error_pct'], '7.3f')}% "
                     f"{f(s['precision_spread_across_exposures_pct'], '7.3f')}% "
                     f"{f(s['orientation_error_mean_deg'], '6.2f')}d "
                     f"{f(s['crb_distance_std_pct'], '7.4f')}% {f(s['spread_over_crb'], '10.1f')} "
                     f"{f(s['median_seconds_per_frame'], '8.3f')}")
    return "\n".join(lines)


def plot_curves(result: SweepResult, out: Path) -> None:
    curves = {m: result.error_curve(m) for m in dict.fromkeys(o.method for o in result.observations)}
    plot_report_curves(curves, result.crb_distance_rel, result.scenario, out)


def plot_report_curves(curves: dict[str, tuple[list, list, list]], crb_distance_rel: dict,
                       scenario: str, out: Path) -> None:
    """Left: median signed distance error vs exposure per method (linear); right: median |error| on a log scale
    with the Cramer-Rao bound (median over poses), where the compensated methods are visible.
    ``curves``: method -> (exposure factors, median signed %, median abs %)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax_log) = plt.subplots(1, 2, figsize=(13, 5), dpi=110)
    for method, (x, med, med_abs) in curves.items():
        pts = [(a, b) for a, b in zip(x, med, strict=True) if b is not None]
        if pts:
            line, = ax.plot(*zip(*pts, strict=True), marker="o", label=method)
            pts_abs = [(a, b) for a, b in zip(x, med_abs, strict=True) if b is not None and b > 0]
            ax_log.plot(*zip(*pts_abs, strict=True), marker="o", color=line.get_color(), label=method)
    if crb_distance_rel and curves:
        x = next(iter(curves.values()))[0]
        crb = np.median(np.array(list(crb_distance_rel.values()), dtype=float), axis=0) * 100.0
        ax_log.plot(x, crb, "k--", label="Cramer-Rao bound (std)")
    for a in (ax, ax_log):
        a.set_xscale("log", base=2)
        a.set_xlabel("exposure factor (x nominal: white paper at 55 % of full well)")
        a.grid(True, which="both", alpha=0.3)
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_ylabel("distance error, median over poses (%)")
    ax.set_title(f"Distance error vs exposure — {scenario}")
    ax.legend()
    ax_log.set_yscale("log")
    ax_log.set_ylabel("|distance error|, median over poses (%)")
    ax_log.set_title("the same, |error| on a log scale")
    ax_log.legend(fontsize=8)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)


# ---------------------------------------------------------------------------------------------- detection
def default_photos() -> list[Path]:
    """Real photos without our targets from the shared real data, if present."""
    root = Path(os.environ.get("LIVETRACK_REALDATA", Path(__file__).resolve().parents[3] / "shared" / "realdata"))
    if not root.is_dir():
        return []
    return sorted((root / "other-markers").glob("*.png")) + sorted((root / "chessboard").glob("*.jpg"))


def run_single_searches(args: argparse.Namespace) -> int:
    from livetrack.evaluation import single_searches

    seeds = 4 if args.seed is None else args.seed
    if seeds < 1:
        raise ConfigError("--seed", f"single-searches takes the number of seeds per ground, >= 1; got {seeds}")
    rows = single_searches.run(seeds=seeds, progress=lambda msg: print(f"  {msg}", file=sys.stderr, flush=True))
    report = {"experiment": "single-searches", "seeds": seeds, **single_searches.report(rows)}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=1))
    print("sheet  exposure  found      mean |error|  median |error|  mean error")
    for row in report["summary"]:
        print(f"{row['sheet']:<6} x{row['exposure_factor']:<8g} {row['found']:>3} / {row['frames']:<4} "
              f"{row['mean_abs_error_pct']:10.3f} % {row['median_abs_error_pct']:12.3f} % "
              f"{row['mean_error_pct']:+10.3f} %")
    print(f"report: {args.json}")
    return 0


def run_detection(args: argparse.Namespace) -> int:
    import cv2

    from livetrack.evaluation.detection import TABLE_KEYS, run_detection_sweep

    if args.scale <= 0:
        print("livetrack evaluate: error: --scale must be > 0", file=sys.stderr)
        return 2
    files = default_photos() if args.photos is None else list(args.photos)
    photos = []
    for file in files:
        image = cv2.imread(str(file), cv2.IMREAD_UNCHANGED | cv2.IMREAD_IGNORE_ORIENTATION)
        if image is None:
            print(f"livetrack evaluate: error: cannot read {file}", file=sys.stderr)
            return 2
        photos.append((file.name, image))
    # The other circular markers' photos also serve as backgrounds behind targets.
    backgrounds = [str(f) for f in files if "other-markers" in f.parts]
    if _batch(args):
        from livetrack.batch.evaluate import run_detection_batch

        result = _on_executor(args, "one task per scene", lambda executor: run_detection_batch(
            executor, seed=0 if args.seed is None else args.seed, scale=args.scale, quick=args.quick, photos=photos,
            background_files=backgrounds, progress=not args.no_progress, explain=args.explain,
            encoding_known=args.encoding_known))
        if result is None:
            return 1
    else:
        result = run_detection_sweep(seed=0 if args.seed is None else args.seed, scale=args.scale, quick=args.quick,
                                     photos=photos, background_files=backgrounds, explain=args.explain,
                                     encoding_known=args.encoding_known,
                                     progress=lambda msg: print(f"  {msg}", file=sys.stderr, flush=True))
    report = {"experiment": "detection", "seed": 0 if args.seed is None else args.seed, "quick": args.quick,
              "encoding_known": args.encoding_known,
              "scale": args.scale, "photos": [str(f) for f in files], **result.to_dict()}
    if args.no_timings:
        report = _without_timings(report)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=1))
    print(format_detection(result.summary(), {k: result.table(k) for k in TABLE_KEYS}))
    if args.explain:
        print(format_explain(result.misses()))
    if args.plot:
        plot_detection(report, args.plot)
        print(f"plot: {args.plot}")
    print(f"report: {args.json}")
    return 0


def format_explain(misses: list) -> str:
    """The misses by the stage that lost them, then one line per miss."""
    from livetrack.evaluation.detection import explain_counts

    lines = ["", f"misses by stage ({len(misses)} visible targets missed):"]
    lines += [f"  {stage:12s} {n:4d}" for stage, n in explain_counts(misses).items()]
    lines.append("")
    lines.append(f"{'case':18s} {'exp':>5s} {'b px':>6s} {'tilt':>5s} {'bg':12s} {'sheet':5s} stage")
    for t in misses:
        lines.append(f"{t.case:18s} {'x' + format(t.exposure_factor, 'g'):>5s} {t.semi_minor_px:6.1f} "
                     f"{t.tilt_deg:5.0f} {t.background:12s} {t.sheet[:5]:5s} {t.explain}")
    return "\n".join(lines)


def format_detection(summary: dict, tables: dict[str, list[dict]]) -> str:
    """The summary and one table per dimension, as text."""
    from livetrack.evaluation.detection import MIN_SEMI_MINOR_PX, SPECIFIED_AREA_FRACTIONS

    lo, hi = SPECIFIED_AREA_FRACTIONS

    def pct(v, digits=1):
        return "-" if v is None else f"{100.0 * v:.{digits}f}%"

    def err(v):
        return "-" if v is None else f"{v:.4f}%"

    s = summary
    lines = [f"visible targets found: {s['found']}/{s['visible']} ({pct(s['found_rate'], 2)}); detected (pose or "
             f"not): {pct(s['detected_rate'], 2)}; wrong id: {s['wrong_id']}; not visible: {s['invisible']} "
             f"(found anyway: {s['found_invisible']})",
             f"ring visible but too small to identify (semi-minor axis < {MIN_SEMI_MINOR_PX:g} px, not counted): "
             f"{s['ring_visible_too_small']} (found anyway: {s['found_too_small']})",
             f"false positives: {s['false_positives_no_target']} on {s['no_target_frames']} frames without "
             f"targets, {s['false_positives_with_targets']} beside the targets",
             f"of those covering {100 * lo:g}-{100 * hi:g} % of the frame (the specified range): "
             f"{s['found_in_specified_range']}/"
             f"{s['visible_in_specified_range']} ({pct(s['found_rate_in_specified_range'], 2)})",
             f"gross pose errors (distance off by > 5 %): {s['gross_pose_errors']}",
             f"|distance error| of found targets: median {err(s['median_abs_distance_error_pct'])}, 95th "
             f"percentile {err(s['p95_abs_distance_error_pct'])}, max {err(s['max_abs_distance_error_pct'])}; "
             f"within 3 sd of their own covariance: {pct(s['distance_within_3sd'])}; {s['seconds']:.0f} s"]
    for key, rows in tables.items():
        lines.append("")
        head = (f"{key:>16s} {'frames':>7s} {'visible':>8s} {'found':>6s} {'rate':>8s} {'med |err|':>10s} "
                f"{'max |err|':>10s}")
        lines += [head, "-" * len(head)]
        for r in rows:
            lines.append(f"{str(r[key]):>16s} {r['frames']:7d} {r['visible']:8d} {r['found']:6d} "
                         f"{pct(r['found_rate']):>8s} {err(r['median_abs_distance_error_pct']):>10s} "
                         f"{err(r['max_abs_distance_error_pct']):>10s}")
    return "\n".join(lines)


def plot_detection(report: dict, out: Path) -> None:
    """Found rate among visible targets against exposure (per background), target area and tilt, and the
    |distance error| of the found ones against exposure."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    targets = report["targets"]
    fig, axes = plt.subplots(2, 2, figsize=(13, 9), dpi=100)
    ax = axes[0, 0]
    for bg in sorted({t["background"] for t in targets}):
        xs, ys = [], []
        for f in sorted({t["exposure_factor"] for t in targets}):
            vis = [t for t in targets if t["background"] == bg and t["exposure_factor"] == f and t["visible"]]
            if vis:
                xs.append(f)
                ys.append(100.0 * sum(t["found"] for t in vis) / len(vis))
        ax.plot(xs, ys, marker="o", label=bg)
    ax.set_xscale("log", base=2)
    ax.set_xlabel("exposure factor")
    ax.set_ylabel("found among visible (%)")
    ax.set_title("found rate per background")
    ax.legend(fontsize=7)
    for ax, key, label in ((axes[0, 1], "area", "target area (share of the frame)"), (axes[1, 0], "tilt", "tilt")):
        rows = report["tables"][key]
        names = [str(r[key]) for r in rows]
        rates = [100.0 * r["found_rate"] if r["found_rate"] is not None else 0.0 for r in rows]
        bars = ax.bar(names, rates, color="tab:blue")
        for bar, r in zip(bars, rows, strict=True):
            ax.annotate(f"{r['found']}/{r['visible']}", (bar.get_x() + bar.get_width() / 2, bar.get_height()),
                        ha="center", va="bottom", fontsize=7)
        ax.set_ylim(0, 105)
        ax.set_xlabel(label)
        ax.set_ylabel("found among visible (%)")
    ax = axes[1, 1]
    found = [t for t in targets if t["found"] and t["distance_error_pct"] is not None]
    if found:
        ax.scatter([t["exposure_factor"] * (1 + 0.08 * (n % 7 - 3) / 3) for n, t in enumerate(found)],
                   [max(abs(t["distance_error_pct"]), 1e-5) for t in found], s=6, alpha=0.5)
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("exposure factor")
    ax.set_ylabel("|distance error| (%)")
    ax.set_title("pose error of the found targets")
    s = report["summary"]
    fig.suptitle(f"livetrack evaluate detection: {s['found']}/{s['visible']} visible targets found, "
                 f"{s['false_positives_no_target']} false positives on {s['no_target_frames']} frames without targets")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)


def _on_executor(args: argparse.Namespace, split: str, run_on: Callable[[Any], Any]) -> Any:
    """``run_on(executor)`` on the executor ``--workers``/``--scheduler`` ask for; None, each failed task printed,
    when some failed (``split``: how the work is cut, for the opening line)."""
    from livetrack.batch.evaluate import BatchFailed

    with make_executor(args.workers, args.scheduler, args.retries) as executor:
        print(f"livetrack evaluate: {executor.description}, {split}", file=sys.stderr)
        try:
            return run_on(executor)
        except BatchFailed as exc:
            for failure in exc.failures:
                print(f"FAILED {failure}", file=sys.stderr)
            return None
