"""Format version 3: the file states its measurand in keys a program reads, names every parameter element
one way (zero-based, rows = output axes), gives P12's raw offset a name of its own, and files of versions 1
and 2 still load and say what they lack."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

import calib
from calib import synthetic
from calib.calibration import MAGNITUDES_KEY, MEASURAND, Calibration
from calib.equations import EQUATIONS, INDEXING, parameter_label, parameter_labels
from calib.errors import DataError
from calib.io import calfile
from calib.stats.magnitudes import outside_magnitudes, unit_suspected
from calib.uncertainty.budgeting import budget

READING = {"device": {"name": "mmc0", "type": "mmc5983ma", "model": "MMC5983MA", "serial": None,
                      "product_id": "0x30"},
           "mode": "set_reset_pair", "mode_text": "h = (H_SET - H_RESET) / 2", "raw_unit": "nT",
           "conversion": "H_nT = (code - 131072) / 16384 * 100000 per axis",
           "settings": {"bandwidth_hz": 100}, "samples_averaged": 1}
STATED = {"reading": READING,
          "tau_source": {"device": {"name": "tmp0", "type": "tmp117", "model": "TMP117"},
                         "place": "beside mmc0", "unit": "degC", "lag_corrected_s": None},
          "frame": {"B": {"name": "station", "text": "the coil axes"},
                    "h": {"name": "sensor", "text": "x, y, z"}},
          "reference_chain": {"traceable": False, "text": "the coils' declared constants only"}}


@pytest.fixture(scope="module")
def p12_with_covariance():
    ds, _ = synthetic.p12_dataset(np.random.default_rng(1), samples_per_point=2)
    cal = calib.fit(ds, "p12")
    grid = (np.array([[50_000.0, 0, 0], [0, 50_000.0, 0], [0, 0, 50_000.0]]), None)
    cal.uncertainty = budget(ds, cal, [], grid, rng=np.random.default_rng(0)).as_dict()
    return cal


def _t24():
    ds, _ = synthetic.t24_dataset(np.random.default_rng(2), samples_per_point=2)
    return calib.fit(ds, "t24")


def test_a_version_3_file_round_trips_its_measurand(tmp_path):
    cal = _t24()
    for key, value in STATED.items():
        setattr(cal, key, value)
    for name in ("cal.yaml", "cal.json"):
        calfile.save(cal, tmp_path / name)
        back = calfile.load(tmp_path / name)
        assert back.to_dict() == cal.to_dict() and back.format_version == 3
        assert back.missing_measurand() == []
    doc = yaml.safe_load((tmp_path / "cal.yaml").read_text())
    assert doc["indexing"] == INDEXING and doc["reading"]["mode"] == "set_reset_pair"
    assert list(doc)[list(doc).index("equation") + 2:][:6] == ["solve_centre_c", *MEASURAND]  # beside it
    span = doc["stats"][MAGNITUDES_KEY]
    assert span["h"][0] < span["h"][1] and span["B"] == pytest.approx([50_000.0, 50_000.0])


@pytest.mark.parametrize("version", [1, 2])
def test_older_files_load_and_say_what_they_lack(version, tmp_path):
    cal = _t24()
    old = cal.to_dict()
    for key in (*MEASURAND, "equation", "tau") if version == 1 else MEASURAND:
        old.pop(key)
    old["stats"].pop(MAGNITUDES_KEY)
    old["source"] = {"path": "run.session", "sha256": "ab" * 32, "kind": "session"}
    old["format_version"] = version
    path = tmp_path / "old.yaml"
    path.write_text(yaml.safe_dump(old))
    back = calfile.load(path)
    lacks = back.missing_measurand()
    assert [w for w in lacks if "(" in w][:5] == list(MEASURAND.values())
    assert any(MAGNITUDES_KEY in w for w in lacks) and any("source.sha256" in w for w in lacks)
    assert len(lacks) == 7
    h, t = np.random.default_rng(3).normal(0, 40_000, (5, 3)), np.full(5, 20.0)
    np.testing.assert_array_equal(back.apply(h, t), cal.apply(h, t))


def test_a_p12_file_that_calls_its_raw_offset_b_nt_loads_as_h0_nt(p12_with_covariance, tmp_path):
    """P12's offset is subtracted from h (B = inv(Q P) (h - h0_nt)); T24's b_nt is added to B: no key
    means two things. A version 2 file with P12's b_nt everywhere loads under the new name."""
    cal = p12_with_covariance
    assert EQUATIONS["p12"].startswith("B = inv(Q P) (h - h0_nt)") and "h0_nt" in cal.params
    old = yaml.safe_load(yaml.safe_dump(cal.to_dict(), sort_keys=False).replace("h0_nt", "b_nt"))
    old["format_version"] = 2
    assert "b_nt" in old["params"] and old["uncertainty"]["covariance"]["parameters"][6] == "b_nt[0]"
    path = tmp_path / "old-p12.yaml"
    path.write_text(yaml.safe_dump(old, sort_keys=False))
    back = calfile.load(path)
    assert list(back.params) == ["k", "angles_deg", "h0_nt"] and list(back.std_errors) == list(back.params)
    np.testing.assert_array_equal(back.params["h0_nt"], cal.params["h0_nt"])
    assert back.uncertainty["covariance"]["parameters"] == parameter_labels(cal.params)
    assert list(back.uncertainty["expanded"]) == list(back.params)
    h = np.random.default_rng(4).normal(0, 40_000, (5, 3))
    np.testing.assert_array_equal(back.apply(h), cal.apply(h))


def test_one_naming_of_every_element(p12_with_covariance):
    """The covariance the budget writes, and every export, name elements as parameter_labels does:
    zero-based, row-major, rows the output axes."""
    assert p12_with_covariance.uncertainty["covariance"]["parameters"] == \
        parameter_labels(p12_with_covariance.params)
    labels = parameter_labels({"S": np.zeros((3, 3)), "b_nt": np.zeros(3)})
    assert labels[:4] == ["S[0][0]", "S[0][1]", "S[0][2]", "S[1][0]"] and labels[-1] == "b_nt[2]"
    assert parameter_label("S", (2, 1)) == "S[2][1]" and parameter_label("field_norm") == "field_norm"


def test_a_file_that_misstates_its_measurand_is_refused_naming_the_key(tmp_path):
    cal = _t24()
    for change, expected in (({"reading": {**READING, "mode": "pair"}}, "'reading.mode' is 'pair'"),
                             ({"frame": "station"}, "key 'frame' must be a mapping"),
                             ({"reference_chain": {"text": "x"}}, "'reference_chain.traceable'")):
        path = tmp_path / "bad.yaml"
        path.write_text(yaml.safe_dump({**cal.to_dict(), **change}))
        with pytest.raises(DataError, match=expected):
            calfile.load(path)
    assert Calibration.from_dict({**cal.to_dict(), "reading": None}).reading is None  # null: not stated


def test_magnitude_guards():
    span = [48_000.0, 52_000.0]
    h = np.array([[50_000.0, 0, 0], [0, 43_000.0, 0], [0, 0, 58_000.0], [0, 0, 150_000.0]])
    assert outside_magnitudes(span, h).tolist() == [False, True, True, True]
    assert unit_suspected(span, h) is None
    assert "gauss given as nT" in unit_suspected(span, h / 1e5)  # 0.5 gauss read as 0.5 nT
    assert "uT given as nT" in unit_suspected(span, h / 1e3)
    assert "counts" in unit_suspected(span, h * 1e3)
