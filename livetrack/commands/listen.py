"""``livetrack listen``: receive the pose stream (UDP or ZeroMQ SUB) and print one line per message.

A reference receiver for docs/pose-stream.md: it decodes both encodings, checks magic and version, and counts
sequence gaps (lost or dropped messages). It survives any datagram: what it rejects is counted by reason
(``MessageError.reason``) in the summary line. Bounded by ``--count`` and ``--duration``; Ctrl-C ends it.
``--mavlink udpin:HOST:PORT`` (or ``serial:DEVICE:BAUD``) prints the MAVLink output instead, decoded by pymavlink.
"""

from __future__ import annotations

import argparse
import logging
import socket
import sys
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass

from livetrack.config.checks import ConfigError
from livetrack.sinks.pose_message import MessageError, PoseMessage, decode
from livetrack.sinks.udp import parse_host_port

NAME = "listen"
HELP = "receive and print the pose stream of livetrack run (--udp HOST:PORT, --zmq ENDPOINT or --mavlink)"

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--udp", metavar="HOST:PORT", help="bind here and receive datagrams (default "
                                                          "127.0.0.1:5005)")
    group.add_argument("--zmq", metavar="ENDPOINT", help="connect a SUB socket to this PUB endpoint, e.g. "
                                                         "tcp://127.0.0.1:5556")
    group.add_argument("--mavlink", metavar="CONNECTION", help="receive livetrack's MAVLink output: udpin:HOST:PORT "
                                                               "or serial:/dev/ttyX:BAUD (docs/vehicle.md)")
    parser.add_argument("--target", type=int, action="append", metavar="ID",
                        help="only this target id (repeatable; ZeroMQ subscribes to its topic)")
    parser.add_argument("--count", type=int, metavar="N", help="stop after N messages")
    parser.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    parser.add_argument("--json", action="store_true",
                        help="print each message as one JSON line (the stream's JSON encoding: NaN as null)")


def run(args: argparse.Namespace) -> int:
    if args.count is not None and args.count < 1:
        raise ConfigError("--count", f"must be >= 1, got {args.count}")
    if args.duration is not None and args.duration <= 0:
        raise ConfigError("--duration", f"must be > 0, got {args.duration}")
    deadline = time.monotonic() + args.duration if args.duration else None
    wanted = set(args.target) if args.target else None
    if getattr(args, "mavlink", None):
        return _listen_mavlink(args.mavlink, wanted, deadline, args.count, args.json)
    if args.zmq:
        from livetrack.config.app import normalise_zmq_endpoint

        payloads = _zmq_payloads(normalise_zmq_endpoint(args.zmq, "--zmq"), wanted, deadline)
    else:
        try:
            host, port = parse_host_port(args.udp or "127.0.0.1:5005", "--udp")
        except ValueError as exc:
            raise ConfigError("--udp", str(exc)) from None
        payloads = _udp_payloads(host, port, deadline)
    received = 0
    rejected: Counter[str] = Counter()
    gaps = SequenceGaps()
    try:
        for payload in payloads:
            if isinstance(payload, Rejected):
                rejected[payload.reason] += 1
                print(f"invalid message: {payload.problem}", file=sys.stderr)
                continue
            try:
                message = decode(payload)
            except MessageError as exc:
                rejected[exc.reason] += 1
                print(f"invalid message ({len(payload)} bytes): {exc}", file=sys.stderr)
                continue
            except Exception as exc:  # noqa: BLE001 - a receiver survives any datagram; decode should not get here
                rejected["decoder-error"] += 1
                print(f"invalid message ({len(payload)} bytes): decoder error {type(exc).__name__}: {exc}",
                      file=sys.stderr)
                continue
            if wanted is None:
                gaps.add(message.sequence)
            if wanted is not None and message.target_id not in wanted:
                continue
            received += 1
            print(message.to_json().decode("utf-8") if args.json else format_message(message), flush=True)
            if args.count is not None and received >= args.count:
                break
    except KeyboardInterrupt:
        pass
    print(summary_line(received, rejected, gaps if wanted is None else None), file=sys.stderr)
    return 0


def summary_line(received: int, rejected: Counter[str], gaps: SequenceGaps | None) -> str:
    """``livetrack listen: 12 messages, 3 invalid (json-syntax 2, size 1), 0 missing sequence numbers``."""
    invalid = sum(rejected.values())
    by_reason = ", ".join(f"{reason} {n}" for reason, n in sorted(rejected.items()))
    text = f"livetrack listen: {received} messages, {invalid} invalid" + (f" ({by_reason})" if by_reason else "")
    if gaps is not None:
        text += f", {gaps.missing} missing sequence numbers"
        if gaps.restarts:
            text += f", {gaps.restarts} sequence restarts or jumps (not counted as missing)"
    return text


class SequenceGaps:
    """Counts messages missing from a stream by its ``sequence`` numbers (valid messages only).

    A step forward of more than one counts the numbers skipped; a step backward (the sender restarted) or
    forward by more than ``max_gap`` (not a loss a receiver could have survived: a different sender, a corrupt
    message) restarts the count from the new number and is counted in ``restarts`` instead.
    """

    def __init__(self, max_gap: int = 1_000_000) -> None:
        self.max_gap = max_gap
        self.missing = 0
        self.restarts = 0
        self.last: int | None = None

    def add(self, sequence: int) -> None:
        if self.last is not None:
            step = sequence - self.last
            if 1 < step <= self.max_gap + 1:
                self.missing += step - 1
            elif step > self.max_gap + 1 or step < 0:
                self.restarts += 1
        self.last = sequence


def format_message(m: PoseMessage) -> str:
    t = ", ".join(f"{v:+.4f}" for v in m.t_m)
    state = "ok" if m.ok else "FAILED"
    frames = ""
    if m.frames is not None:  # version 2: the target in body FRD, the vehicle in NED when the target is placed
        frames = " body_m ({})".format(", ".join(f"{v:+.4f}" for v in m.frames.target_in_body.t_m))
        if m.frames.vehicle_in_ned is not None:
            frames += " vehicle_ned_m ({})".format(", ".join(f"{v:+.4f}" for v in m.frames.vehicle_in_ned.t_m))
    return (f"seq {m.sequence:6d} frame {m.frame_id:6d} id {m.target_id:3d} t_m ({t}) dist {m.distance_m:.4f} m "
            f"delta {m.delta_px:+.3f} px exp {_exposure(m.exposure_us)} latency {m.latency_ms:.1f} ms "
            f"rms {m.residual_rms_px:.3f} px {state}{'' if m.heading_known else ' heading-unknown'}{frames}")


def _exposure(exposure_us: float | None) -> str:
    return "unknown" if exposure_us is None else f"{exposure_us:.1f} us"


def _udp_payloads(host: str, port: int, deadline: float | None) -> Iterator[bytes]:
    infos = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
    family, _, _, _, address = infos[0]
    with socket.socket(family, socket.SOCK_DGRAM) as sock:
        sock.bind(address)
        sock.settimeout(0.2)
        print(f"livetrack listen: UDP {host}:{port}", file=sys.stderr, flush=True)
        while deadline is None or time.monotonic() < deadline:
            try:
                yield sock.recv(65536)
            except TimeoutError:
                continue


@dataclass(frozen=True)
class Rejected:
    """What a transport refused before decoding (counted by ``reason`` like ``MessageError``)."""

    reason: str
    problem: str


MAX_ZMQ_MESSAGE_BYTES = 1 << 20  # a pose message is 320 bytes (binary) or about 1.5 kB (JSON)


def _zmq_payloads(endpoint: str, wanted: set[int] | None, deadline: float | None) -> Iterator[bytes | Rejected]:
    import zmq

    from livetrack.sinks.zmq_pub import TOPIC_PREFIX, topic_for

    context = zmq.Context()
    sock = context.socket(zmq.SUB)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.MAXMSGSIZE, MAX_ZMQ_MESSAGE_BYTES)  # a larger frame drops that peer, not our memory
    topics = [topic_for(i) for i in sorted(wanted)] if wanted else [TOPIC_PREFIX]
    for topic in topics:
        sock.setsockopt(zmq.SUBSCRIBE, topic)
    sock.connect(endpoint)
    print(f"livetrack listen: ZeroMQ {endpoint}", file=sys.stderr, flush=True)
    try:
        while deadline is None or time.monotonic() < deadline:
            if not sock.poll(200):
                continue
            frames = sock.recv_multipart()
            if len(frames) != 2:
                yield Rejected("zmq-frames", f"{len(frames)} frames (a pose message is topic + payload)")
            elif not wanted or frames[0] in topics:  # topic prefixes: 3 also matches 30
                yield frames[1]
    finally:
        sock.close(linger=0)
        context.term()


def _listen_mavlink(connection: str, wanted: set[int] | None, deadline: float | None, count: int | None,
                    as_json: bool) -> int:
    """Print every MAVLink message received (``--target``: only LANDING_TARGET of those target numbers)."""
    import json

    from livetrack.sinks.mavlink import DIALECT, import_mavutil

    kind, _, rest = connection.partition(":")
    device, _, baud = rest.rpartition(":")
    if kind == "udpin":
        try:
            parse_host_port(rest, "--mavlink udpin")
        except ValueError as exc:
            raise ConfigError("--mavlink", str(exc)) from None
        kwargs: dict = {}
    elif kind == "serial" and device and baud.isdigit():
        connection, kwargs = device, {"baud": int(baud)}
    else:
        raise ConfigError("--mavlink", f"must be udpin:HOST:PORT or serial:/dev/ttyX:BAUD, got {connection!r}")
    mavutil = import_mavutil()
    conn = mavutil.mavlink_connection(connection, dialect=DIALECT, **kwargs)
    print(f"livetrack listen: MAVLink {connection}", file=sys.stderr, flush=True)
    received = 0
    rejected: Counter[str] = Counter()
    try:
        while deadline is None or time.monotonic() < deadline:
            message = conn.recv_match(blocking=True, timeout=0.2)
            if message is None:
                continue
            kind = message.get_type()
            if kind == "BAD_DATA":
                rejected["mavlink-bad-data"] += 1
                continue
            if wanted is not None and not (kind == "LANDING_TARGET" and message.target_num in wanted):
                continue
            received += 1
            if as_json:
                data = {"sys": message.get_srcSystem(), "comp": message.get_srcComponent(), **message.to_dict()}
                print(json.dumps(data, default=str), flush=True)
            else:
                print(f"sys {message.get_srcSystem()} comp {message.get_srcComponent()} {message}", flush=True)
            if count is not None and received >= count:
                break
    except KeyboardInterrupt:
        pass
    finally:
        conn.close()
    print(summary_line(received, rejected, None), file=sys.stderr)
    return 0
