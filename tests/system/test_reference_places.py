"""`rig commission --position`: the reference measured at more places is added to the commissioning file,
each coil loop is fitted to them, a run's references use the fitted loops, and each bad input is one line
naming it."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from rig.commission.places import commission_place
from rig.commission.procedure import commission
from rig.config import commissioning_file
from rig.config.loading import load_campaign
from rig.core.errors import ConfigError
from rig.fieldsources.coils.loops import matrix_with_loops
from rig.reference import chain_record
from rig.run.campaign import run_campaign
from rig.session.reader import SessionReader
from tests.helpers.reference_station import write_station
from tests.helpers.small_plan import PLAN
from tests.system.campaign_helpers import run_rig

pytestmark = pytest.mark.system

LOOPS = {"x": {"turns_error_ppm": [1500, -800], "offset_mm": [[0, 0.6, -0.3], [0, -0.2, 0.5]],
               "tilt_deg": [0.08, -0.05]}}


def _with_loops(data):
    data["sim"]["coil_loops"] = LOOPS


@pytest.fixture(scope="module")
def placed(tmp_path_factory):
    folder = tmp_path_factory.mktemp("places")
    station = write_station(folder, _with_loops)
    commission(station, folder, repeats=1)
    commission_place(station, folder, (70.0, 0.0, 0.0), repeats=1)
    proc = run_rig("commission", str(station), "--out", str(folder), "--position", "-70,0,0",
                   "--repeats", "1")
    assert proc.returncode == 0, proc.stderr
    assert "loops fitted to the matrices at the centre and 2 place(s)" in proc.stdout
    return folder, station


def test_places_are_added_and_the_run_uses_the_fitted_loops(placed):
    folder, station = placed
    path = folder / "sim-commissioned.commissioning.yaml"
    com = commissioning_file.read(path)  # sealed again, whole
    coils = com.record.coils
    assert [p.position_mm for p in coils.places] == [(70.0, 0.0, 0.0), (-70.0, 0.0, 0.0)]
    assert coils.loops is not None and len(coils.loops.unidentified) < 30
    assert "x+ shift y mm" not in coils.loops.unidentified  # across the x loops, seen at +-70 mm on x
    deviations = np.asarray(coils.loops.deviations)
    assert deviations[0, 0, 1] == pytest.approx(0.6, abs=0.25)  # the + x loop's shift along y
    data = yaml.safe_load(station.read_text())
    data["field_source"]["commissioning"] = path.name
    station.write_text(yaml.safe_dump(data, sort_keys=False))
    plan = folder / "plan.yaml"
    plan.write_text(PLAN)
    session = folder / "run.session"
    outcome = run_campaign(campaign=load_campaign(plan, station), session_path=session)
    assert outcome.result.status == "completed", outcome.result.reason
    with SessionReader(session) as reader:
        recorded = reader.snapshot(chain_record.SNAPSHOT)["matrices_nt_per_a"]["dut1"]
    g = load_campaign(plan, station).station.field_source.geometry
    expected = matrix_with_loops(com.matrix_nt_per_a, g.shape, g.size_m, g.spacing_m,
                                 np.array([0.07, 0.0, 0.0]), deviations)
    drawn = matrix_with_loops(com.matrix_nt_per_a, g.shape, g.size_m, g.spacing_m,
                              np.array([0.07, 0.0, 0.0]), np.zeros_like(deviations))
    np.testing.assert_allclose(recorded, expected, atol=1e-6)  # the run's references: the fitted loops
    assert np.max(np.abs(expected - drawn)) > 5.0


def _refused(station, folder, position, fragment, **kw):
    with pytest.raises(ConfigError) as err:
        commission_place(station, folder, position, repeats=1, **kw)
    message = str(err.value)
    assert "\n" not in message and fragment in message, message
    return message


def test_a_place_measured_already_is_refused(placed):
    folder, station = placed
    _refused(station, folder, (70.4, 0.0, 0.0), "already measured")
    _refused(station, folder, (0.0, 0.3, 0.0), "already measured")  # the centre, the file's own place


def test_a_place_outside_the_coils_is_refused(placed):
    folder, station = placed
    assert "--position (150, 0, 0) mm is outside the coil set" in _refused(station, folder, (150, 0, 0),
                                                                           "outside the coil set")


def test_places_without_a_file_from_the_centre_are_refused(tmp_path):
    station = write_station(tmp_path)
    _refused(station, tmp_path, (70.0, 0.0, 0.0), "with the reference at its own place first")


def test_bad_position_text_and_thermal_with_a_place_are_one_line(tmp_path):
    station = write_station(tmp_path)
    for args, fragment in ((["--position", "70,0"], "give the place as X,Y,Z in mm"),
                           (["--position", "70,0,0", "--thermal"], "--thermal is measured")):
        proc = run_rig("commission", str(station), "--out", str(tmp_path), *args)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
        line = proc.stderr.strip().splitlines()[-1]
        assert line.startswith("error: ") and fragment in line, line
