"""Bus scans against the register-level fake: switches found and every channel searched, chips named by
their identification registers, strangers reported as such, EEPROM ranges read rather than written,
adapters without a quick command, and every switch left off."""

from __future__ import annotations

import errno

import numpy as np
import pytest

from drivers import busscan
from drivers.clock import SimClock
from drivers.sim.devices.hmc5883l import HMC5883LSim
from drivers.sim.devices.mmc5983ma import MMC5983MASim
from drivers.sim.devices.tmp117 import TMP117Sim
from drivers.sim.transports.i2c_bus import FakeSMBus, RegisterChip
from drivers.sim.world import DutTruth, World


@pytest.fixture
def world():
    w = World(SimClock(), ambient_nt=(20_000.0, -3_000.0, 42_000.0))
    for i, name in enumerate(("a", "b", "c")):
        w.add_dut(name, DutTruth.random(np.random.default_rng(i), noise_nt=0.0))
    return w


def bench(world) -> tuple[FakeSMBus, dict]:
    """On the bus: an HMC5883L, an EEPROM-like stranger at 0x50 and a chip at the HMC address of
    another kind; behind switch 0x70: an MMC5983MA on channel 2 and a TMP117 on channel 6; switch 0x74
    with nothing behind it."""
    bus = FakeSMBus()
    bus.attach(0x1E, HMC5883LSim(world, "a"))
    bus.attach(0x50, RegisterChip())
    switch = bus.add_switch(0x70)
    switch.attach(2, 0x30, MMC5983MASim(world, "b"))
    switch.attach(6, 0x48, TMP117Sim(world, "c"))
    other = bus.add_switch(0x74)
    return bus, {0x70: switch, 0x74: other}


def test_everything_is_found_where_it_is_and_named(world):
    bus, switches = bench(world)
    scan = busscan.scan_i2c(bus)
    found = {(f.switch, f.channel, f.address): f.what for f in scan.found}
    assert set(found) == {(None, None, 0x70), (None, None, 0x74), (None, None, 0x1E), (None, None, 0x50),
                          (0x70, 2, 0x30), (0x70, 6, 0x48)}
    assert found[(None, None, 0x1E)].startswith("Honeywell HMC5883L or HMC5983 (id 'H43'")
    assert found[(0x70, 2, 0x30)] == "MEMSIC MMC5983MA (product id 0x30 at 0x2F)"
    assert found[(0x70, 6, 0x48)] == "TI TMP117 (device id 0x0117 at 0x0F)"
    assert found[(None, None, 0x50)] == "answers; no chip the rig drives lives at this address"
    assert found[(None, None, 0x70)].startswith("TCA9548A/PCA9548A I2C switch")
    assert scan.switches == [0x70, 0x74] and scan.notes == []
    assert switches[0x70].control == 0 and switches[0x74].control == 0  # left as at power-up


def test_a_chip_with_other_id_registers_is_no_chip_the_rig_drives(world):
    bus = FakeSMBus()
    bus.attach(0x30, RegisterChip())  # answers at the MMC5983MA's address, product id register 0x00
    chip = RegisterChip()
    chip.registers[0x0F:0x11] = b"\x21\x17"  # a TMP119's device id
    bus.attach(0x49, chip)
    found = {f.address: f.what for f in busscan.scan_i2c(bus).found}
    assert found[0x30] == "answers, but its identification registers match no chip the rig drives here"
    assert found[0x49].startswith("TI TMP119 (device id 0x2117")


def test_eeprom_ranges_are_read_not_quick_written(world):
    bus, _ = bench(world)
    calls = []

    class Watch:  # every transfer on its way to the bus, by method and address
        def __getattr__(self, name):
            method = getattr(bus, name)
            return lambda *a, **k: (calls.append((name, a[0])), method(*a, **k))[1]

    busscan.scan_i2c(Watch())
    quick = {a for name, a in calls if name == "write_quick"}
    assert not quick & (set(range(0x30, 0x38)) | set(range(0x50, 0x60)))
    assert {("read_byte", 0x50), ("read_byte", 0x30)} <= set(calls)
    assert ("write_quick", 0x1E) in calls


def test_an_adapter_without_the_quick_command_is_asked_by_reads(world):
    bus, _ = bench(world)

    class NoQuick(FakeSMBus):  # like a CP2112: SMBus quick is not supported
        def __init__(self):
            self.__dict__.update(bus.__dict__)

        def write_quick(self, i2c_addr, force=None):
            raise OSError(errno.EOPNOTSUPP, "Operation not supported")

    found = {(f.switch, f.channel, f.address) for f in busscan.scan_i2c(NoQuick()).found}
    assert {(None, None, 0x1E), (0x70, 2, 0x30), (0x70, 6, 0x48)} <= found


def test_a_switch_that_does_not_read_back_is_said_so_and_not_searched(world):
    bus, switches = bench(world)
    switches[0x70].readback = 0x55
    scan = busscan.scan_i2c(bus)
    found = {(f.switch, f.address): f.what for f in scan.found}
    assert "does not read back its control byte" in found[(None, 0x70)]
    assert not any(f.switch == 0x70 for f in scan.found)  # MMC and TMP117 behind it stay unknown
    assert scan.switches == [0x74]


def test_nothing_answers_on_an_empty_bus():
    assert busscan.scan_i2c(FakeSMBus()).found == []
