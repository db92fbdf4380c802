"""A calibration file states its equation and temperature convention in keys a program reads: a small
script that knows only numpy, yaml and those keys gives the field `rig apply` gives. Old files (a
top-level `temp_ref_c`) still load; a file whose stated equation is not its model's is refused."""

from __future__ import annotations

import csv
import re

import numpy as np
import pytest
import yaml

import calib
from calib import synthetic
from calib.calibration import Calibration
from calib.errors import DataError
from calib.io import calfile, csvio
from rig.cli import main

# The equations as a reader of the file finds them: literal text, not our constants.
T24_EQUATION = "B = (S + tau K) h + b_nt + tau kb_nt_per_c"
SCALAR_T_EQUATION = "B = (A + (tau - tau_0_c) KA_per_c) (h - c_nt - (tau - tau_0_c) kc_nt_per_c)"


def independent_field(path, h: np.ndarray, temp_c: np.ndarray) -> np.ndarray:
    """What someone with the file and no magrig computes: reads `equation`, `tau` and the parameters."""
    doc = yaml.safe_load(open(path))
    assert doc["tau"] == "absolute_c"  # tau is the temperature as measured, nothing subtracted
    p = {k: np.array(v, float) for k, v in doc["params"].items()}
    tau = temp_c[:, None]
    if doc["equation"] == T24_EQUATION:
        matrix = p["S"] + tau[:, :, None] * p["K"]
        return np.einsum("nij,nj->ni", matrix, h) + p["b_nt"] + tau * p["kb_nt_per_c"]
    if doc["equation"] == SCALAR_T_EQUATION:
        t = tau - doc["tau_0_c"]
        v = h - p["c_nt"] - t * p["kc_nt_per_c"]
        return np.einsum("nij,nj->ni", p["A"] + t[:, :, None] * p["KA_per_c"], v)
    raise AssertionError(f"an equation this script does not know: {doc['equation']}")


def applied(tmp_path, cal_path, h, temp_c) -> np.ndarray:
    data = tmp_path / "data.csv"
    csvio.write_csv(data, {"hx": h[:, 0], "hy": h[:, 1], "hz": h[:, 2], "temp": temp_c})
    assert main(["apply", str(cal_path), str(data), "-o", str(tmp_path / "out.csv")]) == 0
    with open(tmp_path / "out.csv") as f:
        return np.array([[float(r["bx"]), float(r["by"]), float(r["bz"])] for r in csv.DictReader(f)])


def _t24(rng):
    ds, _ = synthetic.t24_dataset(rng, samples_per_point=2)
    return calib.fit(ds, "t24", temp_ref_c=20.0)  # a solve centre that is not 0: it must not be applied


def _scalar_with_temperature(rng):
    ds, _ = synthetic.scalar_dataset(rng, n=600, temps_c=(-10.0, 20.0, 50.0))
    return calib.fit(ds, "scalar", temperature_terms=True, temp_ref_c=20.0)


@pytest.mark.parametrize("make", [_t24, _scalar_with_temperature])
def test_an_independent_script_reading_the_file_gives_what_rig_apply_gives(make, tmp_path, capsys):
    rng = np.random.default_rng(11)
    cal = make(rng)
    path = tmp_path / "cal.yaml"
    calfile.save(cal, path)
    h, temp_c = rng.normal(0, 40_000, (40, 3)), rng.uniform(-30, 70, 40)
    ours = applied(tmp_path, path, h, temp_c)
    np.testing.assert_allclose(independent_field(path, h, temp_c), ours, rtol=1e-12, atol=1e-6)
    assert "tau = the temp column in degC as it is" in capsys.readouterr().out


def test_t24_file_states_its_convention_and_no_reference_to_subtract(tmp_path):
    cal = _t24(np.random.default_rng(3))
    path = tmp_path / "cal.yaml"
    calfile.save(cal, path)
    doc = yaml.safe_load(path.read_text())
    assert doc["format_version"] == 3
    assert doc["equation"] == T24_EQUATION and doc["tau"] == "absolute_c"
    assert "temp_ref_c" not in doc and "tau_0_c" not in doc
    assert doc["solve_centre_c"] == 20.0  # internal to the solve; its name says so
    assert calfile.load(path).to_dict() == cal.to_dict()  # exact round trip
    json_path = tmp_path / "cal.json"
    calfile.save(cal, json_path)
    assert calfile.load(json_path).to_dict() == cal.to_dict()


def test_a_format_1_file_with_temp_ref_c_still_loads_and_applies_the_same(tmp_path):
    rng = np.random.default_rng(5)
    for cal in (_t24(rng), _scalar_with_temperature(rng)):
        old = cal.to_dict()
        for key in ("equation", "tau", "tau_0_c", "solve_centre_c"):
            old.pop(key, None)
        old.update(format_version=1, temp_ref_c=20.0)
        path = tmp_path / f"old-{cal.model}.yaml"
        path.write_text(yaml.safe_dump(old))
        loaded = calfile.load(path)
        h, t = rng.normal(0, 40_000, (10, 3)), rng.uniform(-30, 70, 10)
        np.testing.assert_array_equal(loaded.apply(h, t), cal.apply(h, t))
        assert loaded.to_dict() == cal.to_dict()  # saved again, it states its equation


@pytest.mark.parametrize("change, message", [
    ({"equation": "B = S h + b_nt"}, "key 'equation' is 'B = S h + b_nt'"),
    ({"tau": "relative_c"}, "key 'tau' is 'relative_c'"),
    ({"temp_ref_c": 25.0}, "keys 'solve_centre_c' and 'temp_ref_c' both given"),
    ({"format_version": 4}, "key 'format_version' is 4"),
])
def test_a_file_that_says_something_else_is_refused_naming_the_key(change, message, tmp_path):
    doc = {**_t24(np.random.default_rng(2)).to_dict(), **change}
    path = tmp_path / "cal.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(DataError, match=re.escape("cal.yaml: " + message)):
        calfile.load(path)


def test_a_scalar_file_without_its_tau_0_is_refused():
    doc = _scalar_with_temperature(np.random.default_rng(4)).to_dict()
    del doc["tau_0_c"]
    with pytest.raises(DataError, match="key 'tau_0_c' is missing"):
        Calibration.from_dict(doc, where="cal.yaml")
