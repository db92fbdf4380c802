"""Register-level MMC5983MA: `MMC5983MASim(world, dut)`, attached to a FakeSMBus at 0x30.

Faithful where the driver can tell: control registers 0x09..0x0C are write-only and read back 0;
TM_M / TM_T / SET / RESET / SW_RST are self-clearing; Meas_M_Done clears on a new command and sets when
the bandwidth's measurement time has passed on the world's clock; SET and RESET flip the sign of the
bridge term (world.dut_raw_nt polarity) while the bridge offset stays; codes are 18-bit, clipped at
+-8 G; continuous mode (Cmm_en + CM_Freq) produces a new measurement every period.

Fault hook: `never_done = True` (a measurement never completes; the driver must time out).
"""

from __future__ import annotations

import math

import numpy as np

from drivers import mmc5983ma as mmc
from drivers.registry import SimI2c, SimRequest
from drivers.sim.transports.i2c_bus import RegisterChip
from drivers.sim.world import World

POWER_ON_STATUS = mmc.STATUS_OTP_READ_DONE
WRITE_ONLY = range(mmc.REG_CONTROL0, mmc.REG_CONTROL3 + 1)


def encode_field_codes(codes: tuple[int, int, int]) -> bytes:
    """X, Y, Z 18-bit codes -> the 7 data bytes at 0x00 (inverse of the driver's decoder)."""
    x, y, z = codes
    low = (x & 3) << 6 | (y & 3) << 4 | (z & 3) << 2
    return bytes([x >> 10, x >> 2 & 0xFF, y >> 10, y >> 2 & 0xFF, z >> 10, z >> 2 & 0xFF, low])


def field_to_codes(field_nt: np.ndarray) -> tuple[int, int, int]:
    """Quantise to 18 bits around the null code; beyond +-8 G the code sticks at the rail."""
    # in floats, not arrays (every simulated reading comes through here); round() is half-to-even like
    # numpy's rint
    return tuple(min(mmc.CODE_MAX, max(0, round(x / mmc.NT_PER_GAUSS * mmc.COUNTS_PER_GAUSS) + mmc.NULL_CODE))
                 for x in np.asarray(field_nt, float).tolist())


class MMC5983MASim(RegisterChip):
    def __init__(self, world: World, dut: str):
        super().__init__()
        self.world = world
        self.dut = dut
        self.never_done = False
        self.faults = None  # a drivers.sim.devices.faults.DeviceFaults: a stuck window freezes the
                            # temperature
        self._power_on()

    def _power_on(self) -> None:
        self.registers = bytearray(256)
        self.registers[mmc.REG_PRODUCT_ID] = mmc.PRODUCT_ID
        self.registers[mmc.REG_STATUS] = POWER_ON_STATUS
        self.registers[0:6] = bytes([0x80, 0, 0x80, 0, 0x80, 0])  # null field
        self.polarity = 1  # +1 after SET, -1 after RESET
        self.bandwidth = 0
        self.field_done_at: float | None = None
        self.temp_done_at: float | None = None
        self.continuous_period_s: float | None = None
        self.continuous_start = 0.0
        self.continuous_count = 0

    @property
    def measurement_time_s(self) -> float:
        return mmc.MEASUREMENT_TIME_S[self.bandwidth]

    # --- time ---------------------------------------------------------------------------------------
    def update(self) -> None:
        now = self.world.clock.now()
        if self.field_done_at is not None and now >= self.field_done_at:
            self.field_done_at = None
            self._latch_field()
        if self.temp_done_at is not None and now >= self.temp_done_at:
            self.temp_done_at = None
            self._latch_temperature()
        if self.continuous_period_s is not None and not self.never_done:
            count = math.floor((now - self.continuous_start) / self.continuous_period_s)
            if count > self.continuous_count:
                self.continuous_count = count
                self._latch_field()

    def _latch_field(self) -> None:
        raw_nt = self.world.dut_raw_nt(self.dut, self.polarity)
        self.registers[0:7] = encode_field_codes(field_to_codes(raw_nt))
        self.registers[mmc.REG_STATUS] |= mmc.STATUS_MEAS_M_DONE

    def _latch_temperature(self) -> None:
        temp_c = self.world.dut_temp_c(self.dut)
        if self.faults is not None:
            temp_c = self.faults.shown_temperature(temp_c)
        raw = round((temp_c - mmc.TEMP_ZERO_C) / mmc.TEMP_C_PER_COUNT)
        self.registers[mmc.REG_TOUT] = min(255, max(0, raw))
        self.registers[mmc.REG_STATUS] |= mmc.STATUS_MEAS_T_DONE

    # --- registers ----------------------------------------------------------------------------------
    def read_register(self, register: int) -> int:
        if register in WRITE_ONLY:
            return 0
        return self.registers[register]

    def write_register(self, register: int, value: int) -> None:
        if register == mmc.REG_STATUS:  # write 1 to clear an interrupt bit
            self.registers[register] &= ~(value & (mmc.STATUS_MEAS_M_DONE | mmc.STATUS_MEAS_T_DONE))
        elif register == mmc.REG_CONTROL0:
            self._control0(value)
        elif register == mmc.REG_CONTROL1:
            if value & mmc.CONTROL1_SW_RST:
                self._power_on()
            else:
                self.bandwidth = value & mmc.CONTROL1_BW_MASK
        elif register == mmc.REG_CONTROL2:
            self._control2(value)
        # other registers are read-only or unused: writes are ignored

    def _control0(self, value: int) -> None:
        now = self.world.clock.now()
        if value & mmc.CONTROL0_SET:
            self.polarity = 1
        if value & mmc.CONTROL0_RESET:
            self.polarity = -1
        done_in_s = math.inf if self.never_done else self.measurement_time_s
        if value & mmc.CONTROL0_TM_M:
            self.registers[mmc.REG_STATUS] &= ~mmc.STATUS_MEAS_M_DONE
            self.field_done_at = now + done_in_s
        if value & mmc.CONTROL0_TM_T:
            self.registers[mmc.REG_STATUS] &= ~mmc.STATUS_MEAS_T_DONE
            self.temp_done_at = now + done_in_s

    def _control2(self, value: int) -> None:
        rate_hz = mmc.CM_FREQ_HZ.get(value & mmc.CONTROL2_CM_FREQ_MASK)
        if value & mmc.CONTROL2_CMM_EN and rate_hz:
            self.continuous_period_s = 1.0 / rate_hz
            self.continuous_start = self.world.clock.now()
            self.continuous_count = 0
        else:
            self.continuous_period_s = None


def simulate(req: SimRequest) -> SimI2c:
    return SimI2c(MMC5983MASim(req.world, req.name), mmc.ADDRESS)
