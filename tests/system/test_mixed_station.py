"""Mixed real/simulated stations (a dry run): a "real" Modbus chamber - in fact a chamber simulator this
test serves on 127.0.0.1 as `kind: modbus_tcp` - with simulated coils and DUTs. The simulated devices
share one world, the real one is reached over its real transport, the run is on the real clock, and
nothing ends in a traceback."""

from __future__ import annotations

import pytest
import yaml

from drivers.clock import RealClock
from drivers.sim.devices.chamber import ChamberSim
from drivers.sim.world import World
from tests.system.campaign_helpers import SIM_STATION, events, run_rig, session_counts

pytestmark = pytest.mark.system


@pytest.fixture
def real_chamber():
    """A chamber controller on loopback, as the station sees any networked F4T."""
    sim = ChamberSim(World(RealClock(), air_c=22.0), "f4t", unit=1)
    port = sim.start()
    try:
        yield sim, port
    finally:
        sim.stop()


def mixed_station(tmp_path, port: int):
    station = yaml.safe_load(SIM_STATION.read_text())
    station["name"] = "dry-run"
    station["chamber"]["transport"] = {"kind": "modbus_tcp", "host": "127.0.0.1", "port": port,
                                       "timeout_s": 1.0}
    station["chamber"].pop("alarm", None)  # a stock F4T: no alarm register (the simulated bench names one)
    path = tmp_path / "dry-run.yaml"
    path.write_text(yaml.safe_dump(station, sort_keys=False))
    return path


def test_devices_check_on_a_real_chamber_with_simulated_duts(tmp_path, real_chamber):
    sim, port = real_chamber
    proc = run_rig("devices", "check", str(mixed_station(tmp_path, port)), timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    assert "all 6 devices answer" in proc.stdout
    chamber_row = next(line for line in proc.stdout.splitlines() if line.startswith("│ chamber"))
    assert "real" in chamber_row and f"127.0.0.1:{port}" in proc.stdout
    assert sim.world.setpoint_c == 25.0  # the check left the real chamber at its safe setpoint


def test_a_short_dry_run_campaign_completes_on_the_real_clock(tmp_path, real_chamber):
    sim, port = real_chamber
    plan = {
        "name": "dry",
        "temperatures": {"steps": [22], "ramp_c_per_min": 2.0,
                         "stability": {"band_c": 0.5, "rate_c_per_min": 0.3, "dwell_s": 0}},
        "fields": {"kind": "directions", "magnitude_nt": 30000,
                   "directions": [[1, 0, 0], [0, 1, 0], [0, 0, 1], [-1, -1, -1]]},
        "samples_per_point": 2,
        "settle_s": 0,
        "fit": {"models": ["p12"]},
    }
    plan_path = tmp_path / "dry.yaml"
    plan_path.write_text(yaml.safe_dump(plan, sort_keys=False))
    session = tmp_path / "dry.session"
    proc = run_rig("run", str(plan_path), "--station", str(mixed_station(tmp_path, port)),
                   "--session", str(session), "--no-live", timeout=120)
    assert "Traceback" not in proc.stderr
    assert proc.returncode == 0, proc.stderr
    counts = session_counts(session)
    assert counts["status"] == "completed" and counts["done"] == 4
    start = next(message for kind, message in events(session) if kind == "start")
    # readable text, not a Python dict: which devices are simulated, which are real
    assert start.endswith("simulated: coils, mmc0, serial0, tmp0, tmp1; real: chamber"), start
    assert sim.world.setpoint_c == 25.0  # the run ended with the real chamber at its safe setpoint


def test_a_simulated_probe_beside_a_real_dut_fails_only_the_real_dut(tmp_path):
    station = yaml.safe_load(SIM_STATION.read_text())
    station["duts"][0]["transport"] = {"kind": "i2c", "bus": 97, "address": 0x30}  # no /dev/i2c-97 here
    path = tmp_path / "half.yaml"
    path.write_text(yaml.safe_dump(station, sort_keys=False))
    proc = run_rig("devices", "check", str(path), timeout=60)
    assert proc.returncode == 1
    assert "Traceback" not in proc.stderr and "KeyError" not in proc.stdout + proc.stderr
    assert "1 of 6 devices failed: mmc0" in proc.stderr
    tmp_row = next(line for line in proc.stdout.splitlines() if line.startswith("│ tmp0"))
    assert "ok" in tmp_row  # the simulated probe beside the real DUT reads the simulated mount
