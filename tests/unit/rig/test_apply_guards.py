"""A calibration refitted from a CSV says it has no reference chain (on screen, in the file, in every export);
`rig apply` names rows outside the calibrated magnitudes and input in a wrong raw unit, and an older file's
gaps, one line each; `rig report` says those gaps too."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from calib.calibration import MAGNITUDES_KEY, MEASURAND
from calib.io import calfile, csvio
from rig.cli import main

EXAMPLE = Path(__file__).resolve().parents[3] / "examples" / "t24_synthetic.csv"
NO_CHAIN = "NO COMMISSIONED REFERENCE CHAIN"


@pytest.fixture(scope="module")
def refitted(tmp_path_factory):
    """`rig refit` of the example CSV: (its file, what it printed)."""
    folder = tmp_path_factory.mktemp("csv-refit")
    out = folder / "cal.yaml"
    from click.testing import CliRunner

    from rig.cli import cli

    result = CliRunner().invoke(cli, ["refit", str(EXAMPLE), "--model", "t24", "-o", str(out)])
    assert result.exit_code == 0, result.output
    return out, result.output


def _rows(path: Path, n: int):
    ds = csvio.read_csv(path)
    return ds.h_nt[:n], ds.temp_c[:n]


def test_a_csv_refit_states_its_measurand_and_that_it_has_no_reference_chain(refitted, tmp_path, capsys):
    path, printed = refitted
    assert f"{NO_CHAIN}: none: refitted from a CSV's bx,by,bz" in " ".join(printed.split())
    cal = calfile.load(path)
    assert cal.reference_chain == {"traceable": False, "text": "none: refitted from a CSV's bx,by,bz"}
    assert cal.reading["mode"] == "not_stated" and cal.reading["device"] is None
    assert cal.reading["raw_unit"] == "nT" and cal.tau_source["place"] == "CSV column temp"
    assert cal.frame["B"]["name"] == "csv" and cal.missing_measurand() == []
    assert cal.source["path"] == str(EXAMPLE)
    for fmt in ("c-header", "json", "csv"):
        assert main(["export-cal", str(path), "--format", fmt]) == 0
        text = " ".join(capsys.readouterr().out.split())
        assert NO_CHAIN in text and cal.source["sha256"] in text, fmt


def test_apply_names_rows_beyond_the_calibrated_magnitudes_and_a_wrong_unit(refitted, tmp_path, capsys):
    path, _ = refitted
    span = calfile.load(path).stats[MAGNITUDES_KEY]["h"]
    h, t = _rows(EXAMPLE, 10)
    h[[2, 5, 7]] *= 3.0  # three rows at three times the field calibrated
    data = tmp_path / "strong.csv"
    csvio.write_csv(data, {"hx": h[:, 0], "hy": h[:, 1], "hz": h[:, 2], "temp": t})
    assert main(["apply", str(path), str(data), "-o", str(tmp_path / "out.csv")]) == 0
    lines = capsys.readouterr().err.strip().splitlines()
    said = (f"warning: 3 of 10 rows with |h| outside the calibrated field magnitudes ({span[0]:.0f} .. "
            f"{span[1]:.0f} nT) by more than 10%")
    assert len(lines) == 1 and lines[0].startswith(said)
    assert "first row 2" in lines[0]
    gauss = tmp_path / "gauss.csv"  # the same readings in gauss, given without --raw-unit
    h, t = _rows(EXAMPLE, 10)
    csvio.write_csv(gauss, {"hx": h[:, 0] / 1e5, "hy": h[:, 1] / 1e5, "hz": h[:, 2] / 1e5, "temp": t})
    assert main(["apply", str(path), str(gauss), "-o", str(tmp_path / "out.csv")]) == 0
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 2 and lines[0].startswith("warning: 10 of 10 rows with |h| outside")
    assert lines[1] == ("warning: raw unit nT: values about 1e-05 of the calibrated magnitudes: gauss given "
                        "as nT? (state it with --raw-unit)")
    assert main(["apply", str(path), str(gauss), "--raw-unit", "gauss", "-o", str(tmp_path / "out.csv")]) == 0
    assert capsys.readouterr().err == ""


def test_an_older_file_says_what_it_lacks_in_apply_and_report(refitted, tmp_path, capsys):
    path, _ = refitted
    old = yaml.safe_load(path.read_text())
    for key in MEASURAND:
        old.pop(key)
    old["stats"].pop(MAGNITUDES_KEY)
    old["format_version"] = 2
    old_path = tmp_path / "old.yaml"
    old_path.write_text(yaml.safe_dump(old, sort_keys=False))
    lacks = calfile.load(old_path).missing_measurand()
    assert len(lacks) == 6  # the five keys and the magnitudes (not a session's: its hash is the CSV's own)
    assert main(["apply", str(old_path), str(EXAMPLE), "-o", str(tmp_path / "out.csv")]) == 0
    notes = [line for line in capsys.readouterr().err.splitlines() if line.startswith("note: ")]
    assert notes == [f"note: {old_path} (format version 2) does not state {what}" for what in lacks]
    assert main(["report", str(old_path), "--data", str(EXAMPLE), "-o", str(tmp_path / "report")]) == 0
    notes = [line for line in capsys.readouterr().err.splitlines() if line.startswith("note: ")]
    assert len(notes) == len(lacks) and all("does not state" in n for n in notes)
    page = (tmp_path / "report" / "report.html").read_text()
    assert page.count("not stated") >= len(lacks)
