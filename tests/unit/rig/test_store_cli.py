"""`rig check` and `rig export`, through the real command line entry point."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from calib.io import calfile, csvio
from drivers.sim.world import DutTruth
from rig.cli import main
from rig.config.loading import load_campaign
from rig.schedules.compile import compile_plan
from rig.session.reader import read_dataset
from rig.session.rows import SampleRow
from rig.session.writer import Session

CONFIGS = Path(__file__).resolve().parents[3] / "configs"
DEMO = CONFIGS / "plans" / "demo.yaml"


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_check_prints_steps_and_duration(capsys):
    code, out, err = run(capsys, "check", DEMO)
    assert code == 0, err
    assert "plan demo" in out and "every device simulated" in out
    assert "note: the coils are not commissioned" in out  # why the demo's uncertainties will be large
    assert "104 points = 4 temperatures x 26 fields; 520 samples per DUT, 2 DUT(s)" in out
    assert "estimated duration" in out and "largest coil current" in out


def test_check_against_another_station(capsys):
    code, out, _ = run(capsys, "check", DEMO, "--station", CONFIGS / "stations" / "lab-example.yaml")
    assert code == 0 and "station lab-b214" in out and "every device real" in out
    assert "warning: ambient field not yet measured" in out


def test_check_refuses_an_over_current_plan_in_one_line(tmp_path, capsys):
    station = (CONFIGS / "stations" / "sim.yaml").read_text()
    station = station.replace("max_current_a: 2.0", "max_current_a: 0.5")
    (tmp_path / "weak.yaml").write_text(station)
    code, out, err = run(capsys, "check", DEMO, "--station", tmp_path / "weak.yaml")
    assert code == 2 and out == ""
    assert err.count("\n") == 1
    assert err.startswith(f"error: {DEMO}: fields.directions[0]: point T01-F01 field (50000, 0, 0) nT")
    assert "above field_source.max_current_a 0.5 A (line 19)" in err


def test_check_names_file_key_and_line_of_a_bad_plan(tmp_path, capsys):
    bad = DEMO.read_text().replace("samples_per_point: 5", "samples_per_point: 0")
    (tmp_path / "bad.yaml").write_text(bad)
    code, _, err = run(capsys, "check", tmp_path / "bad.yaml", "--station", CONFIGS / "stations" / "sim.yaml")
    line = bad.splitlines().index("samples_per_point: 0") + 1
    assert code == 2
    assert err == f"error: {tmp_path / 'bad.yaml'}: samples_per_point: must be >= 1 (line {line})\n"


@pytest.fixture
def recorded(tmp_path):
    """A session with noise-free readings of a known T24 truth at the demo's 4 temperatures x 26 fields."""
    campaign = load_campaign(DEMO)
    points = compile_plan(campaign.plan, campaign.station)
    truth = DutTruth.random(np.random.default_rng(5), noise_nt=0.0)
    path = tmp_path / "demo.magrig"
    session = Session.create_for(path, campaign, points)
    for p in points:
        temp = p.setpoint_c + 0.3
        h = tuple(truth.raw_from_field(np.array(p.field_nt), temp))
        rows = [SampleRow("mmc0", p.index + i / 10, h, p.field_nt, temp_c=temp, ref_temp_c=p.setpoint_c)
                for i in range(3)]
        rows.append(SampleRow("serial0", p.index, (1.0, 2.0, 3.0), p.field_nt, temp_c=temp))
        if p.index == 5:
            rows.append(SampleRow("mmc0", p.index + 0.5, (9e9, 0.0, 0.0), p.field_nt, temp_c=temp,
                                  flags=frozenset({"overflow"})))
        session.record_point(p.id, rows)
    session.finish("completed", "")
    session.close()
    return path


def test_export_writes_the_csv_contract_that_refit_reads(recorded, tmp_path, capsys):
    out_csv = tmp_path / "mmc0.csv"
    code, out, err = run(capsys, "export", recorded, "--csv", "--dut", "mmc0", "-o", out_csv)
    assert code == 0, err
    assert "wrote 312 samples of mmc0" in out and "1 flagged sample(s) left out" in out
    with out_csv.open(newline="") as f:
        header = next(csv.reader(f))
    assert {"hx", "hy", "hz", "temp", "bx", "by", "bz", "point", "t", "flags"} <= set(header)
    from_csv = csvio.read_csv(out_csv)
    from_session = read_dataset(recorded, "mmc0")
    assert np.array_equal(from_csv.h_nt, from_session.h_nt)  # exact: floats are written in full
    assert np.array_equal(from_csv.ref_nt, from_session.ref_nt)
    assert np.array_equal(from_csv.temp_c, from_session.temp_c)
    assert list(from_csv.group) == list(from_session.group)
    cal_path = tmp_path / "cal.yaml"
    code, _, err = run(capsys, "refit", out_csv, "--model", "t24", "-o", cal_path)
    assert code == 0, err
    cal = calfile.load(cal_path)
    fitted = cal.apply(from_csv.h_nt, from_csv.temp_c)
    assert np.max(np.abs(fitted - from_csv.ref_nt)) < 1.0  # nT: the exported data carries the truth


def test_export_with_flagged_rows_on_request(recorded, tmp_path, capsys):
    out_csv = tmp_path / "all.csv"
    code, out, _ = run(capsys, "export", recorded, "--dut", "mmc0", "--include-flagged", "-o", out_csv)
    assert code == 0 and "wrote 313 samples" in out
    with out_csv.open(newline="") as f:
        flags = [row["flags"] for row in csv.DictReader(f)]
    assert flags.count("overflow") == 1 and flags.count("") == 312


def test_export_needs_a_dut_when_there_are_several(recorded, tmp_path, capsys):
    code, out, err = run(capsys, "export", recorded, "-o", tmp_path / "x.csv")
    assert code == 2 and "several DUTs (mmc0, serial0): choose one with --dut" in err
    assert not (tmp_path / "x.csv").exists()


def test_export_of_something_that_is_not_a_session(tmp_path, capsys):
    not_session = tmp_path / "notes.txt"
    not_session.write_text("hello\n" * 100)
    code, _, err = run(capsys, "export", not_session, "-o", tmp_path / "x.csv")
    assert code == 2 and str(not_session) in err and "not a session file" in err
