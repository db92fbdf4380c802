"""What a plan is made and checked with, and where each number comes from: what was measured on the
station, or what the station states for real. The simulated world's own truth is never read.

    inputs = planning_inputs(plan, station, session=None)
    inputs.duts[name]            DutInput: noise, lag, offset (None where nothing says), with their origin
    inputs.missing()             DUTs whose noise or lag nothing gives
    require_duts(inputs, station)   ConfigError naming a DUT and the three ways, when any is missing
    inputs.rate_c_per_min        the fastest the air moves: the measured pace, never above the stated limit
    inputs.chamber, inputs.timing   the chamber (ChamberInput) and a point's pace (Timing)
    inputs.lines()               where each number comes from, for rig check and rig design

Sources, the first that says wins:
- each DUT's noise and lag (and where it settles relative to the air): `--from SESSION`
  (rig/planning/measured.py); a designed plan's `assumed:` (what it was designed with); the station's
  thermal commissioning (`rig commission --thermal`, rig/commission/thermal.py); the station's
  `duts[].expect: {noise_nt, thermal_lag_s}` (stated by the user: one plain reading's noise, so a
  SET/RESET pair divides it by sqrt 2). Without any, `rig design` refuses in one line naming the three.
- the chamber's pace, overshoot and starting air: `--from SESSION`, the thermal commissioning; else the
  station's stated `chamber.limits.max_ramp_c_per_min`, no overshoot and ASSUMED_START_C, said so.
- the pace of a point: `--from SESSION`, the thermal commissioning, a designed plan's `timing:`; else the
  drivers' stated conversion times (rig/schedules/check.py `stated_sample_time_s`), said so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

from rig.config import DesignedTemperatures, Plan, Station
from rig.core.errors import ConfigError
from rig.core.yamlload import blamed
from rig.planning.facts import ASSUMED_START_C, ChamberInput, DutInput, Timing
from rig.planning.pace import format_duration


def stated_sample_time_s(plan: Plan, station: Station) -> float:
    """Time for one sample of every DUT from the drivers' stated conversion times, for a station whose pace
    nothing has measured (rig/planning/inputs.py). Reading is interleaved (rig/devices/interleave.py): the
    DUTs wait for their conversions together, so a sample takes as long as the slowest DUT, except that
    DUTs sharing one serial line are polled in turn. The temperature sensors are read first, together
    likewise."""
    pair = plan.set_reset == "pair"
    groups: dict[tuple[str, str], float] = {}
    for d in station.duts:
        line, port = getattr(d.transport, "line", None), getattr(d.transport, "port", None)
        key = ("line", line) if line else ("port", port) if port else ("dut", d.name)
        groups[key] = groups.get(key, 0.0) + d.spec.sample_time_s(d.options, pair)
    sensors = [s.spec.sample_time_s(s.options, pair) for s in station.temperature_sensors]
    return max(groups.values()) + max(sensors, default=0.0)


THREE_WAYS = ("give `rig design --from SESSION` (an earlier session of these DUTs), run `rig commission "
              "--thermal` (the station's commissioning file), or state them in the station "
              "(duts[].expect: {noise_nt, thermal_lag_s})")


@dataclass
class PlanningInputs:
    duts: dict[str, DutInput]
    chamber: ChamberInput
    timing: Timing
    rate_c_per_min: float
    stated_rate: bool  # the rate is the station's stated limit, not a measurement
    notes: list[str] = field(default_factory=list)

    def missing(self) -> list[str]:
        return [n for n, d in self.duts.items() if d.noise_nt is None or d.lag_s is None]

    def lags_s(self) -> dict[str, float]:
        """The lags known (a DUT without one is left out)."""
        return {n: d.lag_s for n, d in self.duts.items() if d.lag_s is not None}

    def slowest_lag_s(self) -> float | None:
        """The longest lag of the DUTs, None unless every DUT's lag is known."""
        lags = self.lags_s()
        return max(lags.values()) if len(lags) == len(self.duts) else None

    def overshoot_c(self) -> float:
        return self.chamber.overshoot_c or 0.0

    def lines(self, *, per_dut: bool = False) -> list[str]:
        c, t = self.chamber, self.timing
        if self.stated_rate:
            chamber = (f"chamber: {self.rate_c_per_min:g} degC/min is chamber.limits.max_ramp_c_per_min, the "
                       "station's stated limit, not a measurement")
        else:
            chamber = (f"chamber: the air moves at up to {self.rate_c_per_min:.3g} degC/min, overshoot "
                       f"{self.overshoot_c():.2g} degC")
        lines = [f"{chamber}; the air starts at {c.start_c:.1f} degC ({c.origin})",
                 f"pace: {t.sample_s:.3g} s a sample of every DUT, {t.point_overhead_s:.3g} s a point beyond "
                 f"settle_s and its samples ({t.origin})"]
        missing = self.missing()
        if missing:
            lines.append(f"DUT noise and lags: not known for {_names(missing)}: {THREE_WAYS}")
        if per_dut:
            lines += [f"  {d.name}: {_dut_text(d)} ({d.origin})" for d in self.duts.values()]
        elif len(missing) < len(self.duts):
            known = [d for d in self.duts.values() if d.name not in missing]
            origins = sorted({d.origin for d in known})
            noise, lags = _span([d.noise_nt for d in known]), _span([d.lag_s for d in known], ".0f")
            lines.append(f"DUT noise {noise} nT, lags {lags} s ({'; '.join(origins)})")
        return lines


def _names(names: list[str]) -> str:
    return ", ".join(names[:4]) + (f" and {len(names) - 4} more" if len(names) > 4 else "")


def _span(values, fmt: str = ".3g") -> str:
    values = [v for v in values if v is not None]
    lo, hi = min(values), max(values)
    return f"{lo:{fmt}}" if f"{lo:{fmt}}" == f"{hi:{fmt}}" else f"{lo:{fmt}}..{hi:{fmt}}"


def _dut_text(d: DutInput) -> str:
    noise = "noise not known" if d.noise_nt is None else f"noise {d.noise_nt:.3g} nT"
    lag = "lag not known" if d.lag_s is None else f"lag {d.lag_s:.0f} s"
    offset = "" if d.offset_c is None else f", settles {d.offset_c:+.2f} degC from the air"
    return f"{noise}, {lag}{offset}"


# --- the sources ------------------------------------------------------------------------------------------
def thermal_of(station: Station):
    """The station's thermal commissioning (rig.config.commissioning_file.ThermalRecord) or None."""
    commissioned = getattr(station.field_source, "commissioned", None)
    return None if commissioned is None else commissioned.thermal


def _pair_factor(plan: Plan, dut, read_as_pair: bool) -> float:
    """Noise of a reading as the plan takes it, over a reading taken as `read_as_pair` says: a SET/RESET pair
    averages two readings (a DUT without SET/RESET reads plainly either way)."""
    if not getattr(dut.options, "set_reset", False):
        return 1.0
    plan_pair = plan.set_reset == "pair"
    return 1.0 if plan_pair == read_as_pair else (1 / math.sqrt(2.0) if plan_pair else math.sqrt(2.0))


def _stated(plan: Plan, station: Station, thermal) -> dict[str, list[DutInput]]:
    """Each DUT's candidates after a session's: the plan's `assumed:`, the thermal commissioning, the
    station's `expect:`, in that order."""
    temps = plan.temperatures
    assumed = temps.assumed if isinstance(temps, DesignedTemperatures) else {}
    out: dict[str, list[DutInput]] = {}
    for d in station.duts:
        found = []
        if d.name in assumed:
            a = assumed[d.name]
            found.append(DutInput(d.name, a.noise_nt, a.lag_s, a.offset_c, "the plan's assumed values"))
        if thermal is not None and d.name in thermal.duts:
            m = thermal.duts[d.name]
            noise = max(m.noise_nt) * _pair_factor(plan, d, thermal.set_reset == "pair")
            found.append(DutInput(d.name, noise, m.lag_s, m.offset_c, "thermal commissioning"))
        if d.expect is not None:
            noise = d.expect.noise_nt * _pair_factor(plan, d, False)
            found.append(DutInput(d.name, noise, d.expect.thermal_lag_s, None,
                                  "stated in the station (duts[].expect), not measured"))
        out[d.name] = found
    return out


def _merge(name: str, candidates: list[DutInput]) -> DutInput:
    """Noise and lag each from the first candidate that has it; the offset with the lag."""
    noise = next((c for c in candidates if c.noise_nt is not None), None)
    lag = next((c for c in candidates if c.lag_s is not None), None)
    if noise is None and lag is None:
        return DutInput(name, None, None, None, "nothing measured or stated")
    origin = (noise or lag).origin if noise is lag or lag is None or noise is None else \
        f"noise: {noise.origin}; lag: {lag.origin}"
    return DutInput(name, None if noise is None else noise.noise_nt, None if lag is None else lag.lag_s,
                    None if lag is None else lag.offset_c, origin)


def planning_inputs(plan: Plan, station: Station, session: Path | None = None) -> PlanningInputs:
    thermal = thermal_of(station)
    measured = None
    if session is not None:
        from rig.planning.measured import measure_session

        measured = measure_session(session, [d.name for d in station.duts])
    stated = _stated(plan, station, thermal)
    duts = {}
    for d in station.duts:
        first = [measured.duts[d.name]] if measured is not None and d.name in measured.duts else []
        duts[d.name] = _merge(d.name, first + stated[d.name])
    limit = station.chamber.limits.max_ramp_c_per_min
    chamber = measured.chamber if measured is not None else None
    if (chamber is None or chamber.rate_c_per_min is None) and thermal is not None:
        start = chamber.start_c if chamber is not None else thermal.start_air_c
        chamber = ChamberInput(thermal.rate_c_per_min, thermal.overshoot_c, start, "thermal commissioning")
    if chamber is None:
        chamber = ChamberInput(None, None, ASSUMED_START_C, f"a room's {ASSUMED_START_C:g} degC, not "
                               "measured")
    stated_rate = chamber.rate_c_per_min is None
    rate = limit if stated_rate else min(limit, chamber.rate_c_per_min)
    timing = measured.timing if measured is not None else None
    timing = timing or timing_of(plan, station)
    notes = [] if measured is None else measured.notes
    return PlanningInputs(duts, chamber, timing, rate, stated_rate, notes)


def timing_of(plan: Plan, station: Station) -> Timing:
    """The pace of a point without a session: the thermal commissioning's, a designed plan's `timing:`,
    else the drivers' stated conversion times."""
    thermal = thermal_of(station)
    if thermal is not None:
        return Timing(thermal.sample_s, thermal.move_s + 3 * thermal.chamber_read_s, "thermal commissioning")
    temps = plan.temperatures
    if isinstance(temps, DesignedTemperatures) and temps.timing is not None:
        return Timing(temps.timing.sample_s, temps.timing.point_overhead_s, "the plan's timing, measured by "
                      f"{temps.timing.measured_by}")
    return Timing(stated_sample_time_s(plan, station), 0.0,
                  "the drivers' stated conversion times, not measured: `rig commission --thermal` or "
                  "`rig design --from SESSION` measures it")


def require_duts(inputs: PlanningInputs, station: Station) -> None:
    """ConfigError (blamed on the station's first such DUT) when a DUT's noise or lag is not known."""
    missing = inputs.missing()
    if not missing:
        return
    index = next(i for i, d in enumerate(station.duts) if d.name == missing[0])
    what = f"no measured or stated noise and thermal lag for {_names(missing)}: {THREE_WAYS}"
    raise blamed(ConfigError(f"station {station.name}: {what}"), ("duts", index), what, document="station")


def dut_models(inputs: PlanningInputs):
    """calib.design.planner.DutModel of every DUT (require_duts first)."""
    from calib.design.planner import DutModel

    return [DutModel(d.name, max(d.noise_nt, 1e-3), d.lag_s, d.offset_c or 0.0) for d in inputs.duts.values()]


def with_lags(inputs: PlanningInputs, lags: dict[str, DutInput]) -> PlanningInputs:
    """The inputs with some DUTs replaced (a sequential run's re-estimates)."""
    return replace(inputs, duts={**inputs.duts, **lags})


def thermal_lines(thermal) -> list[str]:
    """What `rig commission --thermal` measured, for its summary."""
    lines = [f"thermal: the air moved at {thermal.rate_c_per_min:.3g} degC/min when told "
             f"{thermal.commanded_rate_c_per_min:g}, overshoot {thermal.overshoot_c:.2g} degC; the step took "
             f"{format_duration(thermal.duration_s)}",
             f"pace: {thermal.sample_s:.3g} s a sample of every DUT, {thermal.move_s:.3g} s a move and its "
             f"settling, {thermal.chamber_read_s:.3g} s a chamber reading"]
    lines += [f"  {name}: lag {d.lag_s:.0f} +- {d.lag_se_s:.0f} s, settles {d.offset_c:+.2f} degC from the "
              f"air, noise {max(d.noise_nt):.3g} nT" for name, d in thermal.duts.items()]
    return lines
