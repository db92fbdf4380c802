"""MEMSIC MMC5983MA 3-axis AMR magnetometer (18-bit, +-8 G) over I2C.

    MMC5983MA(bus, address=0x30, *, name="dut1", clock=None, bandwidth=0, set_reset=True,
              read_temperature=True, tries=3)

- `bus`: an smbus2.SMBus (drivers.transports.i2c.open_smbus) or drivers.sim.transports.i2c_bus.FakeSMBus.
- `bandwidth`: BW code 0..3 (measurement time 8 / 4 / 2 / 0.5 ms).
- `set_reset`: read() does a SET and a RESET measurement and returns H = (H_set - H_reset)/2 with
  the bridge offset (H_set + H_reset)/2 in FieldSample.offset_nt; counts are then the SET codes.
- `read_temperature`: read() also measures the die temperature (about 0.8 degC resolution); with
  `set_reset`, between the two halves, while the RESET settles (TM_M and TM_T only may not be high
  together), so that it is the pair's temperature and costs no wait of its own.

Control registers 0x09..0x0C are write-only (they read back 0), so the driver keeps shadow copies.
Register facts: hardware-notes 1.1 (MMC5983MA datasheet rev A).
"""

from __future__ import annotations

import logging
import math
from typing import Literal

from drivers import registry
from drivers.base import Device, FieldSample, reading_description
from drivers.clock import Clock
from drivers.errors import DeviceError, OptionError, ProtocolError
from drivers.steps import Steps, run_steps
from drivers.transports.i2c import I2CTransport, SMBusLike

log = logging.getLogger("magrig.drivers.mmc5983ma")

# --- register map -----------------------------------------------------------------------------------
ADDRESS = 0x30
REG_XOUT0 = 0x00  # 7-byte burst: X[17:10] X[9:2] Y.. Y.. Z.. Z.. XYZout2
REG_TOUT = 0x07
REG_STATUS = 0x08
REG_CONTROL0 = 0x09  # write-only
REG_CONTROL1 = 0x0A  # write-only
REG_CONTROL2 = 0x0B  # write-only
REG_CONTROL3 = 0x0C  # write-only
REG_PRODUCT_ID = 0x2F
PRODUCT_ID = 0x30
FIELD_BURST_BYTES = 7

STATUS_MEAS_M_DONE = 0x01
STATUS_MEAS_T_DONE = 0x02
STATUS_OTP_READ_DONE = 0x10
CONTROL0_TM_M = 0x01
CONTROL0_TM_T = 0x02
CONTROL0_SET = 0x08
CONTROL0_RESET = 0x10
CONTROL0_AUTO_SR_EN = 0x20
CONTROL1_BW_MASK = 0x03
CONTROL1_SW_RST = 0x80
CONTROL2_CM_FREQ_MASK = 0x07
CONTROL2_CMM_EN = 0x08

CODE_BITS = 18
CODE_MAX = (1 << CODE_BITS) - 1
NULL_CODE = 131072  # zero field, 18-bit mode
COUNTS_PER_GAUSS = 16384  # 18-bit mode: 6.25 nT/LSB
NT_PER_GAUSS = 100_000.0
RANGE_GAUSS = 8.0
TEMP_ZERO_C = -75.0  # Tout = 0
TEMP_C_PER_COUNT = 200.0 / 255.0

MEASUREMENT_TIME_S = (0.008, 0.004, 0.002, 0.0005)  # by BW code
BANDWIDTH_HZ = (100, 200, 400, 800)
NOISE_RMS_MILLIGAUSS = (0.4, 0.6, 0.8, 1.2)
MAX_ODR_HZ = (50, 100, 225, 580)
CM_FREQ_HZ = {1: 1.0, 2: 10.0, 3: 20.0, 4: 50.0, 5: 100.0, 6: 200.0, 7: 1000.0}  # CM_Freq code -> Hz
CM_FREQ_MIN_BW = {6: 1, 7: 3}  # 200 Hz needs BW=01, 1000 Hz needs BW=11
SET_RESET_WAIT_S = 0.001  # the pulse is 500 ns; settle before measuring
SW_RESET_WAIT_S = 0.015  # power-on time after SW_RST is 10 ms
TEMP_TIMEOUT_MIN_S = 0.005


# --- pure decoding ----------------------------------------------------------------------------------
def decode_field_codes(block: bytes) -> tuple[int, int, int]:
    """The 7-byte burst from 0x00 -> unsigned 18-bit X, Y, Z codes (low two bits live in byte 6)."""
    if len(block) != FIELD_BURST_BYTES:
        raise ValueError(f"field burst must be {FIELD_BURST_BYTES} bytes, got {len(block)}")
    b = block
    x = b[0] << 10 | b[1] << 2 | (b[6] >> 6) & 0x03
    y = b[2] << 10 | b[3] << 2 | (b[6] >> 4) & 0x03
    z = b[4] << 10 | b[5] << 2 | (b[6] >> 2) & 0x03
    return x, y, z


def code_to_nt(code: float) -> float:
    """18-bit code -> field in nT: (code - 131072) / 16384 gauss."""
    return (code - NULL_CODE) / COUNTS_PER_GAUSS * NT_PER_GAUSS


def decode_temp_c(raw: int) -> float:
    """Tout byte -> degC: -75 + raw * 200/255."""
    return TEMP_ZERO_C + raw * TEMP_C_PER_COUNT


def status_timeout_s(bandwidth: int) -> float:
    """How long to wait for Meas_M_Done: 4x the measurement time plus 1 ms."""
    return 4 * MEASUREMENT_TIME_S[bandwidth] + 0.001


def cm_freq_code(rate_hz: float) -> int:
    """Continuous-mode rate in Hz -> CM_Freq code; only the datasheet's rates exist."""
    for code, hz in CM_FREQ_HZ.items():
        if math.isclose(hz, rate_hz):
            return code
    raise OptionError(f"continuous rate {rate_hz} Hz: must be one of {sorted(CM_FREQ_HZ.values())} Hz")


# --- driver -----------------------------------------------------------------------------------------
class MMC5983MA(Device):
    kind = "magnetometer"
    model = "MMC5983MA"

    def __init__(
        self,
        bus: SMBusLike,
        address: int = ADDRESS,
        *,
        name: str = "mmc5983ma",
        clock: Clock | None = None,
        bandwidth: int = 0,
        set_reset: bool = True,
        read_temperature: bool = True,
        tries: int = 3,
    ):
        super().__init__(name, clock)
        self._check_bandwidth(bandwidth)
        self.link = I2CTransport(bus, address, name=name, clock=self.clock, tries=tries)
        self.bandwidth = bandwidth
        self.set_reset = set_reset
        self.read_temperature = read_temperature
        self.continuous_hz: float | None = None
        self.product_id: int | None = None
        # shadows of the write-only control registers
        self._control0 = 0
        self._control1 = 0
        self._control2 = 0

    # --- vocabulary -------------------------------------------------------------------------------
    def connect(self) -> None:
        """Check the product id, software-reset, then program the bandwidth (continuous mode off)."""
        found = self.link.read_byte(REG_PRODUCT_ID, "product id")
        if found != PRODUCT_ID:
            raise ProtocolError(
                self.name, f"check product id (register 0x{REG_PRODUCT_ID:02X})",
                f"read 0x{found:02X}, expected 0x{PRODUCT_ID:02X} for an MMC5983MA: another chip at "
                f"0x{self.link.address:02X}?",
            )
        self.product_id = found
        self.link.write_byte(REG_CONTROL1, CONTROL1_SW_RST, "control 1 (software reset)")
        self.clock.sleep(SW_RESET_WAIT_S)
        self._control0 = self._control1 = self._control2 = 0
        self.continuous_hz = None
        self.set_bandwidth(self.bandwidth)
        self._write_control2(0)

    def describe(self) -> dict:
        noise_nt = NOISE_RMS_MILLIGAUSS[self.bandwidth] * 1e-3 * NT_PER_GAUSS
        return {
            **super().describe(),
            "model": self.model,
            "address": f"0x{self.link.address:02X}",
            "product_id": None if self.product_id is None else f"0x{self.product_id:02X}",
            "range_nt": RANGE_GAUSS * NT_PER_GAUSS,
            "resolution_nt": NT_PER_GAUSS / COUNTS_PER_GAUSS,
            "noise_rms_nt": noise_nt,
            "bandwidth_code": self.bandwidth,
            "bandwidth_hz": BANDWIDTH_HZ[self.bandwidth],
            "measurement_time_s": MEASUREMENT_TIME_S[self.bandwidth],
            "max_odr_hz": MAX_ODR_HZ[self.bandwidth],
            "set_reset": self.set_reset,
            "continuous_hz": self.continuous_hz,
            "reading": self.reading(),
        }

    def reading(self) -> dict:
        """How read() makes h (drivers/base.py reading_description)."""
        conversion = (f"H_nT = (code - {NULL_CODE}) / {COUNTS_PER_GAUSS} * {NT_PER_GAUSS:.0f} per axis "
                      f"(18-bit output codes X, Y, Z; {NT_PER_GAUSS / COUNTS_PER_GAUSS:.4g} nT per code)")
        if self.set_reset and self.continuous_hz is None:
            return reading_description(
                "set_reset_pair", "h = (H_SET - H_RESET) / 2: a measurement after a SET pulse and one after "
                "a RESET pulse; the bridge offset cancels", conversion)
        return reading_description(
            "single", "h = H of one measurement, no SET/RESET pulse before it: the bridge offset stays in h "
            "(the calibration's offset holds it)", conversion)

    def read(self) -> FieldSample:
        """One field sample (and the temperature, if enabled); in continuous mode the next new one.
        t is the start of a triggered measurement, or when continuous-mode data arrived."""
        return run_steps(self.read_steps(), self.clock)

    def read_steps(self) -> Steps[FieldSample]:
        """read() as steps (drivers/steps.py): the conversions of several chips can then overlap."""
        t = self.clock.now()
        offset_nt = temp_c = None
        codes_reset: tuple[int, ...] = ()
        if self.continuous_hz is not None:
            codes = self._read_continuous_codes()
            t = self.clock.now()  # when the new data was seen, not when we started waiting
            field_nt = tuple(code_to_nt(c) for c in codes)
        elif self.set_reset:
            yield from self._pulse_steps(CONTROL0_SET)
            codes = yield from self._measure_steps()
            if self.read_temperature:  # the die temperature between the pair's halves, as the RESET settles
                self._write_pulse(CONTROL0_RESET)
                temp_c = yield from self._temp_steps(settle_s=SET_RESET_WAIT_S)
            else:
                yield from self._pulse_steps(CONTROL0_RESET)
            codes_reset = yield from self._measure_steps()
            pairs = list(zip(codes, codes_reset, strict=True))
            field_nt = tuple(code_to_nt(NULL_CODE + (s - r) / 2) for s, r in pairs)
            offset_nt = tuple(code_to_nt((s + r) / 2) for s, r in pairs)
        else:
            codes = yield from self._measure_steps()
            field_nt = tuple(code_to_nt(c) for c in codes)
        if temp_c is None and self.read_temperature:
            temp_c = yield from self._temp_steps()
        saturated = any(c in (0, CODE_MAX) for c in codes + codes_reset)
        flags = frozenset({"saturated"}) if saturated else frozenset()
        return FieldSample(
            t=t, field_nt=field_nt, counts=codes, temp_c=temp_c, offset_nt=offset_nt, flags=flags
        )

    def safe_state(self) -> None:
        """Stop continuous mode and automatic SET/RESET; the chip then idles. Never raises."""
        try:
            self._write_control2(0)
            self._control0 = 0
            self.link.write_byte(REG_CONTROL0, 0, "control 0")
            self.continuous_hz = None
        except DeviceError as exc:
            log.warning("%s: safe state not confirmed: %s", self.name, exc, extra={"device": self.name})

    # --- operations -------------------------------------------------------------------------------
    def set_bandwidth(self, bandwidth: int) -> None:
        self._check_bandwidth(bandwidth)
        self._control1 = (self._control1 & ~CONTROL1_BW_MASK) | bandwidth
        self.link.write_byte(REG_CONTROL1, self._control1, "control 1 (bandwidth)")
        self.bandwidth = bandwidth

    def pulse(self, set_or_reset: int) -> None:
        """Send a SET (CONTROL0_SET) or RESET (CONTROL0_RESET) pulse and let the bridge settle."""
        run_steps(self._pulse_steps(set_or_reset), self.clock)

    def measure_codes(self) -> tuple[int, int, int]:
        """One single magnetic measurement: TM_M, wait for Meas_M_Done, burst-read the 7 data bytes."""
        return run_steps(self._measure_steps(), self.clock)

    def measure_temp_c(self) -> float:
        return run_steps(self._temp_steps(), self.clock)

    def _pulse_steps(self, set_or_reset: int) -> Steps[None]:
        self._write_pulse(set_or_reset)
        yield SET_RESET_WAIT_S

    def _write_pulse(self, set_or_reset: int) -> None:
        self.link.write_byte(REG_CONTROL0, self._control0 | set_or_reset, "control 0 (SET/RESET)")

    def _measure_steps(self) -> Steps[tuple[int, int, int]]:
        self.link.write_byte(REG_CONTROL0, self._control0 | CONTROL0_TM_M, "control 0 (TM_M)")
        yield from self._status_steps(STATUS_MEAS_M_DONE, "Meas_M_Done", MEASUREMENT_TIME_S[self.bandwidth],
                                      status_timeout_s(self.bandwidth))
        return decode_field_codes(self.link.read_block(REG_XOUT0, FIELD_BURST_BYTES, "field data"))

    def _temp_steps(self, settle_s: float = 0.0) -> Steps[float]:
        """TM_T, its wait (at least `settle_s`: a SET/RESET pulse written just before settles meanwhile),
        the temperature."""
        self.link.write_byte(REG_CONTROL0, self._control0 | CONTROL0_TM_T, "control 0 (TM_T)")
        timeout_s = max(TEMP_TIMEOUT_MIN_S, status_timeout_s(self.bandwidth), settle_s)
        yield from self._status_steps(STATUS_MEAS_T_DONE, "Meas_T_Done",
                                      max(MEASUREMENT_TIME_S[self.bandwidth], settle_s), timeout_s)
        return decode_temp_c(self.link.read_byte(REG_TOUT, "temperature"))

    def start_continuous(self, rate_hz: float) -> None:
        """Measure continuously at a CM_Freq rate (1, 10, 20, 50, 100, 200, 1000 Hz); read() then
        returns each new measurement. One SET first, so the bridge sign is +H; no SET/RESET per sample."""
        code = cm_freq_code(rate_hz)
        if self.bandwidth < CM_FREQ_MIN_BW.get(code, 0):
            raise OptionError(
                f"{self.name}: continuous rate {rate_hz:g} Hz needs bandwidth code >= "
                f"{CM_FREQ_MIN_BW[code]}, set {self.bandwidth}"
            )
        self.pulse(CONTROL0_SET)
        self._write_control2(CONTROL2_CMM_EN | code)
        self.continuous_hz = rate_hz

    def stop_continuous(self) -> None:
        self._write_control2(0)
        self.continuous_hz = None

    # --- helpers ----------------------------------------------------------------------------------
    def _read_continuous_codes(self) -> tuple[int, int, int]:
        period_s = 1.0 / (self.continuous_hz or 1.0)
        self._wait_status(STATUS_MEAS_M_DONE, "Meas_M_Done (continuous)", 0.0,
                          period_s + status_timeout_s(self.bandwidth))
        codes = decode_field_codes(self.link.read_block(REG_XOUT0, FIELD_BURST_BYTES, "field data"))
        self.link.write_byte(REG_STATUS, STATUS_MEAS_M_DONE, "status (clear Meas_M_Done)")
        return codes

    def _wait_status(self, mask: int, what: str, first_wait_s: float, timeout_s: float) -> None:
        run_steps(self._status_steps(mask, what, first_wait_s, timeout_s), self.clock)

    def _status_steps(self, mask: int, what: str, first_wait_s: float, timeout_s: float) -> Steps[None]:
        yield from self.link.wait_steps(
            lambda: bool(self.link.read_byte(REG_STATUS, "status") & mask),
            what=f"{what} (status 0x{REG_STATUS:02X})", first_wait_s=first_wait_s, timeout_s=timeout_s,
        )

    def _write_control2(self, value: int) -> None:
        self._control2 = value
        self.link.write_byte(REG_CONTROL2, value, "control 2 (continuous mode)")

    @staticmethod
    def _check_bandwidth(bandwidth: int) -> None:
        if bandwidth not in range(len(MEASUREMENT_TIME_S)):
            raise OptionError(f"MMC5983MA bandwidth code {bandwidth!r}: must be 0, 1, 2 or 3")


# --- registration -----------------------------------------------------------------------------------
class MMC5983MAOptions(registry.Options):
    bandwidth_hz: Literal[100, 200, 400, 800] = 100
    set_reset: bool = True


def _build(link: registry.I2cLink, options: MMC5983MAOptions, *, name: str, clock: Clock,
           set_reset: bool = True) -> MMC5983MA:
    """`set_reset=False` (the plan's `set_reset: off`) turns SET/RESET off whatever the option says."""
    return MMC5983MA(link.bus, link.address, name=name, clock=clock,
                     bandwidth=BANDWIDTH_HZ.index(options.bandwidth_hz),
                     set_reset=set_reset and options.set_reset)


def _sample_time_s(options: MMC5983MAOptions, set_reset_pair: bool) -> float:
    one = MEASUREMENT_TIME_S[BANDWIDTH_HZ.index(options.bandwidth_hz)] + 0.002  # + bus transfer
    return 2 * (one + SET_RESET_WAIT_S) if set_reset_pair else one


def identify(bus: SMBusLike, address: int) -> str | None:
    """For bus scans: the product id register, nothing written."""
    found = bus.read_byte_data(address, REG_PRODUCT_ID)
    if found != PRODUCT_ID:
        return None
    return f"MEMSIC MMC5983MA (product id 0x{found:02X} at 0x{REG_PRODUCT_ID:02X})"


registry.register(registry.DeviceSpec(
    role="magnetometer", type="mmc5983ma", options=MMC5983MAOptions, transports=("i2c",), build=_build,
    simulator="drivers.sim.devices.mmc5983ma:simulate", has_temperature=True, sample_time=_sample_time_s,
    probe=registry.I2cProbe((ADDRESS,), identify), manufacturer="MEMSIC"))
