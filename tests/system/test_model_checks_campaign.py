"""The model checks decide on a simulated station: a DUT with a strong quadratic temperature term (its
truth's K2_per_c2, kb2_nt_per_c2) fails T24's linearity in temperature, gets a T36 that validates better
and is judged on it, and passes; a DUT with a cubic field term (cubic_ppm_at_50ut) fails acceptance on
T24's linearity in the field, which no model captures; without `acceptance.model_checks` it passes.

Three temperatures all reached heating leave the hysteresis check nothing to compare: "not run". The
effects are several times the noise at every point (the quadratic 100 nT at the range's ends, the cubic
100 nT at 50 uT against 10 nT of noise), so the verdicts hold on any seed."""

from __future__ import annotations

import re
from html import unescape
from types import SimpleNamespace

import pytest
import yaml

from calib.checks.model_checks import FIELD, HYSTERESIS
from rig.analysis.acceptance import judge_session
from rig.analysis.judged import judged_cell, judged_fits
from rig.cli import main
from rig.config import load_plan
from rig.config.loading import load_campaign
from rig.core.paths import calibration_file
from rig.report.certificate import certificate_html
from rig.run.campaign import run_campaign
from rig.run.summary import calibration_rows
from rig.session.reader import SessionReader
from rig.web.pages import SessionRef, session_page
from tests.system.campaign_helpers import SIM_STATION

pytestmark = pytest.mark.system

AXES = [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]
S = [[1.01, 0.002, -0.001], [0.001, 0.99, 0.003], [-0.002, 0.001, 1.0]]


def _station(folder):
    data = yaml.safe_load(SIM_STATION.read_text())
    data["sim"]["duts"] = {
        "mmc0": {"truth": {"S": S, "b_nt": [200, -100, 50], "kb_nt_per_c": [2, -1, 1],
                           "K2_per_c2": [[2e-5, 0, 0], [0, -2e-5, 0], [0, 0, 2e-5]],
                           "kb2_nt_per_c2": [1.0, -1.0, 0.5]}, "noise_nt": 10, "thermal_lag_s": 120},
        "serial0": {"truth": {"S": [list(row) for row in S], "b_nt": [-50, 80, 20],
                              "cubic_ppm_at_50ut": [2000, -1500, 1000]},
                    "noise_nt": 10, "thermal_lag_s": 120},
    }
    path = folder / "station.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _plan(folder, model_checks: bool = True):
    plan = {"name": "checks",
            "temperatures": {"steps": [30, 40, 50], "ramp_c_per_min": 5.0,
                             "stability": {"band_c": 0.5, "rate_c_per_min": 0.3, "dwell_s": 60}},
            "fields": {"kind": "directions", "magnitudes_nt": [25000, 50000], "directions": AXES},
            "samples_per_point": 4, "settle_s": 0.2, "fit": {"models": ["t24"]},
            "acceptance": {"model_checks": model_checks}}
    path = folder / f"checks-{model_checks}.yaml"
    path.write_text(yaml.safe_dump(plan, sort_keys=False))
    return path


def test_the_model_checks_decide_acceptance_and_the_judged_model(tmp_path, capsys):
    station, plan = _station(tmp_path), _plan(tmp_path)
    session = tmp_path / "checks.session"
    campaign = load_campaign(plan, station)
    outcome = run_campaign(campaign=campaign, session_path=session)
    assert outcome.result.status == "completed", outcome.result.reason

    fitted = {(f["dut"], f["model"]): f for f in outcome.fits}
    assert set(fitted) == {("mmc0", "t24"), ("mmc0", "t36"), ("serial0", "t24")}  # T36 only where it failed
    assert calibration_file(session, "mmc0", "t36").is_file()
    choice = fitted["mmc0", "t24"]["calibration"].stats["temperature_model"]
    assert choice["model"] == "t36" and choice["heldout_rms_nt"]["t36"] < choice["heldout_rms_nt"]["t24"]
    assert fitted["mmc0", "t36"]["calibration"].stats["temperature_model"] == choice

    verdicts = {v.dut: v for v in outcome.verdicts}
    assert verdicts["mmc0"].passed and verdicts["mmc0"].model == "t36", verdicts["mmc0"].line()
    assert verdicts["mmc0"].not_run == [HYSTERESIS]
    assert not verdicts["serial0"].passed and verdicts["serial0"].model == "t24"
    assert [f for f in verdicts["serial0"].failed if f.startswith(f"{FIELD} fails (statistic ")], \
        verdicts["serial0"].line()
    assert "p " in verdicts["serial0"].line() and "model checks not run: thermal hysteresis" in \
        verdicts["serial0"].line()

    # every listing names the judged calibration: T36 for mmc0
    with SessionReader(session) as reader:
        model, judged = judged_fits(reader)
        assert model == "t24" and judged["mmc0"]["model"] == "t36" and judged["serial0"]["model"] == "t24"
        assert "mmc0 (t36)" in judged_cell(model, judged)
        recorded = {(r["dut"], r["model"]) for r in reader.fits()}
        assert ("mmc0", "t36") in recorded
    rows = {(r[0], r[1]) for r in calibration_rows(outcome)}
    assert {("mmc0", "t36 (judged)"), ("mmc0", "t24"), ("serial0", "t24 (judged)")} == rows

    page = session_page(SimpleNamespace(db_url=None, csrf_token="t"), SessionRef(0, session.name, session))
    assert "t36 (judged)" in page and "t24 (judged)" in page
    assert main(["report", str(session), "-o", str(tmp_path / "r")]) == 0
    html = (tmp_path / "r" / "report.html").read_text()
    text = re.sub(r"\s+", " ", unescape(re.sub(r"<[^>]+>", " ", html)))
    assert "the run's T36 calibration (judged instead of the plan's T24: T36 validated better" in text
    assert "T36 chosen" in text  # the temperature model's row among the model checks
    certificate = certificate_html(session, "mmc0")
    assert "T36 (checks.mmc0.t36.yaml)" in certificate and "PASS (t36)" in certificate
    capsys.readouterr()

    # the same fits judged without the model checks: both pass
    off = load_plan(_plan(tmp_path, model_checks=False))
    again = {v.dut: v for v in judge_session(session, off, campaign.station, outcome.fits)}
    assert again["serial0"].passed and again["mmc0"].passed and again["serial0"].not_run == []
