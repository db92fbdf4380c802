"""One answer everywhere. On a measured-ambient campaign, the calibration the run wrote, `rig refit
SESSION` and `rig refit-all` are the very same numbers (one code path: the references remade with the
run's best ambient), and `rig sessions`, the cockpit, the report and the run's summary name the calibration
the plan judges. On a commissioned station, whose budgets are small, a fit whose residual exceeds its
stated uncertainty is flagged in the run's table, `rig sessions`, the cockpit, the report and the C header."""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import sqlite3
from html import unescape
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pyarrow.parquet as pq
import pytest
import yaml

import calib
from rig.cli import main
from rig.config.loading import load_campaign
from rig.report.sessions import session_cells
from rig.run.campaign import run_campaign
from rig.run.summary import calibration_notes, calibration_rows
from rig.session.reader import read_dataset
from rig.web.pages import SessionRef, session_page
from tests.system.campaign_helpers import REPO

pytestmark = pytest.mark.system

MEASURED = REPO / "configs" / "stations" / "sim-measured-ambient.yaml"
COMMISSIONED = REPO / "configs" / "stations" / "sim-commissioned.yaml"
AXES = [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1],
        [1, 1, 1], [-1, -1, 1], [1, -1, -1], [-1, 1, -1]]


def campaign(folder: Path, station: Path, models: list[str]) -> tuple[Path, object]:
    stability = {"band_c": 0.5, "rate_c_per_min": 0.3, "dwell_s": 60}
    temperatures = {"steps": [0, 25, 50], "ramp_c_per_min": 5.0, "stability": stability}
    plan = {"name": "one", "temperatures": temperatures,
            "fields": {"kind": "directions", "magnitude_nt": 50000, "directions": AXES},
            "samples_per_point": 3, "settle_s": 0.2, "fit": {"models": models}}
    plan_path = folder / "one.yaml"
    plan_path.write_text(yaml.safe_dump(plan, sort_keys=False))
    session = folder / "one.session"
    outcome = run_campaign(campaign=load_campaign(plan_path, station), session_path=session)
    assert outcome.result.status == "completed", outcome.result.reason
    return session, outcome


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    return campaign(tmp_path_factory.mktemp("measured"), MEASURED, ["t24", "p12"])


@pytest.fixture(scope="module")
def commissioned(tmp_path_factory):
    return campaign(tmp_path_factory.mktemp("commissioned"), COMMISSIONED, ["p12", "t24"])


def params_of(doc: dict) -> dict:
    return {k: np.asarray(v) for k, v in doc["params"].items()}


def test_run_refit_and_refit_all_give_the_same_calibration(measured, tmp_path, capsys):
    session, outcome = measured
    written = yaml.safe_load((session.parent / "one.mmc0.t24.yaml").read_text())
    refit = tmp_path / "refit.json"  # JSON keeps every digit
    assert main(["refit", str(session), "--dut", "mmc0", "-o", str(refit)]) == 0
    refitted = json.loads(refit.read_text())
    assert refitted["model"] == "t24"  # the plan's judged model, unasked
    out = tmp_path / "all.parquet"
    assert main(["refit-all", str(session.parent), "--model", "t24", "--out", str(out), "--workers", "1",
                 "--no-progress"]) == 0
    row = next(r for r in pq.read_table(out).to_pylist() if r["dut"] == "mmc0")
    batch = {k: np.asarray(v) for k, v in json.loads(row["params"]).items()}
    for name, value in params_of(written).items():
        np.testing.assert_array_equal(params_of(refitted)[name], value)
        np.testing.assert_array_equal(batch[name], value)
    assert written["stats"]["ambient"] == refitted["stats"]["ambient"]  # the run's ambient model, both
    assert written["stats"]["linearity"] == refitted["stats"]["linearity"]
    assert row["rms_after_nt"] == written["stats"]["rms_after_nt"]
    # the shared path matters: the session's references as recorded give another calibration
    raw = calib.fit(read_dataset(session, "mmc0"), "t24")
    assert not np.array_equal(raw.params["b_nt"], params_of(written)["b_nt"])
    capsys.readouterr()


def test_every_listing_names_the_calibration_the_plan_judges(measured, tmp_path, capsys):
    session, outcome = measured
    cell = session_cells(session)[-1]
    t24 = {f["dut"]: f["rms_nt"] for f in outcome.fits if f["model"] == "t24"}
    p12 = {f["dut"]: f["rms_nt"] for f in outcome.fits if f["model"] == "p12"}
    assert max(p12.values()) > max(t24.values())  # the worst model is not the one named
    assert cell == f"t24 RMS: mmc0 {t24['mmc0']:.1f}, serial0 {t24['serial0']:.1f} nT"
    page = session_page(SimpleNamespace(db_url=None, csrf_token="t"), SessionRef(0, session.name, session))
    assert f"t24 RMS: mmc0 {t24['mmc0']:.1f}" in unescape(page) and "t24 (judged)" in page
    assert main(["report", str(session), "-o", str(tmp_path / "r")]) == 0
    html = (tmp_path / "r" / "report.html").read_text()
    text = re.sub(r"\s+", " ", unescape(re.sub(r"<[^>]+>", " ", html)))
    cal_file = session.parent / "one.mmc0.t24.yaml"
    digest = hashlib.sha256(cal_file.read_bytes()).hexdigest()
    assert (f"residuals shown for the run's T24 calibration (the model the plan judges): {cal_file.name} "
            f"(sha256 {digest})") in text
    # its parameters with the expanded uncertainties the file states, not "-"
    expanded = yaml.safe_load(cal_file.read_text())["uncertainty"]["expanded"]["b_nt"][0]
    assert re.search(rf"b_nt\[0\] \S+ \S+ {expanded:.3g} nT", text)  # zero-based, as the file names it
    assert "Equation: B = (S + tau K) h + b_nt + tau kb_nt_per_c" in text
    assert "linearity in temperature" in text  # its model check
    assert "Comparison: models re-fitted here (robust: false)" in text  # the plan says robust: false
    capsys.readouterr()


def test_every_calibration_states_an_uncertainty_that_covers_its_residual(commissioned):
    """P12 leaves these DUTs' T24 errors (hundreds of nT): its budget's misfit line carries them, so no
    stated uncertainty is below the scatter the fit itself shows."""
    _, outcome = commissioned
    for fit in outcome.fits:
        assert fit["rms_nt"] <= fit["calibration"].uncertainty["expanded_vector_error_nt"], fit["dut"]
    p12 = [f for f in outcome.fits if f["model"] == "p12"]
    assert any(line["source"] == "misfit" for f in p12 for line in f["calibration"].uncertainty["budget"])


def understated(session: Path, fit: dict, folder: Path) -> tuple[Path, list[dict]]:
    """A copy of the session in which one P12 calibration states a third of its residual, as a file written
    before the misfit entered the budget would: in its file and in the session's record of the fit."""
    copy = folder / "copy"
    shutil.copytree(session.parent, copy)
    stated = fit["rms_nt"] / 3.0
    path = copy / Path(fit["path"]).name
    doc = yaml.safe_load(path.read_text())
    doc["uncertainty"]["expanded_vector_error_nt"] = stated
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    with sqlite3.connect(copy / session.name) as db:
        query = "SELECT id, calibration_json FROM fits WHERE dut = ? AND model = 'p12'"
        for row_id, text in db.execute(query, (fit["dut"],)).fetchall():
            recorded = json.loads(text)
            recorded["uncertainty"]["expanded_vector_error_nt"] = stated
            db.execute("UPDATE fits SET calibration_json = ? WHERE id = ?", (json.dumps(recorded), row_id))
    return copy / session.name, [dict(fit, path=path, calibration=calib.io.calfile.load(path))]


def test_a_residual_above_its_stated_uncertainty_is_flagged_wherever_it_is_shown(commissioned, tmp_path,
                                                                                  capsys):
    session, outcome = commissioned
    fit = next(f for f in outcome.fits if f["model"] == "p12")
    session, fits = understated(session, fit, tmp_path)
    dut = fit["dut"]
    rows = calibration_rows(SimpleNamespace(fits=fits, judged_model="p12"))
    assert [dut, "p12 (judged)"] == rows[0][:2] and rows[0][-1] == "RMS > radius"
    notes = calibration_notes(SimpleNamespace(fits=fits, judged_model="p12"))
    assert any(n.startswith(f"{dut} p12: residual RMS") and "above its stated 95 % error radius" in n
               for n in notes)
    assert dut in session_cells(session)[-1].split("[RMS > radius: ")[1]
    page = session_page(SimpleNamespace(db_url=None, csrf_token="t"), SessionRef(0, session.name, session))
    assert "RMS &gt; radius: residual RMS" in page
    assert main(["report", str(session), "--dut", dut, "-o", str(tmp_path / "r")]) == 0
    assert "FLAGGED: residual RMS" in unescape((tmp_path / "r" / "report.html").read_text())
    header = tmp_path / "p12.h"
    assert main(["export-cal", str(fits[0]["path"]), "--format", "c-header", "-o", str(header)]) == 0
    assert " * WARNING: residual RMS" in header.read_text()
    capsys.readouterr()
