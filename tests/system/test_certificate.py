"""`rig certificate` against ISO/IEC 17025:2017 7.8 (issue 47 items 1-3): the refusals, the marks on every
page (HTML and every page of the PDF), every 7.8.2.1/7.8.4.1 item from the station's `lab:`, the DUTs'
serials and the plan's customer, received and condition (and, without them, what is not stated on every
page), the measurand in the file's own numbering, the as-found errors with their U, the run's deviations,
the ILAC-G8 decision rule, the traceability chain with and without a reference certificate, the ids and
sha256; and the page as the cockpit's headless browser renders it."""

from __future__ import annotations

import dataclasses
import html
import re

import numpy as np
import pytest
import yaml

from calib.io.digest import sha256_file
from rig.report import decision_rule
from rig.report.build import write_certificates
from rig.report.certificate import certificate_of
from rig.report.certificate_record import gather, session_record
from rig.report.traceability import assess
from rig.session.reader import SessionReader
from tests.system import browser
from tests.system import certificate_runs as runs
from tests.system.campaign_helpers import run_rig

pytestmark = pytest.mark.system


def _text(page, section: str | None = None) -> str:
    """The page's text, or one section's (from its heading to the next), blanks made one."""
    markup = page.read_text()
    if section is not None:
        markup = markup.split(f"<h2>{section}</h2>", 1)[1].split("<h2>", 1)[0]
    return re.sub(r"\s+", " ", html.unescape(re.sub(r"<[^>]+>", " ", markup)))


def _refused(session, tmp_path) -> str:
    out = tmp_path / "out"
    proc = run_rig("certificate", str(session), "--dut", "mmc0", "-o", str(out))
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    assert not out.exists() or not list(out.iterdir())  # nothing written
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    return lines[0]


def test_a_calibration_without_uncertainty_missing_inputs_or_chain_is_refused(tmp_path_factory, tmp_path):
    folder = runs.demo(tmp_path_factory)
    session = runs.copy_run(folder, tmp_path / "a")
    cal = session.with_name(session.stem + ".mmc0.t24.yaml")
    data = yaml.safe_load(cal.read_text())
    cal.write_text(yaml.safe_dump({k: v for k, v in data.items() if k != "uncertainty"}, sort_keys=False))
    assert f"{cal.name}: no uncertainty: section" in _refused(session, tmp_path / "a")

    session = runs.copy_run(folder, tmp_path / "b")
    cal = session.with_name(session.stem + ".mmc0.t24.yaml")
    data["uncertainty"]["missing"] = [{"source": "ambient", "key": "field_source.ambient_u_nt",
                                       "why": "stated without an uncertainty"}]
    cal.write_text(yaml.safe_dump(data, sort_keys=False))
    line = _refused(session, tmp_path / "b")
    assert f"{cal.name}: uncertainty.missing: " in line and "ambient (field_source.ambient_u_nt)" in line
    links, refused = write_certificates(session, ["mmc0", "serial0"], tmp_path / "b" / "report")
    assert [name for _, name in links] == [f"{session.stem}.serial0.certificate.html"]  # the report goes on
    assert refused == [line.removeprefix("error: ")]

    session = runs.copy_run(folder, tmp_path / "d")  # a U that is not a number: calib refuses the file
    cal = session.with_name(session.stem + ".mmc0.t24.yaml")
    broken = yaml.safe_load(cal.read_text())
    broken["uncertainty"]["expanded"]["b_nt"][1] = float("nan")
    cal.write_text(yaml.safe_dump(broken, sort_keys=False))
    assert f"{cal.name}: key 'uncertainty.expanded.b_nt' must have" in _refused(session, tmp_path / "d")

    session = runs.copy_run(folder, tmp_path / "c")  # a CSV refit written over the run's calibration
    csv = tmp_path / "mmc0.csv"
    assert run_rig("export", str(session), "--csv", "--dut", "mmc0", "-o", str(csv)).returncode == 0
    cal = session.with_name(session.stem + ".mmc0.t24.yaml")
    cal.unlink()
    assert run_rig("refit", str(csv), "--model", "t24", "-o", str(cal)).returncode == 0
    line = _refused(session, tmp_path / "c")
    assert f"{cal.name}: no reference chain: it was fitted from csv" in line


def test_every_page_carries_the_id_the_marks_and_what_is_not_stated(tmp_path_factory):
    demo, commissioned = runs.demo(tmp_path_factory), runs.commissioned(tmp_path_factory)
    for folder, dut, marks, absent in (
            (demo, "mmc0", ["NOT VALID: SIMULATED STATION", "NOT TRACEABLE", "NOT STATED: lab.name"],
             []),
            (commissioned, "dut1", ["NOT VALID: SIMULATED STATION"], ["NOT TRACEABLE", "NOT STATED"])):
        page = next((folder / "certificates").glob(f"*.{dut}.certificate.html"))
        banner = page.read_text().split('<div class="marks">', 1)[1].split("</div>", 1)[0]
        ident = re.search(r"Certificate (\S+/\S+/[0-9a-f]{8})<", banner).group(1)
        assert all(m in banner for m in marks) and not any(a in banner for a in absent), banner
        pdf = page.with_suffix(".pdf")
        if not pdf.is_file():
            pytest.skip(f"no PDF printed here: {browser.missing() or 'no renderer'}")
        pages = runs.pdf_pages(pdf)
        assert len(pages) > 3
        for number, text in enumerate(pages, 1):
            assert f"page{number}of{len(pages)}" in text and f"Certificate{ident}" in text, number
            assert all("".join(m.split()) in text for m in marks), number
            assert not any("".join(a.split()) in text for a in absent), number
    demo_text = _text(next((demo / "certificates").glob("*.mmc0.certificate.html")))
    assert ("NOT STATED: lab.name, lab.address, lab.country, lab.accreditation_id, lab.place_of_work, "
            "lab.procedure_id, lab.responsible, duts[mmc0].serial") in demo_text
    assert "customer" not in demo_text.split("NOT STATED: ", 1)[1].split(" Calibration certificate", 1)[0]


def test_the_certificate_states_every_item_of_7_8(tmp_path_factory):
    folder = runs.commissioned(tmp_path_factory)
    session = next(folder.glob("*.session"))
    text = _text(next((folder / "certificates").glob("*.dut1.certificate.html")))
    station = yaml.safe_load(runs.COMMISSIONED.read_text())
    lab = station["lab"]
    for fact in (lab["name"], lab["address"], lab["accreditation_id"], lab["place_of_work"],
                 lab["procedure_id"], "A. Example, head of the calibration laboratory",
                 "serial number MMC-24-0001 (the station (duts[].serial))", "Example Spacecraft Ltd",
                 "order PO-2026-0042", "received 2026-11-20", "in sealed ESD bags",
                 "condition when received as received",
                 "by MEMSIC", "sampling none: the item itself was calibrated",
                 "This certificate recommends no calibration interval"):
        assert fact in text, fact
    # the measurand, each item with what states it (the file's own keys, or the session's record)
    measurand = _text(next((folder / "certificates").glob("*.dut1.certificate.html")), "Measurand")
    said_by = r"(?:the calibration file|the session's record|this certificate)"
    rows = dict(re.findall(r"(how h was read|the thermometer that gave tau|frames of B and h|index order) "
                           rf"(.*?) {said_by}", measurand))
    assert "MMC5983MA" in rows["how h was read"] and "SET" in rows["how h was read"]
    assert all(f in rows["the thermometer that gave tau"] for f in ("tmp1", "tmp117", "beside dut1"))
    assert rows["frames of B and h"].startswith("B: the station's field frame")
    assert "h: the DUT's axes as its driver reports them" in rows["frames of B and h"]
    assert "M[row][column], zero-based" in rows["index order"]
    assert "equation B = (S + tau K) h + b_nt + tau kb_nt_per_c" in measurand
    assert "S (3x3) dimensionless; K (3x3) in 1/°C; b_nt (3) in nT; kb_nt_per_c (3) in nT/°C" in measurand
    # the results in the file's own numbering, in its order
    cal = folder / f"{session.stem}.dut1.t24.yaml"
    labels = yaml.safe_load(cal.read_text())["uncertainty"]["covariance"]["parameters"]
    results = _text(next((folder / "certificates").glob("*.dut1.certificate.html")), "Results")
    shown = re.findall(r"T24 ((?:S|K|b_nt|kb_nt_per_c)\[\d\](?:\[\d\])?) ", results)
    assert shown[:len(labels)] == labels
    # the sha256 of the session file and of every calibration file
    assert f"sha256 {sha256_file(session)}" in text
    for cal in folder.glob(f"{session.stem}.dut1.*.yaml"):
        assert f"{cal.name}, sha256 {sha256_file(cal)}" in text


def test_as_found_errors_are_the_raw_readings_against_the_reference_with_their_u(tmp_path_factory):
    session = next(runs.demo(tmp_path_factory).glob("*.session"))
    c = certificate_of(session, "mmc0")
    with SessionReader(session) as reader:
        ds = reader.dataset("mmc0")
    ids = np.asarray(ds.columns["point"])
    assert [a.point for a in c.as_found] == list(dict.fromkeys(ids.tolist()))  # every point, in order
    ambient = np.array(yaml.safe_load(runs.REPO.joinpath("configs/stations/sim.yaml").read_text())
                       ["field_source"]["ambient_nt"])
    for a in c.as_found:
        rows = ids == a.point
        assert np.allclose(a.error_nt, (ds.h_nt[rows] - ds.ref_nt[rows]).mean(axis=0), atol=1e-9)
    # sim.yaml's coils are declared to 1 % of 50 000 nT/A per element: the reference field's U per axis is
    # 2 x 1 % of the currents' field |B_ref - ambient|, which grows with it; what U holds beyond (the
    # reading's scatter, a stated ambient's uncertainty) is the same at every point
    declared = np.array([[2 * 0.01 * np.linalg.norm(a.reference_nt - ambient)] * 3 for a in c.as_found])
    expanded = np.array([a.expanded_nt for a in c.as_found])
    assert np.all(expanded >= declared)
    beyond = np.sqrt(expanded**2 - declared**2)
    assert np.all(np.ptp(beyond, axis=0) <= 10 + 0.05 * beyond.mean(axis=0)), beyond
    assert np.ptp(declared) > 100  # the points' fields differ enough for a wrong share to show
    page = next((runs.demo(tmp_path_factory) / "certificates").glob("*.mmc0.certificate.html"))
    assert all(a.point in _text(page, "As found") for a in c.as_found)


def test_deviations_and_the_decision_rule_are_stated(tmp_path_factory):
    folder = runs.faulty(tmp_path_factory)
    session = next(folder.glob("*.session"))
    with SessionReader(session) as reader:
        events = reader.events()
    holds = [e for e in events if e.kind == "hold"]
    assert "device_timeout" in {e.code.value for e in holds}
    page = next((folder / "certificates").glob("*.mmc0.certificate.html"))
    said, text = _text(page, "Deviations"), _text(page, "Statement of conformity")
    for kind in ("hold", "warning"):  # each kind's counts add up to the session's events of that kind
        counted = re.findall(kind + r": [a-z ]+(?: \([a-z0-9]+\))? (\d+) ", said)
        assert sum(map(int, counted)) == sum(e.kind == kind for e in events) > 0, kind
    assert "ILAC-G8:09/2019 guarded acceptance with guard band w = U" in text
    assert re.search(r"bounds\.b_nt every element within \[-1500, 1500\] nT .* w = U of each element "
                     r"\(the calibration file's uncertainty\.expanded\) (PASS|CONDITIONAL|FAIL) ", text)
    assert re.search(r"fit_rms <= 1000 nT \S+ nT w = 0: no uncertainty is stated for this figure PASS", text)


def test_the_rule_gives_pass_conditional_and_fail_on_a_real_calibration(tmp_path_factory):
    """The faulty run's T24 b_nt judged against bounds placed around its own values and U."""
    session = next(runs.faulty(tmp_path_factory).glob("*.session"))
    recorded = session_record(session)
    record = gather(session, "mmc0", recorded)
    b = np.asarray(record.cals["t24"].cal.params["b_nt"])
    big_u = np.asarray(record.cals["t24"].uncertainty["expanded"]["b_nt"])
    outcomes = {}
    for label, (low, high) in {"pass": (b.min() - 2 * big_u.max(), b.max() + 2 * big_u.max()),
                               "conditionalPass": (b.min() - big_u.min() / 2, b.max() + 2 * big_u.max()),
                               "conditionalFail": (b.min() + big_u.min() / 2, b.max() + 2 * big_u.max()),
                               "fail": (b.min() + 2 * big_u.max(), b.max() + 3 * big_u.max())}.items():
        acceptance = record.plan.acceptance.model_copy(update={"bounds": {"b_nt": (low, high)}})
        plan = record.plan.model_copy(update={"acceptance": acceptance})
        judged = decision_rule.judge(dataclasses.replace(record, recorded={**recorded, "plan": plan}))
        outcomes[label] = next(c.conformity for c in judged if c.name == "bounds.b_nt")
    assert outcomes == {k: k for k in outcomes}


def test_the_chain_to_the_si_and_what_breaks_it(tmp_path_factory):
    commissioned = next(runs.commissioned(tmp_path_factory).glob("*.session"))
    recorded = session_record(commissioned)
    chain = assess(gather(commissioned, "dut2", recorded))
    assert chain.traceable and chain.why_not == ""
    said = " ".join(f"{a}: {b}" for a, b in chain.links)
    for fact in ("SI: the tesla", "EX-MAG-2026-0117 of 2026-01-01 by Example Magnetometry Calibration",
                 "U = 3 nT (k = 2", "reference magnetometer ref0: mmc5983ma, serial REF-0001",
                 "sim-reference-cal-certified.yaml (sha256 ", "commissioning: ",
                 "temperature (tau): tmp2: +-0.15 degC"):
        assert fact in said, fact
    # the same chain with the reference's certificate taken out of its recorded calibration
    refs = {name: {**data, "source": {k: v for k, v in data["source"].items() if k != "certificate"}}
            for name, data in recorded["chain"]["reference_calibrations"].items()}
    bare = {**recorded, "chain": {**recorded["chain"], "reference_calibrations": refs}}
    chain = assess(gather(commissioned, "dut2", bare))
    assert not chain.traceable
    assert "ref0: its calibration file states no calibration certificate" in chain.why_not
    demo = next(runs.demo(tmp_path_factory).glob("*.session"))
    chain = assess(gather(demo, "mmc0"))
    assert not chain.traceable and "the field source was not commissioned" in chain.why_not


def test_the_certificate_renders_in_the_headless_browser(tmp_path_factory):
    if (why := browser.missing()) is not None:
        pytest.skip(why)
    page = next((runs.commissioned(tmp_path_factory) / "certificates").glob("*.dut1.certificate.html"))
    with browser.headless_page() as (tab, errors):
        tab.goto(page.resolve().as_uri())
        shown = tab.inner_text("body")
        banner = tab.inner_text("div.marks")
        assert not errors, errors
    from rig.report.certificate import ITEMS

    assert all(item in shown for item in ITEMS)
    assert "NOT VALID: SIMULATED STATION" in banner and "NOT TRACEABLE" not in banner


def test_the_measurand_keys_a_file_states_are_quoted(tmp_path_factory, tmp_path):
    """A calibration file with the measurand's own keys (issue 46's `reading`, `tau_source`, `frame`,
    `indexing`, `reference_chain`): the certificate quotes them, and a chain the file calls not traceable
    is NOT TRACEABLE whatever the session says."""
    session = runs.copy_run(runs.commissioned(tmp_path_factory), tmp_path / "run")
    cal = session.with_name(session.stem + ".dut1.t24.yaml")
    data = yaml.safe_load(cal.read_text())
    data |= {"reading": {"device": {"name": "dut1", "model": "MMC5983MA", "serial": "MMC-24-0001"},
                         "mode": "set_reset_pair", "mode_text": "H = (H_SET - H_RESET) / 2",
                         "raw_unit": "nT", "samples_averaged": 1},
             "tau_source": {"device": {"name": "tmp1", "type": "tmp117"}, "place": "beside dut1",
                            "unit": "degC"},
             "frame": {"B": {"name": "station", "text": "the coil axes as mounted"},
                       "h": {"name": "sensor", "text": "the DUT's axes"}},
             "indexing": {"matrices": "M[row][column], zero-based"},
             "reference_chain": {"traceable": False, "text": "a test of the file's word"}}
    cal.write_text(yaml.safe_dump(data, sort_keys=False))
    c = certificate_of(session, "dut1")
    assert not c.chain.traceable and "reference_chain: a test of the file's word" in c.chain.why_not
    from rig.report.certificate import certificate_html

    text = re.sub(r"\s+", " ", html.unescape(re.sub(r"<[^>]+>", " ", certificate_html(session, "dut1",
                                                                                      certificate=c))))
    assert "mode: set_reset_pair; mode_text: H = (H_SET - H_RESET) / 2" in text
    assert "the calibration file (reading:)" in text and "the calibration file (tau_source:)" in text
    assert "B: the coil axes as mounted; h: the DUT's axes the calibration file (frame:)" in text
    assert "matrices: M[row][column], zero-based the calibration file (indexing:)" in text
