"""``livetrack model`` over many inputs (``livetrack model SWEEPS/* --json-dir OUT/``): one task per recording.

Each task reads its input itself (a recording path as text), runs the same analysis as ``livetrack model INPUT``
and returns the report's JSON and its summary text; an input that cannot be analysed (too few exposures, not a
recording) comes back as its error. Each analysis is independent, so the reports are those of one-by-one runs
whatever the executor (only their measured ``seconds`` differ).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from livetrack.batch.executor import Executor, Task
from livetrack.config.checks import ConfigError


def model_input(path: str, filter_nm: str | None) -> dict[str, Any]:
    """Task: the model report of one input: ``{"report": ..., "summary": text}`` or ``{"error": text}``."""
    from livetrack.commands.model import load_series
    from livetrack.modelcheck.rings_input import is_ring_recording

    folder = Path(path)
    try:
        if is_ring_recording(folder):
            from livetrack.modelcheck.rings import analyse_rings
            from livetrack.modelcheck.rings_input import ring_series_from_recording

            report = analyse_rings(ring_series_from_recording(folder))
        else:
            from livetrack.modelcheck.analysis import analyse

            report = analyse(load_series(folder, filter_nm))
    except (ValueError, ConfigError) as exc:
        return {"error": str(exc)}
    return {"report": report.to_json(), "summary": report.summary()}


def model_inputs(paths: Sequence[str | Path], executor: Executor, filter_nm: str | None = None,
                 progress: bool = False) -> list[dict[str, Any]]:
    """Every input's ``{"input": path, "report"/"summary" or "error"}``, in order; a task that failed after its
    retries gives its error too."""
    tasks = [Task(model_input, (str(p), filter_nm), f"model {p}") for p in paths]
    out = []
    for outcome in executor.run(tasks, progress="inputs" if progress else None):
        value = outcome.value if outcome.ok else {"error": outcome.error}
        out.append({"input": outcome.task.args[0], **value})
    return out
