"""TI TMP117 digital temperature sensor (+-0.1 degC, 7.8125 m degC/LSB) over I2C.

    TMP117(bus, address=0x48, *, name="tmp1", clock=None, mode="one_shot", averaging=8,
           conversion_code=4, tries=3)

- `mode`: "one_shot" (each read() starts a conversion, the chip shuts down after it) or "continuous"
  (read() waits for the next Data_Ready).
- `averaging`: 1, 8, 32 or 64 conversions per result (15.5 ms each).
- `conversion_code`: CONV 0..7, the continuous-mode cycle (15.5 ms .. 16 s; never shorter than the
  averaging needs).

Registers are 16-bit big-endian, read and written as 2-byte I2C bursts (smbus read_word_data would be
little-endian). Register facts: hardware-notes 2.1.
"""

from __future__ import annotations

import logging

from drivers import registry
from drivers.base import Device, TempSample
from drivers.clock import Clock
from drivers.errors import DeviceError, OptionError, ProtocolError
from drivers.steps import Steps, run_steps
from drivers.transports.i2c import I2CTransport, SMBusLike

log = logging.getLogger("magrig.drivers.tmp117")

# --- register map -----------------------------------------------------------------------------------
ADDRESS = 0x48
ADDRESSES = (0x48, 0x49, 0x4A, 0x4B)  # by the ADD0 pin: GND, V+, SDA, SCL (0x48 the default)
REG_TEMP_RESULT = 0x00
REG_CONFIGURATION = 0x01
REG_THIGH = 0x02
REG_TLOW = 0x03
REG_TEMP_OFFSET = 0x07
REG_DEVICE_ID = 0x0F
DEVICE_ID = 0x0117
TMP119_DEVICE_ID = 0x2117

CONFIG_HIGH_ALERT = 1 << 15
CONFIG_LOW_ALERT = 1 << 14
CONFIG_DATA_READY = 1 << 13
CONFIG_EEPROM_BUSY = 1 << 12
CONFIG_MODE_SHIFT = 10
CONFIG_MODE_MASK = 0b11 << CONFIG_MODE_SHIFT
CONFIG_CONV_SHIFT = 7
CONFIG_AVG_SHIFT = 5
CONFIG_SOFT_RESET = 1 << 1
MODE_CONTINUOUS = 0b00
MODE_SHUTDOWN = 0b01
MODE_ONE_SHOT = 0b11

C_PER_LSB = 0.0078125
NO_RESULT_CODE = -32768  # TEMP_RESULT before the first conversion (-256 degC)
AVG_CODES = {1: 0, 8: 1, 32: 2, 64: 3}
CONVERSION_TIME_S = 0.0155  # one conversion; averaging repeats it
DEFAULT_AVERAGING = 8
CONV_CYCLE_S = (0.0155, 0.125, 0.25, 0.5, 1.0, 4.0, 8.0, 16.0)  # by CONV code
RANGE_C = (-55.0, 150.0)
ACCURACY_C = 0.1  # -20..50 degC
MODES = ("one_shot", "continuous")


# --- pure decoding ----------------------------------------------------------------------------------
def decode_temp_c(word: bytes) -> float:
    """TEMP_RESULT (2 bytes, big-endian two's complement) -> degC."""
    return int.from_bytes(word, "big", signed=True) * C_PER_LSB


def config_word(mode: int, averaging: int, conversion_code: int = 0) -> bytes:
    """CONFIGURATION register value (big-endian bytes) for a mode, averaging count and CONV code."""
    value = (
        mode << CONFIG_MODE_SHIFT
        | conversion_code << CONFIG_CONV_SHIFT
        | AVG_CODES[averaging] << CONFIG_AVG_SHIFT
    )
    return value.to_bytes(2, "big")


def active_time_s(averaging: int) -> float:
    """Time one (averaged) result takes to convert."""
    return averaging * CONVERSION_TIME_S


def cycle_time_s(averaging: int, conversion_code: int) -> float:
    """Continuous-mode period: the CONV setting, but never shorter than the averaging needs."""
    return max(CONV_CYCLE_S[conversion_code], active_time_s(averaging))


# --- driver -----------------------------------------------------------------------------------------
class TMP117(Device):
    kind = "thermometer"
    model = "TMP117"

    def __init__(
        self,
        bus: SMBusLike,
        address: int = ADDRESS,
        *,
        name: str = "tmp117",
        clock: Clock | None = None,
        mode: str = "one_shot",
        averaging: int = DEFAULT_AVERAGING,
        conversion_code: int = 4,
        tries: int = 3,
    ):
        super().__init__(name, clock)
        if mode not in MODES:
            raise OptionError(f"{name}: mode {mode!r}: must be one of {', '.join(MODES)}")
        if averaging not in AVG_CODES:
            raise OptionError(f"{name}: averaging {averaging!r}: must be 1, 8, 32 or 64")
        if conversion_code not in range(len(CONV_CYCLE_S)):
            raise OptionError(f"{name}: conversion_code {conversion_code!r}: must be 0..7")
        self.link = I2CTransport(bus, address, name=name, clock=self.clock, tries=tries)
        self.mode = mode
        self.averaging = averaging
        self.conversion_code = conversion_code
        self.device_id: int | None = None

    # --- vocabulary -------------------------------------------------------------------------------
    def connect(self) -> None:
        """Check DEVICE_ID, then start continuous conversions or shut down until the first read()."""
        found = int.from_bytes(self._read_word(REG_DEVICE_ID, "device id"), "big")
        if found != DEVICE_ID:
            hint = " (that is a TMP119)" if found == TMP119_DEVICE_ID else ""
            raise ProtocolError(
                self.name, f"check device id (register 0x{REG_DEVICE_ID:02X})",
                f"read 0x{found:04X}{hint}, expected 0x{DEVICE_ID:04X} for a TMP117",
            )
        self.device_id = found
        mode = MODE_CONTINUOUS if self.mode == "continuous" else MODE_SHUTDOWN
        self._write_config(mode)

    def describe(self) -> dict:
        return {
            **super().describe(),
            "model": self.model,
            "address": f"0x{self.link.address:02X}",
            "product_id": None if self.device_id is None else f"0x{self.device_id:04X}",
            "range_c": RANGE_C,
            "resolution_c": C_PER_LSB,
            "accuracy_c": ACCURACY_C,
            "mode": self.mode,
            "averaging": self.averaging,
            "cycle_time_s": cycle_time_s(self.averaging, self.conversion_code),
        }

    def read(self) -> TempSample:
        return run_steps(self.read_steps(), self.clock)

    def read_steps(self) -> Steps[TempSample]:
        """read() as steps (drivers/steps.py): several probes then wait for their conversions together."""
        t = self.clock.now()
        if self.mode == "one_shot":
            self._write_config(MODE_ONE_SHOT)
            first_wait_s = active_time_s(self.averaging)
            timeout_s = 4 * first_wait_s + 0.001
        else:
            first_wait_s = 0.0
            timeout_s = 4 * cycle_time_s(self.averaging, self.conversion_code) + 0.001
        yield from self.link.wait_steps(
            lambda: bool(int.from_bytes(self._read_word(REG_CONFIGURATION, "configuration"), "big")
                         & CONFIG_DATA_READY),
            what=f"Data_Ready (configuration 0x{REG_CONFIGURATION:02X} bit 13)",
            first_wait_s=first_wait_s, timeout_s=timeout_s,
        )
        word = self._read_word(REG_TEMP_RESULT, "temperature result")
        no_result = int.from_bytes(word, "big", signed=True) == NO_RESULT_CODE
        flags = frozenset({"no_result"}) if no_result else frozenset()
        return TempSample(t=t, temp_c=decode_temp_c(word), flags=flags)

    def safe_state(self) -> None:
        """Shutdown mode (no self-heating, nothing harmful either way). Never raises."""
        try:
            self._write_config(MODE_SHUTDOWN)
        except DeviceError as exc:
            log.warning("%s: safe state not confirmed: %s", self.name, exc, extra={"device": self.name})

    # --- helpers ----------------------------------------------------------------------------------
    def _read_word(self, register: int, what: str) -> bytes:
        return self.link.read_block(register, 2, what)

    def _write_config(self, mode: int) -> None:
        word = config_word(mode, self.averaging, self.conversion_code)
        self.link.write_block(REG_CONFIGURATION, word, "configuration")


# --- registration -----------------------------------------------------------------------------------
def _build(link: registry.I2cLink, options: registry.NoOptions, *, name: str, clock: Clock, **_) -> TMP117:
    return TMP117(link.bus, link.address, name=name, clock=clock)


def identify(bus: SMBusLike, address: int) -> str | None:
    """For bus scans: the DEVICE_ID register (16-bit, big-endian), nothing written."""
    found = int.from_bytes(bytes(bus.read_i2c_block_data(address, REG_DEVICE_ID, 2)), "big")
    if found == DEVICE_ID:
        return f"TI TMP117 (device id 0x{found:04X} at 0x{REG_DEVICE_ID:02X})"
    if found == TMP119_DEVICE_ID:
        return f"TI TMP119 (device id 0x{found:04X} at 0x{REG_DEVICE_ID:02X}; the rig drives TMP117s)"
    return None


def _sample_time_s(options: registry.NoOptions, set_reset_pair: bool) -> float:
    """One one-shot result at the averaging the rig builds it with (the default)."""
    return active_time_s(DEFAULT_AVERAGING)


registry.register(registry.DeviceSpec(
    role="temperature", type="tmp117", options=registry.NoOptions, transports=("i2c",), build=_build,
    simulator="drivers.sim.devices.tmp117:simulate", has_temperature=True, sample_time=_sample_time_s,
    temperature_accuracy_c=0.15,  # TI datasheet: +-0.1 degC from -20 to 50 degC, +-0.15 from -55 to 150
    probe=registry.I2cProbe(ADDRESSES, identify), manufacturer="Texas Instruments"))
