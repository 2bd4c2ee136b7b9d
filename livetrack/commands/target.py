"""``livetrack target``: write a printable target (SVG, PDF or PNG) at exact 1:1 scale."""

from __future__ import annotations

import argparse
from pathlib import Path

from livetrack.config.checks import ConfigError
from livetrack.targets import artwork
from livetrack.targets.spec import TargetSpec, load_targets

NAME = "target"
HELP = "write a printable target (SVG, PDF or PNG) at exact 1:1 scale"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--id", type=int, required=True, help="target id (default design: code book index)")
    parser.add_argument("--diameter-mm", type=float, default=None,
                        help="outer black disk diameter (2R) in mm; required for the default design, with "
                             "--spec it must match the file if given")
    parser.add_argument("--out", type=Path, required=True, help="output file; format from the suffix "
                        f"({', '.join(artwork.FORMATS)})")
    parser.add_argument("--dpi", type=int, default=300,
                        help="PNG resolution, stored in the file (default 300)")
    parser.add_argument("--spec", type=Path, default=None, metavar="FILE",
                        help="take the geometry of --id from this targets YAML file instead of the default "
                             "design")
    parser.add_argument("--levels", type=int, choices=(1, 2), default=None,
                        help="fractal levels of the default design (default 2)")


def _spec_from_args(args: argparse.Namespace) -> TargetSpec:
    if args.spec is not None:
        if args.levels is not None:
            raise ConfigError("--levels", "only for the default design; the spec file defines the levels")
        specs = {s.id: s for s in load_targets(args.spec)}
        if args.id not in specs:
            raise ConfigError("--id", f"no target with id {args.id} in {args.spec} "
                                      f"(ids: {', '.join(str(i) for i in sorted(specs))})")
        spec = specs[args.id]
        file_mm = 2000.0 * spec.outer_radius_m
        if args.diameter_mm is not None and abs(args.diameter_mm - file_mm) > 1e-6:
            raise ConfigError("--diameter-mm", f"{args.diameter_mm} mm disagrees with {args.spec} "
                                               f"({file_mm:.1f} mm for id {args.id}); omit --diameter-mm")
        return spec
    if args.diameter_mm is None:
        raise ConfigError("--diameter-mm", "required for the default design (or give --spec FILE)")
    if not args.diameter_mm > 0:
        raise ConfigError("--diameter-mm", f"must be > 0, got {args.diameter_mm}")
    try:
        return TargetSpec.default(args.id, args.diameter_mm / 2000.0, args.levels or 2)
    except ValueError as exc:
        raise ConfigError("--id", str(exc)) from None


def run(args: argparse.Namespace) -> int:
    spec = _spec_from_args(args)
    if args.out.suffix.lower() not in artwork.FORMATS:
        raise ConfigError("--out", f"unknown format {args.out.suffix!r} (use {', '.join(artwork.FORMATS)})")
    if args.dpi <= 0:
        raise ConfigError("--dpi", f"must be > 0, got {args.dpi}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    try:
        out = artwork.write_target(spec, args.out, dpi=args.dpi)
    except ValueError as exc:
        raise ConfigError("--out", str(exc)) from None
    lay = artwork.page_layout(spec)
    levels = sum(1 for _ in spec.levels())
    print(f"wrote {out}")
    print(f"  page {lay.width_mm:.1f} x {lay.height_mm:.1f} mm, print at 100 % (no fit-to-page)")
    if out.suffix.lower() == ".png":
        w, h = artwork.png_size_px(spec, args.dpi)
        print(f"  {w} x {h} px at {args.dpi} dpi")
    print(f"  id {spec.id}, outer diameter {2000.0 * spec.outer_radius_m:.1f} mm, {levels} level(s), "
          f"scale bar {lay.scale_bar_mm:.0f} mm")
    if spec.code is None:
        print("  bits: none")
        print("  heading: none (no code)")
    else:
        print(f"  bits: {spec.code.bits} (slot k at {360 / spec.code.slots:g}*k deg from +x, clockwise as "
              "printed)")
        print("  heading: none (symmetric code)" if spec.code.symmetric else "  heading: from the code")
    return 0
