"""The uncertainty budget of a turntable station, end to end: the commissioned station with a two-axis
table instead of coils, in a lab whose field drifts (tens of nT an hour, hardware-notes 9.4) and has a
gradient, the table commissioned and a campaign run. The site field is measured at home at the start, at
each temperature step and at the end: the budget's 'site field' is the run's model of it, the references
are made with its best estimate at each sample, and the stated gradient follows each DUT around the
table."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import yaml

import calib
from calib.commissioning.tablefit import table_field_nt
from calib.io import calfile
from rig.budget.run_inputs import RunInputs
from rig.commission.procedure import commission
from rig.config.loading import load_campaign
from rig.core.paths import calibration_file
from rig.fieldsources.turntable.budget import _with_home, table_rows
from rig.run.campaign import run_campaign
from rig.session.reader import SessionReader
from tests.helpers.once import made_once
from tests.helpers.reference_station import write_station
from tests.system.test_uncertainty import PLAN

pytestmark = pytest.mark.system

DUTS = ("dut1", "dut3")  # at (70, 0, 0) and (0, 50, 0) mm on the table; the reference at its centre
DRIFT_NT_PER_H = [30.0, -20.0, 15.0]
GRADIENT_BOUND = 300.0


def _table(data) -> None:
    sim = data["sim"]
    sim["turntable_axes"] = {"az_tilt_deg": [0.2, -0.15], "el_tilt_deg": 0.3, "zero_offsets_deg": [1.0, -0.4]}
    sim["site_field_nt"] = [19_148.0, 894.0, 45_587.0]
    sim["ambient_drift_nt_per_h"] = DRIFT_NT_PER_H
    sim["ambient_gradient_nt_per_m"] = [[200, 60, -40], [60, -120, 90], [-40, 90, -80]]
    data["field_source"] = {"kind": "turntable", "transport": {"kind": "sim"}, "rate_deg_s": 30,
                            "site_field": {"reference_magnetometer": "ref0"},
                            "ambient_gradient_nt_per_m": GRADIENT_BOUND}
    data["duts"] = [d for d in data["duts"] if d["name"] in DUTS]
    data["temperature_sensors"] = [s for s in data["temperature_sensors"] if s["beside"] in DUTS]
    sim["duts"] = {k: v for k, v in sim["duts"].items() if k in (*DUTS, "ref0")}
    del sim["coil_geometry"]


def _make(folder) -> None:
    station = write_station(folder, _table)
    com = commission(station, folder, repeats=1)
    data = yaml.safe_load(station.read_text())
    data["field_source"]["commissioning"] = com.name
    station.write_text(yaml.safe_dump(data, sort_keys=False))
    plan = folder / "plan.yaml"
    plan.write_text(PLAN.replace("fields: {kind: cube24, magnitude_nt: 50000}",
                                 "fields: {kind: grid, az_deg: [0, 90, 180, 270], el_deg: [-60, 0, 60]}"))
    outcome = run_campaign(campaign=load_campaign(plan, station), session_path=folder / "table.session")
    assert outcome.result.status == "completed", outcome.result.reason


@pytest.fixture(scope="module")
def table_run(tmp_path_factory):
    """(session, RunInputs, {dut: its dataset as recorded})"""
    session = made_once(tmp_path_factory, "turntable-budget", _make) / "table.session"
    with SessionReader(session) as reader:
        return session, RunInputs.of_session(reader), {d: reader.dataset(d) for d in DUTS}


def _lines(b) -> dict[str, float]:
    return {c["source"]: c["contribution_nt"] for c in b.contributions}


def _budget(inputs, dut, ds):
    ds, _ = inputs.refined(ds)
    return inputs.budget(dut, ds, calib.fit(ds, "t24"), monte_carlo="never")


def test_a_turntable_budget_states_its_axes_site_field_reference_and_gradient(table_run):
    session, _, _ = table_run
    cal = calfile.load(calibration_file(session, "dut1", "t24"))
    lines = {b["source"]: b["contribution_nt"] for b in cal.uncertainty["budget"]}
    wanted = ("table axes", "site field", "reference magnetometer", "ambient gradient")
    assert set(wanted) <= set(lines)
    assert all(lines[k] > 0 for k in wanted)
    total = sum(v**2 for v in lines.values())
    # the rectangular gradient's kurtosis sends the file's figures to the Monte Carlo: its tolerance
    assert cal.uncertainty["monte_carlo"]["converged"]
    assert cal.uncertainty["combined_standard_nt"] ** 2 == pytest.approx(total, rel=0.05)


def test_the_site_field_is_the_runs_model_of_it_and_each_reference_is_made_with_its_best_estimate(table_run):
    _, inputs, data = table_run
    model = inputs.ambient
    assert model is not None and model.n >= 4  # the start, each of the three steps, the end
    assert model.drifting  # 30 nT/h over hours of simulated time: far beyond the readings' noise
    for got, drift in zip(model.as_dict()["drift_nt_per_h"], DRIFT_NT_PER_H, strict=True):
        assert got == pytest.approx(drift, abs=3.0)
    ds = data["dut1"]
    refined, said = inputs.refined(ds)
    assert said == model.as_dict()
    # the table's field is linear in the home reading: each refined reference is exactly the table of its
    # point made from the model's site field at that sample's time
    params, angles = table_rows(inputs, ds)
    best = model.at(ds.columns["t"])
    expected = np.array([table_field_nt(_with_home(p, h), [a])[0] for p, h, a in zip(params, best, angles,
                                                                                   strict=True)])
    np.testing.assert_allclose(refined.ref_nt, expected, atol=1e-6)
    assert np.max(np.abs(refined.ref_nt - ds.ref_nt)) > 0.1  # the drift since each measurement, now followed
    site = next(c for c in _budget(inputs, "dut1", ds).contributions if c["source"] == "site field")
    assert "measured" in site["note"] and "with a drift" in site["note"]


def test_the_stated_gradient_follows_each_dut_around_the_table(table_run):
    """Its line grows with the stated bound and with how far from the reference the DUT sits; a DUT at
    the axes' crossing, where the reference measured, has none; an unstated bound is said, never silent."""
    _, inputs, data = table_run

    def with_source(**update):
        source = inputs.station.field_source.model_copy(update=update)
        return dataclasses.replace(inputs, station=inputs.station.model_copy(update={"field_source": source}),
                                   _chains={})

    def at_centre(dut):
        duts = [d.model_copy(update={"position_mm": None}) if d.name == dut else d
                for d in inputs.station.duts]
        station = inputs.station.model_copy(update={"duts": duts})
        return dataclasses.replace(inputs, station=station, _chains={})

    lines = {dut: _lines(_budget(inputs, dut, data[dut]))["ambient gradient"] for dut in DUTS}
    for dut, r_mm in (("dut1", 70.0), ("dut3", 50.0)):
        assert 0.2 * GRADIENT_BOUND * r_mm / 1000 < lines[dut] < GRADIENT_BOUND * r_mm / 1000
    assert lines["dut1"] > lines["dut3"]
    doubled = _lines(_budget(with_source(ambient_gradient_nt_per_m=2 * GRADIENT_BOUND), "dut1", data["dut1"]))
    assert doubled["ambient gradient"] == pytest.approx(2 * lines["dut1"], rel=1e-6)
    assert "ambient gradient" not in _lines(_budget(at_centre("dut1"), "dut1", data["dut1"]))
    unstated = _budget(with_source(ambient_gradient_nt_per_m=None), "dut1", data["dut1"])
    assert "ambient gradient" not in _lines(unstated)
    assert any("ambient_gradient_nt_per_m" in n for n in unstated.notes)


def test_the_certificate_states_the_site_field_as_measured_over_the_run(table_run):
    from rig.report.certificate import certificate_html

    session, inputs, _ = table_run
    html = certificate_html(session, "dut1")
    assert "site field (measured)</td><td>" in html
    assert f"{inputs.ambient.n} measurements, drifting" in html
    assert "ambient field (measured)" not in html
    # the site field 22.8 deg off the vertical, the table tilted up to 60 deg: the DUT sees it at most
    # 82.8 deg from its own z, so the direction opposite that is 97.2 deg from the nearest one taken
    site = np.array([19_148.0, 894.0, 45_587.0])
    farthest = 180.0 - (np.degrees(np.arccos(site[2] / np.linalg.norm(site))) + 60.0)
    reach = float(html.split("every direction within ", 1)[1].split(" deg", 1)[0])
    assert reach == pytest.approx(farthest, abs=2.5)
