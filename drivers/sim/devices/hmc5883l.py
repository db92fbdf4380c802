"""Register-level HMC5883L / HMC5983: `HMC5883LSim(world, dut, variant="HMC5883L"|"HMC5983")` at 0x1E.

Faithful where the driver can tell: id 'H43'; single-measurement mode clears RDY, sets it after the
measurement time on the world's clock and returns to idle; continuous mode (MD 00) measures at the
Config A output rate; data in X, Z, Y order, big-endian int16, 12-bit range -2048..2047 with -4096 on
overflow; a gain write takes effect from the second measurement after it; the HMC5983 fills
0x31/0x32 with the DUT temperature when TS is set. The bridge sees world.dut_raw_nt(dut, +1): the
part's own SET pulse leaves the offset in.

Fault hook: `never_ready = True` (RDY never sets; the driver must time out).
"""

from __future__ import annotations

import math

import numpy as np

from drivers import hmc5883l as hmc
from drivers.registry import SimI2c, SimRequest
from drivers.sim.transports.i2c_bus import RegisterChip
from drivers.sim.world import World

POWER_ON_CONFIG_A = 0x10  # 15 Hz, 1 average, normal
POWER_ON_CONFIG_B = 0x20  # GN = 1
POWER_ON_MODE = hmc.MODE_SINGLE
READ_ONLY = (hmc.REG_STATUS, *range(hmc.REG_ID, hmc.REG_ID + 3))


def field_to_codes(field_nt: np.ndarray, gain: int) -> tuple[int, int, int]:
    """Quantise at gain GN; outside -2048..2047 the axis reads -4096."""
    codes = np.rint(np.asarray(field_nt) / hmc.NT_PER_GAUSS * hmc.GAIN_LSB_PER_GAUSS[gain])
    return tuple(
        int(c) if hmc.DATA_MIN_CODE <= c <= hmc.DATA_MAX_CODE else hmc.OVERFLOW_CODE for c in codes
    )


def encode_xzy(codes: tuple[int, int, int]) -> bytes:
    x, y, z = codes
    return b"".join(v.to_bytes(2, "big", signed=True) for v in (x, z, y))


class HMC5883LSim(RegisterChip):
    def __init__(self, world: World, dut: str, variant: str = "HMC5883L"):
        super().__init__()
        if variant not in hmc.VARIANTS:
            raise ValueError(f"variant {variant!r}: must be one of {hmc.VARIANTS}")
        self.world = world
        self.dut = dut
        self.variant = variant
        self.never_ready = False
        self.faults = None  # a drivers.sim.devices.faults.DeviceFaults: a stuck window freezes the
                            # temperature
        self.registers[hmc.REG_CONFIG_A] = POWER_ON_CONFIG_A
        self.registers[hmc.REG_CONFIG_B] = POWER_ON_CONFIG_B
        self.registers[hmc.REG_MODE] = POWER_ON_MODE
        self.registers[hmc.REG_ID:hmc.REG_ID + 3] = hmc.ID_BYTES
        self.active_gain = POWER_ON_CONFIG_B >> hmc.CONFIG_B_GAIN_SHIFT
        self.done_at: float | None = None
        self.continuous_start: float | None = None
        self.continuous_count = 0

    def update(self) -> None:
        now = self.world.clock.now()
        if self.done_at is not None and now >= self.done_at:
            self.done_at = None
            self._latch()
            self.registers[hmc.REG_MODE] = hmc.MODE_IDLE
        if self.continuous_start is not None and not self.never_ready:
            rate_code = (self.registers[hmc.REG_CONFIG_A] >> hmc.CONFIG_A_RATE_SHIFT) & 0b111
            count = math.floor((now - self.continuous_start) * hmc.OUTPUT_RATE_HZ[rate_code])
            if count > self.continuous_count:
                self.continuous_count = count
                self._latch()

    def _latch(self) -> None:
        raw_nt = self.world.dut_raw_nt(self.dut, 1)
        codes = field_to_codes(raw_nt, self.active_gain)
        self.registers[hmc.REG_DATA:hmc.REG_DATA + hmc.DATA_BYTES] = encode_xzy(codes)
        self.active_gain = self.registers[hmc.REG_CONFIG_B] >> hmc.CONFIG_B_GAIN_SHIFT  # from the next one on
        if self.variant == "HMC5983" and self.registers[hmc.REG_CONFIG_A] & hmc.CONFIG_A_TS:
            temp_c = self.world.dut_temp_c(self.dut)
            if self.faults is not None:
                temp_c = self.faults.shown_temperature(temp_c)
            raw = round((temp_c - hmc.TEMP_ZERO_C) * hmc.TEMP_COUNTS_PER_C)
            raw = max(-32768, min(32767, raw))
            self.registers[hmc.REG_TEMP:hmc.REG_TEMP + 2] = raw.to_bytes(2, "big", signed=True)
        self.registers[hmc.REG_STATUS] |= hmc.STATUS_RDY

    def read_register(self, register: int) -> int:
        if self.variant != "HMC5983" and register in (hmc.REG_TEMP, hmc.REG_TEMP + 1):
            return 0
        return self.registers[register]

    def write_register(self, register: int, value: int) -> None:
        if register in READ_ONLY or register in range(hmc.REG_DATA, hmc.REG_DATA + hmc.DATA_BYTES):
            return
        if register == hmc.REG_CONFIG_B:
            value &= 0xE0  # bits 4:0 must be 0
        self.registers[register] = value
        if register != hmc.REG_MODE:
            return
        now = self.world.clock.now()
        mode = value & 0x03
        self.continuous_start = now if mode == hmc.MODE_CONTINUOUS else None
        self.continuous_count = 0
        self.done_at = None
        if mode == hmc.MODE_SINGLE:
            self.registers[hmc.REG_STATUS] &= ~hmc.STATUS_RDY
            self.done_at = math.inf if self.never_ready else now + hmc.MEASUREMENT_TIME_S


def simulate(req: SimRequest) -> SimI2c:
    return SimI2c(HMC5883LSim(req.world, req.name, req.type.upper()), hmc.ADDRESS)
