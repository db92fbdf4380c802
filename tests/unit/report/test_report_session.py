"""`rig report` on a session file: figures, tables, warnings and provenance in one self-contained page."""

from __future__ import annotations

import base64
import dataclasses
import hashlib
import re
from html import unescape

import pytest

from rig.cli import main
from rig.report.build import build_report
from rig.report.evaluate import analyse_dut
from rig.report.page import step_table
from rig.report.sources import from_session
from tests.helpers.synthetic_session import SynthOptions, build_session

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    path = tmp_path_factory.mktemp("s") / "run.sqlite"
    opts = SynthOptions(
        temps_c=(-20.0, 10.0, 40.0),
        directions=14,
        samples=3,
        outlier_fraction=0.03,
        saturated_points=("T02-F03",),
        timeout_step=2,
        failed_point="T03-F05",
        seed=7,
    )
    build_session(path, opts)
    return path


@pytest.fixture(scope="module")
def report(session, tmp_path_factory):
    out = tmp_path_factory.mktemp("r")
    page = build_report(session, out_dir=out)
    return page, page.read_text(encoding="utf-8")


def _text(html: str) -> str:
    return re.sub(r"\s+", " ", unescape(re.sub(r"<[^>]+>", " ", html)))


def test_page_is_self_contained(report):
    page, html = report
    sources = re.findall(r'src="([^"]*)"', html)
    assert len(sources) == 5 and all(s.startswith("data:image/png;base64,") for s in sources)
    assert "<script" not in html and "<link" not in html
    pngs = sorted(page.parent.glob("*.png"))
    assert len(pngs) == 5
    embedded = {base64.b64decode(s.split(",", 1)[1]) for s in sources}
    assert {p.read_bytes() for p in pngs} == embedded
    assert all(p.read_bytes().startswith(PNG_MAGIC) for p in pngs)


def test_warnings_name_every_problem(report):
    text = _text(report[1])
    warnings = text[text.index("Data-quality warnings") : text.index("DUT dut1")]
    # from the hold's code, point and device (its wording is free text the report never reads)
    assert "1 settle timeout(s): T02-F01 (dut1: settle timeout)" in warnings
    assert "synthetic settle timeout" not in warnings
    assert "did not reach stability" not in warnings  # it settled on the retake
    assert "1 point(s) failed: T03-F05 (coil compliance fault)" in warnings
    assert "1 sample(s) flagged 'saturated' (not fitted) at points T02-F03" in warnings
    assert re.search(r"\d+ outlier sample\(s\) of the T24 calibration, flagged by the robust fit", warnings)
    assert "direction coverage:" in warnings  # 14 random directions leave gaps


def test_models_steps_and_parameters(report):
    text = _text(report[1])
    assert "5-fold over 41 points" in text  # 3 x 14 points, one failed
    # the run wrote no calibration and its plan cannot be read: one is fitted here, and says so
    assert "residuals shown for a T24 calibration fitted here (robust: true): the run wrote none" in text
    assert "T24: fitted here (robust: true)" in text and "kb_nt_per_c[2]" in text
    comparison = text[text.index("Comparison: models re-fitted here (robust: true)"):]
    assert all(f" {model} " in comparison[:2000] for model in ("T24", "P12", "SCALAR"))
    # step 2: setpoint 10, 14 of 14 points, settled in 1920 s = 32.0 min after one timeout
    assert re.search(r" 2 10 \d+\.\d\d \d+ 14/14 32\.0 yes, after 1 timeout\(s\) ", text)
    assert re.search(r" 3 40 \d+\.\d\d \d+ 13/14 33\.0 yes ", text)


def test_a_step_that_never_settles(tmp_path):
    path = tmp_path / "aborted.session"
    build_session(path, SynthOptions(temps_c=(0.0, 20.0, 40.0), directions=6, samples=1, abort_at_step=3))
    inputs = from_session(path)
    assert inputs.steps[3].stable is False and inputs.steps[3].settle_timeouts == 3
    assert inputs.steps[2].stable is True and inputs.steps[2].settle_s == 1920.0
    text = " | ".join(inputs.warnings)
    assert "temperature step 3 (40 °C) did not reach stability (3 settle timeout(s))" in text
    assert "12 of 18 done; run exit status aborted" in text
    table = step_table(analyse_dut(inputs.duts[0], inputs.steps).steps, inputs.steps)
    assert table.rows[-1][:7] == ["3", "40", "-", "0", "0/6", "-", "NO (3 timeout(s))"]


def test_provenance(report, session):
    text = _text(report[1])
    digest = hashlib.sha256(session.read_bytes()).hexdigest()
    assert f"session file sha256 {digest}" in text
    assert "station simstation" in text and "plan synth" in text
    assert "plan text sha256 " + hashlib.sha256(b"name: synth\n").hexdigest() in text
    assert "recorded with magrig" in text and "report made with magrig" in text


def test_report_cli_on_one_dut(session, tmp_path, capsys):
    assert main(["report", str(session), "--dut", "dut1", "-o", str(tmp_path / "r")]) == 0
    assert "5 figures" in capsys.readouterr().out
    assert main(["report", str(session), "--dut", "nobody", "-o", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no DUT named 'nobody'" in err and str(session) in err


@pytest.mark.parametrize(
    "args, message",
    [
        (["missing.sqlite"], "missing.sqlite: no such file"),
        (["{session}", "--data", "x.csv"], "--data is only for a calibration file"),
        (["{damaged}"], "damaged"),
    ],
)
def test_bad_input_is_one_line(args, message, session, tmp_path, capsys):
    damaged = tmp_path / "damaged.sqlite"
    damaged.write_bytes(session.read_bytes()[:3000])
    argv = (
        ["report"] + [a.format(session=session, damaged=damaged) for a in args] + ["-o", str(tmp_path / "o")]
    )
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err


def test_a_session_without_samples_is_one_line(tmp_path, capsys):
    path = tmp_path / "empty.session"
    build_session(path, SynthOptions(temps_c=(0.0,), directions=6, samples=1, abort_at_step=1))
    assert main(["report", str(path), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err == f"error: {path}: the session holds no samples yet; nothing to report\n"


def test_many_duts_are_drawn_on_every_core_in_order(session, monkeypatch):
    """Four DUTs or more: each DUT's sections come from a worker process, the same as drawn here and in the
    DUTs' order, and the progress names each DUT once."""
    from rig.report import build

    inputs = from_session(session)
    first = analyse_dut(inputs.duts[0], inputs.steps)
    results = [dataclasses.replace(first, name=f"dut{n}") for n in range(build.POOL_MIN_DUTS)]
    here = [build.dut_sections(r, inputs.steps) for r in results]
    monkeypatch.setattr(build.os, "cpu_count", lambda: 2)  # a pool even on a one-core machine
    said = []
    pooled = build.each_dut_sections(results, inputs.steps, said.append)
    assert pooled == here
    assert sorted(s.split()[0] for s in said) == [r.name for r in results]
    assert [s.split(" (")[1] for s in said] == [f"{n} of 4)" for n in range(1, 5)]
