"""The certificate's rules on their own: the ILAC-G8 guarded decision rule, the keys a certificate reads
from the station, the plan and a reference's calibration file (strict, optional, refused in one line each),
and the DCC's numbers and units (exact on reading back, valid D-SI)."""

from __future__ import annotations

import re

import pytest
import yaml

from calib.equations import OPTIONAL_PARAMS, PARAM_SHAPES
from rig.config import CONFIGS_DIR, load_plan, load_station
from rig.config.lab import reference_certificate
from rig.core.errors import ConfigError
from rig.report import dcc_xml
from rig.report import decision_rule as rule
from rig.report.dcc_results import DSI_UNITS

STATIONS = CONFIGS_DIR / "stations"


@pytest.mark.parametrize("value, expanded, conformity", [
    (80.0, 10.0, "pass"),              # 80 + 10 <= 100: inside by at least U
    (95.0, 10.0, "conditionalPass"),   # inside, by less than U
    (104.0, 10.0, "conditionalFail"),  # outside, by less than U
    (111.0, 10.0, "fail"),             # outside by more than U
    (100.0, 0.0, "pass"),              # no U stated: the figure as it is
    (100.5, 0.0, "fail"),
])
def test_an_upper_limit_is_guarded_by_u(value, expanded, conformity):
    c = rule.upper_limit("fit_rms", value, 100.0, "nT", expanded)
    assert c.conformity == conformity
    assert c.result == {"pass": rule.PASS, "fail": rule.FAIL}.get(conformity, rule.CONDITIONAL)
    assert ("w = U" in c.guard) == (expanded > 0)


def test_bounds_are_guarded_element_by_element():
    labels = ["b_nt[0]", "b_nt[1]", "b_nt[2]"]
    judged = [rule.within_bounds("bounds.b_nt", values, [10.0, 10.0, 10.0], labels, -100.0, 100.0, "nT")
              for values in ([0, 50, -80], [0, 95, 0], [0, -105, 0], [0, 50, 120])]
    assert [c.conformity for c in judged] == ["pass", "conditionalPass", "conditionalFail", "fail"]
    assert "b_nt[1] 95" in judged[1].words and "b_nt[2] 120" in judged[3].words
    assert rule.overall(judged[:1]) == rule.PASS and rule.overall(judged[:3]) == rule.CONDITIONAL
    assert rule.overall(judged) == rule.FAIL


def test_a_station_and_plan_state_the_laboratory_serials_and_customer():
    station = load_station(STATIONS / "sim-commissioned.yaml")
    assert station.lab.name and station.lab.accreditation_id and station.lab.procedure_id
    assert [d.serial for d in station.duts] == [f"MMC-24-{i:04d}" for i in range(1, 7)]
    assert station.reference_magnetometers[0].serial == "REF-0001"
    plan = load_plan(CONFIGS_DIR / "plans" / "demo.yaml")
    assert plan.customer.name and plan.received.isoformat() == "2026-11-20" and plan.condition
    bare = load_station(STATIONS / "sim.yaml")  # every key optional: a station without them loads
    assert bare.lab is None and all(d.serial is None for d in bare.duts)


def test_a_misspelt_lab_key_is_refused_in_one_line(tmp_path):
    data = yaml.safe_load((STATIONS / "sim.yaml").read_text())
    data["lab"] = {"name": "X", "acreditation_id": "D-K-1", "country": "Germany"}
    path = tmp_path / "station.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(ConfigError) as err:
        load_station(path)
    lines = str(err.value).splitlines()
    assert any("lab.acreditation_id: unknown key; did you mean 'accreditation_id'?" in line for line in lines)
    assert any(line.startswith(f"{path}: lab.country: ") for line in lines)


def test_a_reference_certificate_is_read_whole_or_refused_naming_its_key(tmp_path):
    stated = reference_certificate(STATIONS / "sim-reference-cal-certified.yaml")
    assert stated.id == "EX-MAG-2026-0117" and stated.expanded_uncertainty_nt == 3.0
    assert reference_certificate(STATIONS / "sim-reference-cal.yaml") is None  # sim-lab's: none stated
    data = yaml.safe_load((STATIONS / "sim-reference-cal-certified.yaml").read_text())
    del data["source"]["certificate"]["date"]
    path = tmp_path / "ref.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(ConfigError, match=r"ref\.yaml: source\.certificate\.date: required key is missing "
                                          r"\(line \d+\)"):
        reference_certificate(path)


def test_dcc_numbers_read_back_exactly_and_match_the_schema_patterns():
    for x in (0.99536548619456, -92.8199616427763, 1.4418842723422016e-06, 1e16, -0.0, 50000.0):
        assert float(dcc_xml.decimal(x)) == x
    assert re.fullmatch(r"[-+]?((\d*\.\d+)|(\d+\.\d*)|(\d+\.?))([Ee][-+]?\d+)?", dcc_xml.decimal(1e-07))
    for k in (2.0, 2.0023435112556554, 12.706204736174704, 1.0):
        assert re.fullmatch(r"\+?(([1-9]\d*\.\d*)|([1-9]\d*))", dcc_xml.coverage_factor(k))
        assert float(dcc_xml.coverage_factor(k)) == k
    assert dcc_xml.probability(0.9545) == "0.9545"
    with pytest.raises(ValueError, match="not a number"):
        dcc_xml.decimal(float("nan"))


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # dsiUnits warns of `\\per` for any string
def test_every_parameter_of_every_model_has_a_valid_d_si_unit():
    names = {name for model in PARAM_SHAPES for name in [*PARAM_SHAPES[model], *OPTIONAL_PARAMS[model]]}
    assert names <= set(DSI_UNITS), names - set(DSI_UNITS)
    dsi = pytest.importorskip("dsi_unit")
    for name, unit in DSI_UNITS.items():
        parsed = dsi.DsiUnit(unit)
        assert parsed.valid and not parsed.warnings, (name, unit)
        assert "\\per" not in unit, (name, unit)  # deprecated in D-SI 2: \tothe{-N} instead
