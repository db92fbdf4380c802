"""The uncertainty budget on simulated stations, end to end: two worlds of the commissioned station, one
with every measurable departure off and one with them on (the current source's errors, a coil's
non-linearity, DUTs beyond T24 with thermal hysteresis, their offsets' slow noise, the lab field's
steps), each commissioned and run. A source turned on in the simulator moves its line of the budget, and
every line moves the stated uncertainty by what it says; stated sources (the station's keys) likewise.
Then the files: the calibration's full covariance, the DUTs' cross-covariance, `rig apply --uncertainty`,
the post-run progress, a reference calibration without an uncertainty refused, and the certificate."""

from __future__ import annotations

import csv
import dataclasses
import json

import numpy as np
import pytest
import yaml

import calib
from calib.io import calfile
from calib.uncertainty.budgeting import cross_covariance_of
from calib.uncertainty.fielderror import expanded_at, expanded_norm_at
from rig.analysis.crosscov import cross_covariance, cross_covariance_path
from rig.analysis.sessionfit import SessionFitter
from rig.budget.run_inputs import RunInputs
from rig.commission.procedure import commission
from rig.config import load_station
from rig.config.loading import load_campaign
from rig.core.errors import ConfigError
from rig.core.paths import calibration_file
from rig.reference.sitefield import load_reference_calibrations
from rig.run.campaign import run_campaign
from rig.session.events import Kind
from rig.session.reader import SessionReader
from tests.helpers.once import made_once
from tests.helpers.reference_station import REFERENCE_CAL, write_station
from tests.system import browser
from tests.system.campaign_helpers import run_rig

pytestmark = pytest.mark.system

PLAN = """\
name: budget
temperatures:
  steps: [0, 40, 15]
  ramp_c_per_min: 5
  stability: {band_c: 0.5, rate_c_per_min: 0.2, dwell_s: 60}
fields: {kind: cube24, magnitude_nt: 50000}
samples_per_point: 3
settle_s: 0.2
fit: {models: [t24, p12]}
"""
DUTS = ("dut1", "dut3")
HYSTERESIS_NT = [60.0, -80.0, 50.0]


def _world(on: bool):
    def change(data):
        data["duts"] = [d for d in data["duts"] if d["name"] in DUTS]
        data["temperature_sensors"] = [s for s in data["temperature_sensors"] if s["beside"] in DUTS]
        sim = data["sim"]
        sim["duts"] = {k: v for k, v in sim["duts"].items() if k in DUTS or k.startswith("ref")}
        for name in DUTS:
            rng = np.random.default_rng(abs(hash(name)) % 1000)
            truth = {"S": (np.eye(3) + rng.normal(0, 0.01, (3, 3))).round(5).tolist(),
                     "K": rng.normal(0, 1e-4, (3, 3)).round(8).tolist(), "b_nt": [300.0, -200.0, 100.0],
                     "kb_nt_per_c": [4.0, -3.0, 2.0]}
            spec = {"truth": truth, "noise_nt": 15, "thermal_lag_s": 300}
            if on:
                truth["K2_per_c2"] = np.diag([2e-6, -1.5e-6, 1e-6]).tolist()
                truth["hysteresis"] = {"offset_nt": list(HYSTERESIS_NT), "band_c": 5}
                spec.update(flicker_nt=60.0, random_walk_nt_per_sqrt_h=6.0)
            sim["duts"][name] = spec
        if on:
            sim["current_source"] = {"gain_error_ppm": [300, -250, 200], "offset_ma": [0.3, -0.2, 0.25],
                                     "noise_ma": [0.05, 0.05, 0.05], "readback_error_ppm": [200, -300, 150]}
            sim["coil_nonlinearity_per_a"] = [0.0008, 0.0, 0.0]
            sim["ambient_steps"] = {"mean_interval_h": 0.3, "size_nt": 40.0}
    return change


@pytest.fixture(scope="module")
def worlds(tmp_path_factory):
    """{"off": (session, inputs, datasets, what the post-run fits told), "on": ...}: each world
    commissioned and run once for every test worker (the first to come makes them, under a lock)."""
    out = {}
    for label in ("off", "on"):
        folder = made_once(tmp_path_factory, f"uncertainty-world-{label}",
                           lambda folder, label=label: _make(folder, label == "on"))
        session = folder / "run.session"
        with SessionReader(session) as reader:
            inputs = RunInputs.of_session(reader)
            data = {d: SessionFitter(inputs).prepare(reader.dataset(d)).ds for d in DUTS}  # as fitted
        told = [tuple(t) for t in json.loads((folder / "told.json").read_text())]
        out[label] = (session, inputs, data, told)
    return out


def _make(folder, on: bool) -> None:
    station = write_station(folder, _world(on))
    com = commission(station, folder)
    data = yaml.safe_load(station.read_text())
    data["field_source"]["commissioning"] = com.name
    station.write_text(yaml.safe_dump(data, sort_keys=False))
    plan = folder / "plan.yaml"
    plan.write_text(PLAN)
    told: list = []
    outcome = run_campaign(campaign=load_campaign(plan, station), session_path=folder / "run.session",
                           display_factory=lambda status, runner: _Recorder(told))
    assert outcome.result.status == "completed", outcome.result.reason
    (folder / "told.json").write_text(json.dumps(told))


class _Recorder:
    """A display that keeps what the post-run fits told it."""

    def __init__(self, told: list):
        self.told = told

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return None

    def fit_progress(self, dut, model, done, total):
        self.told.append((dut, model, done, total))


def _lines(b) -> dict[str, float]:
    return {c["source"]: c["contribution_nt"] for c in b.contributions}


def _budget(inputs, dut, ds, **kw):
    cal = calib.fit(ds, "t24")
    return cal, inputs.budget(dut, ds, cal, monte_carlo="never", **kw)


MEASURED = {  # source: what the "on" world turned on, and the least its line must grow by (nT)
    "coil non-linearity": "a coil off linear by 8e-4 per ampere",
    # the hysteresis is corrected in the readings: its estimate's uncertainty moves every line through the
    # correction (calib/uncertainty/correction.py), no line of its own
    "model checks (temperature)": "quadratic temperature terms",
    "thermal hysteresis state": "a thermal hysteresis of the offset",
    "offset wander": "1/f noise and a random walk of the offset",
    "ambient": "steps of the lab's field",
}


@pytest.mark.parametrize("source", list(MEASURED))
def test_a_source_turned_on_in_the_simulator_moves_its_line_and_the_uncertainty_by_it(worlds, source):
    on = {}
    for label in ("off", "on"):
        _, inputs, data, _ = worlds[label]
        cal, b = _budget(inputs, "dut1", data["dut1"])
        on[label] = _lines(b).get(source, 0.0)
        if label == "on":
            sources, _, noise, correction = inputs.sources("dut1", data["dut1"], cal)
            kept = [s for s in sources if s.name != source]
            assert len(kept) == len(sources) - 1, f"{source} missing from the budget"
            from calib.uncertainty.budgeting import budget as calib_budget

            without = calib_budget(data["dut1"], cal, kept, inputs._grid, rng=np.random.default_rng(1),
                                   monte_carlo="never", noise_nt=noise, correction=correction)
            # the law of propagation adds independent sources' variances: the line is exactly what it adds
            assert b.combined_standard_nt**2 == pytest.approx(without.combined_standard_nt**2 + on["on"] ** 2,
                                                              rel=1e-9)
    assert on["on"] > 5.0 and on["on"] > 2.0 * on["off"], (source, MEASURED[source], on)


def test_the_current_source_errors_cancel_where_the_chain_is_referred_to_its_readback(worlds):
    """The "on" world's supply delivers (1 + g) I + o and reports that times (1 + r): the commissioning
    measures its read-back against the commanded currents, the matrix is fitted against the read-back and
    every ambient measurement has the read-back currents' field (the offset's, at 0 A) taken out, so the
    errors cancel: no budget line, a note that says why."""
    _, inputs, data, _ = worlds["on"]
    _, b = _budget(inputs, "dut1", data["dut1"])
    assert "current source" not in _lines(b)
    assert any("read-back" in n and "cancel" in n for n in b.notes)
    com = inputs.station.field_source.commissioned
    assert com.record.coils.fitted_to == "readback"
    rb = com.record.coils.current_readback
    np.testing.assert_allclose(rb.gain_ppm, [300 + 200, -250 - 300, 200 + 150], atol=30)
    np.testing.assert_allclose(rb.offset_ma, [0.3, -0.2, 0.25], atol=0.03)
    offset_field = com.matrix_nt_per_a @ np.array([0.3e-3, -0.2e-3, 0.25e-3])
    for m in inputs.site:
        np.testing.assert_allclose(m["source_field_nt"], offset_field, atol=3.0)


def test_the_line_holds_under_the_monte_carlo_too(worlds):
    """The same additivity when the budget draws (its adaptive tolerance: 2 significant digits)."""
    _, inputs, data, _ = worlds["on"]
    ds = data["dut3"]
    cal = calib.fit(ds, "t24")
    drawn = inputs.budget("dut3", ds, cal, monte_carlo="always")
    exact = inputs.budget("dut3", ds, cal, monte_carlo="never")
    assert drawn.monte_carlo["converged"]
    assert drawn.combined_standard_nt == pytest.approx(exact.combined_standard_nt, rel=0.05)


def test_a_stated_source_is_the_line_it_states(worlds):
    """The station states a gradient bound g: the DUT at r from the reference sees a constant offset G r,
    which T24's offset takes entirely: the field error is that offset. G being source-free (symmetric,
    traceless: Gxx, Gyy, Gxy, Gxz, Gyz each +-g, rectangular, Gzz = -Gxx - Gyy), its mean square is
    g^2 / 3 (3 x^2 + 3 y^2 + 4 z^2)."""
    _, inputs, data, _ = worlds["off"]
    source = inputs.station.field_source
    stated = dataclasses.replace(inputs, station=inputs.station.model_copy(update={
        "field_source": source.model_copy(update={"ambient_gradient_nt_per_m": 200.0})}), _chains={})
    _, b = _budget(stated, "dut1", data["dut1"])
    x, y, z = np.asarray(inputs.station.dut("dut1").position_mm) / 1000.0
    line = 200.0 * np.sqrt((3 * x**2 + 3 * y**2 + 4 * z**2) / 3.0)
    assert _lines(b)["ambient gradient"] == pytest.approx(line, rel=1e-6)
    _, before = _budget(inputs, "dut1", data["dut1"])
    assert "ambient gradient" not in _lines(before)
    assert any("ambient_gradient_nt_per_m" in n for n in before.notes)  # never silent
    assert b.combined_standard_nt**2 == pytest.approx(before.combined_standard_nt**2 + line**2, rel=1e-9)


def test_the_files_carry_the_covariance_and_the_duts_cross_covariance(worlds, tmp_path):
    session, inputs, data, _ = worlds["on"]
    cals = {d: calfile.load(calibration_file(session, d, "t24")) for d in DUTS}
    for cal in cals.values():
        cov = np.asarray(cal.uncertainty["covariance"]["matrix"])
        assert cov.shape == (24, 24) and np.all(np.linalg.eigvalsh(cov) > -1e-12 * np.max(np.abs(cov)))
        assert len(cal.uncertainty["model_error_nt"]) == 3
        again = calfile.load(calibration_file(session, DUTS[0], "t24"))
        assert again.uncertainty == calfile.load(calibration_file(session, DUTS[0], "t24")).uncertainty
    # dut1's thermal hysteresis: its state at a point of use, apart from the normal model error
    assert np.all(np.asarray(cals["dut1"].uncertainty["hysteresis_state_nt"]) > 0)
    path = cross_covariance_path(session)
    budgets = {d: inputs.budget(d, data[d], calib.fit(data[d], "t24")) for d in DUTS}
    np.testing.assert_allclose(cross_covariance(path, "t24", *DUTS), cross_covariance_of(*budgets.values()),
                               rtol=1e-6, atol=1e-12 * np.max(np.abs(cross_covariance_of(*budgets.values()))))
    assert np.any(cross_covariance(path, "t24", *DUTS) != 0)  # the coil matrix and the reference are shared
    # rig apply --uncertainty: every row's expanded uncertainty from the file's covariance
    csv_path = tmp_path / "samples.csv"
    exported = run_rig("export", str(session), "--dut", DUTS[0], "-o", str(csv_path))
    assert exported.returncode == 0, exported.stderr
    applied = tmp_path / "applied.csv"
    proc = run_rig("apply", str(calibration_file(session, DUTS[0], "t24")), str(csv_path), "-o", str(applied),
                   "--uncertainty")
    assert proc.returncode == 0, proc.stderr
    with applied.open() as f:
        rows = list(csv.DictReader(f))
    assert {"u_bx", "u_by", "u_bz", "u_b", "u_norm"} <= set(rows[0])
    h = np.array([[float(r[k]) for k in ("hx", "hy", "hz")] for r in rows[:5]])
    temps = np.array([float(r["temp"]) for r in rows[:5]])
    _, radius = expanded_at(cals[DUTS[0]], h, temps)
    np.testing.assert_allclose([float(r["u_b"]) for r in rows[:5]], radius, rtol=1e-6)
    size_u = expanded_norm_at(cals[DUTS[0]], h, temps)  # |B|'s interval: narrower than the 3-D radius
    np.testing.assert_allclose([float(r["u_norm"]) for r in rows[:5]], size_u, rtol=1e-6)
    assert np.all(size_u < radius)
    # the file states the largest |B| interval over its grid beside the largest radius
    u = cals[DUTS[0]].uncertainty
    assert 0 < u["expanded_norm_error_nt"] < u["expanded_vector_error_nt"]


def test_the_post_run_fits_say_which_dut_and_model_in_the_terminal_and_the_session(worlds):
    session, _, _, told = worlds["on"]
    assert (None, None, 4, 4) in told and ("dut1", "t24", 0, 4) in told
    with SessionReader(session) as reader:
        told = [e.message for e in reader.events() if e.kind == Kind.POSTRUN]
    assert told[0].startswith("post-run fits: dut1 t24 (1 of 4)") and "done: 4 in" in told[-1]


def test_a_reference_calibration_without_an_uncertainty_is_refused_in_one_line(tmp_path):
    station = write_station(tmp_path)
    cal_path = tmp_path / REFERENCE_CAL.name
    cal = calfile.load(cal_path)
    cal.uncertainty = None
    calfile.save(cal, cal_path)
    proc = run_rig("commission", str(station), "--out", str(tmp_path / "out"))
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    line = proc.stderr.strip().splitlines()[-1]
    assert line.startswith("error: ") and "reference_magnetometers[0].calibration" in line
    assert "states no uncertainty" in line
    text = station.read_text()
    with pytest.raises(ConfigError, match="states no uncertainty"):
        load_reference_calibrations(load_station(station), station, text)


def test_a_certificate_states_every_item_and_renders_in_the_browser(worlds, tmp_path):
    from rig.report.certificate import ITEMS

    session, _, _, _ = worlds["on"]
    proc = run_rig("certificate", str(session), "--dut", "dut1", "-o", str(tmp_path))
    assert proc.returncode == 0, proc.stderr
    page = next(tmp_path.glob("*.dut1.certificate.html"))
    text = page.read_text()
    for item in ITEMS:
        assert f">{item}</h2>" in text, item
    for fact in ("dut1", "mmc5983ma", "expanded", "coverage factor" if "coverage factor" in text else "k",
                 "ref0", "sha256", "commissioning", "linearity in temperature", "magrig"):
        assert fact in text, fact
    assert "U = k u" in text and "thermal hysteresis" in text
    assert "The parameters of each model are those that describe the DUT best" in text
    assert "T24 at a point of use, per axis: model error (" in text
    assert "nT (the largest interval of |B|&#x27;s error)" in text  # html.escape's apostrophe
    if (why := browser.missing()) is not None:
        pytest.skip(why)
    if not list(tmp_path.glob("*.dut1.certificate.pdf")):
        pytest.fail(f"chromium is here but no PDF was printed: {proc.stdout}")
    with browser.headless_page() as (tab, errors):
        tab.goto(page.resolve().as_uri())
        shown = tab.inner_text("body")
        assert not errors, errors
    for item in ITEMS:
        assert item in shown


def test_the_cockpit_links_and_serves_each_certificate(worlds):
    import urllib.parse
    import urllib.request

    session, _, _, _ = worlds["on"]
    with browser.cockpit(str(session.parent)) as url:
        base = f"{url}/s/0/{urllib.parse.quote(session.name)}"
        with urllib.request.urlopen(base, timeout=30) as reply:
            page = reply.read().decode()
        assert "Calibration certificates" in page and "certificate?dut=dut1" in page
        with urllib.request.urlopen(f"{base}/certificate?dut=dut1", timeout=60) as reply:
            certificate = reply.read().decode()
        assert "Calibration certificate" in certificate and ">Traceability</h2>" in certificate
        name = urllib.parse.quote(session.name.removesuffix(".session") + ".dut3.certificate.html")
        with urllib.request.urlopen(f"{base}/{name}", timeout=60) as reply:  # the report's own link
            assert "dut3" in reply.read().decode()
