"""Register-level TMP117: `TMP117Sim(world, dut, offset_c=0.0)` at 0x48, reading world.dut_temp_c(dut).

Faithful where the driver can tell: 16-bit big-endian registers (a 2-byte burst per register; SMBus
read_word_data therefore comes back byte-swapped); DEVICE_ID 0x0117; TEMP_RESULT -256 degC until the
first conversion; Data_Ready (bit 13) sets at the end of each conversion and clears when the
configuration or the result is read; one-shot converts for averaging x 15.5 ms and then shuts down;
continuous mode converts every cycle; TEMP_OFFSET is added to every result; SOFT_RESET restores the
power-on state.

Fault hooks: `stuck_c = value` (every result reads that temperature), `never_ready = True`
(Data_Ready never sets; the driver must time out), `faults` (a stuck window of
drivers.sim.devices.faults.DeviceFaults: conversions go on, the result stays what it was).
"""

from __future__ import annotations

import math

from drivers import tmp117 as tmp
from drivers.registry import SimI2c, SimRequest
from drivers.sim.world import World

AVG_COUNTS = {code: n for n, code in tmp.AVG_CODES.items()}
POWER_ON_CONFIG = 0x0220  # continuous, CONV 100 (1 s), AVG 01 (8)
WRITABLE = (tmp.REG_THIGH, tmp.REG_TLOW, tmp.REG_TEMP_OFFSET)
CONFIG_WRITABLE_MASK = 0x0FFC  # bits 15:12 are status, bit 1 (soft reset) self-clears, bit 0 reserved


def _int16(value: int) -> int:
    return value - 0x10000 if value & 0x8000 else value


class TMP117Sim:
    def __init__(self, world: World, dut: str, offset_c: float = 0.0):
        self.world = world
        self.dut = dut
        self.offset_c = offset_c
        self.stuck_c: float | None = None
        self.never_ready = False
        self.faults = None  # a drivers.sim.devices.faults.DeviceFaults: a stuck window freezes the result
        self.pointer = tmp.REG_TEMP_RESULT
        self._power_on()

    def _power_on(self) -> None:
        self.words = {
            tmp.REG_TEMP_RESULT: tmp.NO_RESULT_CODE & 0xFFFF,
            tmp.REG_THIGH: 0x6000,
            tmp.REG_TLOW: 0x8000,
            tmp.REG_TEMP_OFFSET: 0x0000,
            tmp.REG_DEVICE_ID: tmp.DEVICE_ID,
        }
        self.config = POWER_ON_CONFIG
        self.data_ready = False
        self._start_conversions()

    # --- conversions --------------------------------------------------------------------------------
    @property
    def mode(self) -> int:
        return (self.config & tmp.CONFIG_MODE_MASK) >> tmp.CONFIG_MODE_SHIFT

    def _averaging(self) -> int:
        return AVG_COUNTS[(self.config >> tmp.CONFIG_AVG_SHIFT) & 0b11]

    def _start_conversions(self) -> None:
        now = self.world.clock.now()
        averaging = self._averaging()
        self.one_shot_done_at: float | None = None
        self.cycle_s: float | None = None
        self.cycle_start = now
        self.cycle_count = 0
        if self.mode == tmp.MODE_ONE_SHOT:
            self.one_shot_done_at = now + tmp.active_time_s(averaging)
        elif self.mode != tmp.MODE_SHUTDOWN:  # 00 and 10 are both continuous
            conv = (self.config >> tmp.CONFIG_CONV_SHIFT) & 0b111
            self.cycle_s = tmp.cycle_time_s(averaging, conv)

    def update(self) -> None:
        if self.never_ready:
            return
        now = self.world.clock.now()
        if self.one_shot_done_at is not None and now >= self.one_shot_done_at:
            self.one_shot_done_at = None
            self._latch()
            self.config = (self.config & ~tmp.CONFIG_MODE_MASK) | tmp.MODE_SHUTDOWN << tmp.CONFIG_MODE_SHIFT
        if self.cycle_s is not None:
            count = math.floor((now - self.cycle_start) / self.cycle_s)
            if count > self.cycle_count:
                self.cycle_count = count
                self._latch()

    def _latch(self) -> None:
        temp_c = self.stuck_c if self.stuck_c is not None else self.world.dut_temp_c(self.dut) + self.offset_c
        if self.faults is not None:
            temp_c = self.faults.shown_temperature(temp_c)
        temp_c += _int16(self.words[tmp.REG_TEMP_OFFSET]) * tmp.C_PER_LSB
        code = max(-32768, min(32767, round(temp_c / tmp.C_PER_LSB)))
        self.words[tmp.REG_TEMP_RESULT] = code & 0xFFFF
        self.data_ready = True

    # --- bus side -----------------------------------------------------------------------------------
    def on_read(self, register: int, length: int) -> bytes:
        self.update()
        self.pointer = register
        if register == tmp.REG_CONFIGURATION:
            word = self.config | (tmp.CONFIG_DATA_READY if self.data_ready else 0)
            self.data_ready = False
        else:
            word = self.words.get(register, 0)
            if register == tmp.REG_TEMP_RESULT:
                self.data_ready = False
        data = word.to_bytes(2, "big")
        return (data * (length // 2 + 1))[:length]  # the pointer stays: longer reads repeat the word

    def on_receive(self) -> int:
        """A one-byte read with no pointer written first: the high byte of the register pointed at."""
        return self.on_read(self.pointer, 1)[0]

    def on_write(self, register: int, data: bytes) -> None:
        self.update()
        self.pointer = register
        if len(data) < 2:  # a pointer write, or half a word: nothing is stored
            return
        word = data[0] << 8 | data[1]
        if register == tmp.REG_CONFIGURATION:
            if word & tmp.CONFIG_SOFT_RESET:
                self._power_on()
                return
            self.config = word & CONFIG_WRITABLE_MASK
            self._start_conversions()
        elif register in WRITABLE:
            self.words[register] = word


def simulate(req: SimRequest) -> SimI2c:
    """The probe reads the temperature of the DUT it sits beside."""
    return SimI2c(TMP117Sim(req.world, req.beside or req.name), tmp.ADDRESS)
