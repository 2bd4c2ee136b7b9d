"""Batch runs on a real Dask ``LocalCluster`` (2 worker processes, shared by the module's tests): the same JSON as
the serial run, a worker killed mid-run survived with no frame lost, a corrupt recording reported while the rest
completes, failed tasks retried then reported with their recording and frame range (livetrack.batch, issue 16)."""

from __future__ import annotations

import json
import os
import shutil
import signal
import threading
import time
from pathlib import Path

import pytest

from livetrack.batch.detect import DetectSettings, detect_recordings, frame_ranges, output_names
from livetrack.batch.executor import DaskExecutor, SerialExecutor, Task, start_local_cluster
from livetrack.batch.synthetic import write_archive
from livetrack.cli import main as cli_main

RANGE_FRAMES = 9  # 2 ranges per recording: 6 tasks of ~0.1-0.3 s
SETTINGS = DetectSettings(timings=False)


@pytest.fixture(scope="module")
def archive(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """3 recordings of 18 frames (160 x 100 px: a few ms per frame)."""
    return write_archive(tmp_path_factory.mktemp("archive"), recordings=3, frames=18, width_px=160, height_px=100,
                         poses=3)


@pytest.fixture(scope="module")
def serial(archive: list[Path]) -> list[str]:
    """The reference: the same frame ranges in this process."""
    return _json(detect_recordings(archive, SETTINGS, SerialExecutor(), RANGE_FRAMES))


@pytest.fixture(scope="module")
def client():
    """One LocalCluster (2 processes, loopback) for the module; closed, its processes gone, at the end."""
    from distributed import Client

    cluster = start_local_cluster(2)
    client = Client(cluster)
    try:
        client.wait_for_workers(2, timeout=60)
        yield client
    finally:
        client.close()
        cluster.close()


def _json(outputs) -> list[str]:
    return [json.dumps(o.to_dict(), indent=1, allow_nan=False) for o in outputs]


def test_the_reference_finds_the_target_in_every_frame(serial: list[str]) -> None:
    for text in serial:
        data = json.loads(text)
        assert data["complete"] and data["frame_count"] == 18 and not data["skipped"]
        assert [f["frame_id"] for f in data["frames"]] == list(range(18))
        assert all(any(t["ok"] for t in f["targets"]) for f in data["frames"])
        assert all("timings_ms" not in f for f in data["frames"])


def test_frame_ranges_and_output_names() -> None:
    assert frame_ranges(13, 5) == [(0, 5), (5, 10), (10, 13)]
    assert frame_ranges(0, 5) == []
    assert output_names(["x/a/run1", "x/b/run2"]) == ["run1.json", "run2.json"]
    assert output_names(["x/a/run1", "x/b/run1", "x/b/run2"]) == ["a_run1.json", "b_run1.json", "b_run2.json"]
    with pytest.raises(ValueError, match="twice"):
        output_names(["x/a", "x/a"])


def test_two_workers_give_the_serial_json(client, archive: list[Path], serial: list[str]) -> None:
    executor = DaskExecutor(client=client)
    assert executor.workers == 2
    assert _json(detect_recordings(archive, SETTINGS, executor, RANGE_FRAMES)) == serial


def test_cli_on_a_scheduler_writes_the_serial_files(client, archive: list[Path], serial: list[str],
                                                    tmp_path: Path) -> None:
    assert cli_main(["detect", *map(str, archive), "--no-timings", "--range-frames", str(RANGE_FRAMES), "--no-progress",
                     "--json-dir", str(tmp_path / "dask"), "--scheduler", client.scheduler.address]) == 0
    names = sorted(p.name for p in (tmp_path / "dask").iterdir())
    assert names == ["rec-000.json", "rec-001.json", "rec-002.json"]
    for name, reference in zip(names, serial, strict=True):
        assert (tmp_path / "dask" / name).read_text() == reference


def test_a_corrupt_recording_is_reported_and_the_rest_completes(client, archive: list[Path], serial: list[str],
                                                                tmp_path: Path, capsys) -> None:
    good = [shutil.copytree(p, tmp_path / p.name) for p in archive]
    broken = tmp_path / "broken"  # recording.yaml that is not YAML: the recording cannot be opened
    shutil.copytree(archive[0], broken)
    (broken / "recording.yaml").write_text("format: [\n")
    torn = tmp_path / "torn"  # one truncated PNG: that frame is skipped and listed
    shutil.copytree(archive[1], torn)
    png = sorted(torn.rglob("*.png"))[4]  # frame 4
    png.write_bytes(png.read_bytes()[:100])
    outputs = detect_recordings([good[0], broken, good[1], torn, good[2]], SETTINGS, DaskExecutor(client=client),
                                RANGE_FRAMES)
    assert not outputs[1].complete and outputs[1].errors[0]["frames"] is None
    assert "not valid YAML" in outputs[1].errors[0]["error"] and not outputs[1].frames
    assert outputs[3].complete and len(outputs[3].frames) == 17
    assert [s["frame_id"] for s in outputs[3].skipped] == [4] and "cannot be decoded" in outputs[3].skipped[0]["reason"]
    for out, reference in zip([outputs[0], outputs[2], outputs[4]], serial, strict=True):
        assert json.loads(_json([out])[0])["frames"] == json.loads(reference)["frames"]
    # the command: the summary names the broken recording, exit status 1, the others written
    code = cli_main(["detect", str(good[0]), str(broken), "--json-dir", str(tmp_path / "out"), "--no-progress",
                     "--scheduler", client.scheduler.address, "--range-frames", str(RANGE_FRAMES)])
    captured = capsys.readouterr()
    assert code == 1 and "FAILED" in captured.out and f"FAILED {broken}" in captured.err
    assert json.loads((tmp_path / "out" / "rec-000.json").read_text())["complete"]


def always_fails(label: str) -> None:
    raise RuntimeError(f"no luck with {label}")


def fails_once(marker: str) -> str:
    """Raises on the first call (``marker`` file missing), succeeds on the next: a transient failure."""
    if not os.path.exists(marker):
        Path(marker).write_text("tried")
        raise OSError("transient")
    return "done"


@pytest.mark.parametrize("where", ["serial", "dask"])
def test_failed_tasks_are_retried_then_reported(where: str, client, tmp_path: Path) -> None:
    executor = SerialExecutor(retries=1) if where == "serial" else DaskExecutor(client=client, retries=1)
    tasks = [Task(fails_once, (str(tmp_path / "marker"),), "flaky"),
             Task(always_fails, ("rec-x frames 0-9",), "rec-x frames 0-9"),
             Task(len, ("abc",), "fine")]
    outcomes = executor.run(tasks)
    assert [o.value for o in outcomes] == ["done", None, 3]
    assert outcomes[1].error == "RuntimeError: no luck with rec-x frames 0-9"
    assert outcomes[1].task.label == "rec-x frames 0-9"


def test_a_worker_killed_mid_run_loses_no_frame(client, archive: list[Path], serial: list[str]) -> None:
    """SIGKILL one worker process while it runs a range: Dask gives the range to another worker (the nanny
    starts a new process); every frame is in the output, the same as serial."""
    pids = client.run(os.getpid)
    victim, victim_pid = sorted(pids.items())[0]
    killed = threading.Event()

    def kill_when_busy() -> None:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            busy = client.processing(workers=[victim]).get(victim, ())
            if busy:
                time.sleep(0.05)
                os.kill(victim_pid, signal.SIGKILL)
                killed.set()
                return
            time.sleep(0.01)

    killer = threading.Thread(target=kill_when_busy, daemon=True)
    killer.start()
    outputs = detect_recordings(archive, SETTINGS, DaskExecutor(client=client), RANGE_FRAMES)
    killer.join(timeout=30)
    assert killed.is_set(), "no task was seen running on the worker to kill"
    assert _json(outputs) == serial
    client.wait_for_workers(2, timeout=60)
    assert victim_pid not in client.run(os.getpid).values()  # the killed process was replaced


SMALL_SWEEP = """\
name: small-sweep
seed: 3
camera: {width: 240, height: 150, fx: 230, fy: 230, cx: 119.5, cy: 74.5, bit_depth: 12}
sensor: {full_well_e: 10000, read_noise_e: 5, black_level_dn: 0}
optics: {psf_sigma_px: 0.8}
scene: {white_reflectance: 0.85, black_reflectance: 0.04, background_reflectance: 0.2}
targets:
  - {id: 3, outer_radius_m: 0.125}
trajectory: {kind: spread, count: 2, distance_m: [0.8, 1.2], tilt_deg: [0, 35], margin_px: 8}
exposure: {nominal_us: auto, white_fraction_of_full_well: 0.55, factors: [0.5, 1, 4], gain_db: 0}
timing: {fps: 30}
"""


def test_exposure_sweep_on_the_cluster_gives_the_serial_report(client, tmp_path: Path) -> None:
    scenario = tmp_path / "small.yaml"
    scenario.write_text(SMALL_SWEEP)
    common = ["evaluate", "exposure-sweep", "--scenario", str(scenario), "--methods", "livetrack,naive-ellipse",
              "--no-crb", "--poses", "5", "--range-poses", "2", "--no-timings", "--no-progress"]
    assert cli_main([*common, "--workers", "0", "--json", str(tmp_path / "serial.json")]) == 0
    assert cli_main([*common, "--scheduler", client.scheduler.address, "--json", str(tmp_path / "dask.json")]) == 0
    serial_report = (tmp_path / "serial.json").read_bytes()
    assert serial_report == (tmp_path / "dask.json").read_bytes()
    report = json.loads(serial_report)
    assert report["poses"] == 5 and sorted({o["step"] for o in report["observations"]}) == [0, 1, 2, 3, 4]
    assert len(report["observations"]) == 5 * 3 * 2 and report["summary"]["livetrack"]["detection_rate"] >= 0.6


def test_detection_scenes_as_tasks_give_the_in_process_result(client) -> None:
    from livetrack.batch.evaluate import run_detection_batch
    from livetrack.evaluation.detection import make_case, run_detection_sweep

    cases = [make_case(f"b{n}", "single", "grey", "1280x800-8bit", [(0.01, 20.0 * n)], (1.0,), seed=n)
             for n in range(2)]
    reference = run_detection_sweep(cases=cases).to_dict()
    batch = run_detection_batch(DaskExecutor(client=client), cases=cases).to_dict()
    for report in (reference, batch):
        report["summary"].pop("seconds")  # measured
    assert batch == reference and len(batch["targets"]) == 2


def test_model_over_many_inputs_reports_each_failure(client, tmp_path: Path, capsys) -> None:
    """The plumbing of ``livetrack model IN... --json-dir`` (a full analysis takes ~20 s: not run here): inputs
    that cannot be analysed are reported one by one, exit status 1."""
    from livetrack.modelcheck.rings_simulate import ring_scenario, write_ring_series
    from livetrack.modelcheck.simulate import HiddenEffect

    two = tmp_path / "two-exposures"
    write_ring_series(two, ring_scenario(HiddenEffect(None, None, None, {}), 3, poses=1, white_fractions=(0.5, 2.0)))
    empty = tmp_path / "empty"
    empty.mkdir()
    code = cli_main(["model", str(two), str(empty), "--json-dir", str(tmp_path / "out"), "--no-progress",
                     "--scheduler", client.scheduler.address])
    out = capsys.readouterr()
    assert code == 1 and "2 inputs, 0 reports, 2 failed" in out.out
    assert "three or more" in out.err and f"FAILED {empty}" in out.err
