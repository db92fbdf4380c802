"""Every temperature schedule on configs/stations/sim-lab.yaml, the world with every deviation on: it
completes and its fits exist. The DUTs' places are off the air (up to 0.4 degC) and the coil supply's
read-back is off by its stated accuracy; the plans are made only from what the station's thermal
commissioning measured."""

from __future__ import annotations

import json

import pytest
import yaml

from calib.io import calfile
from rig.config import CONFIGS_DIR, load_station
from rig.config.loading import load_campaign
from rig.planning.design import design_inputs, design_plan, designed_plan_text
from rig.run.campaign import run_campaign
from tests.system.campaign_helpers import query

pytestmark = pytest.mark.system

LAB = CONFIGS_DIR / "stations" / "sim-lab.yaml"
DIAGONALS = [[x, y, z] for x in (1, -1) for y in (1, -1) for z in (1, -1)]
LOOSE = {"S": 3e-4, "K": 2e-5, "b": 15.0, "kb": 1.0}


def write(tmp_path, name: str, temperatures: dict, **extra) -> str:
    fields = {"kind": "directions", "magnitude_nt": 50000, "directions": DIAGONALS}
    plan = {"name": name, "temperatures": temperatures, "fields": fields, "samples_per_point": 2,
            "settle_s": 0.5, "fit": {"models": ["t24"]}, **extra}
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(plan, sort_keys=False))
    return str(path)


def completed_with_fits(tmp_path, plan_path: str, station=LAB):
    session = tmp_path / "s.session"
    outcome = run_campaign(campaign=load_campaign(plan_path, station), session_path=session)
    assert outcome.result.status == "completed", outcome.result.reason
    duts = {d.name for d in load_station(station).duts}
    fitted = {f["dut"]: calfile.load(f["path"]) for f in outcome.fits if "path" in f}
    assert set(fitted) == duts, outcome.fits
    return session, outcome, fitted


def test_steps_on_the_lab_settle_each_dut_where_its_place_puts_it(tmp_path):
    # a band of 0.3 degC: three of the places, 0.32 to 0.39 degC off the air, are never within it of the set
    # point; each DUT is stable once what is left of its approach to its own level is within it
    band = 0.3
    plan = write(tmp_path, "steps", {"steps": [20, 28], "ramp_c_per_min": 5.0,
                                     "stability": {"band_c": band, "rate_c_per_min": 0.2, "dwell_s": 60}})
    session, _, _ = completed_with_fits(tmp_path, plan)
    settled = [json.loads(r[0]) for r in query(session, "SELECT settle_json FROM points WHERE id LIKE "
                                                        "'T0_-F01' ORDER BY idx")]
    truth = load_station(LAB).sim.duts
    for step in settled:
        for dut, where in step["duts"].items():  # recorded: where each DUT settled
            assert where["offset_c"] == pytest.approx(truth[dut].air_offset_c, abs=band), (dut, where)
            assert abs(where["temp_c"] - where["settled_c"]) <= band


def test_a_ramp_on_the_lab_completes_with_its_lag_corrected_fits(tmp_path):
    plan = write(tmp_path, "ramp", {"mode": "ramp", "range_c": [20, 30], "rate_c_per_min": 2.0,
                                    "stability": {"band_c": 0.5, "rate_c_per_min": 0.3, "dwell_s": 60}})
    _, _, fitted = completed_with_fits(tmp_path, plan)
    assert all("thermal_lag" in cal.stats for cal in fitted.values())


def test_a_plan_designed_from_the_thermal_commissioning_covers_its_range_at_the_duts(tmp_path):
    source = write(tmp_path, "seq", {"mode": "sequential", "range_c": [20, 32], "rate_c_per_min": 1.5,
                                     "checks_c": [26], "fields_per_sweep": 6}, stop_when=LOOSE,
                   acceptance={"model_checks": False})  # the lab's DUTs are curved: coverage is judged here
    station = lab_with(tmp_path, ("dut1", "dut3"))  # places 0.39 degC colder and 0.36 warmer than the air
    campaign = load_campaign(source, station)
    inputs = design_inputs(campaign.plan, campaign.station)
    assert {d.origin for d in inputs.planning.duts.values()} == {"thermal commissioning"}
    designed = design_plan(campaign.plan, campaign.station, inputs)
    data = yaml.safe_load(designed_plan_text(campaign.plan_text, designed, campaign.station, name="designed",
                                             station_ref=None, made_for="a test"))
    data.pop("stop_when")  # the whole plan: both ends held as designed
    path = tmp_path / "designed.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    ends = [leg["to_c"] for leg in data["temperatures"]["legs"] if not leg.get("check")]
    assert min(ends) < 20.0 and max(ends) > 32.0  # the air goes past each end by the places' offsets
    _, outcome, fitted = completed_with_fits(tmp_path, str(path), station)
    assert all(v.passed for v in outcome.verdicts), [v.line() for v in outcome.verdicts]  # coverage judged
    for dut, cal in fitted.items():
        low, high = cal.stats["temperature_range_c"]
        assert low <= 20.5 and high >= 31.5, (dut, low, high)


def lab_with(tmp_path, keep: tuple[str, ...]) -> str:
    """sim-lab with only these DUTs (and their probes and simulated truths): every deviation still on."""
    data = yaml.safe_load(LAB.read_text())
    data["duts"] = [d for d in data["duts"] if d["name"] in keep]
    data["temperature_sensors"] = [t for t in data["temperature_sensors"] if t["beside"] in keep]
    data["sim"]["duts"] = {k: v for k, v in data["sim"]["duts"].items() if k in keep or k.startswith("ref")}
    data["field_source"]["commissioning"] = str(LAB.parent / data["field_source"]["commissioning"])
    for ref in data["reference_magnetometers"]:
        ref["calibration"] = str(LAB.parent / ref["calibration"])
    path = tmp_path / "lab.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return str(path)


def test_a_sequential_plan_on_the_lab_completes_at_its_targets(tmp_path):
    plan = write(tmp_path, "seq", {"mode": "sequential", "range_c": [18, 26], "rate_c_per_min": 1.0,
                                   "checks_c": [22], "fields_per_sweep": 6, "max_duration_h": 3},
                 stop_when=LOOSE)
    data = yaml.safe_load(open(plan))
    data["settle_s"] = 5.0  # a sweep is a minute of the campaign clock: few points
    open(plan, "w").write(yaml.safe_dump(data, sort_keys=False))
    station = lab_with(tmp_path, ("dut1", "dut5"))  # its fastest and slowest places: the run measures both
    session, outcome, _ = completed_with_fits(tmp_path, plan, station)
    assert outcome.result.code == "targets_met", outcome.result.reason
    decisions = [json.loads(d[0]) for d in query(session, "SELECT decision_json FROM decisions ORDER BY seq")]
    assert decisions[-1]["stop"] and all(d["estimates"] for d in decisions)
