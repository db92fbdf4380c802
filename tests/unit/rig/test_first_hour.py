"""What a newcomer meets first: every number said with its meaning (the station, simulated or real, what
dominates the uncertainty, a residual above its stated uncertainty flagged), the plan's judged calibration
named, every mistake of a config file listed with its line and a "did you mean", a simulated bus wired
like a real one, a piped run that does not print a line per point, and docs that match the files."""

from __future__ import annotations

import io
import re
from pathlib import Path
from types import SimpleNamespace

import pytest
import yaml

from drivers.clock import SimClock
from rig.analysis.judged import dominant_phrase, judged_cell, quality
from rig.cli import main
from rig.config import load_plan, load_station
from rig.core.errors import ConfigError
from rig.devices.simulated.bench import SimBench
from rig.engine.executor import RunStatus
from rig.run.display import PlainLog
from rig.run.summary import header_lines
from rig.session.reader import simulated_text
from tests.helpers.synthetic_session import SynthOptions, build_session

REPO = Path(__file__).resolve().parents[3]
CONFIGS = REPO / "configs"

# a budget as a calibration file carries it (literal: the words a reader of the file sees)
BUDGET = {"coverage_factor": 2.0, "expanded_vector_error_nt": 52.5, "combined_standard_nt": 26.0,
          "budget": [{"source": "fit (statistical)", "contribution_nt": 6.3, "note": "residual scatter"},
                     {"source": "coil matrix", "contribution_nt": 1227.3,
                      "note": "declared, 10000 ppm per element: not commissioned"},
                     {"source": "temperature", "contribution_nt": 1.3, "note": "+-0.15 degC"}]}


def test_the_largest_budget_line_in_one_phrase_from_its_source_and_note():
    assert dominant_phrase(BUDGET) == ("coil matrix 1227 nT (declared, 10000 ppm per element: not "
                                       "commissioned): run `rig commission`")
    commissioned = {"budget": [{"source": "position", "contribution_nt": 24.75, "note": "+-1 mm"}]}
    assert dominant_phrase(commissioned) == "position 24.75 nT (+-1 mm)"
    assert dominant_phrase(None) is None and dominant_phrase({"budget": []}) is None


def test_a_residual_above_the_stated_uncertainty_is_flagged():
    over, under = quality({"rms_after_nt": 380.6}, BUDGET), quality({"rms_after_nt": 29.0}, BUDGET)
    assert over.exceeds and not under.exceeds
    assert over.exceeds_text().startswith("residual RMS 380.6 nT is above its stated 95 % error radius "
                                          "52.5 nT")
    assert under.exceeds_text() == "" and not quality({"rms_after_nt": 380.6}, None).exceeds
    fits = {"a": {"residual_rms_nt": 380.6, "calibration": {"stats": {"rms_after_nt": 380.6},
                                                            "uncertainty": BUDGET}},
            "b": {"residual_rms_nt": 29.0, "calibration": {"stats": {"rms_after_nt": 29.0},
                                                           "uncertainty": BUDGET}}}
    assert judged_cell("p12", fits) == "p12 RMS: a 380.6, b 29.0 nT [RMS > radius: a]"
    assert judged_cell("t24", {}) == "no t24 fit" and judged_cell(None, {}) == "no fit"


def test_a_run_says_first_which_station_it_is_and_why_its_uncertainties_will_be_large():
    sim = CONFIGS / "stations" / "sim.yaml"
    lines = header_lines(load_station(sim), sim)
    assert lines[0].startswith(f"station sim ({sim}): every device simulated (chamber, coils, mmc0, ")
    assert "on a simulated clock" in lines[0]
    assert lines[1].startswith("note: the coils are not commissioned: each coil constant is taken as "
                               "uncertain by its declared 10000 ppm (1 %)") and "`rig commission`" in lines[1]
    commissioned = CONFIGS / "stations" / "sim-commissioned.yaml"
    from rig.config.loading import load_campaign

    campaign = load_campaign(CONFIGS / "plans" / "demo.yaml", commissioned)
    assert len(header_lines(campaign.station, commissioned)) == 1  # commissioned: nothing to excuse
    assert simulated_text({"chamber": False, "mmc0": True}) == "simulated: mmc0; real: chamber"


def test_the_plan_judges_its_acceptance_model_else_its_first_model(tmp_path):
    text = (CONFIGS / "plans" / "demo.yaml").read_text().replace("station: ../stations/sim.yaml", "")
    plan = tmp_path / "plan.yaml"
    plan.write_text(text)
    assert load_plan(plan).judged_model == "t24"
    plan.write_text(text.replace("models: [t24, p12]", "models: [p12, t24]"))
    assert load_plan(plan).judged_model == "p12"
    plan.write_text(text + "acceptance: {model: t24, max_rms_nt: 100}\n")
    assert load_plan(plan).judged_model == "t24"


def test_a_piped_run_prints_progress_at_most_every_few_seconds():
    status, stream, now = RunStatus(), io.StringIO(), [0.0]
    status.points_total = 30
    log = PlainLog(status, SimpleNamespace(on_point=[]), stream=stream, every_s=5.0, monotonic=lambda: now[0])
    for i in range(30):  # a point every second of wall time
        now[0] = float(i)
        log.point_done(f"T01-F{i + 1:02d}")
        status.points_done += 1
    shown = [line.split()[0] for line in stream.getvalue().splitlines()]
    assert shown == ["T01-F01", "T01-F06", "T01-F11", "T01-F16", "T01-F21", "T01-F26", "T01-F30"]
    every_point = PlainLog(RunStatus(points_total=3), SimpleNamespace(on_point=[]), stream=io.StringIO(),
                           every_s=0.0, monotonic=lambda: 0.0)
    for i in range(3):
        every_point.point_done(f"P{i}")
    assert len(every_point.stream.getvalue().splitlines()) == 3  # --progress-every 0: one line per point


def test_rig_sessions_without_a_folder_looks_in_sessions(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["sessions"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: sessions/: no such folder here") and err.count("\n") == 1
    (tmp_path / "sessions").mkdir()
    build_session(tmp_path / "sessions" / "a.session", SynthOptions(temps_c=(0.0, 20.0), directions=6))
    assert main(["sessions"]) == 0
    assert capsys.readouterr().out.splitlines()[1].startswith("a.session")


def test_every_problem_of_a_config_file_is_listed_with_its_line_and_a_near_miss_named(tmp_path, capsys):
    text = (CONFIGS / "plans" / "demo.yaml").read_text()
    station = str(CONFIGS / "stations" / "sim.yaml")
    bad = (text.replace("samples_per_point: 5", "samples_per_pont: 5")
           .replace("settle_s: 0.5", "settle_s: -1")
           .replace("robust: false", "robus: false").replace("../stations/sim.yaml", station))
    plan = tmp_path / "plan.yaml"
    plan.write_text(bad)
    lines = bad.splitlines()

    def line_of(key: str) -> int:
        return next(i + 1 for i, line in enumerate(lines) if line.lstrip().startswith(key))

    assert main(["check", str(plan)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == [
        f"error: {plan}: samples_per_pont: unknown key; did you mean 'samples_per_point'? "
        f"(line {line_of('samples_per_pont')})",
        f"error: {plan}: settle_s: must be >= 0 (line {line_of('settle_s')})",
        f"error: {plan}: fit.robus: unknown key; did you mean 'robust'? (line {line_of('robus')})",
    ]


def _station(tmp_path: Path, second: dict) -> Path:
    data = yaml.safe_load((CONFIGS / "stations" / "sim.yaml").read_text())
    data["sim"]["duts"] = {}
    wired = {"kind": "sim", "bus": 0, "address": 0x30}
    data["duts"] = [{"name": "mmc0", "type": "mmc5983ma", "transport": wired,
                     "options": {"bandwidth_hz": 100, "set_reset": True}, "temp_source": "tmp0"},
                    {**second, "temp_source": "tmp1"}]
    data["temperature_sensors"][1]["beside"] = second["name"]
    path = tmp_path / "station.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_two_simulated_chips_at_one_explicit_address_without_a_switch_are_refused_as_real_ones(tmp_path):
    second = {"name": "mmc1", "type": "mmc5983ma", "transport": {"kind": "sim", "bus": 0, "address": 0x30},
              "options": {"bandwidth_hz": 100, "set_reset": True}}
    with pytest.raises(ConfigError) as err:
        load_station(_station(tmp_path, second))
    assert re.fullmatch(r".*station\.yaml: duts\[1\]\.transport\.address: 0x30 on i2c-0 is taken twice: "
                        r"mmc1 and mmc0 \(duts\[0\]\); put one behind another switch channel \(line \d+\)",
                        str(err.value))
    real = {**second, "transport": {"kind": "i2c", "bus": 0, "address": 0x30}}
    data = yaml.safe_load(_station(tmp_path, real).read_text())
    data["duts"][0]["transport"] = {"kind": "i2c", "bus": 0, "address": 0x30}
    (tmp_path / "real.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(ConfigError, match="0x30 on i2c-0 is taken twice: mmc1 and mmc0"):
        load_station(tmp_path / "real.yaml")  # the same words for the same clash on a real bus


def test_simulated_chips_wired_to_one_bus_share_it(tmp_path):
    second = {"name": "hmc0", "type": "hmc5883l", "transport": {"kind": "sim", "bus": 0, "address": 0x1E}}
    station = load_station(_station(tmp_path, second))
    bench = SimBench(station, SimClock())
    try:
        for dut in station.duts:
            bench.link(dut)
        assert sorted(bench.i2c_bus(0).chips) == [0x1E, 0x30]  # one simulated i2c-0, as on the bench
    finally:
        bench.stop()


def test_the_configs_readme_describes_the_demo_as_it_is():
    plan = yaml.safe_load((CONFIGS / "plans" / "demo.yaml").read_text())
    readme = (CONFIGS / "README.md").read_text()
    line = next(line for line in readme.splitlines() if line.strip().startswith("plans/demo.yaml"))
    described = re.search(r"(\d+) temperatures x (\d+) field directions x (\d+) samples", line)
    steps, fields, samples = map(int, described.groups())
    assert (steps, fields, samples) == (len(plan["temperatures"]["steps"]), len(plan["fields"]["directions"]),
                                        plan["samples_per_point"])
    assert f"models {' and '.join(plan['fit']['models'])}" in line


def test_rig_design_prints_its_targets_with_units(tmp_path, capsys):
    out = tmp_path / "designed.yaml"
    # sim-4 with its DUTs' noise and lags stated (duts[].expect): a design needs measured or stated ones
    plan, station = CONFIGS / "plans" / "sequential-campaign.yaml", tmp_path / "stated.yaml"
    text = (CONFIGS / "stations" / "sim-4.yaml").read_text()
    stated = "expect: {noise_nt: 40, thermal_lag_s: 400}, temp_source: tmp"
    station.write_text(text.replace("temp_source: tmp", stated))
    assert main(["design", str(plan), "--station", str(station), "-o", str(out)]) == 0
    text = capsys.readouterr().out
    targets = re.search(r"targets (.*):\n", text).group(1)
    assert re.fullmatch(r"S \S+, K \S+ /degC, b \S+ nT, kb \S+ nT/degC", targets), targets
    assert re.search(r"after leg 1 .*: S \S+, K \S+ /degC, b \S+ nT, kb \S+ nT/degC", text)
