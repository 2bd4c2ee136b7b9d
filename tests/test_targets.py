"""Target specs, the code book and decoding."""

from pathlib import Path

import numpy as np
import pytest

from livetrack.config.checks import ConfigError
from livetrack.targets import codebook
from livetrack.targets.spec import TargetSpec, load_targets
from tests.realdata import realdata_dir


def test_code_book_is_rotationally_distinct_and_separated():
    book = codebook.code_book()
    assert len(book) >= 12
    for i, a in enumerate(book):
        assert not codebook.is_symmetric(a)
        assert codebook.self_distance(a) >= 2  # heading unambiguous even with one wrong slot
        for b in book[i + 1:]:
            assert codebook.rotation_distance(a, b) >= 2


@pytest.mark.parametrize("target_id", range(14))
@pytest.mark.parametrize("rotation", [0, 3, 7])
def test_decode_recovers_id_and_rotation_with_noise(target_id, rotation):
    rng = np.random.default_rng(target_id * 10 + rotation)
    bits = codebook.bits_for_id(target_id)
    measured = np.array([float(b) for b in codebook.rotate(bits, rotation)]) + rng.normal(0, 0.05, 8)
    got = codebook.decode(np.clip(measured, 0, 1), list(codebook.code_book()))
    assert got.index == target_id
    assert got.rotation_slots == rotation
    assert got.heading_known


def test_symmetric_code_decodes_without_heading():
    candidates = ["11111111", "01001111"]
    got = codebook.decode(np.ones(8), candidates)
    assert got.index == 0 and got.rotation_slots is None and not got.heading_known
    assert not codebook.decode(np.full(8, 0.5), candidates)  # ambiguous: no match, falsy


def test_default_design_and_dark_area():
    spec = TargetSpec.default(3, 0.125)
    assert spec.inner_radius_m == pytest.approx(0.05)
    assert spec.code.ring_radius_m == pytest.approx(0.0875)
    assert spec.code.dot_radius_m == pytest.approx(0.0125)
    assert spec.child.outer_radius_m == pytest.approx(0.025)
    # dark area by Monte-Carlo integration of the reflectance function
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.125, 0.125, (400_000, 2))
    dark = 1.0 - spec.reflectance(xy[:, 0], xy[:, 1])
    assert dark.mean() * 0.25**2 == pytest.approx(spec.dark_area_m2(), rel=0.01)


def test_slot_positions_follow_the_convention():
    spec = TargetSpec.from_dict({"id": 0, "outer_radius_m": 1.0, "inner_radius_m": 0.4,
                                 "code": {"slots": 8, "ring_radius_m": 0.7, "dot_radius_m": 0.1, "bits": "01000000"}})
    # slot 1 sits at 45 degrees from +x toward +y (y down): (0.495, 0.495)
    x, y = 0.7 * np.cos(np.pi / 4), 0.7 * np.sin(np.pi / 4)
    assert spec.reflectance(np.array([x]), np.array([y]))[0] == 1.0
    assert spec.reflectance(np.array([x]), np.array([-y]))[0] == 0.0


def test_spec_errors_name_the_key():
    with pytest.raises(ConfigError, match=r"target\.inner_radius_m: must be < 0\.1"):
        TargetSpec.from_dict({"id": 1, "outer_radius_m": 0.1, "inner_radius_m": 0.2})
    with pytest.raises(ConfigError, match=r"target\.code\.bits"):
        TargetSpec.from_dict({"id": 1, "outer_radius_m": 0.1, "inner_radius_m": 0.04,
                              "code": {"slots": 8, "ring_radius_m": 0.07, "dot_radius_m": 0.01, "bits": "0101"}})
    with pytest.raises(ConfigError, match=r"target\.id: id 99 is not in the 8-slot code book"):
        TargetSpec.from_dict({"id": 99, "outer_radius_m": 0.1})
    with pytest.raises(ConfigError, match=r"target\.colour: unknown key"):
        TargetSpec.from_dict({"id": 1, "outer_radius_m": 0.1, "colour": "red"})


def test_round_trip_and_real_data_targets():
    spec = TargetSpec.default(5, 0.2)
    assert TargetSpec.from_dict(spec.to_dict()) == spec
    folder = realdata_dir()
    if folder is None:
        pytest.skip("../shared/realdata not present (set LIVETRACK_REALDATA)")
    specs = load_targets(Path(folder) / "target-photos" / "targets.yaml")
    assert [s.id for s in specs] == [1, 8, 19, 33]
    assert specs[0].code.symmetric  # "11111111" gives no heading: reported, not an error
    assert not any(s.code.symmetric for s in specs[1:])
