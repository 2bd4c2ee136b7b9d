"""``livetrack model`` on the real exposure-series-disks folder (skipped if the real data is absent)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from livetrack.modelcheck.fitting import ModelCheck
from livetrack.modelcheck.series import from_exposure_series_disks
from tests.realdata import realdata_dir

FOLDER = realdata_dir() / "exposure-series-disks" if realdata_dir() is not None else None
pytestmark = pytest.mark.skipif(FOLDER is None or not FOLDER.is_dir(),
                                reason="real data absent (set LIVETRACK_REALDATA)")


@pytest.mark.parametrize("filter_nm, channels", [("500nm", ["G1", "G2"]), ("550nm", ["G1", "G2"]),
                                                 ("600nm", ["R"])])
def test_adapter_reads_the_folder(filter_nm, channels):
    series = from_exposure_series_disks(FOLDER, filter_nm)
    assert [g.label for g in series.grids] == channels
    assert series.exposure_ms.tolist() == [25, 50, 100, 250, 500, 2000, 3916]
    mc = ModelCheck(series)
    # 8 mm pitch at about 32 cm through an 8 mm lens with 3.45 um pixels: about 58 px (measured ~65 px).
    assert 50 < mc.layout.pitch_px < 80
    assert mc.layout.interior.sum() >= 20


@pytest.mark.slow
@pytest.mark.parametrize("filter_nm", ["500nm", "550nm", "600nm"])
def test_command_on_real_data(filter_nm, tmp_path):
    from livetrack.commands.model import main

    out = tmp_path / "report.json"
    assert main([str(FOLDER), "--filter", filter_nm, "--json", str(out), "--plots", str(tmp_path / "plots")]) == 0
    data = json.loads(out.read_text())
    # Frames whose disks clip entirely have no radius (null); the others shrink as the exposure grows.
    radii = np.asarray([r for r in data["bias_curve"]["threshold_radius_px_measured"] if r is not None])
    assert radii.size >= 5
    assert radii[-1] < radii[0] - 0.5
    assert np.all(np.diff(radii) < 0.05)
    assert data["heldout"]["chosen_heldout_rms"] < data["heldout"]["baseline"]
    assert data["compensation"]["spread_extended_px"] < data["compensation"]["spread_raw_px"]
    assert (tmp_path / "plots" / "bias_curve.png").is_file()


def test_any_filter_in_the_folder_is_accepted_and_a_wrong_one_lists_them(capsys):
    from livetrack.commands.model import main
    from livetrack.modelcheck.series import available_filters

    assert available_filters(FOLDER) == ["500nm", "550nm", "600nm"]
    assert main([str(FOLDER), "--filter", "700nm"]) == 2
    assert "filters there: 500nm, 550nm, 600nm" in capsys.readouterr().err
