"""Where batch tasks run: in this process (``workers=0``), on a local Dask cluster started here (``workers=N``,
the default), or on an existing Dask cluster (``scheduler="tcp://HOST:8786"``).

A ``Task`` is a module-level function and plain arguments (paths as text, frame ranges, option dicts): the
function is sent by reference, the workers read the frames themselves, and the value a task returns is plain data
(dicts, lists, numbers, text). No frame or other user data is pickled on the way out. Dask does the scheduling:
a task that raises is retried (``retries``), a task whose worker dies is given to another worker (Dask's own
rescheduling, up to ``distributed.scheduler.allowed-failures`` worker deaths per task); after that the task is
reported as an ``Outcome`` with its label (recording and frame range) and the error, and the others go on.

Results come back in task order whatever the number of workers or the order in which they finish, so a run's
output does not depend on the executor.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
import traceback
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from livetrack.config.checks import ConfigError

log = logging.getLogger(__name__)

DEFAULT_RETRIES = 2
"""Times a task that raised is run again before it is reported as failed (Dask's ``retries=``)."""
LOCAL_HOST = "127.0.0.1"
"""The local cluster's scheduler and workers listen on the loopback address only (no dashboard)."""


@dataclass(frozen=True)
class Task:
    """One unit of work: ``fn(*args)`` somewhere. ``fn`` must be importable (module level); ``args`` plain data.

    ``label`` names the work in reports (e.g. ``"archive/flight-07 frames 0-499"``); ``weight`` is what it counts
    for on the progress bar (frames, poses)."""

    fn: Callable[..., Any]
    args: tuple[Any, ...]
    label: str
    weight: int = 1


@dataclass(frozen=True)
class Outcome:
    """What became of a task: its ``value`` or, after the retries, its ``error`` (one line: type and message)."""

    task: Task
    value: Any = None
    error: str | None = None
    seconds: float = 0.0  # wall time from submission to completion, as seen by this process

    @property
    def ok(self) -> bool:
        return self.error is None


class Executor:
    """Runs tasks and returns their outcomes in task order. ``description``: the executor in one line."""

    description = ""
    workers = 0

    def run(self, tasks: Sequence[Task], progress: str | None = None) -> list[Outcome]:
        raise NotImplementedError

    def close(self) -> None:
        pass


class SerialExecutor(Executor):
    """Every task in this process, one after the other, in order: the reference run (``--workers 0``)."""

    def __init__(self, retries: int = DEFAULT_RETRIES):
        self.retries = retries
        self.description = "serial (this process)"

    def run(self, tasks: Sequence[Task], progress: str | None = None) -> list[Outcome]:
        out = []
        with _progress_bar(tasks, progress) as bar:
            for task in tasks:
                t0 = time.perf_counter()
                error = None
                for attempt in range(self.retries + 1):
                    try:
                        value = task.fn(*task.args)
                        error = None
                        break
                    except Exception as exc:  # reported as a value, like a failed Dask task
                        value, error = None, _error_text(exc)
                        log.debug("%s: attempt %d failed: %s", task.label, attempt + 1, traceback.format_exc())
                out.append(Outcome(task, value, error, time.perf_counter() - t0))
                bar.update(task.weight)
        return out


class DaskExecutor(Executor):
    """Tasks on a Dask distributed cluster: a ``LocalCluster`` of ``workers`` processes started here (one thread
    each, loopback only, no dashboard), the cluster at ``scheduler``, or the one behind an existing ``client``."""

    def __init__(self, workers: int | None = None, scheduler: str | None = None, client: Any = None,
                 retries: int = DEFAULT_RETRIES):
        from distributed import Client

        self.retries = retries
        self._cluster = None
        self._own_client = client is None
        if client is not None:
            self.client = client
        elif scheduler is not None:
            self.client = Client(scheduler)
        else:
            self._cluster = start_local_cluster(workers if workers else default_workers())
            self.client = Client(self._cluster)
        self.workers = len(self.client.scheduler_info(n_workers=-1)["workers"])
        self.check_code()
        where = "local cluster" if self._cluster is not None else f"cluster at {self.client.scheduler.address}"
        self.description = f"dask, {where}, {self.workers} workers"

    def check_code(self) -> bool:
        """Whether every worker runs the livetrack code of this process (``code_fingerprint``); a warning names
        those that do not (another install or version on a cluster, or files edited since they started)."""
        here = code_fingerprint()
        other = {w: f for w, f in self.client.run(code_fingerprint).items() if f != here}
        if other:
            log.warning("%d of %d workers run other livetrack code than this process (their results may differ "
                        "from a serial run): %s", len(other), self.workers, ", ".join(sorted(other)))
        return not other

    def run(self, tasks: Sequence[Task], progress: str | None = None) -> list[Outcome]:
        from distributed import as_completed

        run_id = uuid.uuid4().hex[:8]
        t0 = time.perf_counter()
        futures = [self.client.submit(task.fn, *task.args, key=f"livetrack-{run_id}-{n}", retries=self.retries,
                                      pure=False) for n, task in enumerate(tasks)]
        index = {f.key: n for n, f in enumerate(futures)}
        outcomes: list[Outcome | None] = [None] * len(tasks)
        with _progress_bar(tasks, progress) as bar:
            for future in as_completed(futures):
                n = index[future.key]
                task = tasks[n]
                seconds = time.perf_counter() - t0
                if future.status == "finished":
                    outcomes[n] = Outcome(task, future.result(), None, seconds)
                else:
                    try:
                        exc = future.exception()
                        error = _error_text(exc) if exc is not None else f"task {future.status}"
                    except Exception as exc:  # cancelled, or the scheduler lost it
                        error = _error_text(exc)
                    outcomes[n] = Outcome(task, None, error, seconds)
                future.release()
                bar.update(task.weight)
        return [o for o in outcomes if o is not None]

    def close(self) -> None:
        if self._own_client:
            self.client.close()
        if self._cluster is not None:
            self._cluster.close()


def start_local_cluster(workers: int) -> Any:
    """A Dask ``LocalCluster`` of ``workers`` processes (one thread each; started by spawn, as Dask does), its
    scheduler and workers on the loopback address only. No dashboard; the scheduler's small HTTP server (health,
    metrics), which Dask starts anyway, goes to a free loopback port, not to 8787 (which another cluster may hold:
    Dask then warns that the port is in use). Close it with ``.close()``."""
    from distributed import LocalCluster

    _quiet_distributed_logs()
    return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host=LOCAL_HOST,
                        dashboard_address=None, silence_logs=logging.ERROR,
                        scheduler_kwargs={"dashboard_address": f"{LOCAL_HOST}:0"})


def code_fingerprint() -> str:
    """Task: a hash of the livetrack package's Python sources as this process sees them on disk."""
    import hashlib

    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha1()
    for file in sorted(root.rglob("*.py")):
        digest.update(str(file.relative_to(root)).encode())
        digest.update(file.read_bytes())
    return digest.hexdigest()[:12]


def default_workers() -> int:
    """Local worker processes by default: one per core."""
    return max(1, os.cpu_count() or 1)


def check_executor_args(workers: int | None, scheduler: str | None) -> None:
    """``--workers`` and ``--scheduler`` checked at the command line (``ConfigError`` naming the option)."""
    if workers is not None and workers < 0:
        raise ConfigError("--workers", f"must be >= 0 (0: in this process), got {workers}")
    if scheduler is not None:
        if workers is not None:
            raise ConfigError("--scheduler", "give either --workers (a local cluster) or --scheduler, not both")
        if "://" not in scheduler:
            raise ConfigError("--scheduler", f"expected an address like tcp://HOST:8786, got {scheduler!r}")


@contextlib.contextmanager
def make_executor(workers: int | None = None, scheduler: str | None = None, retries: int = DEFAULT_RETRIES,
                  default_workers_n: int | None = None) -> Iterator[Executor]:
    """The executor for ``--workers N`` (0: this process; None: ``default_workers_n``, or one per core) or
    ``--scheduler ADDRESS``; closed (its local cluster stopped) on exit."""
    check_executor_args(workers, scheduler)
    if workers is None and scheduler is None:
        workers = default_workers_n if default_workers_n is not None else default_workers()
    executor: Executor = (SerialExecutor(retries) if scheduler is None and workers == 0
                          else DaskExecutor(workers=workers, scheduler=scheduler, retries=retries))
    try:
        yield executor
    finally:
        executor.close()


def add_executor_arguments(parser: Any, default_hint: str = "one per core") -> None:
    """``--workers``, ``--scheduler``, ``--retries`` and ``--no-progress`` for a command that runs batches."""
    parser.add_argument("--workers", type=int, default=None, metavar="N",
                        help=f"local worker processes (a Dask LocalCluster started here, loopback only; default "
                             f"{default_hint}); 0 runs every task in this process, the reference serial run")
    parser.add_argument("--scheduler", default=None, metavar="tcp://HOST:8786",
                        help="run on an existing Dask cluster (dask scheduler + dask worker; docs/batch.md); the "
                             "workers must see the same paths")
    parser.add_argument("--retries", type=int, default=DEFAULT_RETRIES, metavar="N",
                        help=f"runs again a task that failed, N times, before reporting it (default "
                             f"{DEFAULT_RETRIES})")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")


def _quiet_distributed_logs() -> None:
    """Dask's own INFO lines (scheduler and nanny start and stop) would drown livetrack's; warnings stay."""
    for name in ("distributed", "distributed.scheduler", "distributed.nanny", "distributed.core",
                 "distributed.http.proxy"):
        logger = logging.getLogger(name)
        if logger.getEffectiveLevel() < logging.WARNING:
            logger.setLevel(logging.WARNING)


def _error_text(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}".rstrip(": ")


@contextlib.contextmanager
def _progress_bar(tasks: Sequence[Task], description: str | None) -> Iterator[Any]:
    """A tqdm bar on stderr counting task weights (frames, poses), or a stand-in when ``description`` is None."""
    if description is None:
        yield _NoBar()
        return
    from tqdm import tqdm

    with tqdm(total=sum(t.weight for t in tasks), desc=description, unit="", dynamic_ncols=True,
              smoothing=0.1) as bar:
        yield bar


class _NoBar:
    def update(self, n: int) -> None:
        pass
