"""End to end on a two-DUT session: report, calibration export for firmware, session listing."""

from __future__ import annotations

import csv
import re

import numpy as np
import pytest

from rig.cli import main
from rig.fieldsources import fieldsets
from tests.helpers.synthetic_session import SynthOptions, build_session
from tests.unit.report.ccheck import max_relative_error, run_header

pytestmark = pytest.mark.system


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """8 temperatures x the full campaign's 48 field vectors x 5 samples x 2 DUTs, through the store API."""
    path = tmp_path_factory.mktemp("sys") / "campaign.session"
    vectors = fieldsets.scaled(fieldsets.cube24_directions(), [30_000.0, 60_000.0])
    temps_c = (-30.0, -15.0, 0.0, 15.0, 25.0, 40.0, 55.0, 70.0)
    opts = SynthOptions(
        temps_c=temps_c,
        field_vectors_nt=vectors,
        samples=5,
        duts=("dutA", "dutB"),
        outlier_fraction=0.005,
        saturated_points=("T04-F10",),
        timeout_step=5,
        seed=3,
    )
    truths = build_session(path, opts)
    return path, truths


def test_report_covers_both_duts(session, tmp_path, capsys):
    path, _ = session
    assert main(["report", str(path), "-o", str(tmp_path)]) == 0
    assert "10 figures" in capsys.readouterr().out
    html = (tmp_path / "report.html").read_text(encoding="utf-8")
    assert html.count('src="data:image/png;base64,') == 10
    for dut in ("dutA", "dutB"):
        assert f"DUT {dut}</h2>" in html
        assert (tmp_path / f"{dut}_residuals_vs_temperature.png").stat().st_size > 10_000
    assert "5-fold over 384 points" in html
    # an evenly spread design at 8 temperatures: no coverage warning, one settle timeout (step 5)
    assert "direction coverage:" not in html
    assert "1 settle timeout(s)" in html


def test_refit_export_and_firmware_apply_agree(session, tmp_path, capsys):
    path, truths = session
    cal = tmp_path / "dutB.yaml"
    data = tmp_path / "dutB.csv"
    assert main(["refit", str(path), "--dut", "dutB", "--robust", "-o", str(cal)]) == 0
    assert main(["export", str(path), "--dut", "dutB", "-o", str(data)]) == 0
    assert main(["apply", str(cal), str(data), "-o", str(tmp_path / "applied.csv")]) == 0
    assert main(["export-cal", str(cal), "--format", "c-header", "-o", str(tmp_path / "dutb.h")]) == 0
    with open(data) as f:
        rows = list(csv.DictReader(f))
    h = np.array([[float(r["hx"]), float(r["hy"]), float(r["hz"])] for r in rows])
    temp = np.array([float(r["temp"]) for r in rows])
    with open(tmp_path / "applied.csv") as f:
        applied = np.array([[float(r["bx"]), float(r["by"]), float(r["bz"])] for r in csv.DictReader(f)])
    from_c = run_header((tmp_path / "dutb.h").read_text(), "dutb", h, temp, tmp_path)
    assert max_relative_error(from_c, applied) < 1e-6
    # and the exported calibration is the truth to within the noise
    ref = np.array([[float(r["bx"]), float(r["by"]), float(r["bz"])] for r in rows])
    # 10 nT noise per axis: the median error vector is ~15 nT long (a few outliers aside)
    assert np.median(np.linalg.norm(from_c - ref, axis=1)) < 20.0
    np.testing.assert_allclose(from_c, truths["dutB"].apply(h, temp), atol=60.0)
    capsys.readouterr()


def test_report_from_the_exported_calibration(session, tmp_path, capsys):
    path, _ = session
    cal, data = tmp_path / "a.yaml", tmp_path / "a.csv"
    assert main(["export", str(path), "--dut", "dutA", "-o", str(data)]) == 0
    assert main(["refit", str(data), "--model", "t24", "--robust", "-o", str(cal)]) == 0
    assert main(["report", str(cal), "--data", str(data), "--dut", "dutA", "-o", str(tmp_path / "r")]) == 0
    html = (tmp_path / "r" / "report.html").read_text(encoding="utf-8")
    assert "given in the calibration file" in html and "is not the file" not in html
    rms_after = float(
        re.search(
            r"<td>dutA</td><td>T24</td><td>\d+</td><td>vector</td><td>[\d.]+</td>"
            r"<td>([\d.]+)</td>",
            html,
        ).group(1)
    )
    assert 9.0 < rms_after < 11.0  # the injected noise is 10 nT per axis
    capsys.readouterr()


def test_sessions_lists_it(session, capsys):
    path, _ = session
    assert main(["sessions", str(path.parent)]) == 0
    line = capsys.readouterr().out.splitlines()[1]
    assert line.startswith("campaign.session") and "dutA,dutB" in line and "384/384" in line


def test_report_of_a_simulated_campaign(tmp_path, capsys):
    """The demo plan run by the campaign engine on the simulated station, then reported."""
    from drivers.clock import SimClock
    from rig.config.loading import load_campaign
    from rig.run.campaign import run_campaign

    session = tmp_path / "demo.session"
    outcome = run_campaign(
        campaign=load_campaign("configs/plans/demo.yaml"), session_path=session, clock=SimClock()
    )
    assert outcome.result.status == "completed"
    assert main(["report", str(session), "--dut", "mmc0", "-o", str(tmp_path / "r")]) == 0
    html = (tmp_path / "r" / "report.html").read_text(encoding="utf-8")
    text = re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", html))
    assert "DUT mmc0 " in text and "DUT serial0" not in text  # --dut: that DUT only
    # every step settled (the campaign's settle statistics), 26 of 26 points of 5 samples each
    steps = re.findall(r" (\d) (-?\d+) -?\d+\.\d\d 130 26/26 (\d+\.\d) yes ", text)
    assert [(s, t) for s, t, _ in steps[:4]] == [("1", "-20"), ("2", "0"), ("3", "25"), ("4", "60")]
    assert all(float(minutes) > 1 for _, _, minutes in steps)
    assert "station sim (configs/stations/sim.yaml): every device simulated (chamber, coils" in text
    assert "device mmc0 MMC5983MA" in text  # the device snapshots the campaign recorded
    summary = re.search(
        r"<td>mmc0</td><td>T24 \(the run&#x27;s\)</td><td>520</td><td>vector</td><td>[\d.]+</td>"
        r"<td>([\d.]+)</td>", html
    )
    assert float(summary.group(1)) < 60  # the simulated noise is 40 nT per axis
    # the demo's fields let every model of its plan be fitted and checked on held-out points
    assert "could not be fitted" not in text and "cannot be fitted" not in text
    comparison = text[text.index("Comparison: models re-fitted here (robust: false)"):]
    assert re.search(r" T24 [\d.]+ [\d.]+ [\d.]+ [\d.]+ 5 ", comparison)
    assert re.search(r" P12 [\d.]+ [\d.]+ [\d.]+ [\d.]+ 5 ", comparison)
    assert "linearity in temperature holds" in text
    capsys.readouterr()
