"""``livetrack dump-config``: print the resolved configuration of ``livetrack run`` (defaults, file, options)."""

from __future__ import annotations

import argparse

from livetrack.commands.run import add_common_arguments, config_from_args

NAME = "dump-config"
HELP = "print the resolved run configuration (built-in defaults merged with --config FILE and the options)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--source", metavar="URI", help="as for livetrack run")
    add_common_arguments(parser)


def run(args: argparse.Namespace) -> int:
    print(config_from_args(args).to_yaml(), end="")
    return 0
