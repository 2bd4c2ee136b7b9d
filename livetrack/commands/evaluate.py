"""``livetrack evaluate exposure-sweep``: the paper's experiment in simulation, every method side by side."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from livetrack.config_checks import ConfigError
from livetrack.estimator.tracker import TrackerOptions
from livetrack.evaluation.exposure_sweep import ALL_METHODS, FITTED_METHOD, SweepResult, run_sweep
from livetrack.sim.scenario import Scenario

NAME = "evaluate"
HELP = "accuracy experiments on simulated ground truth (exposure-sweep)"

DEFAULT_SCENARIO = Path(__file__).resolve().parents[2] / "config" / "scenarios" / "paper-lab.yaml"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("experiment", choices=["exposure-sweep"], help="which experiment")
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
    parser.add_argument("--max-steps", type=int, default=None, help="use only the first N poses (quick runs)")
    parser.add_argument("--no-crb", action="store_true", help="skip the Cramer-Rao bound (saves ~3 s per pose)")
    parser.add_argument("--seed", type=int, default=None, help="override the scenario's seed")
    parser.add_argument("--json", type=Path, required=True, help="report file")
    parser.add_argument("--plot", type=Path, default=None, help="PNG: distance error vs exposure per method")


def run(args: argparse.Namespace) -> int:
    scenario_file = args.scenario or DEFAULT_SCENARIO
    scenario = Scenario.from_file(scenario_file, seed=args.seed)
    fitted = None
    if args.fitted_camera is not None:
        from livetrack.camera_io import load_optics

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
    result = run_sweep(scenario, methods, max_steps=args.max_steps, with_crb=not args.no_crb,
                       progress=lambda msg: print(f"  {msg}", file=sys.stderr, flush=True), fitted_optics=fitted,
                       tracker_options=TrackerOptions(clipped_shared_contrast=not args.per_point_contrast))
    summary = result.summary()
    report = {
        "experiment": "exposure-sweep",
        "scenario": str(scenario_file),
        "tracker_options": {"clipped_shared_contrast": not args.per_point_contrast},
        "fitted_camera": None if fitted is None else {"file": str(args.fitted_camera), **fitted.to_sections()},
        "exposure_factors": result.exposure_factors,
        "summary": summary,
        "ratios_vs_best_square_marker": _ratios(summary),
        "curves": {m: dict(zip(["exposure_factor", "median_error_pct", "median_abs_error_pct"],
                               result.error_curve(m), strict=True)) for m in summary},
        "observations": [o.__dict__ for o in result.observations],
        "crb_distance_rel": {str(k): v for k, v in result.crb_distance_rel.items()},
    }
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
