"""Commissioning files and DUT positions: what a station may rest on, and every refusal as one located
line (`FILE: key: what (line N)`)."""

from __future__ import annotations

import datetime as dt
import re

import numpy as np
import pytest

from rig.config import load_station
from rig.config.loading import load_campaign
from rig.core.errors import ConfigError, LimitError
from rig.schedules.compile import check_campaign
from tests.helpers.reference_station import commissioned_station, commissioning_data, write_station
from tests.helpers.small_plan import PLAN

LOCATED = re.compile(r"^\S+: [\w.\[\]]+: .+ \(line \d+\)$")


def small_plan(folder, extra: dict | None = None):
    path = folder / "plan.yaml"
    path.write_text(PLAN + "".join(f"{k}: {v}\n" for k, v in (extra or {}).items()))
    return path


def _refusal(tmp_path, station) -> str:
    with pytest.raises(ConfigError) as err:
        load_campaign(small_plan(tmp_path), station)
    message = str(err.value)
    assert "\n" not in message and LOCATED.match(message), message
    return message


def test_a_commissioned_station_uses_the_measured_matrix(tmp_path):
    station, com = commissioned_station(tmp_path)
    campaign = load_campaign(small_plan(tmp_path), station)
    source = campaign.station.field_source
    measured = np.asarray(campaign.station.sim.coil_constants_nt_per_a, float)
    assert np.array_equal(source.constants, measured)  # not the declared diag(50000)
    assert not np.array_equal(source.declared_constants, measured)
    lines = check_campaign(campaign).summary_lines()
    assert any(line.startswith(f"commissioning {com}") and "days old" in line and "residual rms" in line
               for line in lines)
    assert any("non-uniformity" in line and "dut1 10816" in line for line in lines)


def test_a_missing_commissioning_file_is_named_in_the_station(tmp_path):
    station = write_station(tmp_path, commissioned=True)  # names a file that is not there
    message = _refusal(tmp_path, station)
    assert message.startswith(f"{station}: field_source.commissioning: ") and "file not found" in message


def test_a_commissioning_file_of_another_station_is_refused(tmp_path):
    station, com = commissioned_station(tmp_path, station="the-other-rig")
    message = _refusal(tmp_path, station)
    assert message.startswith(f"{com}: station: made for station 'the-other-rig'")


def test_an_edited_commissioning_file_is_refused(tmp_path):
    station, com = commissioned_station(tmp_path)
    com.write_text(com.read_text().replace("50480.0", "50481.0"))
    message = _refusal(tmp_path, station)
    assert message.startswith(f"{com}: content_sha256: ") and "edited" in message


def test_a_commissioning_file_older_than_max_age_days_is_refused(tmp_path):
    old = dt.datetime.now(dt.UTC) - dt.timedelta(days=40_000)
    station, com = commissioned_station(tmp_path, created=old)
    message = _refusal(tmp_path, station)
    assert message.startswith(f"{com}: created_utc: ") and "max_age_days 36500" in message


def test_a_changed_reference_calibration_is_refused(tmp_path):
    station, com = commissioned_station(tmp_path)
    cal = tmp_path / "sim-reference-cal.yaml"
    cal.write_text(cal.read_text().replace("b_nt: [180.0", "b_nt: [181.0"))
    message = _refusal(tmp_path, station)
    assert message.startswith(f"{com}: reference_magnetometer.calibration_sha256: ") and "changed" in message


def test_a_singular_matrix_is_refused(tmp_path):
    station, com = commissioned_station(tmp_path, matrix=[[50000, 0, 0], [50000, 0, 0], [0, 0, 50000]])
    message = _refusal(tmp_path, station)
    assert message.startswith(f"{com}: coils.matrix_nt_per_a: ") and "singular" in message


def test_a_covariance_that_is_not_positive_definite_is_refused(tmp_path):
    cov = np.eye(12) * 0.02
    cov[3, 3] = -0.01
    station, com = commissioned_station(tmp_path, covariance=cov)
    message = _refusal(tmp_path, station)
    assert message.startswith(f"{com}: coils.covariance: ") and "positive definite" in message


def test_a_covariance_is_symmetric_to_its_own_scale_not_to_the_last_bit(tmp_path):
    """A fit's inverse is symmetric to rounding: an entry near zero may differ from its mirror by far more
    than its own size and still by nothing against its variances. A real asymmetry is refused."""
    rng = np.random.default_rng(5)
    a = rng.normal(size=(12, 60)) * np.r_[np.full(9, 0.1), np.full(3, 30.0)][:, None]
    cov = a @ a.T
    cov[2, 10] = 1e-10
    cov[10, 2] = 1e-10 + 1e-14  # 1e-4 of the entry, 1e-15 of its variances' scale
    station, _ = commissioned_station(tmp_path, covariance=cov)
    assert load_campaign(small_plan(tmp_path), station) is not None
    cov[10, 2] = cov[2, 10] + 1e-3 * np.sqrt(cov[2, 2] * cov[10, 10])
    station, com = commissioned_station(tmp_path, covariance=cov)
    message = _refusal(tmp_path, station)
    assert message.startswith(f"{com}: coils.covariance: ") and "positive definite" in message


def test_a_commissioning_file_that_is_not_one_is_refused(tmp_path):
    station, com = commissioned_station(tmp_path)
    com.write_text("format: magrig-commissioning\nkind: coils\n")
    with pytest.raises(ConfigError) as err:
        load_campaign(small_plan(tmp_path), station)
    message = str(err.value)
    assert message.startswith(f"{com}: ") and "required key is missing (line 1)" in message


def test_a_dut_outside_the_coil_set_is_refused_at_load(tmp_path):
    def outside(data):
        data["duts"][0]["position_mm"] = [130, 0, 0]  # beyond the x pair at +-108.9 mm

    with pytest.raises(ConfigError) as err:
        load_station(write_station(tmp_path, outside))
    message = str(err.value)
    assert LOCATED.match(message) and "duts[0].position_mm" in message and "outside the coil set" in message


def test_two_duts_at_one_position_are_refused_at_load(tmp_path):
    def same(data):
        data["duts"][3]["position_mm"] = list(data["duts"][1]["position_mm"])

    with pytest.raises(ConfigError) as err:
        load_station(write_station(tmp_path, same))
    message = str(err.value)
    assert LOCATED.match(message) and "duts[3].position_mm" in message and "dut2 sits" in message


def test_a_sim_geometry_too_small_for_the_stated_positions_is_refused(tmp_path):
    def small(data):
        data["sim"]["coil_geometry"] = {"shape": "circular", "size_m": [0.1, 0.1, 0.1],
                                        "spacing_m": [0.05, 0.05, 0.05]}

    with pytest.raises(ConfigError, match=r"position_mm: .* outside the coil set \(sim.coil_geometry"):
        load_station(write_station(tmp_path, small))


def test_rig_check_refuses_a_position_beyond_the_plans_accuracy_target(tmp_path):
    station = write_station(tmp_path)
    plan = small_plan(tmp_path, extra={"accuracy_ppm": 5000})
    with pytest.raises(LimitError) as err:
        check_campaign(load_campaign(plan, station))
    message = str(err.value)
    assert message.startswith(f"{station}: duts[0].position_mm: ") and "10816 ppm" in message
    assert "accuracy_ppm 5000" in message and re.search(r"\(line \d+\)$", message)
    check_campaign(load_campaign(small_plan(tmp_path, extra={"accuracy_ppm": 20000}), station))


def test_without_a_geometry_stated_positions_are_a_warning(tmp_path):
    def no_geometry(data):
        del data["field_source"]["geometry"]
        del data["sim"]["coil_geometry"]

    report = check_campaign(load_campaign(small_plan(tmp_path), write_station(tmp_path, no_geometry)))
    assert any("no geometry" in w for w in report.warnings)


def test_a_station_needs_a_matrix_or_a_commissioning(tmp_path):
    def neither(data):
        del data["field_source"]["coil_constants_nt_per_a"]

    with pytest.raises(ConfigError, match=r"field_source.coil_constants_nt_per_a: give the coil matrix"):
        load_station(write_station(tmp_path, neither))


def test_commissioning_data_helper_round_trips(tmp_path):
    station = write_station(tmp_path, commissioned=True)
    data = commissioning_data(station)
    assert data["station"] == "sim-commissioned" and len(data["coils"]["covariance"]) == 12


def test_commissioning_needs_a_reference_magnetometer(tmp_path):
    from rig.commission.procedure import commission

    def no_reference(data):
        data["field_source"]["ambient_nt"] = [16200, -350, 43100]
        del data["reference_magnetometers"]
        del data["sim"]["duts"]["ref0"]

    station = write_station(tmp_path, no_reference)
    with pytest.raises(ConfigError) as err:
        commission(station, tmp_path)
    message = str(err.value)
    assert LOCATED.match(message) and "field_source" in message and "no reference magnetometer" in message
    assert not list(tmp_path.glob("*.commissioning.yaml"))


def test_an_off_centre_reference_needs_the_geometry(tmp_path):
    from rig.commission.procedure import commission

    def off_centre(data):
        data["reference_magnetometers"][0]["position_mm"] = [20, 0, 0]
        del data["field_source"]["geometry"]

    where = r"reference_magnetometers\[0\]\.position_mm: ref0 is not at the centre"
    with pytest.raises(ConfigError, match=where):
        commission(write_station(tmp_path, off_centre), tmp_path)


def test_a_file_without_a_thermal_section_still_loads_and_plans_nothing_from_it(tmp_path):
    from rig.config import CONFIGS_DIR
    from rig.config.commissioning_file import read
    from rig.planning.inputs import planning_inputs

    old = read(CONFIGS_DIR / "stations" / "sim-commissioned.commissioning.yaml")  # written before --thermal
    assert old.thermal is None and old.record.coils is not None
    campaign = load_campaign(small_plan(tmp_path), CONFIGS_DIR / "stations" / "sim-commissioned.yaml")
    inputs = planning_inputs(campaign.plan, campaign.station)
    assert inputs.stated_rate and inputs.missing() == [d.name for d in campaign.station.duts]
