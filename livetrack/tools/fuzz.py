"""Long fuzz campaign of a parser: ``python -m livetrack.tools.fuzz TARGET --seconds N``.

TARGET is ``pose-message``, ``recording`` or ``config`` (``livetrack.tools.fuzz_targets``). Every input must
make the target return or raise its documented error; any other exception is a crash, an input that runs longer
than ``--timeout`` seconds a hang. Each is saved (input and traceback) in the work directory, and the campaign
goes on. At the end one line gives the inputs tried, the crashes and the hangs; the exit status is 1 if there was
any.

Engines (``--engine``): ``atheris`` (coverage-guided libFuzzer, ``pip install atheris``; the default when it is
installed) runs in a child process, since libFuzzer ends the process when its time is up; ``random`` (the
fallback, no dependency) mutates the seeds and the inputs that gave a new outcome: bit flips, byte edits,
insertions of troublesome tokens (quotes, NUL, non-UTF-8 bytes, huge numbers, deep nesting, YAML tags), range
deletions and duplications, splices.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import traceback
import warnings
from pathlib import Path

from livetrack.tools.fuzz_targets import TARGET_NAMES, FuzzTarget, make_target

STATS_FILE = "stats.json"
TOKENS = [b'"', b"'", b"\xff", b"\xc3", b"\x00", b"\r", b"\n", b",", b":", b"- ", b"{", b"}", b"[", b"]",
          b"1e400", b"-1e400", b"Infinity", b"-Infinity", b"NaN", b".nan", b".inf", b"null", b"~", b"true", b"yes",
          b"-1", b"0", b"1.9", b"18446744073709551616", b"9" * 5000, b"[" * 3000, b"{a: " * 300, b"!!binary",
          b"!!python/object:os.system", b"&a [*a, *a]", b"*a", b"..", b"/", b"/dev/zero", b"frames/../..",
          b"\t", b" " * 100, b"0x10", b"1_000", b"2e9", b"1e32", b"\\", b'""', b"\xef\xbb\xbf"]


class _Hang(Exception):
    pass


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m livetrack.tools.fuzz", description=__doc__.split("\n\n")[0])
    parser.add_argument("target", choices=TARGET_NAMES)
    parser.add_argument("--seconds", type=float, default=60.0, help="campaign length (default 60)")
    parser.add_argument("--engine", choices=["auto", "atheris", "random"], default="auto")
    parser.add_argument("--timeout", type=int, default=10, help="seconds one input may take before it is a hang")
    parser.add_argument("--seed", type=int, default=0, help="random engine: RNG seed")
    parser.add_argument("--workdir", type=Path, help="where the corpus, crashes and logs go (default: a new "
                                                     "temporary directory)")
    parser.add_argument("--atheris-worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.seconds <= 0 or args.timeout < 1:
        parser.error("--seconds must be > 0 and --timeout >= 1")
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix=f"livetrack-fuzz-{args.target}-"))
    workdir.mkdir(parents=True, exist_ok=True)
    logging.disable(logging.CRITICAL)  # readers warn about every bad row: millions of lines
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return _campaign(args, workdir)
    finally:
        logging.disable(logging.NOTSET)


def _campaign(args: argparse.Namespace, workdir: Path) -> int:
    if args.atheris_worker:
        return _atheris_worker(args.target, args.seconds, args.timeout, workdir)
    engine = args.engine
    if engine == "auto":
        try:
            import atheris  # noqa: F401
        except ImportError:
            engine = "random"
        else:
            engine = "atheris"
    print(f"fuzz {args.target}: engine {engine}, {args.seconds:g} s, work directory {workdir}", flush=True)
    problem = _seed_problem(args.target)
    if problem:  # e.g. a half-edited default config in the working tree: every input would fail the same way
        print(f"fuzz {args.target}: not fuzzing, its valid seed input is refused: {problem}", file=sys.stderr)
        return 2
    if engine == "atheris":
        stats = _run_atheris(args, workdir)
    else:
        stats = _run_random(args.target, args.seconds, args.timeout, args.seed, workdir)
    rate = stats.get("rate") or stats["inputs"] / max(stats["seconds"], 1e-9)
    print(f"fuzz {args.target}: engine {engine}, {stats['seconds']:.0f} s, inputs tried {stats['inputs']} "
          f"({rate:.0f}/s), crashes: {stats['crashes']}, hangs: {stats['hangs']}"
          + (f", saved in {workdir}" if stats["crashes"] or stats["hangs"] else ""), flush=True)
    return 1 if stats["crashes"] or stats["hangs"] else 0


def _seed_problem(name: str) -> str | None:
    """Why the target refuses its first (valid) seed, or None: a campaign is only meaningful if it is accepted."""
    target, close = make_target(name)
    try:
        target.run(target.seeds()[0])
    except Exception as exc:  # noqa: BLE001 - reported, whatever it is
        return f"{type(exc).__name__}: {exc}"
    finally:
        close()
    return None


# ---------------------------------------------------------------------------------------------- shared
class _Recorder:
    """Runs one input through the target, counts it, and saves crashes."""

    def __init__(self, target: FuzzTarget, workdir: Path) -> None:
        self.target = target
        self.workdir = workdir
        self.inputs = 0
        self.crashes = 0
        self.hangs = 0
        self.started = time.monotonic()
        self._last_flush = 0.0
        self.outcomes: set[str] = set()
        self._signatures: set[str] = set()

    def run(self, data: bytes) -> str:
        """The input's outcome (``ok``, the documented error's first words, or ``CRASH ...``)."""
        self.inputs += 1
        try:
            self.target.run(data)
            outcome = "ok"
        except self.target.errors as exc:
            outcome = type(exc).__name__ + ":" + re.sub(r"[\d'\"].*", "", str(exc).split(": ")[-1])[:40]
        except _Hang:
            self.hangs += 1
            self._save("hang", data, "no result after the timeout\n", "hang")
            outcome = "HANG"
        except Exception as exc:  # noqa: BLE001 - anything else is what the campaign looks for
            self.crashes += 1
            where = traceback.extract_tb(exc.__traceback__)[-1]
            signature = f"{type(exc).__name__} at {where.filename}:{where.lineno}"
            self._save("crash", data, traceback.format_exc(), signature)
            outcome = f"CRASH {signature}"
        now = time.monotonic()
        if now - self._last_flush > 1.0:
            self.flush()
        return outcome

    def _save(self, kind: str, data: bytes, text: str, signature: str) -> None:
        """Keep the first input of each kind of failure (same exception, same place)."""
        if signature in self._signatures:
            return
        self._signatures.add(signature)
        name = f"{kind}-{hashlib.sha1(data).hexdigest()[:16]}"
        (self.workdir / name).write_bytes(data)
        (self.workdir / f"{name}.txt").write_text(text)
        print(f"fuzz {self.target.name}: {kind.upper()} saved as {self.workdir / name}\n{text}", file=sys.stderr,
              flush=True)

    def flush(self) -> dict:
        self._last_flush = time.monotonic()
        stats = {"inputs": self.inputs, "crashes": self.crashes, "hangs": self.hangs,
                 "seconds": self._last_flush - self.started}
        tmp = self.workdir / (STATS_FILE + ".tmp")
        tmp.write_text(json.dumps(stats))
        os.replace(tmp, self.workdir / STATS_FILE)
        return stats


# ---------------------------------------------------------------------------------------------- atheris
def _run_atheris(args: argparse.Namespace, workdir: Path) -> dict:
    command = [sys.executable, "-m", "livetrack.tools.fuzz", args.target, "--atheris-worker", "--seconds",
               str(args.seconds), "--timeout", str(args.timeout), "--workdir", str(workdir)]
    log_file = workdir / "libfuzzer.log"
    started = time.monotonic()
    try:
        with open(log_file, "wb") as log:
            proc = subprocess.run(command, stdout=log, stderr=subprocess.STDOUT, check=False)
    finally:
        shutil.rmtree(workdir / "scratch", ignore_errors=True)  # libFuzzer's exit skips the worker's cleanup
    text = log_file.read_text(errors="replace")
    stats = json.loads((workdir / STATS_FILE).read_text()) if (workdir / STATS_FILE).is_file() else {
        "inputs": 0, "crashes": 0, "hangs": 0}
    stats["crashes"] = max(stats["crashes"], text.count(": CRASH saved as "))  # the last second's too
    stats["hangs"] = max(stats["hangs"], text.count(": HANG saved as "))
    executed = re.findall(r"stat::number_of_executed_units:\s*(\d+)", text)
    if executed:
        stats["inputs"] = max(stats["inputs"], int(executed[-1]))
    if re.search(r"ERROR: libFuzzer: timeout", text):
        stats["hangs"] += 1
    elif proc.returncode != 0 and re.search(r"ERROR: libFuzzer: (deadly signal|out-of-memory|fuzz target)", text):
        stats["crashes"] += 1  # the process itself died: counted once, input saved by libFuzzer
    elif proc.returncode != 0 and not executed:
        print(f"fuzz {args.target}: the atheris worker failed (status {proc.returncode}), see {log_file}",
              file=sys.stderr)
        stats["crashes"] += 1
    stats["seconds"] = time.monotonic() - started
    rate = re.findall(r"stat::average_exec_per_sec:\s*(\d+)", text)
    if rate:
        stats["rate"] = int(rate[-1])
    return stats


def _atheris_worker(name: str, seconds: float, timeout: int, workdir: Path) -> int:
    import atheris

    with atheris.instrument_imports(include=["livetrack", "yaml"]):
        target, close = make_target(name, workdir / "scratch")
        recorder = _Recorder(target, workdir)
        corpus = workdir / "corpus"
        corpus.mkdir(exist_ok=True)
        for seed in target.seeds():  # also imports (and so instruments) the target's modules
            (corpus / f"seed-{hashlib.sha1(seed).hexdigest()[:16]}").write_bytes(seed)
            recorder.run(seed)

    def one_input(data: bytes) -> None:
        recorder.run(data)

    libfuzzer_args = [sys.argv[0], f"-max_total_time={max(1, round(seconds))}", f"-timeout={timeout}",
                      "-rss_limit_mb=2048", "-max_len=16384", f"-artifact_prefix={workdir}/",
                      "-print_final_stats=1", str(corpus)]
    import atexit

    atexit.register(recorder.flush)
    atexit.register(close)
    atheris.Setup(libfuzzer_args, one_input)
    try:
        atheris.Fuzz()
    finally:
        recorder.flush()
        close()
    return 0


# ---------------------------------------------------------------------------------------------- random
def mutate(data: bytes, rng: random.Random, pool: list[bytes]) -> bytes:
    """1 to 8 random edits of ``data`` (see the module docstring); ``pool`` provides splices."""
    buf = bytearray(data)
    for _ in range(rng.randint(1, 8)):
        op = rng.randrange(8)
        pos = rng.randint(0, len(buf))
        if op == 0 and buf:
            i = rng.randrange(len(buf))
            buf[i] ^= 1 << rng.randrange(8)
        elif op == 1 and buf:
            buf[rng.randrange(len(buf))] = rng.randrange(256)
        elif op in (2, 3):
            buf[pos:pos] = rng.choice(TOKENS)
        elif op == 4 and buf:
            end = min(len(buf), pos + rng.randint(1, 64))
            del buf[pos:end]
        elif op == 5 and buf:
            start = rng.randrange(len(buf))
            chunk = buf[start:start + rng.randint(1, 256)]
            buf[pos:pos] = chunk * rng.randint(1, 4)
        elif op == 6:
            other = rng.choice(pool)
            start = rng.randint(0, len(other))
            buf[pos:] = other[start:start + rng.randint(0, 512)]
        elif op == 7:
            digits = str(rng.choice([-1, 0, 1, 2**31, 2**63, 2**64, -(2**63) - 1, 10**30, rng.randint(-999, 999)]))
            buf[pos:pos] = digits.encode()
    return bytes(buf[:65536])


def _run_random(name: str, seconds: float, timeout: int, seed: int, workdir: Path) -> dict:
    target, close = make_target(name)
    recorder = _Recorder(target, workdir)
    rng = random.Random(seed)
    seeds = target.seeds()
    pool = list(seeds)

    def alarm(signum: int, frame: object) -> None:
        raise _Hang()

    previous = signal.signal(signal.SIGALRM, alarm)
    deadline = time.monotonic() + seconds
    try:
        for data in seeds:
            recorder.outcomes.add(recorder.run(data))
        while time.monotonic() < deadline:
            data = mutate(rng.choice(pool), rng, pool)
            signal.setitimer(signal.ITIMER_REAL, timeout)
            try:
                outcome = recorder.run(data)
            finally:
                signal.setitimer(signal.ITIMER_REAL, 0)
            if outcome not in recorder.outcomes:  # a new kind of result: worth mutating further
                recorder.outcomes.add(outcome)
                pool.append(data)
    finally:
        signal.signal(signal.SIGALRM, previous)
        close()
    return recorder.flush()


if __name__ == "__main__":
    sys.exit(main())
