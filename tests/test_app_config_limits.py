"""Config loading under hostile input (issue 12, findings 7 and 8): bytes that are not UTF-8, absurd values and
source options are refused at load, naming the file and key, the same way by ``dump-config`` and ``run``."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from livetrack import cli
from livetrack.config.app import load_config
from livetrack.config.checks import ConfigError


def write(path: Path, text: str | bytes) -> Path:
    if isinstance(text, str):
        text = text.encode()
    path.write_bytes(text)
    return path


def test_issue12_finding7_a_config_that_is_not_utf8_is_a_clear_error(tmp_path, capsys):
    file = write(tmp_path / "c.yaml", b"# r\xe9glages\ntracker: {tracking: true}\n")
    with pytest.raises(ConfigError, match=r"c.yaml: not UTF-8 text: byte 0xe9 at offset 3 \(line 1\)"):
        load_config(file)
    for command in ("dump-config", "run"):
        assert cli.main([command, "--config", str(file)]) == 2
        err = capsys.readouterr().err
        assert "not UTF-8 text" in err and "Traceback" not in err and str(file) in err


@pytest.mark.parametrize("text, problem", [
    ("tracker: {tracking: " + "[" * 5000 + "]" * 5000 + "}", "nested"),
    ("meta: 2024-13-45\n", "not valid YAML"),  # PyYAML's date constructor raises ValueError
    ("tracker: !!python/object:os.system {}\n", "not valid YAML"),
    ("tracker: {edge_spacing_px: 1" + "0" * 400 + "}\n", "must be finite"),  # float(int) overflows
    ("tracker: {noise_model: [1" + "0" * 400 + ", 1]}\n", "finite number"),
    ("tracker: {edge_spacing_px: 1" + "0" * 5000 + "}\n", "not valid YAML"),  # beyond int's 4300 digits
    ("\x00", "not valid YAML"),
])
def test_issue12_findings7_8_hostile_yaml_is_a_config_error(tmp_path, text, problem):
    with pytest.raises(ConfigError, match=problem):
        load_config(write(tmp_path / "c.yaml", text))


@pytest.mark.parametrize("data, path, problem", [
    ({"pipeline": {"sink_queue_size": 10**32}}, "pipeline.sink_queue_size", "<= 100000"),
    ({"pipeline": {"sink_queue_size": 1e32}}, "pipeline.sink_queue_size", "must be an integer"),
    ({"tracker": {"max_points_per_circle": 10**12}}, "tracker.max_points_per_circle", "<= 20000"),
    ({"pipeline": {"slot_size": 10**9}}, "pipeline.slot_size", "<= 100000"),
    ({"pipeline": {"max_frames": 10**13}}, "pipeline.max_frames", "<= 1000000000000"),
    ({"pipeline": {"sink_close_timeout_s": 1e9}}, "pipeline.sink_close_timeout_s", "<= 86400"),
    ({"tracker": {"edge_spacing_px": 1e6}}, "tracker.edge_spacing_px", "<= 100"),
    ({"tracker": {"tracking_margin": 1e300}}, "tracker.tracking_margin", "<= 100"),
    ({"tracker": {"tracking_verify_every": 10**10}}, "tracker.tracking_verify_every", "<= 1000000"),
    ({"tracker": {"clip_margin_dn": 1e9}}, "tracker.clip_margin_dn", "<= 65535"),
    ({"tracker": {"noise_model": [1e30, 1.0]}}, "tracker.noise_model", "read variance"),
    ({"tracker": {"psf_halo": [0.1, 1e30]}}, "tracker.psf_halo", "sigma_px"),
    ({"tracker": {"edge_bias_floor_px": -0.01}}, "tracker.edge_bias_floor_px", ">= 0"),
    ({"tracker": {"edge_bias_floor_px": 1e6}}, "tracker.edge_bias_floor_px", "<= 100"),
    ({"tracker": {"outer_share_sd": -0.1}}, "tracker.outer_share_sd", ">= 0"),
    ({"tracker": {"outer_share_sd": 1e3}}, "tracker.outer_share_sd", "<= 10"),
    ({"outputs": {"udp": {"queue_size": 10**8}}}, "outputs.udp.queue_size", "<= 100000"),
    ({"outputs": {"zmq": {"sndhwm": 10**12}}}, "outputs.zmq.sndhwm", "<= 10000000"),
    ({"outputs": {"record": {"queue_size": 0}}}, "outputs.record.queue_size", ">= 1"),
    ({"outputs": {"record": {"fsync_every_n_frames": 10**9}}}, "outputs.record.fsync_every_n_frames", "<="),
    ({"outputs": {"rerun": {"server_memory_limit": "lots"}}}, "outputs.rerun.server_memory_limit", "1GiB"),
    ({"outputs": {"rerun": {"serve_bind": ""}}}, "outputs.rerun.serve_bind", "interface"),
    ({"outputs": {"rerun": {"image_every_n": 10**9}}}, "outputs.rerun.image_every_n", "<="),
    ({"logging": {"print_every_s": 1e12}}, "logging.print_every_s", "<= 86400"),
    ({"source": {"uri": "bogus:"}}, "source.uri", "unknown scheme"),
    ({"source": {"uri": "sim:", "options": {"bogus": 1}}}, "source.options.bogus", "unknown key"),
    ({"source": {"uri": "sim:", "options": {"seed": "x"}}}, "source.options.seed", "integer"),
    ({"source": {"uri": "sim:no-such-scenario.yaml"}}, "source.uri", "no such scenario"),
    ({"source": {"uri": "replay:somewhere", "options": {"pace": "warp"}}}, "source.options.pace", "one of"),
    ({"source": {"uri": "replay:"}}, "source.uri", "needs a directory"),
])
def test_issue12_finding8_every_value_has_a_sane_range(tmp_path, capsys, data, path, problem):
    file = write(tmp_path / "bad.yaml", yaml.safe_dump(data))
    with pytest.raises(ConfigError) as info:
        load_config(file)
    assert str(info.value).startswith(f"{file}: {path}: "), str(info.value)
    assert problem in info.value.problem
    assert cli.main(["dump-config", "--config", str(file)]) == 2  # dump-config and run agree
    dump_err = capsys.readouterr().err
    assert f"{path}: " in dump_err
    if path.startswith("source"):
        assert cli.main(["run", "--config", str(file), "--max-frames", "1"]) == 2
        assert f"{path}: " in capsys.readouterr().err


def test_issue12_finding8_sane_values_at_the_limits_are_accepted(tmp_path):
    data = {"pipeline": {"sink_queue_size": 100_000, "max_frames": 10**12, "slot_size": 1},
            "tracker": {"max_points_per_circle": 20_000, "edge_spacing_px": 0.5, "edge_bias_floor_px": 0.02},
            "outputs": {"rerun": {"server_memory_limit": "25%"}, "zmq": {"sndhwm": 10_000_000}},
            "source": {"uri": "sim:", "options": {"seed": 4, "realtime": False}}}
    config = load_config(write(tmp_path / "ok.yaml", yaml.safe_dump(data)))
    assert config.pipeline.sink_queue_size == 100_000 and config.tracker.max_points_per_circle == 20_000
    assert config.tracker.edge_bias_floor_px == 0.02
    assert config.source.options == {"seed": 4, "realtime": False}


@pytest.mark.skipif(not Path("/dev/zero").exists(), reason="needs /dev/zero")
def test_a_file_key_naming_an_endless_device_is_refused_not_read_forever(tmp_path):
    with pytest.raises(ConfigError, match="larger than 16 MiB"):
        load_config(write(tmp_path / "c.yaml", "camera: {file: /dev/zero}\n"))


def test_issue12_finding12_cli_users_are_told_the_flag_not_the_python_argument(tmp_path, capsys):
    out = tmp_path / "existing"
    out.mkdir()
    (out / "recording.yaml").write_text("format: livetrack-recording\n")
    assert cli.main(["sim", "--out", str(out), "--max-frames", "1"]) == 2
    err = capsys.readouterr().err
    assert "--overwrite" in err and "overwrite=True" not in err
    assert (out / "recording.yaml").read_text() == "format: livetrack-recording\n"  # untouched


def test_deep_flow_nesting_is_refused_while_scanning_not_after_minutes(tmp_path):
    # found by the random fuzz campaign: PyYAML's scanner is quadratic in flow depth (3000 '[' took > 5 s)
    for text in ("tracker: " + "[" * 100_000, "meta: {a: " + "{a: " * 50_000):
        with pytest.raises(ConfigError, match="nested more than 100 levels deep"):
            load_config(write(tmp_path / "c.yaml", text))
    assert load_config(write(tmp_path / "ok.yaml", "tracker: {psf_halo: [0.1, 4.0]}\n")).tracker.psf_halo == (0.1, 4.0)


def test_alias_bombs_and_recursive_aliases_are_refused(tmp_path):
    levels = ["&l0 [1,1,1,1,1,1,1,1,1,1]"] + [f"&l{i} [" + ",".join([f"*l{i - 1}"] * 10) + "]" for i in range(1, 9)]
    bomb = "tracker: {edge_spacing_px: [" + ", ".join(levels) + "]}\n"  # 432 bytes, 10**9 values once expanded
    with pytest.raises(ConfigError, match="aliases expand to more than 1000000 nodes"):
        load_config(write(tmp_path / "bomb.yaml", bomb))
    with pytest.raises(ConfigError, match="an alias inside its own anchor"):
        load_config(write(tmp_path / "cycle.yaml", "targets: [&t {id: 3, outer_radius_m: 0.1, child: *t}]\n"))
    shared = "targets: [{id: 3, outer_radius_m: &r 0.1}, {id: 4, outer_radius_m: *r}]\n"
    assert [t.id for t in load_config(write(tmp_path / "ok.yaml", shared)).targets] == [3, 4]  # plain aliases


def test_a_source_uri_the_file_system_refuses_is_a_config_error(tmp_path):
    # found by the random fuzz campaign: sim:NAME with a 300-character name raised OSError (ENAMETOOLONG)
    with pytest.raises(ConfigError, match=r"source\.uri: cannot use 'sim:x{70}"):
        load_config(write(tmp_path / "c.yaml", 'source: {uri: "sim:' + "x" * 300 + '"}\n'))
