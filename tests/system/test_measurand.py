"""Issue 46, "the file is the whole truth for firmware", on real demo runs on the simulated station: every
calibration file a run writes states its measurand from what the session recorded of its devices; its
source.sha256 is the session file's, and the report, the exports and a refit cite that same pair; the
report's labels say what each number is; and a small script reading only the file's stated keys gives what
`rig apply` gives, for T24, T36, P12 and the scalar fit."""

from __future__ import annotations

import csv
import html
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from calib.io import calfile
from calib.io.digest import sha256_file
from tests.helpers.once import made_once
from tests.system.campaign_helpers import REPO, SIM_STATION, quick_demo, run_rig, small_plan
from tests.unit.report.ccheck import max_relative_error, run_header

pytestmark = pytest.mark.system

SCRIPT = REPO / "examples" / "apply_from_file.py"
MODELS = ("t24", "p12", "scalar")


def _make_demo(folder: Path) -> None:
    """The demo plan at three temperatures (T36 needs them) and two samples a point, fitting T24, P12 and
    the scalar model; then a T36 refit of mmc0 and its samples exported."""
    plan_path = quick_demo(folder, steps=(-20, 20, 60), samples=2)
    plan = yaml.safe_load(plan_path.read_text())
    plan["fit"]["models"] = list(MODELS)
    plan_path.write_text(yaml.safe_dump(plan, sort_keys=False))
    done = run_rig("run", str(plan_path), "--station", str(SIM_STATION), "--out", str(folder / "sessions"),
                   timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    session = next((folder / "sessions").glob("*.session"))
    t36 = folder / "mmc0.t36.yaml"
    for args in (("refit", str(session), "--dut", "mmc0", "--model", "t36", "-o", str(t36)),
                 ("export", str(session), "--csv", "--dut", "mmc0", "-o", str(folder / "mmc0.csv"))):
        done = run_rig(*args, timeout=300)
        assert done.returncode == 0, done.stderr[-3000:]
        (folder / f"{args[0]}.out").write_text(done.stdout)


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> Path:
    return made_once(tmp_path_factory, "measurand-demo", _make_demo)


def _session(demo: Path) -> Path:
    return next((demo / "sessions").glob("*.session"))


def _files(demo: Path) -> dict[tuple[str, str], Path]:
    return {(p.name.split(".")[-3], p.name.split(".")[-2]): p for p in (demo / "sessions").glob("*.yaml")}


def test_every_file_states_its_measurand_from_the_session(demo):
    files = _files(demo)
    assert set(files) == {(dut, m) for dut in ("mmc0", "serial0") for m in MODELS}
    for (dut, model), path in files.items():
        cal = calfile.load(path)
        assert cal.format_version == 3 and cal.missing_measurand() == [], path
        device, tau = cal.reading["device"], cal.tau_source
        assert device["name"] == dut and cal.reading["mode"] == "set_reset_pair"  # the demo's set_reset: pair
        assert cal.reading["raw_unit"] == "nT" and cal.reading["samples_averaged"] == 1
        if dut == "mmc0":
            assert device["type"] == "mmc5983ma" and device["product_id"] == "0x30"
            assert "(code - 131072) / 16384 * 100000" in cal.reading["conversion"]
            assert cal.reading["settings"]["bandwidth_hz"] == 100
        else:
            assert device["type"] == "serialmag" and device["serial"] == "SM2300-0001"
            assert "counts / 15000 * 100000" in cal.reading["conversion"]
            assert cal.reading["settings"]["rate_hz"] == 50
        sensor = {"mmc0": "tmp0", "serial0": "tmp1"}[dut]  # the station's temp_source, not the chip's own
        assert tau["device"]["name"] == sensor and tau["device"]["model"] == "TMP117"
        assert tau["place"] == f"beside {dut}" and tau["unit"] == "degC" and tau["lag_corrected_s"] is None
        assert cal.frame["h"]["name"] == "sensor"
        if model == "scalar":
            assert cal.frame["B"]["name"] == "sensor_aligned"
        else:
            assert cal.frame["B"]["name"] == "station" and "coil axes" in cal.frame["B"]["text"]
        assert cal.reference_chain["traceable"] is False and "not commissioned" in cal.reference_chain["text"]
        assert "sim" not in json.dumps(cal.reading)  # from the describe() snapshot, not the station's sim:


def test_source_sha256_is_the_session_file_and_every_output_cites_it(demo, tmp_path):
    session = _session(demo)
    digest = sha256_file(session)
    assert not Path(f"{session}-wal").exists()
    for path in _files(demo).values():
        source = calfile.load(path).source
        assert Path(source["path"]).resolve() == session.resolve() and source["sha256"] == digest, path
    t24 = _files(demo)[("mmc0", "t24")]
    assert calfile.load(demo / "mmc0.t36.yaml").source["sha256"] == digest  # a refit of the closed session
    done = run_rig("report", str(session), "--dut", "mmc0", "-o", str(tmp_path / "report"), timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    page = html.unescape((tmp_path / "report" / "report.html").read_text())
    assert f"session file sha256 {digest}" in " ".join(re.sub("<[^>]+>", " ", page).split())
    assert "hashes" not in page  # no calibration cites another hash
    for fmt in ("c-header", "json", "csv"):
        done = run_rig("export-cal", str(t24), "--format", fmt, timeout=120)
        assert done.returncode == 0 and digest in done.stdout and str(session.name) in done.stdout, fmt
    exported = json.loads(run_rig("export-cal", str(t24), "--format", "json").stdout)
    assert exported["source"]["sha256"] == digest and exported["reading"]["mode"] == "set_reset_pair"


def test_the_report_labels_each_number_for_what_it_is(demo, tmp_path):
    session = _session(demo)
    done = run_rig("report", str(session), "--dut", "mmc0", "-o", str(tmp_path / "report"), timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    page = html.unescape((tmp_path / "report" / "report.html").read_text())
    u = calfile.load(_files(demo)[("mmc0", "t24")]).uncertainty
    cells = {m.group(1): m.group(2) for m in re.finditer(r"<tr><td>([^<]+)</td><td>([^<]+)</td>", page)}
    k, standard = u["coverage_factor"], u["combined_standard_nt"]
    assert cells["combined standard uncertainty u"] == f"{standard:.3g}"
    assert cells[f"expanded uncertainty U = k u (k = {k:.3g})"] == f"{k * standard:.3g}"  # K times u
    radius = cells["95 % error radius (nT, largest over the plan's grid)"]
    assert radius == f"{u['expanded_vector_error_nt']:.3g}" and float(radius) != float(f"{k * standard:.3g}")
    assert "<td>S[0][0]</td>" in page and "<td>S[2][2]</td>" in page and "S[3][3]" not in page
    assert "<td>kb_nt_per_c[2]</td>" in page and "kb_nt_per_c[3]" not in page
    comparison = page[page.index("Comparison: models re-fitted here"):]
    row = r"<tr><td>(\d)</td><td>(T24|P12|SCALAR)</td>(?:<td>[^<]*</td>){3}<td>([^<]+)</td>"
    ranked = re.findall(row, comparison)
    held_out = [float(r[2]) for r in ranked if r[2] != "-"]
    assert [r[0] for r in ranked] == ["1", "2", "3"] and held_out == sorted(held_out)
    assert "ranked by their held-out |B| RMS" in comparison  # the scalar fit has no vector: |B| for all
    assert "the measurand" in page and "beside mmc0" in page and "NO COMMISSIONED REFERENCE CHAIN" in page


def _applied(cal: Path, data: Path, tmp_path: Path) -> tuple[np.ndarray, np.ndarray]:
    out = tmp_path / f"{cal.stem}.rig.csv"
    done = run_rig("apply", str(cal), str(data), "-o", str(out), timeout=120)
    assert done.returncode == 0, done.stderr
    own = tmp_path / f"{cal.stem}.own.csv"
    done = subprocess.run([sys.executable, str(SCRIPT), str(cal), str(data), "-o", str(own)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr

    def field(path: Path) -> np.ndarray:
        with open(path) as f:
            return np.array([[float(r["bx"]), float(r["by"]), float(r["bz"])] for r in csv.DictReader(f)])

    return field(out), field(own)


def test_the_file_alone_reproduces_rig_apply_and_the_c_header(demo, tmp_path):
    files = _files(demo)
    data = demo / "mmc0.csv"
    for cal in (files[("mmc0", "t24")], demo / "mmc0.t36.yaml", files[("mmc0", "p12")],
                files[("mmc0", "scalar")]):
        applied, own = _applied(cal, data, tmp_path)
        assert len(applied) == 156 and max_relative_error(own, applied) < 1e-9, cal.name  # 26 x 3 x 2
    t24 = files[("mmc0", "t24")]
    header = run_rig("export-cal", str(t24), "--format", "c-header", "--name", "mmc0").stdout
    with open(data) as f:
        rows = list(csv.DictReader(f))[:50]
    h = np.array([[float(r["hx"]), float(r["hy"]), float(r["hz"])] for r in rows])
    t = np.array([float(r["temp"]) for r in rows])
    applied = calfile.load(t24).apply(h, t)
    for std in ("c89", "c99"):
        assert max_relative_error(run_header(header, "mmc0", h, t, tmp_path, std), applied) < 1e-9
    text = " ".join(header.split())
    for said in ("mode set_reset_pair", "beside mmc0", "frame of B: station", "indexing: M[row][column]",
                 "NO COMMISSIONED REFERENCE CHAIN", "M = S, M_PER_C = K, O = b_nt"):
        assert said in text, said


def test_a_run_without_set_reset_says_so(tmp_path):
    """The same DUTs with the plan's `set_reset: off`: their files say how h was read differently (the
    offset then holds the bridge's), from what the drivers recorded."""
    plan_path = small_plan(tmp_path, steps=(10, 40), samples=2, dwell_s=30, name="nosr")
    plan = yaml.safe_load(plan_path.read_text())
    plan["set_reset"] = "off"
    plan_path.write_text(yaml.safe_dump(plan, sort_keys=False))
    done = run_rig("run", str(plan_path), "--station", str(SIM_STATION), "--out", str(tmp_path / "s"),
                   timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    modes = {}
    for path in (tmp_path / "s").glob("*.t24.yaml"):
        cal = calfile.load(path)
        modes[cal.reading["device"]["name"]] = cal.reading["mode"]
        assert cal.source["sha256"] == sha256_file(cal.source["path"])
    assert modes == {"mmc0": "single", "serial0": "set_only"}
