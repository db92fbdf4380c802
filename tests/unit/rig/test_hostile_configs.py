"""Hostile plans and stations through the real command line: each is refused with exit code 2 and one
line `error: FILE: key.path: what (line N)`, before any big allocation, and nothing is written
outside --out."""

from __future__ import annotations

import re
import tracemalloc
from pathlib import Path

import pytest

from rig.cli import main
from tests.helpers.small_plan import PLAN
from tests.helpers.small_plan import plan_with as _plan

CONFIGS = Path(__file__).resolve().parents[3] / "configs"
STATION = (CONFIGS / "stations" / "sim.yaml").read_text()
CUBE = "kind: cube24, magnitude_nt: 50000"
AMBIENT = "ambient_nt: [15000, 500, 42000] # what"


def _station(old: str, new: str) -> str:
    assert old in STATION
    return STATION.replace(old, new)


def _rename_dut(name: str) -> str:
    return (STATION.replace("name: mmc0", f"name: {name}").replace("    mmc0:", f"    {name}:")
            .replace("beside: mmc0", f"beside: {name}"))


# (document, text, key path, line) — the line is where the offending key or item is written
PLANS = {
    "name with ..": (_plan("name: p", "name: ../escape"), "name", 1),
    "absolute name": (_plan("name: p", "name: /tmp/escape"), "name", 1),
    "inf settle": (_plan("settle_s: 0.5", "settle_s: .inf"), "settle_s", 7),
    "inf as text": (_plan("settle_s: 0.5", "settle_s: '-Infinity'"), "settle_s", 7),
    "nan setpoint": (_plan("[0, 25]", "[0, .nan]"), "temperatures.steps[1]", 3),
    "boolean samples": (_plan("samples_per_point: 2", "samples_per_point: true"), "samples_per_point", 6),
    "1e14 samples": (_plan("samples_per_point: 2", "samples_per_point: 1.0e+14"), "samples_per_point", 6),
    "boolean magnitude": (_plan("magnitude_nt: 50000", "magnitude_nt: true"), "fields.magnitude_nt", 5),
    "huge magnitude": (_plan("magnitude_nt: 50000", "magnitude_nt: 1.0e+300"), "fields.magnitude_nt", 5),
    "huge dwell": (_plan("ramp_c_per_min: 3", "ramp_c_per_min: 3\n  stability: {dwell_s: 1.0e+300}"),
                   "temperatures.stability.dwell_s", 5),
    "tiny ramp": (_plan("ramp_c_per_min: 3", "ramp_c_per_min: 1.0e-300"), "temperatures.ramp_c_per_min", 4),
    "range bomb": (_plan("steps: [0, 25]", "range: {start_c: -40, stop_c: 85, step_c: 1.0e-9}"),
                   "temperatures.range.step_c", 3),
    "field bomb": (_plan("kind: cube24, magnitude_nt: 50000",
                         "kind: fibonacci, n: 10000, magnitudes_nt: [" + ", ".join(["5.0e+4"] * 3000) + "]"),
                   "fields", 5),
    "sample bomb": (_plan("samples_per_point: 2", "samples_per_point: 100000"), "samples_per_point", 6),
    "alias bomb": (PLAN + "x: &a [1, 1, 1, 1, 1, 1, 1, 1, 1]\ny: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a]\n"
                   "z: [*b, *b, *b, *b, *b, *b, *b, *b, *b]\n", "y[0]", 9),
    "deep nesting": (PLAN + "x: " + "[" * 500 + "]" * 500 + "\n", "x" + "[0]" * 31, 8),
    "setpoint above the chamber": (_plan("[0, 25]", "[0, 200]"), "temperatures.steps[1]", 3),
    "field kind for a turntable": (_plan(CUBE, "kind: grid"), "fields.kind", 5),
    "zero direction": (_plan(CUBE, "kind: directions, directions: [[0, 0, 0]]"),
                       "fields.directions", 5),
    "missing key in a list item": (_plan("steps: [0, 25]", "steps:\n    - {ramp_c_per_min: 1}"),
                                   "temperatures.steps[0].setpoint_c", 4),
    # numbers: booleans, inf/NaN (also as text too long to look like a number at first sight), words
    "boolean settle": (_plan("settle_s: 0.5", "settle_s: true"), "settle_s", 7),
    "boolean dwell": (_plan("ramp_c_per_min: 3", "ramp_c_per_min: 3\n  stability: {dwell_s: true}"),
                      "temperatures.stability.dwell_s", 5),
    "nan max wait as long text": (_plan("ramp_c_per_min: 3",
                                        "ramp_c_per_min: 3\n  stability: {max_wait_s: '          nan'}"),
                                  "temperatures.stability.max_wait_s", 5),
    "boolean setpoint": (_plan("[0, 25]", "[0, true]"), "temperatures.steps[1]", 3),
    "word setpoint": (_plan("[0, 25]", "[0, warm]"), "temperatures.steps[1]", 3),
    "boolean step ramp": (_plan("[0, 25]", "[0, {setpoint_c: 25, ramp_c_per_min: true}]"),
                          "temperatures.steps[1].ramp_c_per_min", 3),
    "boolean in magnitudes": (_plan("magnitude_nt: 50000", "magnitudes_nt: [50000, true]"),
                              "fields.magnitudes_nt[1]", 5),
    "boolean vector component": (_plan(CUBE, "kind: vectors, vectors_nt: [[1, 0, 0], [0, true, 0]]"),
                                 "fields.vectors_nt[1][1]", 5),
    "inf vector component as long text": (
        _plan(CUBE, "kind: vectors, vectors_nt: [['          -inf', 0, 0]]"), "fields.vectors_nt[0][0]", 5),
    "huge direction": (_plan(CUBE, "kind: directions, directions: [[1.0e+300, 0, 1]]"),
                       "fields.directions[0]", 5),
    "boolean fibonacci n": (_plan(CUBE, "kind: fibonacci, n: true"), "fields.n", 5),
}

STATIONS = {
    "DUT name with /": (_rename_dut("a/b"), "duts[0].name", 35),
    "non-ASCII DUT name": (_rename_dut("mägo"), "duts[0].name", 35),
    "DUT names equal but for case": (STATION.replace("name: serial0", "name: MMC0")
                                     .replace("    serial0:", "    MMC0:")
                                     .replace("beside: serial0", "beside: MMC0"), "duts[1].name", 40),
    "inf ambient": (_station(AMBIENT, AMBIENT.replace("15000", ".inf")),
                    "field_source.ambient_nt[0]", 32),
    "boolean ambient": (_station(AMBIENT, AMBIENT.replace("15000", "true")),
                        "field_source.ambient_nt[0]", 32),
    "nan coil constant": (_station("- [50000, 0, 0]", "- ['nan', 0, 0]"),
                          "field_source.coil_constants_nt_per_a[0][0]", 29),
    "huge coil constant": (_station("- [50000, 0, 0]", "- [1.0e+300, 0, 0]"),
                           "field_source.coil_constants_nt_per_a[0]", 29),
    "boolean chamber limit": (_station("max_ramp_c_per_min: 5", "max_ramp_c_per_min: true"),
                              "chamber.limits.max_ramp_c_per_min", 17),
    "nan chamber limit as long text": (_station("max_setpoint_c: 85", "max_setpoint_c: '         nan'"),
                                       "chamber.limits.max_setpoint_c", 17),
    "chamber limit beyond physics": (_station("max_setpoint_c: 85", "max_setpoint_c: 1.0e+300"),
                                     "chamber.limits.max_setpoint_c", 17),
    "boolean chamber unit": (_station("unit: 1", "unit: true"), "chamber.unit", 16),
    "boolean alarm register": (_station("register: 60000", "register: true"), "chamber.alarm.register", 21),
    "boolean max current": (_station("max_current_a: 2.0", "max_current_a: true"),
                            "field_source.max_current_a", 27),
    "nan max current as long text": (_station("max_current_a: 2.0", "max_current_a: '          NaN'"),
                                     "field_source.max_current_a", 27),
    "boolean DUT option": (_station("bandwidth_hz: 100", "bandwidth_hz: true"),
                           "duts[0].options.bandwidth_hz", 38),
    "boolean seed": (_station("seed: 2026", "seed: true"), "sim.seed", 6),
    "boolean sim air": (_station("air_c: 22.0", "air_c: true"), "sim.air_c", 8),
    "boolean sim noise": (_station("noise_nt: 40", "noise_nt: true"), "sim.duts.mmc0.noise_nt", 10),
    "inf sim ambient as long text": (_station("ambient_nt: [15000, 500, 42000] # true",
                                              "ambient_nt: ['         inf', 500, 42000] # true"),
                                     "sim.ambient_nt[0]", 7),
}

ERROR_LINE = re.compile(r"error: (?P<file>\S+): (?P<path>\S+): (?P<what>.+) \(line (?P<line>\d+)\)\n")


def _one_line_error(capsys, argv) -> re.Match:
    tracemalloc.start()
    try:
        code = main([str(a) for a in argv])
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    out, err = capsys.readouterr()
    assert code == 2 and out == "", err
    assert err.count("\n") == 1, err
    assert peak < 50e6, f"{peak / 1e6:.0f} MB allocated before refusing"
    match = ERROR_LINE.fullmatch(err)
    assert match, err
    return match


@pytest.mark.parametrize("case", PLANS)
def test_hostile_plan_is_refused_in_one_line(case, tmp_path, capsys):
    text, path, line = PLANS[case]
    plan = tmp_path / "plan.yaml"
    plan.write_text(text)
    m = _one_line_error(capsys, ["check", plan, "--station", CONFIGS / "stations" / "sim.yaml"])
    assert (m["file"], m["path"], int(m["line"])) == (str(plan), path, line)


@pytest.mark.parametrize("case", STATIONS)
def test_hostile_station_is_refused_in_one_line(case, tmp_path, capsys):
    text, path, line = STATIONS[case]
    (tmp_path / "plan.yaml").write_text(PLAN)
    station = tmp_path / "station.yaml"
    station.write_text(text)
    m = _one_line_error(capsys, ["check", tmp_path / "plan.yaml", "--station", station])
    assert (m["file"], m["path"], int(m["line"])) == (str(station), path, line)


def test_an_oversize_config_is_refused_unread(tmp_path, capsys):
    plan = tmp_path / "plan.yaml"
    plan.write_text(PLAN + "# " + "x" * (2 << 20) + "\n")
    assert main(["check", str(plan)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"error: {plan}: ") and "too big" in err


@pytest.mark.parametrize("where", ["argument", "--station", "plan's station key"])
def test_a_folder_given_as_a_file_is_one_line(where, tmp_path, capsys):
    folder = tmp_path / "folder.yaml"
    folder.mkdir()
    plan = tmp_path / "plan.yaml"
    plan.write_text(PLAN + (f"station: {folder.name}\n" if where == "plan's station key" else ""))
    argv = {"argument": ["check", folder], "--station": ["check", plan, "--station", folder],
            "plan's station key": ["check", plan]}[where]
    assert main([str(a) for a in argv]) == 2
    out, err = capsys.readouterr()
    assert err.count("\n") == 1 and str(folder) in err and "Usage" not in err, err


@pytest.mark.parametrize("name", ["../escape", "/tmp/magrig-escape", "sub/dir"])
def test_run_writes_nothing_outside_out(name, tmp_path, capsys):
    work = tmp_path / "work"
    out = work / "out"
    work.mkdir()
    plan = work / "plan.yaml"
    plan.write_text(_plan("name: p", f"name: {name}"))
    before = set(tmp_path.rglob("*"))
    assert main(["run", str(plan), "--out", str(out), "--no-live"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{plan}: name: " in err and "(line 1)" in err
    assert set(tmp_path.rglob("*")) == before
    assert not Path("/tmp/magrig-escape-").exists()


def test_resume_of_a_session_with_a_hostile_dut_name_is_one_line(tmp_path, capsys):
    """A session recorded before the names rule: its station is reread through the same checks."""
    from rig.config.loading import load_campaign
    from rig.schedules.compile import compile_plan
    from rig.session.writer import Session

    (tmp_path / "plan.yaml").write_text(PLAN)
    (tmp_path / "station.yaml").write_text(STATION)
    campaign = load_campaign(tmp_path / "plan.yaml", tmp_path / "station.yaml")
    hostile = _rename_dut("a/b")
    campaign = type(campaign)(campaign.plan, campaign.station, campaign.plan_path, campaign.station_path,
                              campaign.plan_text, hostile)
    session = tmp_path / "old.session"
    Session.create_for(session, campaign, compile_plan(campaign.plan, campaign.station)).close()
    (tmp_path / "station.yaml").write_text(hostile)  # the file as it was recorded (a resume checks that)
    assert main(["run", "--resume", str(session), "--no-live"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "duts[0].name: 'a/b': character '/' is not allowed" in err
    assert "(line 35)" in err


@pytest.mark.parametrize("case", [("plan", c) for c in PLANS] + [("station", c) for c in STATIONS])
def test_run_refuses_every_hostile_config_in_the_line_check_gives(case, tmp_path, capsys, monkeypatch):
    """`rig run` says what `rig check` says, and never reaches the point of opening a device."""
    import rig.run.campaign

    def refuse(*args, **kwargs):
        raise AssertionError("open_rig was reached")

    monkeypatch.setattr(rig.run.campaign, "open_rig", refuse)
    document, name = case
    plan, station = tmp_path / "plan.yaml", tmp_path / "station.yaml"
    plan.write_text(PLANS[name][0] if document == "plan" else PLAN)
    station.write_text(STATIONS[name][0] if document == "station" else STATION)
    checked = _one_line_error(capsys, ["check", plan, "--station", station])
    ran = _one_line_error(capsys, ["run", plan, "--station", station, "--out", tmp_path / "out", "--no-live"])
    assert ran.group(0) == checked.group(0)
    assert not (tmp_path / "out").exists()
