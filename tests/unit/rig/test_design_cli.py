"""`rig design` and the designed / sequential plans it and the user write: accepted by rig check, with the
predicted standard errors and their figure; planned only on what the station states or what was measured
(never the simulated world's own values), else refused in one line naming the three ways; bad input
refused in one located line."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from rig.cli import main
from rig.config.loading import load_campaign
from rig.schedules.compile import check_campaign, compile_plan
from tests.helpers.statistics import sigma_bounds

CONFIGS = Path(__file__).resolve().parents[3] / "configs"
SIM4 = CONFIGS / "stations" / "sim-4.yaml"
SIM = CONFIGS / "stations" / "sim.yaml"
SEQUENTIAL = CONFIGS / "plans" / "sequential-campaign.yaml"
DESIGNED = CONFIGS / "plans" / "designed-campaign.yaml"
TARGETS = {"S": 3e-5, "K": 8e-7, "b": 1.0, "kb": 0.03}


def run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def stating_station(tmp_path: Path, **expect: dict) -> Path:
    """sim.yaml with its DUTs' noise and lags stated as a lab states them (duts[].expect)."""
    data = yaml.safe_load(SIM.read_text())
    for dut in data["duts"]:
        dut["expect"] = expect.get(dut["name"], {"noise_nt": 40.0, "thermal_lag_s": 400.0})
    path = tmp_path / "stating.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def write_plan(tmp_path: Path, name: str = "p", **overrides) -> Path:
    data = {"name": name, "temperatures": {"steps": [-20, 10, 40, 60]},
            "fields": {"kind": "cube24", "magnitudes_nt": [30000, 60000]}, "samples_per_point": 10,
            "settle_s": 1.0, "fit": {"models": ["t24"]}, "stop_when": TARGETS}
    data.update(overrides)
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_design_writes_a_plan_rig_check_accepts_with_its_predicted_errors(tmp_path, capsys):
    plan = write_plan(tmp_path, field_order="shuffled")  # a step plan's order: not the designed sweeps
    station = stating_station(tmp_path)
    out_path = tmp_path / "sub" / "designed.yaml"
    code, out, err = run(capsys, "design", plan, "--station", station, "-o", out_path)
    assert code == 0, err
    assert "predicted standard errors" in out and "targets met by every DUT" in out
    assert "mmc0: noise 28.3 nT, lag 400 s (stated in the station (duts[].expect), not measured)" in out
    assert "the station's stated limit, not a measurement" in out
    assert f"rig check of {out_path}: OK" in out
    data = yaml.safe_load(out_path.read_text())
    temps = data["temperatures"]
    assert temps["mode"] == "designed" and data["stop_when"] == TARGETS
    ends = [leg["to_c"] for leg in temps["legs"] if not leg.get("check")]
    assert sorted({ends[0], ends[-1]}) == [-20, 60]  # the information lies at the ends of the range
    assert any(leg.get("check") for leg in temps["legs"])  # interior temperatures for the model check
    assert set(temps["assumed"]) == {"mmc0", "serial0"} and "timing" not in temps  # no pace measured
    assert temps["range_c"] == [-20, 60]
    assert "field_order" not in data
    assert data["fields"]["kind"] == "vectors" and len(data["fields"]["vectors_nt"]) >= 8
    assert (out_path.parent / data["station"]).resolve() == station.resolve()  # relative to the new file
    # rig check of the written plan (station from the plan itself) shows the prediction, and draws it
    figure = tmp_path / "pred.png"
    code, out, err = run(capsys, "check", out_path, "--figure", figure)
    assert code == 0, err
    assert "designed schedule:" in out and "predicted standard errors" in out
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    points = compile_plan(*_plan_station(out_path))
    assert points[0].id == "L01-S001-F01" and len({p.id for p in points}) == len(points)


def _plan_station(path: Path):
    campaign = load_campaign(path)
    return campaign.plan, campaign.station


def test_a_sequential_plan_checks_without_measured_lags_and_the_shipped_designed_plan_checks(capsys):
    code, out, err = run(capsys, "check", SEQUENTIAL, "--station", SIM4)
    assert code == 0, err
    assert "points planned before the run (the first sweep)" in out
    assert "not predicted: no measured lags; the run characterises each DUT on its first leg" in out
    campaign = load_campaign(DESIGNED)
    report = check_campaign(campaign)
    assert report.prediction is not None and report.prediction.met
    text = "\n".join(report.summary_lines())
    assert "the plan's assumed values" in text and "the plan's timing, measured by session" in text
    assert "from sequential-campaign.yaml and the noise and lags of session" in DESIGNED.read_text()


def test_design_refuses_without_measured_or_stated_noise_and_lags(tmp_path, capsys):
    plan = write_plan(tmp_path)
    code, out, err = run(capsys, "design", plan, "--station", SIM, "-o", tmp_path / "x.yaml")
    assert code == 2 and out == "" and err.count("\n") == 1, err
    assert err.startswith(f"error: {SIM}: duts[0]: no measured or stated noise and thermal lag for mmc0, "
                          "serial0") and "(line " in err
    for way in ("rig design --from SESSION", "rig commission --thermal", "duts[].expect"):
        assert way in err
    assert not (tmp_path / "x.yaml").exists()


@pytest.fixture(scope="module")
def small_session(tmp_path_factory) -> Path:
    """A short step session of sim.yaml's DUTs: 20 and 30 degC, the six axis directions."""
    from rig.run.campaign import run_campaign

    tmp_path = tmp_path_factory.mktemp("small")
    small = write_plan(tmp_path, "small", temperatures={"steps": [20, 30], "stability": {"dwell_s": 30}},
                       fields={"kind": "directions", "magnitude_nt": 50000,
                               "directions": [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0,
                                                                                                        -1]]},
                       samples_per_point=16)
    session = tmp_path / "small.session"
    assert run_campaign(campaign=load_campaign(small, SIM), session_path=session).result.status == "completed"
    return session


def test_design_uses_an_earlier_sessions_noise_lags_and_pace(tmp_path, capsys, small_session):
    code, out, err = run(capsys, "design", write_plan(tmp_path), "--station", SIM, "--from", small_session,
                         "-o", tmp_path / "d.yaml")
    assert code == 0, err
    assert "session small.session: noise from the fit residual, lag and offset from its temperature " \
           "against the air" in out
    temps = yaml.safe_load((tmp_path / "d.yaml").read_text())["temperatures"]
    assumed = temps["assumed"]
    # its first-order lag behind the air from the session's temperatures (the simulated mount's 300 s and
    # 450 s; not read, measured), where it settles (the simulated places are the air's)
    assert assumed["mmc0"]["lag_s"] == pytest.approx(300.0, rel=0.05)
    assert assumed["serial0"]["lag_s"] == pytest.approx(450.0, rel=0.05)
    assert abs(assumed["mmc0"]["offset_c"]) < 0.1
    assert temps["timing"]["measured_by"] == "session small.session" and temps["timing"]["sample_s"] > 0
    # the fitted noise of mmc0 (40 nT a reading; a SET/RESET pair halves the difference of two: 28.3),
    # the largest of its three axes' residual sigmas (192 rows, 8 parameters each), not the station's 40
    low, high = sigma_bounds(40.0 / 2**0.5, 192 - 8, n=3)
    assert low < assumed["mmc0"]["noise_nt"] < high < 40.0


def test_the_design_from_a_session_is_the_same_whatever_the_simulated_world_states(tmp_path, capsys,
                                                                                   small_session):
    """The station's `sim.duts` noise and lags are the simulator's alone: tripled, or left out, the design
    from the same session does not change by a digit."""
    data = yaml.safe_load(SIM.read_text())
    tripled = tmp_path / "tripled.yaml"
    data["sim"]["duts"] = {name: {**d, "thermal_lag_s": 3 * d["thermal_lag_s"], "noise_nt": 3 * d["noise_nt"]}
                           for name, d in data["sim"]["duts"].items()}
    tripled.write_text(yaml.safe_dump(data, sort_keys=False))
    silent = tmp_path / "silent.yaml"
    data["sim"].pop("duts")
    silent.write_text(yaml.safe_dump(data, sort_keys=False))
    plans = []
    for station in (SIM, tripled, silent):
        out_path = tmp_path / f"d-{station.stem}.yaml"
        code, _, err = run(capsys, "design", write_plan(tmp_path), "--station", station, "--from",
                           small_session, "-o", out_path)
        assert code == 0, err
        body = yaml.safe_load(out_path.read_text())
        body.pop("station")
        plans.append(body)
    assert plans[0] == plans[1] == plans[2]


@pytest.mark.parametrize(("edit", "expected"), [
    ({"stop_when": None}, "nothing to design for"),
    ({"temperatures": {"steps": [25]}}, "needs a range"),
])
def test_design_refuses_a_plan_it_cannot_design_for(tmp_path, capsys, edit, expected):
    plan = write_plan(tmp_path, **edit)
    code, out, err = run(capsys, "design", plan, "--station", SIM, "-o", tmp_path / "x.yaml")
    assert code == 2 and err.count("\n") == 1 and expected in err, err
    assert not (tmp_path / "x.yaml").exists()


def test_design_refuses_a_missing_session(tmp_path, capsys):
    code, _, err = run(capsys, "design", write_plan(tmp_path), "--station", SIM, "--from",
                       tmp_path / "none.session")
    assert code == 2 and err.count("\n") == 1 and "no such session file" in err


LEG_PLAN = """name: legs
temperatures:
  mode: designed
  rate_c_per_min: 3
  legs:
    - {to_c: -20, sweeps: 3}
    - {to_c: 95, sweeps: 3}
fields: {kind: cube24}
samples_per_point: 2
"""


@pytest.mark.parametrize(("text", "where"), [
    (LEG_PLAN, "temperatures.legs[1].to_c: 95 degC is outside chamber.limits"),
    (LEG_PLAN.replace("95", "60").replace("rate_c_per_min: 3", "rate_c_per_min: 9"),
     "temperatures.rate_c_per_min: 9 degC/min exceeds"),
    (LEG_PLAN.replace("sweeps: 3}\n    - {to_c: 95", "sweeps: 0}\n    - {to_c: 95"),
     "temperatures.legs[0].sweeps"),
    ("name: s\ntemperatures: {mode: sequential, range_c: [-20, 60], rate_c_per_min: 3}\n"
     "fields: {kind: cube24}\nsamples_per_point: 2\n", "temperatures.mode: a sequential schedule stops when"),
    ("name: s\ntemperatures: {mode: sequential, range_c: [-20, 60], rate_c_per_min: 3, checks_c: [70]}\n"
     "fields: {kind: cube24}\nsamples_per_point: 2\nstop_when: {K: 1e-6}\n",
     "temperatures.checks_c[0]: 70 degC"),
    ("name: s\ntemperatures: {mode: sequential, range_c: [-20, 60], rate_c_per_min: 3, max_duration_h: 0}\n"
     "fields: {kind: cube24}\nsamples_per_point: 2\nstop_when: {K: 1e-6}\n", "temperatures.max_duration_h"),
    ("name: s\ntemperatures: {mode: designer, legs: []}\nfields: {kind: cube24}\nsamples_per_point: 2\n",
     "temperatures: mode must be ramp, designed or sequential"),
])
def test_bad_designed_and_sequential_plans_are_refused_in_one_located_line(tmp_path, capsys, text, where):
    plan = tmp_path / "bad.yaml"
    plan.write_text(text)
    code, out, err = run(capsys, "check", plan, "--station", SIM)
    assert code == 2 and out == "" and err.count("\n") == 1, err
    assert err.startswith(f"error: {plan}: ") and where in err and "(line " in err, err


def test_figure_needs_a_plan_that_predicts(tmp_path, capsys):
    code, _, err = run(capsys, "check", CONFIGS / "plans" / "demo.yaml", "--figure", tmp_path / "f.png")
    assert code == 2 and "predicts no standard errors" in err and err.count("\n") == 1


def test_a_session_that_cannot_show_the_noise_is_named_in_one_line(tmp_path, capsys):
    from rig.run.campaign import run_campaign

    one = write_plan(tmp_path, "one", temperatures={"steps": [25], "stability": {"dwell_s": 30}},
                     samples_per_point=2, fit={"models": ["p12"]}, stop_when=None)
    session = tmp_path / "one.session"
    assert run_campaign(campaign=load_campaign(one, SIM), session_path=session).result.status == "completed"
    code, out, err = run(capsys, "design", write_plan(tmp_path), "--station", SIM, "--from", session,
                         "-o", tmp_path / "x.yaml")
    assert code == 2 and out == "" and err.count("\n") == 1, err
    assert err.startswith(f"error: --from {session}: mmc0: T24: ") and "not identifiable" in err
