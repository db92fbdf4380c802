"""How long a plan takes, and how large a plan `rig check` accepts: a sweep of the field set at the measured
pace (`timing`: rig/planning/inputs.py `timing_of`), the wait for stability after a ramp, a duration as
text."""

from __future__ import annotations

import math

from rig.config import Plan, Stability, Station

MAX_TEMPERATURES = 1_000
MAX_FIELDS = 10_000
MAX_POINTS = 100_000
MAX_SAMPLES_PER_DUT = 1_000_000  # the full campaign takes 19 200
MAX_DURATION_S = 8 * 7 * 86_400.0  # eight weeks

MAX_SWEEP_SPAN_FRACTION = 0.1  # one sweep may span at most this fraction of a ramp's range


def field_targets(plan: Plan, station: Station) -> list[tuple[float, ...]]:
    """The field source's targets for the plan's field set, in plan order."""
    return station.field_source.targets(plan.fields, plan.name, station.name)


def sweep_time_s(plan: Plan, station: Station, targets: list[tuple[float, ...]], timing) -> dict[str, float]:
    """One sweep of the field set at `timing`'s pace (rig/planning/inputs.py Timing): moves (back to the
    first target included) and each point's own time, settling, and sampling."""
    moves = station.field_source.move_time_s([*targets, targets[0]])
    return {"moves+settle": moves + (plan.settle_s + timing.point_overhead_s) * len(targets),
            "sampling": timing.sample_s * plan.samples_per_point * len(targets)}


def stable_after_ramp_s(delta_c: float, ramp_c_per_min: float, lag_s: float | None, st: Stability,
                        overshoot_c: float = 0.0) -> float:
    """A first-order mount lags a ramp by rate*lag (and the air overshoots by overshoot_c); after the ramp
    that error decays with the lag. Without a known lag only the dwell is counted."""
    if lag_s is None:
        return st.dwell_s
    lag_error_c = max(min(abs(delta_c), ramp_c_per_min / 60.0 * lag_s), overshoot_c)
    decay = lag_s * math.log(lag_error_c / st.band_c) if lag_error_c > st.band_c else 0.0
    return decay + st.dwell_s


def format_duration(seconds: float) -> str:
    seconds = int(round(seconds))
    h, rem = divmod(seconds, 3600)
    m, s = divmod(rem, 60)
    return f"{h}h{m:02d}m" if h else (f"{m}m{s:02d}s" if m else f"{s}s")


