"""``livetrack evaluate single-searches``: one search per over-exposed frame, with and without a white sheet."""

from __future__ import annotations

import json
import math

from livetrack import cli
from livetrack.evaluation import single_searches


def test_each_frame_is_searched_alone_and_summarised_by_sheet_and_exposure():
    rows = single_searches.run(grounds=("grey",), seeds=1, sheets=("none", "2.8"), exposures=(8.0,))
    assert len(rows) == 2 * len(single_searches.SIZES)
    assert {r.sheet for r in rows} == {"none", "2.8"} and {r.exposure_factor for r in rows} == {8.0}
    assert all(r.distance_error_pct is not None and abs(r.distance_error_pct) < 1.0 for r in rows)
    summary = single_searches.summary(rows)
    assert [(s["sheet"], s["exposure_factor"]) for s in summary] == [("2.8", 8.0), ("none", 8.0)]
    for s in summary:
        errors = [abs(r.distance_error_pct) for r in rows if r.sheet == s["sheet"]]
        assert s["frames"] == s["found"] == len(errors)
        assert math.isclose(s["mean_abs_error_pct"], sum(errors) / len(errors))


def test_the_command_refuses_no_seeds_and_writes_its_report(tmp_path, monkeypatch, capsys):
    assert cli.main(["evaluate", "single-searches", "--seed", "0", "--json", str(tmp_path / "r.json")]) == 2
    assert "--seed" in capsys.readouterr().err
    rows = single_searches.run(grounds=("grey",), seeds=1, sheets=("none",), exposures=(16.0,))
    monkeypatch.setattr(single_searches, "run", lambda seeds, progress: rows)
    assert cli.main(["evaluate", "single-searches", "--seed", "1", "--json", str(tmp_path / "r.json")]) == 0
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["experiment"] == "single-searches" and len(report["frames"]) == len(rows)
    assert "none   x16" in capsys.readouterr().out
