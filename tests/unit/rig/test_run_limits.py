"""`rig run` (fresh and `--resume`) refuses what `rig check` refuses, in the same one line, before any
device is opened: open_rig is never reached, so no simulator (or chamber) sees a single write, and no
session is created."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import rig.run.campaign
from rig.cli import main
from rig.config.loading import load_campaign
from rig.session.reader import SessionReader
from rig.session.writer import Session
from tests.helpers.small_plan import PLAN
from tests.helpers.small_plan import plan_with as _plan

CONFIGS = Path(__file__).resolve().parents[3] / "configs"
STATION = CONFIGS / "stations" / "sim.yaml"


# (plan text, key path, line, words of the message)
HOSTILE = {
    "setpoint 200 degC": (_plan("[0, 25]", "[0, 200]"), "temperatures.steps[1]", 3, "max_setpoint_c 85"),
    "infinite ramp": (_plan("ramp_c_per_min: 3", "ramp_c_per_min: .inf"), "temperatures.ramp_c_per_min", 4,
                      "finite"),
    "infinite ramp as long text": (_plan("ramp_c_per_min: 3", "ramp_c_per_min: '0000000000000000001e999'"),
                                   "temperatures.ramp_c_per_min", 4, "finite"),
    "ramp 50 degC/min": (_plan("ramp_c_per_min: 3", "ramp_c_per_min: 50"), "temperatures.ramp_c_per_min", 4,
                         "max_ramp_c_per_min 5"),
    "step ramp 50 degC/min": (_plan("steps: [0, 25]", "steps: [0, {setpoint_c: 25, ramp_c_per_min: 50}]"),
                              "temperatures.steps[1].ramp_c_per_min", 3, "max_ramp_c_per_min 5"),
    "field 500 000 nT": (_plan("magnitude_nt: 50000", "magnitude_nt: 500000"), "fields", 5, "max_current_a"),
    "vector 500 000 nT": (_plan("{kind: cube24, magnitude_nt: 50000}",
                                "{kind: vectors, vectors_nt: [[500000, 0, 0], [0, 1, 0]]}"),
                          "fields.vectors_nt[0]", 5, "max_current_a"),
    "nan setpoint": (_plan("[0, 25]", "[0, .nan]"), "temperatures.steps[1]", 3, "finite"),
    "nan setpoint as long text": (_plan("steps: [0, 25]",
                                        "range: {start_c: '           nan', stop_c: 25, step_c: 5}"),
                                  "temperatures.range.start_c", 3, "finite"),
}
ERROR_LINE = re.compile(r"error: (?P<file>.+?): (?P<path>\S+): (?P<what>.+) \(line (?P<line>\d+)\)\n")


@pytest.fixture
def opened(monkeypatch) -> list:
    """Records every open_rig call (and refuses to open anything): a refused run makes none."""
    calls: list = []

    def refuse(*args, **kwargs):
        calls.append(args)
        raise AssertionError("open_rig was reached: a device could have been commanded")

    monkeypatch.setattr(rig.run.campaign, "open_rig", refuse)
    return calls


def _refused(capsys, argv) -> re.Match:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert code == 2, err
    assert err.count("\n") == 1, err
    match = ERROR_LINE.fullmatch(err)
    assert match, err
    return match


@pytest.mark.parametrize("case", HOSTILE)
def test_run_refuses_what_check_refuses_before_any_device_is_opened(case, tmp_path, capsys, opened):
    text, path, line, words = HOSTILE[case]
    plan = tmp_path / "plan.yaml"
    plan.write_text(text)
    out = tmp_path / "out"
    checked = _refused(capsys, ["check", plan, "--station", STATION])
    ran = _refused(capsys, ["run", plan, "--station", STATION, "--out", out, "--no-live"])
    assert ran.group(0) == checked.group(0)  # the same line as `rig check`
    assert (ran["file"], ran["path"], int(ran["line"])) == (str(plan), path, line)
    assert words in ran["what"]
    assert opened == [] and not out.exists()


RECORDED = {
    "setpoint 200 degC": (_plan("[0, 25]", "[0, 200]"), "temperatures.steps[1]", 3),
    "ramp 50 degC/min": (_plan("ramp_c_per_min: 3", "ramp_c_per_min: 50"), "temperatures.ramp_c_per_min", 4),
    "field 500 000 nT": (_plan("magnitude_nt: 50000", "magnitude_nt: 500000"), "fields", 5),
}


@pytest.mark.parametrize("case", RECORDED)
def test_resume_refuses_a_recorded_plan_beyond_the_limits(case, tmp_path, capsys, opened):
    """A session recorded before the run applied the limits: its recorded plan is checked again."""
    text, path, line = RECORDED[case]
    (tmp_path / "plan.yaml").write_text(PLAN)
    good = load_campaign(tmp_path / "plan.yaml", STATION)
    hostile = type(good)(good.plan, good.station, good.plan_path, good.station_path, text, good.station_text)
    session = tmp_path / "old.session"
    Session.create_for(session, hostile, rig.run.campaign.checked_points(good)).close()
    (tmp_path / "plan.yaml").write_text(text)  # the file as it was recorded (a resume checks that)
    m = _refused(capsys, ["run", "--resume", session, "--no-live"])
    assert (m["file"], m["path"], int(m["line"])) == (f"{session} (recorded plan)", path, line)
    assert opened == []
    with SessionReader(session) as reader:
        assert reader.summary()["points_done"] == 0


TURNTABLE = """\
field_source:
  kind: turntable
  transport: {kind: sim}
  unit: 2
  az_limits_deg: [-170, 175]
  el_limits_deg: [-85, 95]
  site_field: {vector_nt: [19136, 891, 45594]}

duts:"""


def _turntable_station(tmp_path: Path) -> Path:
    text = STATION.read_text()
    start, end = text.index("\nfield_source:"), text.index("\nduts:")
    path = tmp_path / "table.yaml"
    path.write_text(text[:start + 1] + TURNTABLE + text[end + len("\nduts:"):])
    return path


@pytest.mark.parametrize("which", ["coils", "turntable"])
def test_the_drivers_are_built_with_the_station_limits(which, tmp_path):
    from rig.config import load_station
    from rig.devices.build import build_devices

    station = load_station(STATION if which == "coils" else _turntable_station(tmp_path))
    built = build_devices(station)
    try:
        chamber, source = built.devices[station.chamber.name], built.devices[station.field_source.name]
        limits = station.chamber.limits
        assert (chamber.min_setpoint_c, chamber.max_setpoint_c, chamber.max_ramp_c_per_min,
                chamber.safe_setpoint_c) == (limits.min_setpoint_c, limits.max_setpoint_c,
                                             limits.max_ramp_c_per_min, limits.safe_setpoint_c)
        if which == "coils":
            assert source.max_current_a == station.field_source.max_current_a == 2.0
        else:
            assert source.limits_deg == {"az": (-170.0, 175.0), "el": (-85.0, 95.0)}
    finally:
        built.stop_sims()
