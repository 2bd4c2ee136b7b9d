"""``livetrack replay DIR``: ``livetrack run`` on a recording (``replay:DIR``), as fast as possible by default."""

from __future__ import annotations

import argparse
from pathlib import Path

from livetrack.commands.run import add_common_arguments, config_from_args, run_config

NAME = "replay"
HELP = "track a recording (= livetrack run --source replay:DIR), as fast as possible unless --pace recorded"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", type=Path, metavar="DIR", help="recording directory (format v1)")
    parser.add_argument("--pace", choices=["fast", "recorded"], default="fast",
                        help="fast: every frame as soon as the tracker is free (default); recorded: at the "
                             "recorded frame intervals")
    add_common_arguments(parser)


def run(args: argparse.Namespace) -> int:
    extra = {"source": {"uri": f"replay:{args.recording}", "options": {"pace": args.pace}}}
    return run_config(config_from_args(args, extra), args)
