"""Per-sample overhead of the serial magnetometer driver on a pty, against the wire time it cannot beat.

    python bench/serial_overhead.py [--samples 300]

The HMR2300 runs at 9600 or 19200 baud; the bench works at 19200 (the driver switches the simulated
device there with *99!BR=F). The simulator holds every line back for its 8N1 line time at the device's
rate (and replies with no extra latency), so the wall time per sample contains the wire time a real cable
would take. Figures printed:

- polled: wall time per `*00P` sample minus the wire time of the command (5 bytes) and the reply
  (28 bytes); the same for plain pyserial (write + read_until) on the same pty, as a floor that has
  no driver in it; and the caller thread's CPU time per sample (the driver's own cost).
- SET/RESET read: four exchanges per sample (]R, P, ]S, P).
- streamed at 60 Hz, the fastest rate a 28-byte ASCII stream fits at 19200 baud: the device sets the
  pace (one line per 16.7 ms); the overhead is the caller thread's CPU time per sample, to compare with
  the sample period and the line time.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import serial

from drivers.clock import SimClock
from drivers.serialmag import LINE_BYTES, SerialMagnetometer
from drivers.sim.devices.serialmag import SerialMagSim
from drivers.sim.world import DutTruth, World
from drivers.transports.serial import line_time_s

MAX_RATE_HZ = 60  # ASCII: 280 bits per sample, 19200 baud carries at most 68 per second
BAUD = 19200
POLL_COMMAND = b"*00P\r"


def make_world() -> World:
    world = World(SimClock())
    world.add_dut("dut1", DutTruth.random(np.random.default_rng(1)))
    world.set_coil_currents([0.5, -0.2, 1.0])
    return world


def timed(fn, n: int) -> tuple[list[float], float]:
    """Wall seconds of each call, and the caller thread's CPU seconds per call."""
    walls = []
    cpu0 = time.thread_time()
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        walls.append(time.perf_counter() - t0)
    return walls, (time.thread_time() - cpu0) / n


def us(seconds: float) -> str:
    return f"{seconds * 1e6:8.0f} us"


def report(label: str, walls: list[float], cpu_s: float, wire_s: float) -> None:
    median = statistics.median(walls)
    p95 = float(np.percentile(walls, 95))
    print(
        f"{label:<26} wall median {us(median)}  p95 {us(p95)}  wire {us(wire_s)}  "
        f"overhead {us(median - wire_s)}  caller CPU {us(cpu_s)}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=300)
    args = parser.parse_args()
    n, baud = args.samples, BAUD

    reply_s = line_time_s(LINE_BYTES, baud)
    poll_wire_s = line_time_s(len(POLL_COMMAND), baud) + reply_s
    period_s = 1 / MAX_RATE_HZ
    print(
        f"device limits: {MAX_RATE_HZ} Hz max output = {us(period_s)} per sample; "
        f"28-byte line at {baud} baud 8N1 = {us(reply_s)} (at 9600: {us(line_time_s(LINE_BYTES, 9600))}, "
        f"so 9600 baud caps the stream at {1 / line_time_s(LINE_BYTES, 9600):.0f} Hz)"
    )

    world = make_world()
    with SerialMagSim(world, "dut1", reply_latency_s=0.0, line_time=True) as sim:
        raw = serial.Serial(sim.path, 9600, timeout=0.5)  # the device starts at 9600
        raw.write(b"\x1b*99WE\r*99!BR=F\r")
        raw.flush()
        raw.read(1)  # no reply is sent: this waits the port timeout while the device switches
        raw.baudrate = baud

        def raw_poll() -> None:
            raw.write(POLL_COMMAND)
            if len(raw.read_until(b"\r")) != LINE_BYTES:
                raise RuntimeError("raw poll: short reply")

        report("pyserial only, polled", *timed(raw_poll, n), poll_wire_s)
        raw.close()

        def connected(set_reset: str) -> SerialMagnetometer:
            mag = SerialMagnetometer.from_port(
                sim.path, name="dut1", clock=world.clock, baudrate=baud, set_reset=set_reset
            )
            mag.connect()
            return mag

        plain = connected("off")
        report("driver read(), polled", *timed(plain.read, n), poll_wire_s)
        plain.close()

        pulsed = connected("pulse")
        pulse_wire_s = 2 * poll_wire_s + 2 * (line_time_s(len(b"*00]S\r"), baud) + line_time_s(4, baud))
        report("driver read(), SET/RESET", *timed(pulsed.read, max(1, n // 3)), pulse_wire_s)
        pulsed.close()

        streamer = connected("off")  # no offset pair before the stream: time the stream alone
        streamer.set_rate(MAX_RATE_HZ)
        streamer.read_stream(5)  # warm-up
        t0, cpu0 = time.perf_counter(), time.thread_time()
        samples = streamer.read_stream(n)
        wall_s = (time.perf_counter() - t0) / len(samples)
        cpu_s = (time.thread_time() - cpu0) / len(samples)
        streamer.safe_state()
        streamer.close()
    print(
        f"{'driver read_stream(), 60 Hz':<26} wall per sample {us(wall_s)} (period {us(period_s)}); "
        f"caller CPU {us(cpu_s)} = {cpu_s / period_s:.1%} of the period, "
        f"{cpu_s / reply_s:.1%} of the line time"
    )
    print(f"lines the simulator dropped (nobody reading): {sim.dropped_bytes} bytes")


if __name__ == "__main__":
    main()
