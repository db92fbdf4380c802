"""The sessions the certificate tests read, each run once per test run as a user runs them (the demo on
the default simulated station; the demo on configs/stations/sim-commissioned.yaml; a short demo on the
faulty station with acceptance limits), with `rig certificate` written for every DUT; and what the tests
read back: a PDF's text page by page, a DCC validated against the schema and its values by parameter."""

from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import yaml

from tests.helpers.once import made_once
from tests.system.campaign_helpers import DEMO_PLAN, REPO, quick_demo, run_rig

COMMISSIONED = REPO / "configs" / "stations" / "sim-commissioned.yaml"
FAULTS = REPO / "configs" / "stations" / "sim-faults.yaml"
SCHEMA = REPO / "tests" / "data" / "dcc" / "dcc.xsd"
NS = {"dcc": "https://ptb.de/dcc", "si": "https://ptb.de/si"}


def _run(folder: Path, plan: Path, station: Path | None, pdf_duts: tuple[str, ...]) -> None:
    args = ["run", str(plan), "--out", str(folder)] + (["--station", str(station)] if station else [])
    proc = run_rig(*args, timeout=600)
    assert proc.returncode in (0, 3), proc.stderr[-2000:]  # 3: a DUT failed its acceptance limits
    session = next(folder.glob("*.session"))
    out = folder / "certificates"
    for dut in pdf_duts:  # printed: the marks are read page by page
        proc = run_rig("certificate", str(session), "--dut", dut, "-o", str(out), timeout=600)
        assert proc.returncode == 0, proc.stderr
    others = [a for d in _duts(session) if d not in pdf_duts for a in ("--dut", d)]
    if others:
        proc = run_rig("certificate", str(session), *others, "--no-pdf", "-o", str(out), timeout=600)
        assert proc.returncode == 0, proc.stderr


def _duts(session: Path) -> list[str]:
    from rig.session.reader import SessionReader

    with SessionReader(session) as reader:
        return reader.duts()


def demo(tmp_path_factory) -> Path:
    """`rig run configs/plans/demo.yaml` (station sim.yaml: uncommissioned, no lab: section, no serials)."""
    return made_once(tmp_path_factory, "certificate-demo",
                     lambda folder: _run(folder, DEMO_PLAN, None, ("mmc0",)))


def commissioned(tmp_path_factory) -> Path:
    """The demo on sim-commissioned.yaml: commissioned with a reference whose certificate its file states."""
    return made_once(tmp_path_factory, "certificate-commissioned",
                     lambda folder: _run(folder, DEMO_PLAN, COMMISSIONED, ("dut1",)))


def faulty(tmp_path_factory) -> Path:
    """A short demo on sim-faults.yaml, its chamber also unplugged for a while (the run holds and
    retakes), with acceptance limits the rule judges."""
    def make(folder: Path) -> None:
        plan = quick_demo(folder, name="faulty")
        data = yaml.safe_load(plan.read_text())
        data["acceptance"] = {"max_rms_nt": 1000, "bounds": {"b_nt": [-1500, 1500]}, "model_checks": False}
        plan.write_text(yaml.safe_dump(data, sort_keys=False))
        station = yaml.safe_load(FAULTS.read_text())
        station["chamber"]["transport"]["faults"]["unplug"] = {"after_s": 300, "for_s": 90}  # settling
        path = folder / "station.yaml"
        path.write_text(yaml.safe_dump(station, sort_keys=False))
        _run(folder, plan, path, ())
    return made_once(tmp_path_factory, "certificate-faulty", make)


def copy_run(folder: Path, to: Path) -> Path:
    """A copy of a run's folder (session and calibration files) to change; its session file."""
    shutil.copytree(folder, to, ignore=shutil.ignore_patterns("certificates", "made"))
    return next(to.glob("*.session"))


def pdf_pages(path: Path) -> list[str]:
    """Each page's text with every blank left out (a margin box may break a line anywhere)."""
    import pypdf

    return ["".join(page.extract_text().split()) for page in pypdf.PdfReader(path).pages]


def valid_dcc(path: Path) -> ET.ElementTree:
    """The DCC parsed, after validating it against DCC 3.1.2 offline (the schema files in tests/data/dcc:
    local files only, nothing fetched)."""
    import xmlschema

    schema = xmlschema.XMLSchema(str(SCHEMA), allow="local")
    tree = ET.parse(path)
    errors = list(schema.iter_errors(tree))
    assert not errors, f"{path.name}: {errors[0]}"
    return tree


def dcc_values(tree: ET.ElementTree) -> dict[str, dict[str, tuple]]:
    """{measurement result name: {si:real label: (value, U, k, p) or (value, interval...)}} of a DCC."""
    out: dict[str, dict[str, tuple]] = {}
    for result in tree.getroot().iterfind(".//dcc:measurementResult", NS):
        name = result.find("dcc:name/dcc:content", NS).text
        values = out.setdefault(name, {})
        for real in result.iterfind("dcc:results//si:real", NS):
            label = real.find("si:label", NS).text
            value = float(real.find("si:value", NS).text)
            unc = real.find("si:expandedUnc", NS)
            interval = real.find("si:coverageInterval", NS)
            if unc is not None:
                values[label] = (value, *(float(unc.find(f"si:{k}", NS).text) for k in
                                          ("uncertainty", "coverageFactor", "coverageProbability")))
            elif interval is not None:
                values[f"{label} S1"] = tuple(float(interval.find(f"si:{k}", NS).text) for k in
                                              ("intervalMin", "intervalMax", "coverageProbability"))
            else:
                values[label] = (value,)
    return out
