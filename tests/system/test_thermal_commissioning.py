"""`rig commission --thermal` on sim-lab: the chamber's real pace and overshoot, each DUT position's lag,
offset and noise, and the pace of a point, measured (compared here with the simulator's truth, which the
rig never reads), sealed with the rest of the file; the coils safe and the chamber at its safe set point on
every exit, an interrupted step included."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from rig.commission.procedure import commission
from rig.config import CONFIGS_DIR, commissioning_file, load_station
from rig.core.errors import ConfigError

pytestmark = pytest.mark.system

LAB = CONFIGS_DIR / "stations" / "sim-lab.yaml"


def test_the_thermal_commissioning_measures_what_planning_needs(tmp_path):
    seen = []
    path = commission(LAB, tmp_path, thermal=True, on_rig=seen.append)
    world = seen[0].world
    station = load_station(LAB)
    assert not world.coils_enabled and world.setpoint_c == station.chamber.limits.safe_setpoint_c
    thermal = commissioning_file.read(path).thermal
    truth = station.sim
    assert thermal.commanded_rate_c_per_min == station.chamber.limits.max_ramp_c_per_min == 5.0
    assert thermal.rate_c_per_min == pytest.approx(truth.chamber.max_rate_c_per_min, rel=0.02)
    assert thermal.overshoot_c == pytest.approx(truth.chamber.overshoot_c, abs=0.1)
    assert thermal.step_c[1] - thermal.step_c[0] == pytest.approx(15.0, abs=0.1)
    assert set(thermal.duts) == {d.name for d in station.duts}
    for name, measured in thermal.duts.items():
        sim = truth.duts[name]
        # the probe beside the DUT lags its element: one first-order lag spans both
        assert sim.thermal_lag_s <= measured.lag_s <= 1.05 * (sim.thermal_lag_s + sim.sensor_lag_s), name
        assert measured.offset_c == pytest.approx(sim.air_offset_c, abs=0.05), name
        # one SET/RESET pair of 40 nT readings: 28 nT, with the offset's 1/f noise on top
        assert 20.0 < max(measured.noise_nt) < 45.0, name
    assert 0 < thermal.sample_s < 1.0 and thermal.moves == 8 and thermal.set_reset == "pair"
    assert thermal.start_air_c == pytest.approx(truth.air_c, abs=0.1)


def test_the_seal_covers_the_thermal_section(tmp_path):
    path = commission(LAB, tmp_path, thermal=True)
    data = yaml.safe_load(path.read_text())
    data["thermal"]["rate_c_per_min"] *= 2  # a faster chamber than measured
    edited = tmp_path / "edited.yaml"
    edited.write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(ConfigError, match=r"content_sha256: the file was edited after `rig commission`"):
        commissioning_file.read(edited)


def test_an_interrupted_step_leaves_the_chamber_safe_and_writes_nothing(tmp_path):
    seen = []

    def interrupt_the_step(rig):
        seen.append(rig)
        read, calls = rig.chamber.read, []

        def read_then_stop():
            calls.append(1)
            if rig.world.setpoint_c > 30.0 and len(calls) > 40:  # well into the step
                raise KeyboardInterrupt("Ctrl-C")
            return read()

        rig.chamber.read = read_then_stop

    with pytest.raises(KeyboardInterrupt):
        commission(LAB, tmp_path, thermal=True, on_rig=interrupt_the_step)
    world = seen[0].world
    assert world.setpoint_c == 25.0 and not world.coils_enabled
    assert not np.any(world.coil_currents_a) and not list(tmp_path.glob("*.commissioning.yaml"))


def test_a_step_that_does_not_fit_the_limits_is_refused_before_the_set_point_is_written(tmp_path):
    data = yaml.safe_load(LAB.read_text())
    data["chamber"]["limits"].update(min_setpoint_c=20.0, max_setpoint_c=30.0, safe_setpoint_c=25.0)
    station = tmp_path / "sim-lab.yaml"
    station.write_text(yaml.safe_dump(data, sort_keys=False))
    for name in ("sim-reference-cal.yaml", "sim-lab.commissioning.yaml"):
        (tmp_path / name).write_text((LAB.parent / name).read_text())
    seen = []
    with pytest.raises(ConfigError, match=r"a thermal step of 15 degC from the air at 2\d\.\d degC leaves "
                       r"chamber.limits min_setpoint_c 20 .. max_setpoint_c 30"):
        commission(station, tmp_path / "out", thermal=True, on_rig=seen.append)
    assert math.isclose(seen[0].world.setpoint_c, 25.0) and not seen[0].world.coils_enabled
