"""`rig export-cal`: the C header a flight computer compiles gives the same field as `rig apply`."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

import calib
from calib import synthetic
from calib.io import calfile, csvio
from rig.cli import main
from tests.unit.report.ccheck import max_relative_error, run_header


def _fitted(model: str, rng):
    if model in ("t24", "t36"):  # t36 fitted to T24 data: its tau^2 terms small, not zero
        ds, _ = synthetic.t24_dataset(rng, samples_per_point=2)
    elif model == "p12":
        ds, _ = synthetic.p12_dataset(rng, samples_per_point=2)
    else:
        ds, _ = synthetic.scalar_dataset(rng, n=300, temps_c=(0.0, 20.0, 40.0))
    return calib.fit(ds, model)


def _samples(rng, n=50):
    return rng.normal(0, 40_000, (n, 3)), rng.uniform(-30, 70, n)


@pytest.mark.parametrize("model", ["t24", "t36", "p12", "scalar"])
def test_header_matches_rig_apply(model, tmp_path, capsys):
    rng = np.random.default_rng({"t24": 1, "t36": 6, "p12": 2, "scalar": 3}[model])
    cal_path = tmp_path / "cal.yaml"
    calfile.save(_fitted(model, rng), cal_path)
    h, t = _samples(rng)
    data = tmp_path / "data.csv"
    csvio.write_csv(data, {"hx": h[:, 0], "hy": h[:, 1], "hz": h[:, 2], "temp": t})
    header = tmp_path / "mag_cal.h"
    assert (
        main(["export-cal", str(cal_path), "--format", "c-header", "--name", "mag cal", "-o", str(header)])
        == 0
    )
    assert main(["apply", str(cal_path), str(data), "-o", str(tmp_path / "out.csv")]) == 0
    with open(tmp_path / "out.csv") as f:
        applied = np.array([[float(r["bx"]), float(r["by"]), float(r["bz"])] for r in csv.DictReader(f)])
    for std in ("c99", "c89"):  # C89 too: `gcc -std=c89 -pedantic -Werror` (and -Wall -Wextra)
        from_c = run_header(header.read_text(), "mag cal", h, t, tmp_path, std)
        assert max_relative_error(from_c, applied) < 1e-9
    text = header.read_text()
    assert f"model: {model}" in text and "#ifndef MAGRIG_MAG_CAL_H" in text
    assert ("MAG_CAL_M_PER_C2" in text) == (model == "t36")
    assert "MAGRIG_INLINE void mag_cal_apply(" in text and "#define MAGRIG_INLINE static inline" in text
    capsys.readouterr()


def test_header_names_its_source_and_version(tmp_path, capsys):
    cal = _fitted("t24", np.random.default_rng(4))
    cal.source["sha256"] = "1234abcd" * 8
    cal.source["dut"] = "dut-7"
    path = tmp_path / "c.yaml"
    calfile.save(cal, path)
    assert main(["export-cal", str(path), "--format", "c-header"]) == 0
    text = capsys.readouterr().out
    assert "source sha256: " + "1234abcd" * 8 in text
    assert f"magrig {cal.software_version}" in text
    assert "dut_7_apply(" in text  # symbol named after the DUT


def test_json_export_round_trips_the_parameters(tmp_path, capsys):
    cal = _fitted("scalar", np.random.default_rng(5))
    path = tmp_path / "c.json"
    calfile.save(cal, path)
    out = tmp_path / "export.json"
    assert main(["export-cal", str(path), "--format", "json", "-o", str(out)]) == 0
    doc = json.loads(out.read_text())
    for key, value in cal.params.items():
        np.testing.assert_array_equal(np.array(doc["params"][key]), value)
    assert doc["flight_form"]["equation"] == "B = M(tau) (h - o(tau))"
    if "KA_per_c" in cal.params:  # the equation subtracts tau_0_c: the export says so
        assert doc["flight_form"]["tau"] == "temp_c - tau_0_c"
        assert doc["flight_form"]["tau_0_c"] == doc["tau_0_c"] == cal.temp_ref_c
    else:
        assert doc["flight_form"]["tau"] == "not used" and "tau_0_c" not in doc["flight_form"]
    capsys.readouterr()


def test_csv_export_lists_every_parameter(tmp_path, capsys):
    cal = _fitted("p12", np.random.default_rng(6))
    path = tmp_path / "c.yaml"
    calfile.save(cal, path)
    assert main(["export-cal", str(path), "--format", "csv"]) == 0
    lines = capsys.readouterr().out.splitlines()
    rows = list(csv.DictReader(line for line in lines if not line.startswith("#")))
    assert [r["parameter"] for r in rows][:3] == ["k[0]", "k[1]", "k[2]"]
    assert len(rows) == 9
    assert float(rows[0]["std_error"]) == pytest.approx(cal.std_errors["k"][0])


def test_bad_calibration_file_is_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("model: t24\nparams: [1, 2\n")
    assert main(["export-cal", str(bad), "--format", "json"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(bad) in err and "Traceback" not in err
    assert main(["export-cal", str(tmp_path / "missing.yaml"), "--format", "json"]) == 2
    assert "not found" in capsys.readouterr().err
