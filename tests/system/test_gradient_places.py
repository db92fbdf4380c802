"""The lab field's gradient measured by moving the reference (`rig commission --position`) or by a second
reference magnetometer: fitted to the ambient at each place, carried into a run's references where each
DUT sits, and its covariance is the budget's "ambient gradient" line in place of the stated bound."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import yaml

from calib.io import calfile
from rig.commission.places import commission_place
from rig.commission.procedure import commission
from rig.config import commissioning_file
from rig.config.loading import load_campaign
from rig.fieldsources.coils.gradientfit import element_std_errors
from rig.fieldsources.fieldmaths import reference_for
from rig.run.campaign import run_campaign
from tests.helpers.reference_station import write_station
from tests.helpers.small_plan import PLAN

pytestmark = pytest.mark.system

# source-free (symmetric, traceless), each component near the stated bound
TRUE_GRADIENT = np.array([[260.0, 90.0, -70.0], [90.0, -180.0, 140.0], [-70.0, 140.0, -80.0]])
BOUND = 300.0


def _lab_gradient(data):
    data["sim"]["ambient_gradient_nt_per_m"] = TRUE_GRADIENT.tolist()
    data["field_source"]["ambient_gradient_nt_per_m"] = BOUND


@pytest.fixture(scope="module")
def placed(tmp_path_factory):
    folder = tmp_path_factory.mktemp("gradient")
    station = write_station(folder, _lab_gradient)
    commission(station, folder, repeats=1)
    path = folder / "sim-commissioned.commissioning.yaml"
    commission_place(station, folder, (70.0, 0.0, 0.0), repeats=1)
    after_one = commissioning_file.read(path).record.coils.gradient
    for place in ((-70.0, 0.0, 0.0), (0.0, 70.0, 0.0), (0.0, 0.0, 70.0)):
        commission_place(station, folder, place, repeats=1)
    return folder, station, path, after_one


def test_one_place_shows_the_column_along_it_and_leaves_the_rest_at_the_stated_bound(placed):
    *_, after_one = placed
    assert after_one is not None and after_one.places == 2
    assert sorted(after_one.unidentified) == ["Gyy", "Gyz"]  # a place on x shows G's x column alone
    g = np.asarray(after_one.nt_per_m)
    sd = element_std_errors(after_one.covariance)
    for i in range(3):  # Gxx, Gxy (= Gyx), Gxz (= Gzx) measured
        assert abs(g[i, 0] - TRUE_GRADIENT[i, 0]) <= 4 * sd[i, 0] + 5.0, (i, g[i, 0], sd[i, 0])
        assert sd[i, 0] < 0.5 * BOUND / np.sqrt(3)
    assert sd[1, 1] == pytest.approx(BOUND / np.sqrt(3), rel=0.05)  # Gyy: the stated bound's


def test_four_places_measure_the_whole_gradient(placed):
    _, _, path, _ = placed
    gradient = commissioning_file.read(path).record.coils.gradient
    assert gradient.places == 5 and gradient.unidentified == [] and gradient.dof == 15 - 8
    g = np.asarray(gradient.nt_per_m)
    sd = element_std_errors(gradient.covariance)
    assert np.all(np.abs(g - TRUE_GRADIENT) <= 4 * sd + 5.0), (g, sd)
    assert np.all(sd < 0.25 * BOUND / np.sqrt(3))  # far better known than the stated bound
    assert np.trace(g) == pytest.approx(0.0, abs=1e-6) and np.allclose(g, g.T)


def test_the_run_carries_it_to_each_dut_and_budgets_its_covariance(placed):
    folder, station, path, _ = placed
    data = yaml.safe_load(station.read_text())
    data["field_source"]["commissioning"] = path.name
    station.write_text(yaml.safe_dump(data, sort_keys=False))
    plan = folder / "plan.yaml"
    plan.write_text(PLAN)
    campaign = load_campaign(plan, station)
    g = np.asarray(commissioning_file.read(path).record.coils.gradient.nt_per_m)
    reference = reference_for(campaign.station, measured_nt=[16200.0, -350.0, 43100.0])
    for dut in campaign.station.duts:  # the reference ref0 measures the ambient at the centre
        want = g @ np.asarray(dut.position_mm, float) / 1000.0
        np.testing.assert_allclose(reference.ambient_offsets[dut.name], want, atol=1e-9)
        currents = np.array([0.3, -0.2, 0.5])
        without = reference.matrices[dut.name] @ currents + reference.ambient_nt
        np.testing.assert_allclose(reference.field_nt(currents, dut.name), without + want, atol=1e-9)
    outcome = run_campaign(campaign=campaign, session_path=folder / "run.session")
    assert outcome.result.status == "completed", outcome.result.reason
    fit = next(f for f in outcome.fits if f["dut"] == "dut1" and f["model"] == "t24")
    lines = {line["source"]: line for line in calfile.load(fit["path"]).uncertainty["budget"]}
    note = lines["ambient gradient"]["note"]
    assert note.startswith("measured at commissioning from the ambient at 5 places"), note
    # its covariance, over dut1's 70 mm: a few nT/m at most, so well under a nanotesla
    assert 0.0 < lines["ambient gradient"]["contribution_nt"] < 1.0


def _second_reference(data):
    _lab_gradient(data)
    ref = data["reference_magnetometers"][0]
    data["reference_magnetometers"].append({**copy.deepcopy(ref), "name": "ref1", "position_mm": [0, 0, 75]})
    data["sim"]["duts"]["ref1"] = copy.deepcopy(data["sim"]["duts"]["ref0"])  # calibrated alike
    data["field_source"]["reference_magnetometer"] = "ref0"


def test_a_second_reference_shows_the_gradient_along_the_line_between_them(tmp_path):
    station = write_station(tmp_path, _second_reference)
    path = commission(station, tmp_path, repeats=1)
    coils = commissioning_file.read(path).record.coils
    assert [o.name for o in coils.other_references] == ["ref1"]
    gradient = coils.gradient
    # along z: G's z column (Gxz, Gyz, Gzz = -Gxx - Gyy); Gxx and Gyy apart, and Gxy, not
    assert gradient.places == 2 and set(gradient.unidentified) == {"Gxx", "Gyy", "Gxy"}
    g, sd = np.asarray(gradient.nt_per_m), element_std_errors(gradient.covariance)
    for i in range(3):  # G's z column: Gxz, Gyz and Gzz
        assert abs(g[i, 2] - TRUE_GRADIENT[i, 2]) <= 4 * sd[i, 2], (i, g[i, 2], sd[i, 2])
    # two instruments: their calibrations' errors (a few nT over 75 mm) stay in what the line shows
    assert 5.0 < sd[0, 2] < 0.5 * BOUND / np.sqrt(3)


def test_a_second_reference_that_cannot_be_read_is_left_out_and_the_commissioning_stands(tmp_path, caplog):
    def unplugged_second(data):
        _second_reference(data)
        second = data["reference_magnetometers"][1]
        # opened at the start, gone by the time the coils' settings are done
        second["transport"] = {**second["transport"], "faults": {"unplug": {"after_s": 1.0, "for_s": 1e6}}}

    station = write_station(tmp_path, unplugged_second)
    path = commission(station, tmp_path, repeats=1)
    coils = commissioning_file.read(path).record.coils
    assert coils.other_references == [] and coils.gradient is None  # the primary's ambient alone
    assert np.asarray(coils.matrix_nt_per_a).shape == (3, 3)
    assert any("ref1 left out of the ambient gradient" in r.getMessage() for r in caplog.records)
