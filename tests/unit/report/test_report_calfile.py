"""`rig report CAL --data CSV`, and `rig sessions`."""

from __future__ import annotations

import re
from html import unescape

import numpy as np
import pytest

from calib import synthetic
from calib.io import csvio
from rig.cli import main
from tests.helpers.synthetic_session import SynthOptions, build_session


def _text(html: str) -> str:
    return re.sub(r"\s+", " ", unescape(re.sub(r"<[^>]+>", " ", html)))


@pytest.fixture(scope="module")
def csv_and_cal(tmp_path_factory):
    """A CSV in the contract's columns (with two flagged rows) and a calibration refitted from it."""
    d = tmp_path_factory.mktemp("c")
    ds, _ = synthetic.t24_dataset(np.random.default_rng(8), temps_c=(0.0, 30.0), samples_per_point=2)
    flags = np.array([""] * len(ds), dtype=object)
    flags[[3, 4]] = "overflow"
    ds.h_nt[[3, 4]] = -4096 * 100.0  # what an overflowed reading looks like after scaling
    data = d / "data.csv"
    csvio.write_csv(
        data,
        {
            "hx": ds.h_nt[:, 0],
            "hy": ds.h_nt[:, 1],
            "hz": ds.h_nt[:, 2],
            "temp": ds.temp_c,
            "bx": ds.ref_nt[:, 0],
            "by": ds.ref_nt[:, 1],
            "bz": ds.ref_nt[:, 2],
            "flags": flags,
        },
    )
    clean = d / "clean.csv"
    keep = flags == ""
    csvio.write_csv(
        clean,
        {
            "hx": ds.h_nt[keep, 0],
            "hy": ds.h_nt[keep, 1],
            "hz": ds.h_nt[keep, 2],
            "temp": ds.temp_c[keep],
            "bx": ds.ref_nt[keep, 0],
            "by": ds.ref_nt[keep, 1],
            "bz": ds.ref_nt[keep, 2],
        },
    )
    cal = d / "cal.yaml"
    assert main(["refit", str(clean), "--model", "p12", "-o", str(cal)]) == 0
    return data, clean, cal


def test_report_of_a_calibration_file(csv_and_cal, tmp_path, capsys):
    data, _, cal = csv_and_cal
    assert main(["report", str(cal), "--data", str(data), "-o", str(tmp_path)]) == 0
    text = _text((tmp_path / "report.html").read_text(encoding="utf-8"))
    assert "residuals shown for the P12 calibration given in the calibration file" in text
    assert "2 sample(s) flagged 'overflow' (not fitted)" in text
    assert "P12: the given calibration" in text and "Equation: B = inv(Q P) (h - h0_nt)" in text
    # the other models are a labelled comparison, re-fitted here with their own options
    assert "Comparison: models re-fitted here (robust: true) on held-out points" in text
    # the CSV with flagged rows is not the file the calibration was fitted on: said so
    assert "is not the file the calibration was fitted on" in text
    assert f"data file {data.name}: 104 rows, 102 judged (2 flagged left out)" in text
    capsys.readouterr()


def test_same_file_gives_no_hash_warning(csv_and_cal, tmp_path, capsys):
    _, clean, cal = csv_and_cal
    assert main(["report", str(cal), "--data", str(clean), "-o", str(tmp_path)]) == 0
    text = _text((tmp_path / "report.html").read_text(encoding="utf-8"))
    assert "is not the file the calibration was fitted on" not in text
    capsys.readouterr()


@pytest.mark.parametrize(
    "make_args, message",
    [
        (lambda d, c, t: [str(c)], "needs the data it was fitted on: add --data"),
        (lambda d, c, t: [str(c), "--data", str(t / "none.csv")], "none.csv"),
        (lambda d, c, t: [str(d), "--data", str(d)], "data.csv"),  # a CSV is not a calibration file
        (lambda d, c, t: [str(c), "--data", str(t / "bad.csv")], "missing column 'hx'"),
    ],
)
def test_bad_input_is_one_line(make_args, message, csv_and_cal, tmp_path, capsys):
    data, _, cal = csv_and_cal
    (tmp_path / "bad.csv").write_text("mx,my,mz\n1,2,3\n")
    assert main(["report", *make_args(data, cal, tmp_path), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err


def test_sessions_lists_good_and_bad_files(tmp_path, capsys):
    build_session(tmp_path / "a_done.sqlite", SynthOptions(temps_c=(0.0, 20.0), directions=6, samples=1))
    build_session(
        tmp_path / "b_running.db",
        SynthOptions(temps_c=(0.0,), directions=6, samples=1, duts=("x", "y"), finish=None),
    )
    (tmp_path / "c_notes.db").write_text("not a database\n")
    (tmp_path / "d_cut.sqlite").write_bytes((tmp_path / "a_done.sqlite").read_bytes()[:2048])
    (tmp_path / "e_other.txt").write_text("ignored")
    assert main(["sessions", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("file") and len(lines) == 5
    date = r"\d{4}-\d\d-\d\d \d\d:\d\d"  # the wall-clock start
    # "-" in the acceptance column: the plan set no acceptance limits
    assert re.match(rf"a_done\.sqlite +{date} +simstation +dut1 +12/12 +completed +- +no fit", lines[1])
    assert re.match(r"b_running\.db +\S+ \S+ +simstation +x,y +6/6 +not finished", lines[2])
    assert "c_notes.db" in lines[3] and "SKIPPED: not a session file or damaged" in lines[3]
    assert "d_cut.sqlite" in lines[4] and "SKIPPED" in lines[4]


def test_sessions_in_a_missing_folder(tmp_path, capsys):
    assert main(["sessions", str(tmp_path / "nope")]) == 2
    assert "no such folder" in capsys.readouterr().err
    assert main(["sessions", str(tmp_path)]) == 0
    assert "no session files" in capsys.readouterr().out
