"""Honeywell HMC5883L / HMC5983 3-axis AMR magnetometer (12-bit ADC) over I2C.

    HMC5883L(bus, address=0x1E, *, name="dut1", clock=None, variant="HMC5883L", gain=1, averaging=8,
             output_rate_code=4, read_temperature=True, tries=3)

- `variant`: "HMC5883L" or "HMC5983" (same id 'H43'; only the HMC5983 has a temperature sensor).
- `gain`: GN code 0..7 (+-0.88 .. +-8.1 Ga); a gain change takes effect from the second measurement,
  so the driver discards the first measurement after any gain write.
- `averaging`: 1, 2, 4 or 8 samples per output; `output_rate_code`: DO 0..6 (7 = 220 Hz, HMC5983).
- `read_temperature`: HMC5983 only: enable TS and report temp_c with each sample.

read() triggers a single measurement, polls RDY through the clock and reads X, Z, Y (that order,
big-endian int16). An ADC overflow (-4096) gives that axis NaN and the flag "overflow".
Register facts: hardware-notes 1.2.
"""

from __future__ import annotations

import logging
import math
from typing import ClassVar, Literal

from pydantic import Field, field_validator

from drivers import registry
from drivers.base import Device, FieldSample, reading_description
from drivers.clock import Clock
from drivers.errors import DeviceError, OptionError, ProtocolError
from drivers.steps import Steps, run_steps
from drivers.transports.i2c import I2CTransport, SMBusLike

log = logging.getLogger("magrig.drivers.hmc5883l")

# --- register map -----------------------------------------------------------------------------------
ADDRESS = 0x1E
REG_CONFIG_A = 0x00  # bit7 TS (HMC5983), bits6:5 averaging, bits4:2 DO rate, bits1:0 MS bias mode
REG_CONFIG_B = 0x01  # bits7:5 GN
REG_MODE = 0x02  # bits1:0 MD
REG_DATA = 0x03  # X MSB, X LSB, Z MSB, Z LSB, Y MSB, Y LSB
REG_STATUS = 0x09
REG_ID = 0x0A  # 'H' '4' '3'
REG_TEMP = 0x31  # HMC5983: MSB, LSB
ID_BYTES = b"H43"
DATA_BYTES = 6

CONFIG_A_TS = 0x80
CONFIG_A_AVERAGING_SHIFT = 5
CONFIG_A_RATE_SHIFT = 2
CONFIG_B_GAIN_SHIFT = 5
MODE_CONTINUOUS = 0x00
MODE_SINGLE = 0x01
MODE_IDLE = 0x03
STATUS_RDY = 0x01

AVERAGING_CODES = {1: 0, 2: 1, 4: 2, 8: 3}
GAIN_LSB_PER_GAUSS = (1370, 1090, 820, 660, 440, 390, 330, 230)  # by GN code
RANGE_GAUSS = (0.88, 1.3, 1.9, 2.5, 4.0, 4.7, 5.6, 8.1)
OUTPUT_RATE_HZ = (0.75, 1.5, 3.0, 7.5, 15.0, 30.0, 75.0, 220.0)  # by DO code; 220 Hz HMC5983 only
DATA_MIN_CODE, DATA_MAX_CODE = -2048, 2047
OVERFLOW_CODE = -4096
NT_PER_GAUSS = 100_000.0
NOISE_RMS_NT = 200.0  # "2 milli-gauss field resolution"
MEASUREMENT_TIME_S = 0.006  # single measurement, command to data ready (typical)
TEMP_ZERO_C = 25.0
TEMP_COUNTS_PER_C = 128.0
VARIANTS = ("HMC5883L", "HMC5983")


# --- pure decoding ----------------------------------------------------------------------------------
def decode_xzy(block: bytes) -> tuple[int, int, int]:
    """The 6 data bytes (X, Z, Y; big-endian int16 each) -> signed (x, y, z) codes."""
    if len(block) != DATA_BYTES:
        raise ValueError(f"data burst must be {DATA_BYTES} bytes, got {len(block)}")
    x, z, y = (int.from_bytes(block[i:i + 2], "big", signed=True) for i in (0, 2, 4))
    return x, y, z


def code_to_nt(code: int, gain: int) -> float:
    """Signed code at gain GN -> nT; the overflow code gives NaN."""
    if code == OVERFLOW_CODE:
        return math.nan
    return code / GAIN_LSB_PER_GAUSS[gain] * NT_PER_GAUSS


def decode_temp_c(block: bytes) -> float:
    """HMC5983 temperature: big-endian int16 / 128 + 25 degC."""
    return int.from_bytes(block, "big", signed=True) / TEMP_COUNTS_PER_C + TEMP_ZERO_C


def config_a(averaging: int, output_rate_code: int, temperature: bool) -> int:
    """Config A byte for normal measurement (no bias)."""
    ts = CONFIG_A_TS if temperature else 0
    averaging_bits = AVERAGING_CODES[averaging] << CONFIG_A_AVERAGING_SHIFT
    return ts | averaging_bits | output_rate_code << CONFIG_A_RATE_SHIFT


# --- driver -----------------------------------------------------------------------------------------
class HMC5883L(Device):
    kind = "magnetometer"

    def __init__(
        self,
        bus: SMBusLike,
        address: int = ADDRESS,
        *,
        name: str = "hmc5883l",
        clock: Clock | None = None,
        variant: str = "HMC5883L",
        gain: int = 1,
        averaging: int = 8,
        output_rate_code: int = 4,
        read_temperature: bool = True,
        tries: int = 3,
    ):
        super().__init__(name, clock)
        if variant not in VARIANTS:
            raise OptionError(f"{name}: variant {variant!r}: must be one of {', '.join(VARIANTS)}")
        if averaging not in AVERAGING_CODES:
            raise OptionError(f"{name}: averaging {averaging!r}: must be 1, 2, 4 or 8")
        max_rate_code = len(OUTPUT_RATE_HZ) - (1 if variant == "HMC5883L" else 0)
        if output_rate_code not in range(max_rate_code):
            raise OptionError(
                f"{name}: output_rate_code {output_rate_code!r}: must be 0..{max_rate_code - 1}"
            )
        self._check_gain(gain)
        self.model = variant
        self.link = I2CTransport(bus, address, name=name, clock=self.clock, tries=tries)
        self.gain = gain
        self.averaging = averaging
        self.output_rate_code = output_rate_code
        self.read_temperature = read_temperature and variant == "HMC5983"
        self.chip_id: bytes | None = None
        self._discard_next = True

    # --- vocabulary -------------------------------------------------------------------------------
    def connect(self) -> None:
        """Check the 'H43' id, write Config A and the gain, leave the chip idle."""
        found = self.link.read_block(REG_ID, len(ID_BYTES), "identification")
        if found != ID_BYTES:
            raise ProtocolError(
                self.name, f"check id (registers 0x{REG_ID:02X}..0x{REG_ID + 2:02X})",
                f"read {found!r}, expected {ID_BYTES!r} for an {self.model}: another chip at "
                f"0x{self.link.address:02X}?",
            )
        self.chip_id = found
        cra = config_a(self.averaging, self.output_rate_code, self.read_temperature)
        self.link.write_byte(REG_CONFIG_A, cra, "config A")
        self.set_gain(self.gain)
        self.link.write_byte(REG_MODE, MODE_IDLE, "mode (idle)")

    def describe(self) -> dict:
        lsb_per_gauss = GAIN_LSB_PER_GAUSS[self.gain]
        return {
            **super().describe(),
            "model": self.model,
            "address": f"0x{self.link.address:02X}",
            "product_id": None if self.chip_id is None else self.chip_id.decode("ascii", "replace"),
            "range_nt": RANGE_GAUSS[self.gain] * NT_PER_GAUSS,
            "resolution_nt": NT_PER_GAUSS / lsb_per_gauss,
            "noise_rms_nt": NOISE_RMS_NT,
            "gain_code": self.gain,
            "gain_lsb_per_gauss": lsb_per_gauss,
            "averaging": self.averaging,
            "output_rate_hz": OUTPUT_RATE_HZ[self.output_rate_code],
            "temperature": self.read_temperature,
            "reading": reading_description(
                "single", "h = H of one single measurement (the chip averages `averaging` samples into it); "
                "the driver sends no SET/RESET pulse, the chip has none to send: its datasheet states the "
                "bridge offset cancelled inside it",
                f"H_nT = code / {lsb_per_gauss} * {NT_PER_GAUSS:.0f} per axis (signed 12-bit codes, read in "
                f"the order X, Z, Y and reported as x, y, z; gain code {self.gain}; code {OVERFLOW_CODE} is "
                "an overflow)"),
        }

    def read(self) -> FieldSample:
        """One single measurement (after a discarded one if the gain just changed)."""
        return run_steps(self.read_steps(), self.clock)

    def read_steps(self) -> Steps[FieldSample]:
        """read() as steps (drivers/steps.py): the conversions of several chips can then overlap."""
        if self._discard_next:
            yield from self._measure_steps()
            self._discard_next = False
        t = self.clock.now()
        codes = yield from self._measure_steps()
        field_nt = tuple(code_to_nt(c, self.gain) for c in codes)
        flags = frozenset({"overflow"}) if OVERFLOW_CODE in codes else frozenset()
        temp_c = None
        if self.read_temperature:
            temp_c = decode_temp_c(self.link.read_block(REG_TEMP, 2, "temperature"))
        return FieldSample(t=t, field_nt=field_nt, counts=codes, temp_c=temp_c, flags=flags)

    def safe_state(self) -> None:
        """Idle mode. Never raises."""
        try:
            self.link.write_byte(REG_MODE, MODE_IDLE, "mode (idle)")
        except DeviceError as exc:
            log.warning("%s: safe state not confirmed: %s", self.name, exc, extra={"device": self.name})

    # --- operations -------------------------------------------------------------------------------
    def set_gain(self, gain: int) -> None:
        """Write GN; the next measurement still uses the old gain, so read() discards it."""
        self._check_gain(gain)
        self.link.write_byte(REG_CONFIG_B, gain << CONFIG_B_GAIN_SHIFT, "config B (gain)")
        self.gain = gain
        self._discard_next = True

    def measure_codes(self) -> tuple[int, int, int]:
        """Single-measurement mode: trigger, wait for RDY, read X Z Y."""
        return run_steps(self._measure_steps(), self.clock)

    def _measure_steps(self) -> Steps[tuple[int, int, int]]:
        self.link.write_byte(REG_MODE, MODE_SINGLE, "mode (single measurement)")
        yield from self.link.wait_steps(
            lambda: bool(self.link.read_byte(REG_STATUS, "status") & STATUS_RDY),
            what=f"RDY (status 0x{REG_STATUS:02X})",
            first_wait_s=MEASUREMENT_TIME_S, timeout_s=4 * MEASUREMENT_TIME_S + 0.001,
        )
        return decode_xzy(self.link.read_block(REG_DATA, DATA_BYTES, "data X Z Y"))

    def _check_gain(self, gain: int) -> None:
        if gain not in range(len(GAIN_LSB_PER_GAUSS)):
            raise OptionError(f"{self.name}: gain code {gain!r}: must be 0..7")


# --- registration -----------------------------------------------------------------------------------
class HMC5883LOptions(registry.Options):
    TYPE: ClassVar[str] = "hmc5883l"
    RATES_HZ: ClassVar[tuple[float, ...]] = OUTPUT_RATE_HZ[:-1]  # 220 Hz is the HMC5983's only

    gain: int = Field(1, ge=0, le=7)
    rate_hz: float = 15.0
    averaging: Literal[1, 2, 4, 8] = 8

    @field_validator("rate_hz")
    @classmethod
    def _a_rate_of_the_chip(cls, value: float) -> float:
        if value not in cls.RATES_HZ:
            raise ValueError(f"{cls.TYPE} runs at one of {', '.join(f'{r:g}' for r in cls.RATES_HZ)} Hz")
        return value


class HMC5983Options(HMC5883LOptions):
    TYPE: ClassVar[str] = "hmc5983"
    RATES_HZ: ClassVar[tuple[float, ...]] = OUTPUT_RATE_HZ


def _build(link: registry.I2cLink, options: HMC5883LOptions, *, name: str, clock: Clock, **_) -> HMC5883L:
    return HMC5883L(link.bus, link.address, name=name, clock=clock, variant=options.TYPE.upper(),
                    gain=options.gain, averaging=options.averaging,
                    output_rate_code=OUTPUT_RATE_HZ.index(options.rate_hz))


def _sample_time_s(options: HMC5883LOptions, set_reset_pair: bool) -> float:
    return 1.0 / options.rate_hz


def identify(bus: SMBusLike, address: int) -> str | None:
    """For bus scans: the three id registers, nothing written. Both chips read 'H43'."""
    found = bytes(bus.read_i2c_block_data(address, REG_ID, len(ID_BYTES)))
    if found != ID_BYTES:
        return None
    return f"Honeywell HMC5883L or HMC5983 (id {ID_BYTES.decode()!r} at 0x{REG_ID:02X}..0x{REG_ID + 2:02X})"


PROBE = registry.I2cProbe((ADDRESS,), identify)

for _options, _has_temperature in ((HMC5883LOptions, False), (HMC5983Options, True)):
    registry.register(registry.DeviceSpec(
        role="magnetometer", type=_options.TYPE, options=_options, transports=("i2c",), build=_build,
        simulator="drivers.sim.devices.hmc5883l:simulate", has_temperature=_has_temperature,
        sample_time=_sample_time_s, rates_hz=_options.RATES_HZ, probe=PROBE, manufacturer="Honeywell"))
