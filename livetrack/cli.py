"""Command-line entry point: ``livetrack <command> ...``. Thin: each command lives in ``livetrack.commands``."""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from threadpoolctl import threadpool_limits

from livetrack import __version__
from livetrack.config.checks import ConfigError

# Subcommand modules; each defines NAME, HELP, add_arguments(parser) and run(args) -> int.
COMMAND_MODULES = [
    "livetrack.commands.sim",
    "livetrack.commands.target",
    "livetrack.commands.bench_sim",
    "livetrack.commands.detect",
    "livetrack.commands.evaluate",
    "livetrack.commands.bench",
    "livetrack.commands.run",
    "livetrack.commands.replay",
    "livetrack.commands.listen",
    "livetrack.commands.dump_config",
    "livetrack.commands.bench_live",
    "livetrack.commands.model",
    "livetrack.commands.record_sweep",
    "livetrack.commands.calibrate",
    "livetrack.commands.bench_batch",
]

log = logging.getLogger("livetrack")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="livetrack", description=__doc__)
    parser.add_argument("--version", action="version", version=f"livetrack {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv: debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_MODULES:
        module = importlib.import_module(name)
        p = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose + 1, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    try:
        # BLAS on one thread: livetrack's threads (acquisition, tracking, searches, sinks) already share the cores,
        # and its matrices are small or tall-and-thin (the 2-D target model's ~17k x 12 Jacobians), where OpenBLAS's
        # own threads only contend: a paper-lab x32 tracked frame took 149 ms of wall time with them at a load of ~3
        # on 2 cores, 54 ms without.
        with threadpool_limits(limits=1, user_api="blas"):
            return int(args._run(args) or 0)
    except ConfigError as exc:
        print(f"livetrack {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
