"""The Digital Calibration Certificate `rig certificate` writes beside each certificate (issue 47 item 5)
and the S1 interval where Monte Carlo decided (item 4): every DCC the demo and the commissioned demo write
is valid against PTB's DCC 3.1.2 schema (offline), and each parameter, its U, k and p and the field's
figures read back from the XML equal the calibration file's; the administrative data name the software,
the identifier, the dates, the item, the laboratory, the persons, the customer and the statements."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from calib.io.digest import sha256_file
from rig.report.certificate_results import COVERAGE_PROBABILITY
from tests.system import certificate_runs as runs
from tests.system.campaign_helpers import run_rig

pytestmark = pytest.mark.system


def _file_values(cal_path) -> dict[str, tuple[float, float, float]]:
    """{the file's label: (value, U, k)} read from the YAML itself (its covariance names the labels)."""
    data = yaml.safe_load(cal_path.read_text())
    u = data["uncertainty"]
    labels = iter(u["covariance"]["parameters"])
    out = {}
    for name, value in data["params"].items():
        each = np.full(np.size(value), u["coverage_factor"])
        factors = np.ravel(u.get("coverage_factors", {}).get(name, each))
        for v, big_u, k in zip(np.ravel(value), np.ravel(u["expanded"][name]), factors, strict=True):
            out[next(labels)] = (float(v), float(big_u), float(k))
    return out


@pytest.mark.parametrize("which", ["demo", "commissioned"])
def test_every_dcc_the_demos_write_is_valid_and_states_the_files_values(which, tmp_path_factory):
    folder = getattr(runs, which)(tmp_path_factory)
    session = next(folder.glob("*.session"))
    dccs = sorted((folder / "certificates").glob("*.dcc.xml"))
    cal_files = sorted(folder.glob("*.yaml"))
    assert len(dccs) == len({p.name.split(".")[1] for p in cal_files}) >= 2
    for dcc in dccs:
        tree = runs.valid_dcc(dcc)
        dut = dcc.name.split(".")[1]
        values = runs.dcc_values(tree)
        for cal_path in sorted(folder.glob(f"*.{dut}.*.yaml")):
            model = cal_path.name.split(".")[2]
            stated = values[f"{model.upper()} calibration of {dut}"]
            for label, (value, big_u, k) in _file_values(cal_path).items():
                assert stated[label] == (value, big_u, k, COVERAGE_PROBABILITY), (dcc.name, label)
            u = yaml.safe_load(cal_path.read_text())["uncertainty"]
            for key in ("expanded_vector_error_nt", "combined_standard_nt", "expanded_norm_error_nt"):
                assert stated[key] == (u[key],), (dcc.name, key)
        root = tree.getroot()
        text = " ".join(t for t in root.itertext())
        assert sha256_file(session) in text  # the session's and every calibration file's sha256
        assert all(sha256_file(p) in text for p in folder.glob(f"*.{dut}.*.yaml"))
        core = root.find(".//dcc:coreData", runs.NS)
        assert core.find("dcc:uniqueIdentifier", runs.NS).text.startswith(f"{session.stem}/{dut}/")
        assert core.find("dcc:receiptDate", runs.NS).text == "2026-11-20"  # the plan's `received:`
        assert root.find(".//dcc:customer/dcc:name/dcc:content", runs.NS).text == "Example Spacecraft Ltd"
        statements = root.findall(".//dcc:statement", runs.NS)
        simulated = [s for s in statements if s.find("dcc:valid", runs.NS) is not None]
        assert len(simulated) == 1 and simulated[0].find("dcc:valid", runs.NS).text == "false"
        assert "NOT VALID: SIMULATED STATION" in " ".join(simulated[0].itertext())
        traceable = [s.find("dcc:traceable", runs.NS).text for s in statements
                     if s.find("dcc:traceable", runs.NS) is not None]
        assert traceable == (["true"] if which == "commissioned" else ["false"])


def test_the_commissioned_dcc_names_the_laboratory_item_and_reference_certificate(tmp_path_factory):
    folder = runs.commissioned(tmp_path_factory)
    root = runs.valid_dcc(next((folder / "certificates").glob("*.dut3.dcc.xml"))).getroot()

    def first(path):
        return root.find(path, runs.NS).text

    assert first(".//dcc:coreData/dcc:countryCodeISO3166_1") == "DE"
    assert first(".//dcc:calibrationLaboratory/dcc:calibrationLaboratoryCode") == "D-K-00000-01-00"
    assert first(".//dcc:respPerson/dcc:person/dcc:name/dcc:content") == "A. Example"
    ids = {i.find("dcc:issuer", runs.NS).text: i.find("dcc:value", runs.NS).text
           for i in root.iterfind(".//dcc:item/dcc:identifications/dcc:identification", runs.NS)}
    assert ids == {"manufacturer": "MMC-24-0003", "calibrationLaboratory": "dut3"}
    assert first(".//dcc:item/dcc:manufacturer/dcc:name/dcc:content") == "MEMSIC"
    certificate = root.find(".//dcc:measuringEquipment/dcc:certificate", runs.NS)
    assert certificate.find("dcc:referralID", runs.NS).text == "EX-MAG-2026-0117"
    ranges = {c.find("dcc:name/dcc:content", runs.NS).text: [float(v.text) for v in c.iterfind(
        ".//si:value", runs.NS)] for c in root.iterfind(".//dcc:influenceCondition", runs.NS)}
    low, high = ranges["temperature of the DUT"]
    assert -21 < low < -19 and 59 < high < 61  # the demo's -20 .. 60 degC steps, as the DUT reached them
    assert all(45_000 < b < 55_000 for b in ranges["magnitude of the reference field"])  # 50 uT directions


def test_no_dcc_leaves_it_out(tmp_path_factory, tmp_path):
    session = next(runs.demo(tmp_path_factory).glob("*.session"))
    proc = run_rig("certificate", str(session), "--dut", "mmc0", "--no-pdf", "--no-dcc", "-o", str(tmp_path))
    assert proc.returncode == 0, proc.stderr
    assert [p.suffix for p in tmp_path.iterdir()] == [".html"]


def test_where_monte_carlo_decided_the_s1_interval_stands_beside_u(tmp_path_factory, tmp_path):
    """A calibration file of format 3 that states its S1 interval (the shortest, here): the certificate
    gives it beside U = k u and says which kind, and the DCC carries it as si:coverageInterval, at the one
    coverage probability of the file, the certificate and the DCC."""
    session = runs.copy_run(runs.demo(tmp_path_factory), tmp_path / "run")
    cal_path = session.with_name(session.name.replace(".session", ".mmc0.t24.yaml"))
    data = yaml.safe_load(cal_path.read_text())
    u = data["uncertainty"]
    u["coverage_probability"] = COVERAGE_PROBABILITY
    u["monte_carlo"] = {"draws": 20000, "converged": True}
    shift = {name: (np.asarray(v, float) * 1e-3).tolist() for name, v in u["expanded"].items()}
    u["s1_interval"] = {"kind": "shortest", "probability": COVERAGE_PROBABILITY,
                        "parameters": {name: [(np.asarray(data["params"][name]) - np.asarray(big_u)
                                               + np.asarray(shift[name])).tolist(),
                                              (np.asarray(data["params"][name]) + np.asarray(big_u)).tolist()]
                                       for name, big_u in u["expanded"].items()},
                        "vector_radius_nt": 2404.0}
    cal_path.write_text(yaml.safe_dump(data, sort_keys=False))
    proc = run_rig("certificate", str(session), "--dut", "mmc0", "--no-pdf", "-o", str(tmp_path / "out"))
    assert proc.returncode == 0, proc.stderr
    html = next((tmp_path / "out").glob("*.html")).read_text()
    assert "S1 coverage interval" in html
    assert "interval from the draws (column S1 coverage interval): the shortest interval holding" in html
    assert "the calibrated field&#x27;s S1 radius 2404 nT" in html
    assert "mmc0.t24.yaml labels its uncertainty" not in html  # its probability is the certificate's
    dcc = runs.valid_dcc(next((tmp_path / "out").glob("*.dcc.xml")))
    values = runs.dcc_values(dcc)["T24 calibration of mmc0"]
    lows, highs = (np.ravel(np.concatenate([np.ravel(v[i]) for v in u["s1_interval"]["parameters"].values()]))
                   for i in (0, 1))
    labels = u["covariance"]["parameters"]
    for label, low, high in zip(labels, lows, highs, strict=True):
        assert values[f"{label} S1"] == (low, high, COVERAGE_PROBABILITY)
        assert values[label][3] == COVERAGE_PROBABILITY
    assert values["s1_interval.vector_radius_nt"] == (2404.0,)
    assert math.isclose(COVERAGE_PROBABILITY, 0.9545)
