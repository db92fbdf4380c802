"""`rig commission --thermal`: what a plan needs to know of a station, measured on it (the commissioning
file's `thermal:` section, rig/config/commissioning_file.py).

    section = measure_thermal(rig, step_c=THERMAL_STEP_C)     # inside the procedure's try/finally

1. The pace of one campaign point on the station's own transports: the field source driven to settings of
   its commissioning design and waited for (`move_s` beyond what the station states of its moves), a
   chamber reading (`chamber_read_s`), and one sample of every DUT as a campaign reads them: the
   temperature sensors, the field source's read-back, every DUT interleaved (rig/devices/interleave.py)
   (`sample_s`).
2. Each DUT's noise: NOISE_SAMPLES readings at one fixed field (the field source at rest), each axis's
   scatter about a straight line in time.
3. The chamber and each DUT position: the set point is stepped by `step_c` at the station's limit rate
   (checked against the limits before it is written) and the air and every DUT's temperature are logged
   every POLL_S until every DUT has settled (its temperature still for a dwell) or MAX_STEP_S; the air's
   real rate and overshoot (calib/thermal/response.py `air_motion`) and each DUT's first-order lag and offset
   behind the air (`first_order_fit`).
The procedure that calls it leaves the coils or table safe and the chamber at its safe set point on every
exit; a DUT whose lag the step does not show ends it with one line naming the DUT.
"""

from __future__ import annotations

import numpy as np

from calib.thermal.response import air_motion, first_order_fit
from rig.core.errors import ConfigError, DeviceError
from rig.devices.interleave import read_all
from rig.engine.stability import STABLE, StabilityCriteria, StabilityDetector

THERMAL_STEP_C = 15.0  # large enough to show the air's full pace and each DUT's lag, small enough to be quick
POLL_S = 10.0
MAX_STEP_S = 8 * 3600.0
NOISE_SAMPLES = 64
PACE_SAMPLES = 8
# "settled" for the step: still within 0.02 degC for 10 minutes, wherever the DUT's place puts it
SETTLED = StabilityCriteria(band_c=0.02, max_rate_c_per_min=0.005, dwell_s=600.0, max_wait_s=MAX_STEP_S,
                            max_offset_c=100.0)


def step_target_c(station, start_c: float, step_c: float) -> float:
    """Up by step_c from where the air is, or down when up would leave the chamber's limits; ConfigError
    naming the limit when neither fits."""
    lim = station.chamber.limits
    for target in (start_c + step_c, start_c - step_c):
        if lim.min_setpoint_c <= target <= lim.max_setpoint_c:
            return round(target, 3)
    raise ConfigError(f"station {station.name}: a thermal step of {step_c:g} degC from the air at "
                      f"{start_c:.1f} degC leaves chamber.limits min_setpoint_c {lim.min_setpoint_c:g} .. "
                      f"max_setpoint_c {lim.max_setpoint_c:g}")


def measure_pace(rig, station) -> dict:
    """The times a campaign point takes on this station's transports (see the module docstring)."""
    clock, source, mover = rig.clock, station.field_source, rig.field_source
    settings = [s for s, _ in source.commissioning_design(None, 1)][:PACE_SAMPLES]
    moved, stated, previous = [], [], None
    for setting in settings:
        start = clock.now()
        mover.set(setting)
        mover.wait_settled(source.settle_timeout_s())
        moved.append(clock.now() - start)
        stated.append(0.0 if previous is None else source.move_time_s([previous, setting]))
        previous = setting
    start = clock.now()
    for _ in range(PACE_SAMPLES):
        rig.chamber.read()
    chamber_read_s = (clock.now() - start) / PACE_SAMPLES
    start = clock.now()
    for _ in range(PACE_SAMPLES):
        read_all(rig.temp_sensors, clock)
        mover.read()
        read_all(rig.duts, clock)
    sample_s = (clock.now() - start) / PACE_SAMPLES
    move_s = max(0.0, float(np.mean(moved)) - float(np.mean(stated[1:] or [0.0])))
    return {"sample_s": sample_s, "move_s": move_s, "chamber_read_s": chamber_read_s, "moves": len(moved)}


def measure_noise(rig) -> dict[str, list[float]]:
    """Each DUT's scatter per axis (nT) at one fixed field, about a straight line in time (slow drift
    of the lab is not the DUT's noise)."""
    t, readings = [], {name: [] for name in rig.duts}
    for _ in range(NOISE_SAMPLES):
        got = read_all(rig.duts, rig.clock)
        t.append(rig.clock.now())
        for name, sample in got.items():
            readings[name].append(sample.field_nt)
    t = np.asarray(t) - t[0]
    x = np.column_stack([np.ones_like(t), t])
    out = {}
    for name, rows in readings.items():
        h = np.asarray(rows, float)
        residual = h - x @ np.linalg.lstsq(x, h, rcond=None)[0]
        out[name] = [float(v) for v in np.sqrt(np.sum(residual**2, axis=0) / (len(t) - 2))]
    return out


def _dut_temps(rig) -> dict[str, float]:
    cache: dict = {}
    out = {}
    for dut, source in rig.temp_sources.items():
        if source.name not in cache:
            cache[source.name] = source.read()
        temp = cache[source.name].temp_c
        if temp is None:
            raise DeviceError(source.name, "thermal commissioning", f"{dut}: no temperature")
        out[dut] = temp
    return out


def measure_step(rig, station, step_c: float) -> dict:
    """Step the set point at the limit rate and follow the air and the DUTs until they settle."""
    clock, chamber = rig.clock, rig.chamber
    first = chamber.read()
    start_c = first.air_c
    target = step_target_c(station, start_c, step_c)
    rate = station.chamber.limits.max_ramp_c_per_min
    if getattr(chamber, "ramps_setpoint", False):
        chamber.set_ramp_rate(rate)
    chamber.set(target)
    t, air, setpoint = [first.t], [start_c], [first.setpoint_c]
    temps = {dut: [v] for dut, v in _dut_temps(rig).items()}
    t_temps = [first.t]
    detectors = {dut: StabilityDetector(target, SETTLED) for dut in rig.duts}
    t0 = clock.now()
    while True:
        clock.sleep(POLL_S)
        reading = chamber.read()
        if reading.alarm or reading.input_error:
            raise DeviceError(chamber.name, "thermal commissioning", reading.problem)
        t.append(reading.t)
        air.append(reading.air_c)
        setpoint.append(target)
        now = _dut_temps(rig)
        t_temps.append(clock.now())
        for dut, value in now.items():
            temps[dut].append(value)
            detectors[dut].add(clock.now(), value)
        done = all(d.state == STABLE for d in detectors.values()) and abs(reading.air_c - target) < 1.0
        if done or clock.now() - t0 >= MAX_STEP_S:
            break
    motion = air_motion(t, setpoint, air)
    if motion.rate_c_per_min is None:
        raise DeviceError(chamber.name, "thermal commissioning", f"the air did not move: {motion.message}")
    duts = {}
    for dut, values in temps.items():
        fit = first_order_fit(t, air, t_temps, values)
        if not fit.identifiable:
            raise DeviceError(dut, "thermal commissioning", fit.message)
        duts[dut] = {"lag_s": fit.tau_s, "lag_se_s": fit.tau_se_s, "offset_c": fit.offset_c,
                     "residual_c": fit.rms_c, "temp_source": rig.temp_sources[dut].name}
    return {"step_c": [float(first.setpoint_c), target],
            "commanded_rate_c_per_min": rate, "rate_c_per_min": motion.rate_c_per_min,
            "overshoot_c": motion.overshoot_c, "duration_s": clock.now() - t0, "duts": duts}


def measure_thermal(rig, station, *, step_c: float = THERMAL_STEP_C, set_reset: str = "pair",
                    start_air_c: float | None = None) -> dict:
    """The commissioning file's `thermal:` section (see the module docstring); `start_air_c` is the air when
    the rig was opened (where a campaign's air starts; default: now)."""
    start_air_c = rig.chamber.read().air_c if start_air_c is None else start_air_c
    pace = measure_pace(rig, station)
    rig.field_source.safe_state()  # the noise at rest: coils at 0 A, table at home
    noise = measure_noise(rig)
    step = measure_step(rig, station, step_c)
    for dut, entry in step["duts"].items():
        entry["noise_nt"] = noise[dut]
    return {"start_air_c": float(start_air_c), **step, "set_reset": set_reset, **pace}
