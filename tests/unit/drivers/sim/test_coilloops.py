"""Each coil loop on its own (drivers/sim/world/coilfield.py LoopErrors, station `sim.coil_loops`): the loop
by loop Biot-Savart against closed forms and hardware-notes §9.2, and the world built from the key."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.sim.world.coilfield import CoilGeometry, LoopErrors, drawn_pair_field
from rig.config import load_station
from rig.core.errors import ConfigError
from tests.unit.drivers.sim.benches import IDEAL, station_data, world_of, write_station

CIRCLE = CoilGeometry("circular", (2.0, 2.0, 2.0), (1.0, 1.0, 1.0))  # Helmholtz: radius R = 1 m = spacing


def on_axis_loop_t(z_m: float, radius_m: float, centre_m: float) -> float:
    """Closed form: the axial field (T) of a 1 A circular loop at distance z - centre along its axis."""
    return 4e-7 * math.pi * radius_m**2 / (2 * (radius_m**2 + (z_m - centre_m) ** 2) ** 1.5)


def test_a_turns_imbalance_matches_the_closed_form_on_the_axis():
    errors = LoopErrors(turns_error_ppm=(10_000.0, -4_000.0))
    for z in (-0.3, 0.0, 0.12, 0.25):
        want = (1.01 * on_axis_loop_t(z, 1.0, 0.5) + 0.996 * on_axis_loop_t(z, 1.0, -0.5))
        got = drawn_pair_field(CIRCLE, 0, np.array([z, 0.0, 0.0]), errors)
        assert got[0] == pytest.approx(want, rel=1e-9)
        assert abs(got[1]) < 1e-18 and abs(got[2]) < 1e-18


def test_loop_deviations_give_the_sizes_of_hardware_notes_9_2():
    b0 = drawn_pair_field(CIRCLE, 0, np.zeros(3))[0]
    one_percent = LoopErrors(turns_error_ppm=(10_000.0, 0.0))
    assert drawn_pair_field(CIRCLE, 0, np.zeros(3), one_percent)[0] / b0 - 1 == pytest.approx(0.005, rel=1e-3)
    tilted = drawn_pair_field(CIRCLE, 0, np.zeros(3), LoopErrors(tilt_deg=(math.degrees(1e-3), 0.0)))
    # 1 mrad of one loop: 0.35 mrad off the axis, towards -z (an x loop turns about +y)
    assert tilted[2] / tilted[0] == pytest.approx(-0.35e-3, rel=1e-3) and abs(tilted[1]) < 1e-18
    sideways = LoopErrors(offset_m=((0.0, 1e-3, 0.0), (0.0, 0.0, 0.0)))
    shifted = drawn_pair_field(CIRCLE, 0, np.zeros(3), sideways)
    assert shifted[1] / shifted[0] == pytest.approx(3e-4, rel=1e-2)  # 0.1 % of R sideways: 3e-4


def test_the_station_key_shapes_the_field_around_an_unchanged_centre(tmp_path):
    positions = {"centre": [0, 0, 0], "plus": [60, 0, 0], "minus": [-60, 0, 0], "side": [0, 60, 0]}
    duts = {name: {"position_mm": p, "sim": {"truth": IDEAL, "noise_nt": 0}} for name, p in positions.items()}
    geometry = {"shape": "circular", "size_m": [0.4, 0.4, 0.4], "spacing_m": [0.2, 0.2, 0.2]}
    loops = {"x": {"turns_error_ppm": [5000, -5000], "tilt_deg": [0.2, 0.0]},
             "z": {"offset_mm": [[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]}}
    bent, _ = world_of(tmp_path, sim={"coil_geometry": geometry, "coil_loops": loops}, duts=duts)
    drawn, _ = world_of(tmp_path, sim={"coil_geometry": geometry}, duts=duts)
    for world in (bent, drawn):
        world.set_coil_currents([1.0, 0.0, 1.0])
    # the centre matrix is the pair-level truth, whatever the loops
    np.testing.assert_allclose(bent.lab_field_nt("centre"), [50_000.0, 0.0, 50_000.0], atol=1e-6)
    # a 1 % imbalance over R = 0.2 m: about 0.6 % of the field per R along x
    slope = (bent.lab_field_nt("plus")[0] - bent.lab_field_nt("minus")[0]) / 0.12 * 0.2 / 50_000.0
    drawn_slope = (drawn.lab_field_nt("plus")[0] - drawn.lab_field_nt("minus")[0]) / 0.12 * 0.2 / 50_000.0
    assert abs(drawn_slope) < 1e-9 and slope == pytest.approx(0.006, rel=0.1)
    off_axis = bent.lab_field_nt("side") - drawn.lab_field_nt("side")
    assert np.max(np.abs(off_axis)) > 1.0  # the tilted and shifted loops bend the field where a DUT sits


def test_loops_need_coils_with_a_geometry(tmp_path):
    data = station_data(sim={"coil_loops": {"x": {"turns_error_ppm": [100, 0]}}})
    with pytest.raises(ConfigError, match=r"sim\.coil_loops: needs a coil geometry .* \(line \d+\)"):
        load_station(write_station(tmp_path, data))
    data["field_source"] = {"kind": "turntable", "transport": {"kind": "sim"}, "unit": 2,
                            "site_field": {"vector_nt": [19000, 900, 45000]}}
    with pytest.raises(ConfigError, match=r"sim\.coil_loops: needs coils, not a turntable \(line \d+\)"):
        load_station(write_station(tmp_path, data))
    data["sim"].pop("coil_loops")
    data["sim"]["current_source"] = {"gain_error_ppm": [10, 0, 0]}
    with pytest.raises(ConfigError, match=r"sim\.current_source: needs coils, not a turntable"):
        load_station(write_station(tmp_path, data))
