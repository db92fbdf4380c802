"""The reference chain end to end on simulated stations: `rig commission` finds the simulator's true coil
matrix (or table axes), refuses a faulty reference or coil with one line and leaves the coils safe, and a
campaign on the commissioned station states an uncertainty budget on every calibration."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from calib.io import calfile
from drivers.sim.world import TableAxes
from rig.commission.procedure import commission
from rig.config import commissioning_file
from rig.config.loading import load_campaign
from rig.core.errors import DeviceFault
from rig.fieldsources.fieldmaths import TableReference
from rig.reference import chain_record
from rig.run.campaign import load_from_session, run_campaign
from rig.session.reader import SessionReader
from tests.helpers.reference_station import write_station
from tests.system.campaign_helpers import run_rig

pytestmark = pytest.mark.system

PLAN = """\
name: chain
temperatures:
  steps: [5, 45]
  ramp_c_per_min: 5
  stability: {band_c: 0.5, rate_c_per_min: 0.2, dwell_s: 60}
fields: {kind: cube24, magnitudes_nt: [30000, 55000]}
samples_per_point: 2
settle_s: 0.2
fit: {models: [t24, p12, scalar]}
"""


def plan_file(folder, acceptance: dict | None = None):
    text = PLAN + ("" if acceptance is None else yaml.safe_dump({"acceptance": acceptance}))
    path = folder / "plan.yaml"
    path.write_text(text)
    return path


def test_commissioning_finds_the_true_coil_matrix_and_leaves_the_coils_safe(tmp_path):
    station = write_station(tmp_path)
    seen = []
    path = commission(station, tmp_path, on_rig=seen.append)
    world = seen[0].world
    assert not world.coils_enabled and np.all(world.coil_currents_a == 0)  # safe at the end
    com = commissioning_file.read(path)
    truth = yaml.safe_load(station.read_text())["sim"]
    se_m = np.asarray(com.record.coils.std_errors_matrix_nt_per_a)
    z = (com.matrix_nt_per_a - np.asarray(truth["coil_constants_nt_per_a"])) / se_m
    assert np.abs(z).max() < 5, z
    assert np.allclose(com.record.coils.ambient_nt, truth["ambient_nt"], atol=2.0)
    assert max(com.record.coils.nonlinearity_ppm) < 200 and com.record.coils.repeats == 2
    assert len(com.record.settings) == 2 * 45
    assert np.all(np.linalg.eigvalsh(com.covariance) > 0)


def _failed_commission(tmp_path, change, fragment: str) -> str:
    station = write_station(tmp_path, change)
    proc = run_rig("commission", str(station), "--out", str(tmp_path / "out"))
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    line = proc.stderr.strip().splitlines()[-1]  # retries before it are logged as warnings
    assert line.startswith("error: ") and fragment in line, line
    assert not list((tmp_path / "out").glob("*.commissioning.yaml"))  # nothing written
    return line


def test_a_reference_that_does_not_answer_is_named(tmp_path):
    def unplugged(data):
        ref = data["reference_magnetometers"][0]
        ref["transport"] = {"kind": "sim", "faults": {"unplug": {"after_s": 1}}}

    line = _failed_commission(tmp_path, unplugged, "ref0: commission coils at 0 A: ")
    assert "no ACK" in line


def test_a_saturated_reference_names_the_coil(tmp_path):
    def strong(data):
        data["sim"]["coil_constants_nt_per_a"] = [[700_000, 0, 0], [0, 50_000, 0], [0, 0, 50_000]]

    line = _failed_commission(tmp_path, strong, "ref0: commission coil x at ")
    assert "saturated" in line


def test_a_coil_that_does_not_respond_is_named(tmp_path):
    def dead(data):
        data["sim"]["coil_constants_nt_per_a"] = [[50_480, 264, 0], [0, 49_510, 0], [0, 0, 0.001]]

    line = _failed_commission(tmp_path, dead, "coils: commission coil z: ")
    assert "does not respond" in line


def test_a_field_not_linear_in_the_current_is_named(tmp_path):
    def bent(data):
        data["sim"]["coil_nonlinearity_per_a"] = [0.0, 0.02, 0.0]

    line = _failed_commission(tmp_path, bent, "coils: commission coil y: ")
    assert "not linear" in line
    seen = []  # in-process: the coils end safe, and nothing is written
    with pytest.raises(DeviceFault, match="coil y"):
        commission(tmp_path / "station.yaml", tmp_path / "again", on_rig=seen.append)
    assert not seen[0].world.coils_enabled and np.all(seen[0].world.coil_currents_a == 0)
    assert not (tmp_path / "again").exists() or not list((tmp_path / "again").iterdir())


def test_a_commissioned_campaign_states_its_uncertainty_on_every_calibration(tmp_path):
    station = write_station(tmp_path)
    com = commission(station, tmp_path)
    data = yaml.safe_load(station.read_text())
    data["field_source"]["commissioning"] = com.name
    station.write_text(yaml.safe_dump(data, sort_keys=False))

    check = run_rig("check", str(plan_file(tmp_path)), "--station", str(station))
    assert check.returncode == 0, check.stderr
    assert f"commissioning {com}" in check.stdout and "non-uniformity" in check.stdout

    plan = plan_file(tmp_path, {"max_expanded_uncertainty_nt": 30.0})  # far DUTs' position tolerance fails
    session = tmp_path / "chain.session"
    outcome = run_campaign(campaign=load_campaign(plan, station), session_path=session)
    assert outcome.result.status == "completed", outcome.result.reason
    for fit in outcome.fits:
        cal = calfile.load(fit["path"])  # the file round-trips its budget
        u = cal.uncertainty
        # k from the effective degrees of freedom: the residual's hundreds and the run's few ambient
        # measurements leave it a little above 2
        assert 2.0 <= u["coverage_factor"] < 2.2
        assert set(u["coverage_factors"]) == set(u["effective_dof"]) == set(cal.params)
        assert set(u["expanded"]) == set(cal.params)
        for key, value in cal.params.items():
            assert np.shape(u["expanded"][key]) == np.shape(value)
        sources = [b["source"] for b in u["budget"]]
        assert sources[:2] == ["fit (statistical)", "coil matrix"]
        assert {"reference magnetometer", "ambient", "position", "coil geometry",
                "temperature"} <= set(sources)
        assert u["expanded_vector_error_nt"] > 0
    verdicts = {v.dut: v for v in outcome.verdicts}
    near, far = verdicts["dut3"], verdicts["dut1"]  # 50 mm and 70 mm off the centre
    assert far.figures["expanded_uncertainty_nt"] > near.figures["expanded_uncertainty_nt"]
    assert any(f.startswith("uncertainty ") for f in far.failed)

    # the session keeps the commissioning it ran with: a resume or a refit does not need the file
    matrix = commissioning_file.read(com).matrix_nt_per_a
    com.unlink()
    _, restored = load_from_session(session)
    assert np.array_equal(restored.field_source.constants, matrix)
    with SessionReader(session) as reader:
        chain = reader.snapshot(chain_record.SNAPSHOT)
        refs = reader.point_references()
    assert chain["commissioning"]["text"] and set(chain["matrices_nt_per_a"]) >= {"dut1", "ref0"}
    assert all("ambient_nt" in r for r in refs.values())
    refit = run_rig("refit", str(session), "--dut", "dut1", "-o", str(tmp_path / "refit.yaml"))
    assert refit.returncode == 0, refit.stderr
    again = calfile.load(tmp_path / "refit.yaml")
    assert again.uncertainty["budget"][1]["source"] == "coil matrix" and "ambient" in again.stats


def test_a_turntable_is_commissioned_and_its_axes_used(tmp_path):
    axes = {"az_tilt_deg": [0.2, -0.15], "el_tilt_deg": 0.3, "zero_offsets_deg": [1.0, -0.4]}

    def table(data):
        data["sim"]["turntable_axes"] = axes
        data["sim"]["site_field_nt"] = [19_148.0, 894.0, 45_587.0]
        data["field_source"] = {"kind": "turntable", "transport": {"kind": "sim"}, "rate_deg_s": 30,
                                "site_field": {"reference_magnetometer": "ref0"}}
        for d in data["duts"]:
            d.pop("position_mm")
        del data["sim"]["coil_geometry"]

    station = write_station(tmp_path, table)
    path = commission(station, tmp_path, repeats=1)
    com = commissioning_file.read(path)
    params = com.record.table.params
    se = com.record.table.std_errors
    assert abs(params["el_axis_tilt_deg"] - 0.3) < 5 * se["el_axis_tilt_deg"] + 0.01
    assert abs(params["el_zero_deg"] - (-0.4)) < 5 * se["el_zero_deg"] + 0.01
    data = yaml.safe_load(station.read_text())
    data["field_source"]["commissioning"] = path.name
    station.write_text(yaml.safe_dump(data, sort_keys=False))
    campaign = load_campaign(plan_file(tmp_path), station)
    assert campaign.station.field_source.commissioned is not None
    ref = campaign.station.field_source.reference()
    true = TableAxes((0.2, -0.15), 0.3, (1.0, -0.4))
    site = np.array([19_148.0, 894.0, 45_587.0])
    ideal = TableReference.ideal(site)
    for az, el in ((30, 60), (200, -45), (90, 180)):
        truth = true.rotation(az, el).T @ site
        assert np.abs(ref.field_nt((az, el)) - truth).max() < 5.0
        assert np.abs(ideal.field_nt((az, el)) - truth).max() > 100.0  # what the drawing alone gets wrong
