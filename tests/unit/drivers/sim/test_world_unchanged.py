"""With none of the deviation keys, the simulated world is the one before they existed: the same readings
on the same seed (world_before.json was recorded from the world without them), and stating every key at
zero changes nothing at all."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from drivers.clock import SimClock
from rig.config import load_station
from rig.devices.simulated.world import make_world
from tests.unit.drivers.sim.benches import write_station

HERE = Path(__file__).parent
STATIONS = HERE.parents[3] / "configs" / "stations"
BEFORE = HERE / "world_before.json"


def turntable_station(tmp_path: Path) -> Path:
    data = yaml.safe_load((STATIONS / "sim.yaml").read_text())
    data["field_source"] = {"kind": "turntable", "transport": {"kind": "sim"}, "unit": 2,
                            "site_field": {"vector_nt": [19000, 900, 45000]}}
    data["sim"]["ambient_drift_nt_per_h"] = [3.0, -2.0, 1.0]
    data["sim"]["turntable_axes"] = {"az_tilt_deg": [0.05, -0.03], "el_tilt_deg": 0.02}
    path = tmp_path / "sim-table.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def readings(station) -> list[float]:
    """A few hours of a campaign's worth of world calls: setpoints, currents or angles, and every read."""
    clock = SimClock()
    world = make_world(station, clock)
    coils = world.field_source == "coils"
    out: list[float] = []
    for k, (setpoint_c, wait_s) in enumerate([(40.0, 900), (40.0, 1500), (-20.0, 2400), (60.0, 3700),
                                              (25.0, 50), (25.0, 7200)]):
        world.set_chamber_setpoint(setpoint_c)
        if coils:
            world.set_coil_currents([0.3 * (k - 2), -0.2 * k, 0.5 - 0.1 * k])
        else:
            world.set_turntable_target(30.0 * k, 10.0 * k - 20.0)
        clock.sleep(wait_s)
        out.append(world.chamber_air_c())
        for name in world.duts:
            out += [*world.dut_raw_nt(name, 1), *world.dut_raw_nt(name, -1), world.dut_temp_c(name),
                    world.element_temp_c(name), *world.lab_field_nt(name), *world.true_field_nt(name)]
        out += [*world.lab_field_nt()]
    return out


def scenarios(tmp_path: Path) -> dict[str, list[float]]:
    names = ["sim.yaml", "sim-commissioned.yaml"]
    stations = {name: load_station(STATIONS / name) for name in names}
    stations["turntable"] = load_station(turntable_station(tmp_path))
    return {name: readings(station) for name, station in stations.items()}


def test_the_world_without_deviation_keys_reads_as_before(tmp_path):
    before = json.loads(BEFORE.read_text())
    now = scenarios(tmp_path)
    assert set(now) == set(before)
    for name, values in now.items():
        # the same draws and the same formulas: only a BLAS's last bits may differ between machines
        np.testing.assert_allclose(values, before[name], rtol=1e-12, atol=1e-9, err_msg=name)


ZERO3 = [0.0, 0.0, 0.0]
ALL_ZERO = {
    "current_source": {"gain_error_ppm": ZERO3, "offset_ma": ZERO3, "noise_ma": ZERO3,
                       "readback_error_ppm": ZERO3},
    "coil_loops": {axis: {"turns_error_ppm": [0, 0], "offset_mm": [ZERO3, ZERO3], "tilt_deg": [0, 0]}
                   for axis in "xyz"},
    "ambient_gradient_nt_per_m": [ZERO3, ZERO3, ZERO3],
    "ambient_steps": {"mean_interval_h": 1.0, "size_nt": 0.0},
    "chamber": {"max_rate_c_per_min": 3.0, "overshoot_c": 0.0, "heater_field_nt": ZERO3,
                "compressor_field_nt": ZERO3},
}
DUT_ZERO = {"random_walk_nt_per_sqrt_h": 0.0, "flicker_nt": 0.0, "air_offset_c": 0.0}
TRUTH_ZERO = {"K2_per_c2": [ZERO3, ZERO3, ZERO3], "kb2_nt_per_c2": ZERO3, "cubic_ppm_at_50ut": ZERO3,
              "hysteresis": {"offset_nt": ZERO3, "band_c": 2.0}}


def test_every_deviation_key_at_zero_is_the_world_without_them(tmp_path):
    data = yaml.safe_load((STATIONS / "sim-commissioned.yaml").read_text())
    for dut in data["sim"]["duts"].values():
        dut.update(DUT_ZERO)
        if isinstance(dut["truth"], dict):
            dut["truth"].update(TRUTH_ZERO)
    data["sim"].update(ALL_ZERO)
    data["field_source"]["commissioning"] = str(STATIONS / data["field_source"]["commissioning"])
    data["reference_magnetometers"][0]["calibration"] = str(STATIONS / "sim-reference-cal.yaml")
    path = write_station(tmp_path, data)
    assert readings(load_station(path)) == readings(load_station(STATIONS / "sim-commissioned.yaml"))


if __name__ == "__main__":  # records world_before.json (run once, on the world before the deviations)
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        BEFORE.write_text(json.dumps(scenarios(Path(tmp))))
    pytest.main([__file__])
