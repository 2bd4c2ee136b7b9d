"""The fuzz campaign command itself (``python -m livetrack.tools.fuzz``): a short seeded run of the fallback
engine on each target finds nothing, and an exception other than the documented one is counted and saved."""

from __future__ import annotations

import pytest

from livetrack.tools import fuzz, fuzz_targets


@pytest.mark.parametrize("target", fuzz_targets.TARGET_NAMES)
def test_short_random_campaign_finds_no_crash(tmp_path, capsys, target):
    assert fuzz.main([target, "--seconds", "1", "--engine", "random", "--seed", "1", "--workdir",
                      str(tmp_path)]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert f"fuzz {target}: engine random" in line and "crashes: 0, hangs: 0" in line
    assert int(line.split("inputs tried ")[1].split()[0]) > 0


def test_a_crash_is_counted_and_its_input_saved(tmp_path, capsys, monkeypatch):
    real_make_target = fuzz_targets.make_target

    def fragile(name):
        target, close = real_make_target(name)

        def run(data: bytes):
            if b"\xff" in data:
                raise KeyError("not the documented error")
            return target.run(data)
        return fuzz_targets.FuzzTarget(name, run, target.errors, target.seeds), close

    monkeypatch.setattr(fuzz, "make_target", fragile)
    assert fuzz.main(["pose-message", "--seconds", "1", "--engine", "random", "--workdir", str(tmp_path)]) == 1
    out = capsys.readouterr()
    crashes = int(out.out.split("crashes: ")[1].split(",")[0])
    assert crashes > 0
    saved = [p for p in tmp_path.glob("crash-*") if p.suffix != ".txt"]
    assert len(saved) == 1 and b"\xff" in saved[0].read_bytes()  # one per kind of failure
    assert "KeyError" in saved[0].with_suffix(".txt").read_text()
