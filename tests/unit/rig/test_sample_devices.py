"""rig/run/runner.py: a sample reads the DUTs and the temperature probes as one interleave, each probe right
after the DUT it sits beside, so that behind I2C switches it shares its DUT's channel selection: on the
shipped 16-DUT station that writes fewer switch control bytes than reading the probes on their own, and
every reading still comes back."""

from __future__ import annotations

from types import SimpleNamespace

from drivers.sim.transports.i2c_bus import switch_writes
from rig import config as cfg
from rig.devices.build import open_rig
from rig.devices.interleave import read_all
from rig.run.runner import CampaignRunner
from tests.system.campaign_helpers import REPO

STATION = REPO / "configs" / "stations" / "sim-16.yaml"
PLAN = REPO / "configs" / "plans" / "demo.yaml"


def test_each_probe_is_read_right_after_its_dut_and_with_fewer_switch_writes():
    station = cfg.load_station(STATION)
    rig = open_rig(station, cfg.load_plan(PLAN))
    try:
        together = CampaignRunner._sample_devices(SimpleNamespace(rig=rig))
        names = list(together)
        assert sorted(names) == sorted([*rig.duts, *rig.temp_sensors])
        for sensor in station.temperature_sensors:
            assert names.index(sensor.name) == names.index(sensor.beside) + 1
        read_all(together, rig.clock)  # the first readings connect lazily
        before = switch_writes(rig.devices())
        got = read_all(together, rig.clock)
        merged = switch_writes(rig.devices()) - before
        before = switch_writes(rig.devices())
        read_all(rig.temp_sensors, rig.clock)
        read_all(rig.duts, rig.clock)
        apart = switch_writes(rig.devices()) - before
        assert 0 < merged < apart
        assert all(got[name] is not None for name in names)
        assert all(got[name].temp_c is not None for name in rig.temp_sensors)
    finally:
        rig.close()
