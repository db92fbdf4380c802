"""`rig devices scan` against the simulated buses, switches and serial lines: what answers where, named by
its identification registers or replies, matched with the station, and missing devices said."""

from __future__ import annotations

import re

import numpy as np
import yaml

from drivers import busscan
from drivers.clock import SimClock
from drivers.sim.devices.serialmag import SerialMagLine, SerialMagSim
from drivers.sim.world import DutTruth, World
from drivers.transports.serial import SerialLine
from rig.config import load_station
from rig.devices.scan import scan_station
from tests.system.campaign_helpers import REPO, run_rig

STATIONS = REPO / "configs" / "stations"


def test_sixteen_duts_behind_switches_and_on_one_line():
    done = run_rig("devices", "scan", str(STATIONS / "sim-16.yaml"), "--ids", "0-8")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    station = load_station(STATIONS / "sim-16.yaml")
    for dev in [*station.duts, *station.temperature_sensors]:
        t = dev.transport
        if getattr(t, "mux", None) is not None:
            what = "MEMSIC MMC5983MA" if dev.device_type == "mmc5983ma" else "TI TMP117"
            wanted = (f"  0x{t.address:02X}  switch 0x{t.mux.address:02X} channel {t.mux.channel}  "
                      f"{what}")
            assert any(line.startswith(wanted) and line.endswith(f"[station: {dev.name}]")
                       for line in lines), dev
        else:
            device_id = dev.device_options.device_id
            pattern = (rf"  id {device_id:02d}  9600 baud  Honeywell HMR2300 .*serial number SM2300-0001"
                       rf".*\[station: {dev.name}\]$")
            assert any(re.match(pattern, line) for line in lines), dev.name
    switches = [line for line in lines if "TCA9548A/PCA9548A I2C switch" in line]
    assert len(switches) == 3  # 0x70 and 0x71 on bus 1, 0x70 on bus 2
    assert len([line for line in lines if line.startswith("  id ")]) == 6  # ids 0, 7, 8 do not answer
    assert lines[-1] == "not scanned (Modbus; see rig devices check): chamber, coils"


def test_a_device_that_does_not_answer_is_named_and_fails_the_scan(tmp_path):
    station = yaml.safe_load((STATIONS / "sim.yaml").read_text())
    station["temperature_sensors"][0]["transport"] = {"kind": "sim", "faults": {"unplug": {"after_s": 0}}}
    path = tmp_path / "station.yaml"
    path.write_text(yaml.safe_dump(station))
    report = scan_station(load_station(path), device_ids=range(0, 2))
    assert report.problems == ["tmp0 not found (simulated bus of tmp0 0x48)"]
    done = run_rig("devices", "scan", str(path), "--ids", "0-1")
    assert done.returncode == 1 and "error: tmp0 not found" in done.stderr
    assert "simulated bus of mmc0\n  0x30  bus" in done.stdout


def test_a_line_is_asked_at_the_other_rate_when_nothing_answers_at_its_own():
    world = World(SimClock())
    for name in ("a", "b"):
        world.add_dut(name, DutTruth.random(np.random.default_rng(1), noise_nt=0.0))
    sims = [SerialMagSim(world, "a", 3, serial_number="SN-3"),
            SerialMagSim(world, "b", 7, serial_number="SN-7")]
    for sim in sims:
        sim.baud = 19200  # left at 19200 by an earlier run
    with SerialMagLine(sims) as sim_line:
        line = SerialLine(sim_line.path, baudrate=9600)
        try:
            found = busscan.scan_serial(line, device_ids=range(0, 10), timeout_s=0.05)
        finally:
            line.close_port()
    assert [(f.device_id, f.baudrate, f.info["serial_number"]) for f in found] == [(3, 19200, "SN-3"),
                                                                                    (7, 19200, "SN-7")]
    assert found[0].info["firmware"] == "SM2300 fw 1.4"
