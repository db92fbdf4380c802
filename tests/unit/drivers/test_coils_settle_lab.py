"""The coils settle on sim-lab's current source, whose read-back is off by its stated accuracy: the driver
waits for the status word's settled bit and a read-back within the supply's stated accuracy, never a fixed
1 mA."""

from __future__ import annotations

import pytest

from drivers.errors import DeviceFault, DeviceTimeout
from rig.config import CONFIGS_DIR
from rig.config.loading import load_campaign
from rig.devices.build import open_rig

LAB = CONFIGS_DIR / "stations" / "sim-lab.yaml"
DEMO = CONFIGS_DIR / "plans" / "demo.yaml"


def lab_station(readback_ppm: float, offset_ma: float):
    """sim-lab with its supply's read-back error at the size hardware-notes §9.3 states (0.05 % + 0.5 mA)."""
    station = load_campaign(DEMO, LAB).station
    source = station.sim.current_source.model_copy(update={
        "readback_error_ppm": (readback_ppm,) * 3, "offset_ma": (offset_ma,) * 3})
    return station.model_copy(update={"sim": station.sim.model_copy(update={"current_source": source})})


@pytest.mark.parametrize("readback_ppm", [150.0, 400.0])
def test_coils_settle_at_full_current_with_the_supplys_read_back_error(readback_ppm):
    rig = open_rig(lab_station(readback_ppm, 0.5))
    try:
        coils = rig.field_source
        coils.set((1.9, -1.9, 1.9))
        reading = coils.wait_settled(timeout_s=2.0)
        errors = [abs(c - s) for c, s in zip(reading.currents_a, reading.setpoints_a, strict=True)]
        assert all(reading.settled)
        assert max(errors) <= coils.readback_tolerance_a(1.9) < 1.5e-3
        if readback_ppm > 300:  # x reads 1.9 A x 480 ppm + 0.5 mA = 1.41 mA off (noise 0.1 mA RMS): beyond
            assert max(errors) > 1e-3  # the old fixed 1 mA, where it never settled and the run held
            with pytest.raises(DeviceTimeout, match="not within"):
                coils.wait_settled(timeout_s=0.5, tol_a=1e-3)
    finally:
        rig.close()


def _stated(station, ppm: float, ma: float):
    source = station.field_source.model_copy(update={"readback_accuracy_ppm": ppm,
                                                     "readback_accuracy_ma": ma})
    return station.model_copy(update={"field_source": source})


def test_the_tolerance_follows_the_stations_stated_accuracy():
    rig = open_rig(_stated(lab_station(450.0, 0.3), 10.0, 0.01))
    try:
        assert rig.field_source.readback_tolerance_a(2.0) == pytest.approx(2e-5 + 1e-5 + 1e-6)
        rig.field_source.set((1.9, 0.0, 0.0))
        # x reads 1.9 A x 450 ppm + 0.3 mA = 1.2 mA off against 0.03 mA stated: far beyond, a fault
        with pytest.raises(DeviceFault, match=r"axis x settled at .* mA off, its stated read-back accuracy"):
            rig.field_source.wait_settled(timeout_s=2.0)
    finally:
        rig.close()


def test_a_supply_a_little_worse_than_stated_is_warned_of_and_accepted(caplog):
    """The read-back 1.2 mA off (noise 0.1 mA RMS) against 0.6 mA stated: steady, so the axis is where the
    supply puts it; the run goes on from the read-back, warned once per axis."""
    rig = open_rig(_stated(lab_station(450.0, 0.3), 50.0, 0.5))
    try:
        coils = rig.field_source
        for _ in range(2):
            coils.set((1.9, 0.0, 0.0))
            reading = coils.wait_settled(timeout_s=2.0)
            assert abs(reading.currents_a[0] - 1.9) > coils.readback_tolerance_a(1.9)
            coils.set((0.0, 0.0, 0.0))
            coils.wait_settled(timeout_s=2.0)
        warned = [r.getMessage() for r in caplog.records if "settled at" in r.getMessage()]
        on_x = [m for m in warned if "axis x" in m]
        assert len(on_x) == 1 and "going on from the read-back" in on_x[0]
        with pytest.raises(DeviceTimeout, match="not within"):  # a tolerance the caller insists on holds
            coils.set((1.9, 0.0, 0.0))
            coils.wait_settled(timeout_s=0.5, tol_a=1e-3)
    finally:
        rig.close()
