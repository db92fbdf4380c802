"""3-axis bipolar Helmholtz-coil current controller over Modbus (our register map, docs/modbus-maps.md).

Construct (the station YAML maps onto these keywords; `transport` is a ModbusTransport):

    CoilController(transport, *, name, clock, max_current_a, poll_s=0.05)

connect() checks the identity registers (model must start with "MAGRIG-HC3") and that max_current_a
does not exceed the controller's rating; set(currents_a) writes the three setpoints in one request, then
switches the outputs on; read() -> CoilReading; wait_settled(timeout_s) polls on the injected clock until
every axis reports settled (status bit 1) with its read-back within the supply's stated read-back accuracy
of its setpoint (`readback_accuracy_ppm` of the setpoint + `readback_accuracy_ma`; a fixed tol_a instead
when given; a supply steady a little beyond its stated accuracy is warned of and accepted, see
wait_settled); safe_state() sets 0 A on every axis, then switches the outputs off.

Faults (over-temperature, compliance: the supply cannot drive the current) are reported in the reading;
wait_settled raises DeviceFault on one, since a faulted axis will not settle.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass
from numbers import Real

from pydantic import Field

from drivers import registry
from drivers.base import Device, wait_until
from drivers.clock import Clock
from drivers.errors import DeviceFault, DeviceTimeout, LimitError, OptionError, ProtocolError
from drivers.transports.modbus import ModbusTransport, decode_int32, encode_int32

log = logging.getLogger("magrig.drivers.coils")

AXES = ("x", "y", "z")
MODEL_PREFIX = "MAGRIG-HC3"

# --- register map (holding registers; int32 values are two registers, high word first) ------------
MODEL = 0  # R string, 8 registers (16 ASCII characters, zero padded)
MODEL_REGISTERS = 8
FIRMWARE = 8  # R uint16 major, then minor at 9
RATED_CURRENT_MA = 10  # R uint16, full-scale current of each channel, mA
SETPOINT_UA = 100  # RW int32 x3 (x, y, z): bipolar current setpoint, microamps
READBACK_UA = 106  # R  int32 x3: measured output current, microamps
OUTPUT_ENABLE = 112  # RW uint16 x3: 1 = output on
STATUS = 115  # R  uint16 x3: status bits below
COMPLIANCE_LIMIT_UA = 118  # R int32 x3: largest current the supply can drive into its coil
COMMAND = 124  # W uint16: COMMAND_CLEAR_FAULTS
COMMAND_CLEAR_FAULTS = 1

STATUS_OUTPUT_ON = 1 << 0
STATUS_SETTLED = 1 << 1
STATUS_OVER_TEMPERATURE = 1 << 2
STATUS_COMPLIANCE = 1 << 3
FAULT_BITS = {"over_temperature": STATUS_OVER_TEMPERATURE, "compliance": STATUS_COMPLIANCE}

UA_PER_A = 1_000_000
# A bipolar supply's read-back: 0.05 % + 0.5 mA (hardware-notes §9.3, a placeholder the notes flag [A]); a
# station states its own supply's figures (field_source.readback_accuracy_ppm, readback_accuracy_ma)
READBACK_ACCURACY_PPM = 500.0
READBACK_ACCURACY_MA = 0.5
# wait_settled: where the supply has called an axis settled at this many polls, it is where the supply puts
# it; further off its setpoint than this x the stated accuracy is a fault
STEADY_POLLS = 3
OFF_SETPOINT_FACTOR = 4.0


def currents_to_words(currents_a) -> list[int]:
    words: list[int] = []
    for current_a in currents_a:
        words += encode_int32(round(current_a * UA_PER_A))
    return words


def words_to_currents(words) -> tuple[float, float, float]:
    return tuple(decode_int32(words[2 * i : 2 * i + 2]) / UA_PER_A for i in range(3))


def decode_faults(status_words) -> frozenset[str]:
    """{"x:over_temperature", "z:compliance", ...} from the three status words."""
    return frozenset(
        f"{axis}:{fault}"
        for axis, word in zip(AXES, status_words, strict=True)
        for fault, bit in FAULT_BITS.items()
        if word & bit
    )


@dataclass(frozen=True)
class CoilReading:
    t: float
    currents_a: tuple[float, float, float]  # readback
    setpoints_a: tuple[float, float, float]
    enabled: tuple[bool, bool, bool]
    faults: frozenset[str]
    settled: tuple[bool, bool, bool] = (True, True, True)  # status bit 1: the regulation at its target


class CoilController(Device):
    kind = "coils"

    def __init__(
        self,
        transport: ModbusTransport,
        *,
        name: str,
        clock: Clock | None = None,
        max_current_a: float,
        poll_s: float = 0.05,  # 20 Hz: a read-back settles in tenths of a second; a poll is a round trip
        readback_accuracy_ppm: float = READBACK_ACCURACY_PPM,
        readback_accuracy_ma: float = READBACK_ACCURACY_MA,
    ):
        super().__init__(name, clock)
        self.transport = transport
        self.max_current_a = max_current_a
        self.poll_s = poll_s
        self.readback_accuracy_ppm = readback_accuracy_ppm
        self.readback_accuracy_ma = readback_accuracy_ma
        self.model = ""
        self.firmware = ""
        self.rated_current_a: float | None = None
        self.compliance_limit_a: tuple[float, float, float] | None = None
        self._warned_off_setpoint: set[str] = set()  # axes warned of a read-back beyond the stated accuracy

    def connect(self) -> None:
        self.transport.connect()
        self.model = self.transport.read_string(MODEL, MODEL_REGISTERS, operation="read model")
        if not self.model.startswith(MODEL_PREFIX):
            raise ProtocolError(
                self.name, "connect", f"model {self.model!r} is not a {MODEL_PREFIX} controller"
            )
        major, minor, rated_ma = self.transport.read_holding(
            FIRMWARE, 3, operation="read firmware and rating"
        )
        self.firmware = f"{major}.{minor}"
        self.rated_current_a = rated_ma / 1000.0
        if self.max_current_a > self.rated_current_a:
            raise OptionError(
                f"{self.name}: max_current_a {self.max_current_a} A exceeds the controller's "
                f"rating {self.rated_current_a} A"
            )
        words = self.transport.read_holding(COMPLIANCE_LIMIT_UA, 6, operation="read compliance limits")
        self.compliance_limit_a = words_to_currents(words)

    def close(self) -> None:
        self.transport.close()

    def set(self, currents_a) -> None:
        """Command (x, y, z) currents in A; limits are checked before anything is written."""
        currents = self._checked(currents_a)
        text = ", ".join(f"{c:+.6f}" for c in currents)
        self.transport.write_registers(
            SETPOINT_UA, currents_to_words(currents), operation=f"write setpoints ({text}) A"
        )
        self.transport.write_registers(OUTPUT_ENABLE, [1, 1, 1], operation="switch outputs on")

    def read(self) -> CoilReading:
        t = self.clock.now()
        words = self.transport.read_holding(SETPOINT_UA, STATUS + 3 - SETPOINT_UA, operation="read currents")

        def at(reg: int, n: int) -> list[int]:
            return words[reg - SETPOINT_UA : reg - SETPOINT_UA + n]

        status = at(STATUS, 3)
        return CoilReading(
            t=t,
            currents_a=words_to_currents(at(READBACK_UA, 6)),
            setpoints_a=words_to_currents(at(SETPOINT_UA, 6)),
            enabled=tuple(bool(w) for w in at(OUTPUT_ENABLE, 3)),
            faults=decode_faults(status),
            settled=tuple(bool(w & STATUS_SETTLED) for w in status),
        )

    def readback_tolerance_a(self, setpoint_a: float) -> float:
        """How far a settled axis's read-back may be from its setpoint: the supply's stated read-back
        accuracy, plus the registers' 1 uA step."""
        return (abs(setpoint_a) * self.readback_accuracy_ppm * 1e-6 + self.readback_accuracy_ma / 1000.0
                + 1.0 / UA_PER_A)

    def wait_settled(self, timeout_s: float = 1.0, tol_a: float | None = None) -> CoilReading:
        """Poll until every axis reports settled and its read-back is within its tolerance of its setpoint
        (readback_tolerance_a, or tol_a when given); DeviceFault on a fault, DeviceTimeout after timeout_s
        (on the injected clock).

        Against the stated accuracy (no tol_a), a supply can be worse than its figures. Once every axis has
        been reported settled at STEADY_POLLS polls, an axis whose mean read-back over them is up to
        OFF_SETPOINT_FACTOR x its tolerance off the setpoint is accepted, with a warning once per axis:
        the run goes on from the read-back (the reference field follows the measured current), so this
        costs nothing but the warning. Further off is a DeviceFault: a wiring or supply fault, not a slow
        supply."""
        recent: deque[tuple[float, float, float]] = deque(maxlen=STEADY_POLLS)  # the last settled read-backs

        def tolerances(reading: CoilReading) -> list[float]:
            return [tol_a if tol_a is not None else self.readback_tolerance_a(s) for s in reading.setpoints_a]

        def settled(reading: CoilReading) -> bool:
            if reading.faults:
                raise DeviceFault(
                    self.name, "wait settled", f"controller reports {', '.join(sorted(reading.faults))}"
                )
            if not all(reading.settled):
                return False
            tols = tolerances(reading)
            errors = [abs(c - s) for c, s in zip(reading.currents_a, reading.setpoints_a, strict=True)]
            if all(e <= t for e, t in zip(errors, tols, strict=True)):
                return True
            recent.append(reading.currents_a)
            if tol_a is not None or len(recent) < STEADY_POLLS:
                return False
            self._off_setpoint([sum(axis) / len(axis) for axis in zip(*recent, strict=True)],
                               reading.setpoints_a, tols)
            return True

        def timed_out(reading: CoilReading) -> DeviceTimeout:
            tol = ", ".join(f"{t:.4g}" for t in tolerances(reading))
            unsettled = [a for a, ok in zip(AXES, reading.settled, strict=True) if not ok]
            return DeviceTimeout(
                self.name,
                "wait settled",
                f"readback {reading.currents_a} A not within ({tol}) A of setpoints "
                f"{reading.setpoints_a} A after {timeout_s:g} s"
                + (f"; not settled: {', '.join(unsettled)}" if unsettled else ""),
            )

        return wait_until(self.clock, self.read, settled, timeout_s=timeout_s, poll_s=self.poll_s,
                          timed_out=timed_out)

    def _off_setpoint(self, means: list[float], setpoints, tols: list[float]) -> None:
        """Settled read-backs (their mean per axis) beyond the stated accuracy: a fault far off, else
        warned once per axis."""
        for axis, current, setpoint, tol in zip(AXES, means, setpoints, tols, strict=True):
            error = abs(current - setpoint)
            if error <= tol:
                continue
            what = (f"axis {axis} settled at {current:+.6f} A for its setpoint {setpoint:+.6f} A: "
                    f"{error * 1e3:.3f} mA off, its stated read-back accuracy is {tol * 1e3:.3f} mA")
            if error > OFF_SETPOINT_FACTOR * tol:
                raise DeviceFault(self.name, "wait settled",
                                  f"{what}; more than {OFF_SETPOINT_FACTOR:g}x that is a wiring or supply "
                                  "fault (check the axis, or state the supply's figures: "
                                  "field_source.readback_accuracy_ppm / readback_accuracy_ma)")
            if axis not in self._warned_off_setpoint:
                self._warned_off_setpoint.add(axis)
                log.warning("%s: %s; going on from the read-back, which the reference field follows "
                            "(state the supply's figures: field_source.readback_accuracy_ppm / "
                            "readback_accuracy_ma)", self.name, what, extra={"device": self.name})

    def clear_faults(self) -> None:
        self.transport.write_register(COMMAND, COMMAND_CLEAR_FAULTS, operation="clear faults")

    def safe_state(self) -> None:
        self.transport.write_registers(SETPOINT_UA, [0] * 6, operation="safe state: setpoints to 0 A")
        self.transport.write_registers(OUTPUT_ENABLE, [0, 0, 0], operation="safe state: outputs off")

    def describe(self) -> dict:
        return {
            **super().describe(),
            "model": self.model,
            "firmware": self.firmware,
            "rated_current_a": self.rated_current_a,
            "compliance_limit_a": self.compliance_limit_a,
            "max_current_a": self.max_current_a,
            **self.transport.describe(),
        }

    def _checked(self, currents_a) -> tuple[float, float, float]:
        if any(isinstance(c, bool) or not isinstance(c, Real) for c in currents_a):
            raise LimitError(f"{self.name}: currents must be numbers, got {list(currents_a)!r}")
        values = tuple(float(c) for c in currents_a)
        if len(values) != 3:
            raise LimitError(f"{self.name}: expected 3 currents (x, y, z), got {len(values)}")
        for axis, current_a in zip(AXES, values, strict=True):
            if not math.isfinite(current_a):
                raise LimitError(f"{self.name}: current on axis {axis} is {current_a}, not a number")
            if not abs(current_a) <= self.max_current_a:  # a NaN limit refuses every current
                raise LimitError(
                    f"{self.name}: current {current_a:+.4f} A on axis {axis} exceeds max_current_a "
                    f"{self.max_current_a} A"
                )
        return values


# --- registration -----------------------------------------------------------------------------------
class CoilOptions(registry.Options):
    max_current_a: float = Field(gt=0, description="the driver refuses any larger setpoint")
    readback_accuracy_ppm: float = Field(
        READBACK_ACCURACY_PPM, ge=0, le=1e5, description="the supply's read-back accuracy, of the setpoint")
    readback_accuracy_ma: float = Field(
        READBACK_ACCURACY_MA, ge=0, le=1e4, description="the supply's read-back accuracy, offset part (mA)")


def _build(link: ModbusTransport, options: CoilOptions, *, name: str, clock: Clock, **_) -> CoilController:
    return CoilController(link, name=name, clock=clock, max_current_a=options.max_current_a,
                          readback_accuracy_ppm=options.readback_accuracy_ppm,
                          readback_accuracy_ma=options.readback_accuracy_ma)


registry.register(registry.DeviceSpec(
    role="field_source", type="coils", options=CoilOptions, transports=registry.MODBUS_KINDS,
    build=_build, simulator="drivers.sim.devices.coils:simulate"))
