"""Small simulated stations for the world's deviation tests: a station file written from plain data, the
world rig/simstation.py builds from it, on a simulated clock."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from drivers.clock import SimClock
from rig.config import load_station
from rig.devices.simulated.world import make_world

IDEAL = {"S": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}  # a DUT with no T24 errors: its reading is the field


def station_data(*, sim: dict | None = None, duts: dict[str, dict] | None = None,
                 field_source: dict | None = None) -> dict:
    """`duts`: {name: {"position_mm": [...] (optional), "sim": its sim.duts entry}}; one ideal DUT if None."""
    duts = {"dut1": {"sim": {"truth": IDEAL, "noise_nt": 0}}} if duts is None else duts
    return {
        "name": "bench",
        "sim": {"seed": 7, "ambient_nt": [0, 0, 0], "air_c": 22.0, **(sim or {}),
                "duts": {name: d.get("sim", {}) for name, d in duts.items()}},
        "chamber": {"type": "watlow_f4t", "transport": {"kind": "sim"}, "unit": 1,
                    "limits": {"min_setpoint_c": -40, "max_setpoint_c": 85, "max_ramp_c_per_min": 5,
                               "safe_setpoint_c": 25}},
        "field_source": field_source or {
            "kind": "coils", "transport": {"kind": "sim"}, "unit": 2, "max_current_a": 2.0,
            "coil_constants_nt_per_a": [[50000, 0, 0], [0, 50000, 0], [0, 0, 50000]],
            "ambient_nt": [0, 0, 0]},
        "duts": [{"name": name, "type": "mmc5983ma", "transport": {"kind": "sim"}, "temp_source": "self",
                  **({"position_mm": d["position_mm"]} if "position_mm" in d else {})}
                 for name, d in duts.items()],
    }


class _Plain(yaml.SafeDumper):
    def ignore_aliases(self, data) -> bool:  # a station file takes no aliases: write shared values out
        return True


def write_station(tmp_path: Path, data: dict) -> Path:
    path = tmp_path / "station.yaml"
    path.write_text(yaml.dump(data, Dumper=_Plain, sort_keys=False))
    return path


def world_of(tmp_path: Path, **station_keys):
    """(world, clock) of the station `station_data(**station_keys)` describes."""
    clock = SimClock()
    return make_world(load_station(write_station(tmp_path, station_data(**station_keys))), clock), clock


def reading_nt(world, name: str) -> np.ndarray:
    """The DUT's offset-cancelled reading (the SET/RESET pair's half difference), noise-free."""
    return (world.dut_raw_nt(name, 1, noisy=False) - world.dut_raw_nt(name, -1, noisy=False)) / 2


def hold(world, clock, setpoint_c: float, seconds: float = 4 * 3600.0) -> None:
    """Air to `setpoint_c` and long enough for every mount to follow (lags of minutes)."""
    world.set_chamber_setpoint(setpoint_c)
    clock.sleep(seconds)
