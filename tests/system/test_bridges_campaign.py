"""Stations on simulated USB-to-I2C bridges: the demo campaign (at two temperatures and two samples a
point) with an MMC5983MA behind a simulated MCP2221A and a TCA9548A switch and another on a simulated
FT232H gives the calibrations the smbus2 fake gives with the same seed; `rig devices scan` and
`rig devices check` work through the bridges; a bridge in a station file is checked like any I2C
transport."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml

from rig import config as cfg
from rig.devices.simulated.world import dut_truths
from tests.system.campaign_helpers import REPO, quick_demo, run_rig

pytestmark = pytest.mark.system

BRIDGES = REPO / "configs" / "stations" / "sim-bridges.yaml"


def smbus_twin(tmp_path: Path) -> Path:
    """sim-bridges with every bridge swapped for the smbus2 fake (`kind: sim`), same places, same seed."""
    station = yaml.safe_load(BRIDGES.read_text())
    station["name"] = "sim-bridges-smbus"
    for device in station["duts"] + station["temperature_sensors"]:
        t = device["transport"]
        device["transport"] = {"kind": "sim"} if t.get("mux") is None else \
            {"kind": "sim", "bus": 1, "address": t["address"], "mux": t["mux"]}
    path = tmp_path / "sim-bridges-smbus.yaml"
    path.write_text(yaml.safe_dump(station, sort_keys=False))
    return path


def calibrations(out: Path, dut: str) -> dict:
    (path,) = out.glob(f"*.{dut}.t24.yaml")
    return yaml.safe_load(path.read_text())


def test_the_demo_campaign_through_bridges_calibrates_as_on_the_smbus_fake(tmp_path):
    twin = smbus_twin(tmp_path)
    a, b = cfg.load_station(BRIDGES), cfg.load_station(twin)
    for name, truth in dut_truths(a).items():  # truths are drawn per DUT position from sim.seed
        assert np.array_equal(truth.S, dut_truths(b)[name].S)
        assert np.array_equal(truth.b_nt, dut_truths(b)[name].b_nt)
    demo = quick_demo(tmp_path)
    for station, out in ((BRIDGES, tmp_path / "bridges"), (twin, tmp_path / "smbus")):
        done = run_rig("run", str(demo), "--station", str(station), "--out", str(out), "--no-live",
                       timeout=300)
        assert done.returncode == 0, done.stderr[-2000:]
    for dut in ("mmc0", "mmc1"):
        bridged, direct = calibrations(tmp_path / "bridges", dut), calibrations(tmp_path / "smbus", dut)
        for key, value in bridged["params"].items():
            # The same truth, noise drawn in the same order; only the moments of the readings differ
            # (bus and USB time), so the temperatures they see differ by far less than the noise.
            gap = np.abs(np.array(value) - np.array(direct["params"][key]))
            assert np.all(gap < 0.5 * np.array(bridged["std_errors"][key])), (dut, key, gap)


def test_scan_and_check_go_through_the_bridges():
    scan = run_rig("devices", "scan", str(BRIDGES))
    assert scan.returncode == 0, scan.stdout + scan.stderr
    lines = scan.stdout.splitlines()
    assert "mcp2221 0001234567 (simulated, MCP2221A USB 04d8:00dd, serial number 0001234567)" in lines
    assert any(line.startswith("ft232h ftdi://ftdi:232h:FT0SIM01/1 (simulated, FT232H USB 0403:6014")
               for line in lines)
    assert any("switch 0x70 channel 0  MEMSIC MMC5983MA" in line and "[station: mmc0]" in line
               for line in lines)
    check = run_rig("devices", "check", str(BRIDGES))
    assert check.returncode == 0 and "all 6 devices answer" in check.stdout


@pytest.mark.parametrize("change, message", [
    (lambda s: s["duts"][0]["transport"].update(sim=False, faults={"nack": 100}),
     "duts[0].transport.faults: faults are played by a simulated bridge only (sim: true)"),
    (lambda s: s["duts"][0]["transport"].update(speed_hz=20_000),
     "duts[0].transport.speed_hz: must be >= 47000"),
    (lambda s: s["temperature_sensors"][0]["transport"].update(address=0x30),
     "temperature_sensors[0].transport.address: 0x30 on mcp2221 0001234567 switch 0x70 channel 0 is "
     "taken twice"),
    (lambda s: s["duts"][0]["transport"].update(sim=False),
     "mcp2221 0001234567: open: no MCP2221A (USB 04d8:00dd) with serial number 0001234567 is plugged in"),
])
def test_station_mistakes_are_one_line_errors(tmp_path, change, message):
    station = yaml.safe_load(BRIDGES.read_text())
    change(station)
    path = tmp_path / "station.yaml"
    path.write_text(yaml.safe_dump(station, sort_keys=False))
    done = run_rig("devices", "check", str(path))
    assert done.returncode != 0
    assert message in done.stderr and "Traceback" not in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1


def test_switches_behind_a_cp2112_and_an_ft232h(tmp_path):
    station = yaml.safe_load(BRIDGES.read_text())
    cp2112 = {"kind": "cp2112", "sim": True, "serial": "0042", "mux": {"address": 0x71, "channel": 2}}
    ft232h = {"kind": "ft232h", "sim": True, "latency_ms": 2, "mux": {"address": 0x70, "channel": 5}}
    for devices, transport in ((("duts", 0), ("temperature_sensors", 0)), cp2112), \
                               ((("duts", 1), ("temperature_sensors", 1)), ft232h):
        for role, i in devices:
            address = station[role][i]["transport"]["address"]
            station[role][i]["transport"] = {**copy.deepcopy(transport), "address": address}
    path = tmp_path / "station.yaml"
    path.write_text(yaml.safe_dump(station, sort_keys=False))
    check = run_rig("devices", "check", str(path))
    assert check.returncode == 0 and "all 6 devices answer" in check.stdout, check.stdout + check.stderr
    scan = run_rig("devices", "scan", str(path))
    assert scan.returncode == 0, scan.stdout + scan.stderr
    assert "cp2112 0042 (simulated, CP2112 USB 10c4:ea90, serial number 0042)" in scan.stdout
    assert any("switch 0x71 channel 2  TI TMP117" in line and "[station: tmp0]" in line
               for line in scan.stdout.splitlines())
    assert any("switch 0x70 channel 5  MEMSIC MMC5983MA" in line and "[station: mmc1]" in line
               for line in scan.stdout.splitlines())
