"""``livetrack run``: track targets live from a source and stream their poses (default: the simulated camera).

Thin: the config is resolved by ``livetrack.config.app``, the threads live in ``livetrack.pipeline``. SIGINT
(Ctrl-C) or SIGTERM stops cleanly: acquisition stops, outputs drain and close (a recording is marked complete),
the summary is printed and the exit status is 0. A second signal kills at once.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from pathlib import Path
from typing import Any

from livetrack.config.app import AppConfig, load_config
from livetrack.config.checks import ConfigError

NAME = "run"
HELP = ("track targets live (default: the simulated camera) and stream their poses (UDP, ZeroMQ, MAVLink, Rerun, "
        "record)")

log = logging.getLogger(__name__)

FLAG_KEYS = {"udp": "outputs.udp.destination", "zmq": "outputs.zmq.endpoint", "rerun": "outputs.rerun.mode",
             "source": "source.uri", "mavlink": "outputs.mavlink.connection"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--source", metavar="URI", help="sim: | sim:SCENARIO.yaml | replay:DIR | aravis:[DEVICE] | "
                                                        "v4l2:/dev/videoN (default: the config's, sim:)")
    add_common_arguments(parser)


def add_common_arguments(parser: argparse.ArgumentParser) -> None:
    """Options shared by run, replay and dump-config."""
    parser.add_argument("--config", type=Path, metavar="FILE", help="YAML merged over the built-in defaults "
                                                                    "(see livetrack dump-config)")
    parser.add_argument("--max-frames", type=int, metavar="N", help="stop after N processed frames")
    parser.add_argument("--udp", metavar="HOST:PORT", help="send one datagram per target per frame here")
    parser.add_argument("--zmq", metavar="ENDPOINT", help="publish poses on this ZeroMQ PUB endpoint, e.g. "
                                                          "tcp://127.0.0.1:5556")
    parser.add_argument("--mavlink", metavar="CONNECTION", help="MAVLink to a vehicle: udpout:HOST:PORT | "
                                                                 "serial:/dev/ttyX:BAUD (docs/vehicle.md)")
    parser.add_argument("--rerun", metavar="MODE", help="viewer: spawn | connect[:URL] | serve | save:PATH.rrd | off")
    parser.add_argument("--record", type=Path, metavar="DIR", help="write every acquired frame as a recording")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing recording at --record")
    parser.add_argument("--quiet", action="store_true", help="no per-frame lines (the summary is still printed)")


def overrides_from_args(args: argparse.Namespace) -> dict[str, Any]:
    """The command-line options as a config mapping (paths made absolute: relative to the working directory)."""
    out: dict[str, Any] = {}
    source = getattr(args, "source", None)
    if source is not None:
        out["source"] = {"uri": source}
    if args.max_frames is not None:
        if args.max_frames < 1:
            raise ConfigError("--max-frames", f"must be >= 1, got {args.max_frames}")
        out.setdefault("pipeline", {})["max_frames"] = args.max_frames
    outputs: dict[str, Any] = {}
    if args.udp is not None:
        outputs["udp"] = {"destination": args.udp}
    if args.zmq is not None:
        outputs["zmq"] = {"endpoint": args.zmq}
    if getattr(args, "mavlink", None) is not None:
        outputs["mavlink"] = {"connection": args.mavlink}
    if args.rerun is not None:
        mode = args.rerun
        if mode.startswith("save:"):
            mode = "save:" + str(Path(mode[len("save:"):]).resolve())
        outputs["rerun"] = {"mode": mode}
    if args.record is not None:
        outputs["record"] = {"dir": str(args.record.resolve())}
    if args.overwrite:
        outputs.setdefault("record", {})["overwrite"] = True
    if outputs:
        out["outputs"] = outputs
    if args.quiet:
        out["logging"] = {"print_every_s": 0}
    return out


def config_from_args(args: argparse.Namespace, extra: dict[str, Any] | None = None) -> AppConfig:
    overrides = overrides_from_args(args)
    if extra:
        from livetrack.config.app import merge

        overrides = merge(extra, overrides)
    try:
        return load_config(args.config, overrides)
    except ConfigError as exc:
        for attr, key in FLAG_KEYS.items():
            if getattr(args, attr, None) is not None and exc.path.endswith(key):
                raise ConfigError(f"--{attr}", exc.problem) from None
        raise


FLAG_OUTPUT_KEYS = {"record": "outputs.record.dir", "rerun": "outputs.rerun.mode"}


def run(args: argparse.Namespace) -> int:
    return run_config(config_from_args(args), args)


def run_config(config: AppConfig, args: argparse.Namespace | None = None) -> int:
    """Build, run until done or signalled, print the summary. 0 on success (also when stopped by a signal).
    ``args``: the command line, to name its flag (e.g. ``--record``) in an error about what it set."""
    from livetrack.pipeline import build_pipeline
    from livetrack.sources.base import SourceError

    if config.logging.level is not None:
        logging.getLogger("livetrack").setLevel(config.logging.level.upper())
    try:
        pipeline = build_pipeline(config)
    except ConfigError as exc:
        for attr, key in FLAG_OUTPUT_KEYS.items():
            if args is not None and getattr(args, attr, None) is not None and exc.path == key:
                raise ConfigError(f"--{attr}", exc.problem) from None
        raise
    except SourceError as exc:
        print(f"livetrack: cannot open the source {config.source.uri}: {exc}", file=sys.stderr)
        return 1
    print(f"livetrack: compiled kernels ready in {pipeline.warm_up():.2f} s (loaded from numba's cache, or compiled)",
          file=sys.stderr, flush=True)
    restore = _install_signal_handlers(pipeline)  # before start: a signal during start still stops cleanly
    try:
        try:
            pipeline.start()
        except Exception as exc:  # an output that cannot open: port in use, recording exists, no viewer binary
            hint = " (--overwrite replaces a recording)" if isinstance(exc, FileExistsError) else ""
            print(f"livetrack: cannot open an output: {exc}{hint}", file=sys.stderr)
            return 1
        while not pipeline.wait(0.2):
            pass
        summary = pipeline.close()
    finally:
        pipeline.close()
        restore()
    print(summary.format(), flush=True)
    return 1 if summary.source_error else 0


def _install_signal_handlers(pipeline) -> Any:
    """SIGINT/SIGTERM -> pipeline.stop(); the default handlers are back after the first signal."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}

    def handler(signum: int, _frame: Any) -> None:
        name = signal.Signals(signum).name
        pipeline.stop(name)
        for sig, old in previous.items():
            signal.signal(sig, old)
        print(f"livetrack: {name}: stopping (again to abort)", file=sys.stderr, flush=True)

    for sig in previous:
        signal.signal(sig, handler)

    def restore() -> None:
        for sig, old in previous.items():
            signal.signal(sig, old)

    return restore
