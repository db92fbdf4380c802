"""During a sequential campaign: the next leg from what has been measured (a receding horizon over
calib/design/planner.py's least-time search). After each sweep `next_leg` says stay, go on to the next leg, or
stop. With the chamber's `end_tolerance_c` an end is never left before every DUT's element is within it
of the end, and the run never stops before every DUT's data has covered both ends (`covered_c`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

from calib.design.planner import (
    CHECK,
    END,
    MAX_SWEEPS,
    ChamberModel,
    DutModel,
    Leg,
    Pace,
    State,
    air_end,
    covered_at,
    crossing,
    hold_until_met,
    range_end_of,
    sweeps_to_reach,
    sweeps_with_hold,
    temp_ref_of,
)


@dataclass(frozen=True)
class Decision:
    """What the next sweep does: `stop`, or a sweep of `leg` (a new leg when `new_leg`)."""

    stop: bool
    leg: Leg | None
    new_leg: bool
    reason: str
    predicted_remaining_s: float | None = None


def both_ends_covered(chamber: ChamberModel, covered_c: Mapping[str, tuple[float, float]] | None) -> bool:
    """Whether every DUT's data (its lowest and highest element temperature so far) reaches within the
    chamber's end tolerance of both ends of the range."""
    if chamber.end_tolerance_c is None or covered_c is None:
        return True
    lo, hi = chamber.range_c
    return all(covered_at(chamber, {n: low}, lo) and covered_at(chamber, {n: high}, hi)
               for n, (low, high) in covered_c.items())


def next_leg(state: State, legs_done: Sequence[Leg], duts: Sequence[DutModel], chamber: ChamberModel,
             pace: Pace, targets: Mapping[str, float], *, max_duration_s: float,
             ratios_now: Mapping[str, float],
             covered_c: Mapping[str, tuple[float, float]] | None = None) -> Decision:
    """After a sweep: stop (every DUT's measured worst ratio `ratios_now` <= 1, the checks done, both ends
    covered), go on with the current leg, or start the next. `legs_done` are the legs so far, the last one
    current, each with the sweeps taken in it; `covered_c` each DUT's lowest and highest element temperature
    so far. Staying k more sweeps at an end before crossing is weighed against crossing now by the
    predicted time to every target (k = 0, 1, 2, 4, ...)."""
    temp_ref = temp_ref_of(chamber)
    current = legs_done[-1]
    done_checks = [leg.to_c for leg in legs_done if leg.kind == CHECK]
    all_checks_done = all(c in done_checks for c in chamber.checks_c)
    worst = max(ratios_now, key=ratios_now.__getitem__)
    if all_checks_done and ratios_now[worst] <= 1.0 and both_ends_covered(chamber, covered_c):
        return Decision(True, None, False, f"every DUT meets its targets (closest: {worst} at "
                        f"{ratios_now[worst]:.2f} of its target)")
    end = range_end_of(chamber, current.to_c)
    if current.kind == END and not covered_at(chamber, state.element_c, end):
        target = air_end(chamber, duts, end)  # the DUTs' measured offsets may ask for other air
        if abs(target - current.to_c) > 0.5 * chamber.end_tolerance_c:
            return Decision(False, Leg(target, 1, current.rate_c_per_min, END, state.air_c), True,
                            f"the air to {target:g} degC, for every DUT to reach {end:g} degC")
        return Decision(False, replace(current, sweeps=1), False,
                        f"holding at {current.to_c:g} degC until every DUT is within "
                        f"{chamber.end_tolerance_c:g} degC of {end:g} degC")
    if current.kind == CHECK:
        start = current.to_c if current.from_c is None else current.from_c
        needed = sweeps_with_hold(start, current.to_c, current.rate_c_per_min, pace.sweep_s,
                                  chamber.check_sweeps)
        if current.sweeps < needed:
            return Decision(False, replace(current, sweeps=1), False, f"model check at {current.to_c:g} degC")
        ends = [leg.to_c for leg in legs_done if leg.kind == END]
        heading = air_end(chamber, duts, _other_end(chamber, ends[-1]))
        rest = crossing(chamber, current.to_c, heading, pace.sweep_s, done_checks)
        nxt = rest[0] if rest else Leg(heading, 1, chamber.rate_c_per_min)
        return Decision(False, replace(nxt, sweeps=1), True, "model check done here; on across the range")
    elapsed = state.t_s
    budget = max(1, min(MAX_SWEEPS, int((max_duration_s - elapsed) // pace.sweep_s)))
    other = air_end(chamber, duts, _other_end(chamber, current.to_c))
    checks = crossing(chamber, current.to_c, other, pace.sweep_s, done_checks)
    reach_now = sweeps_to_reach(state.air_c, current.to_c, current.rate_c_per_min, pace.sweep_s)
    options: list[tuple[float, int]] = []
    for k in _stay_options(budget):
        stay = [replace(current, sweeps=k)] if k else []
        remaining = budget - k - sum(c.sweeps for c in checks)
        if remaining < 1:
            break
        n2, _, _ = hold_until_met(state, [*stay, *checks], Leg(other, 1, current.rate_c_per_min), pace, duts,
                                  targets, temp_ref, budget, chamber=chamber)
        if n2 is not None:
            options.append((k + sum(c.sweeps for c in checks) + n2, k))
    stay_n, _, _ = hold_until_met(state, [], replace(current, sweeps=1), pace, duts, targets, temp_ref,
                                  budget, chamber=chamber)
    if all_checks_done and stay_n is not None and both_ends_covered(chamber, covered_c):
        options.append((stay_n, budget + 1))  # staying until done: never cross
    if not options and not both_ends_covered(chamber, covered_c):  # staying cannot cover the other end
        nxt = checks[0] if checks else Leg(other, 1, current.rate_c_per_min)
        return Decision(False, replace(nxt, sweeps=1), True, f"crossing to {other:g} degC: a DUT's data does "
                        "not reach that end yet")
    if not options:
        return Decision(False, replace(current, sweeps=1), False,
                        f"targets out of reach within the time left ({worst} at {ratios_now[worst]:.2f}); "
                        "staying where the information is")
    total, k = min(options)
    remaining_s = total * pace.sweep_s
    if k > 0 or reach_now > 1:
        return Decision(False, replace(current, sweeps=1), False,
                        f"staying at {current.to_c:g} degC: predicted {remaining_s / 60:.0f} min to every "
                        "target",
                        remaining_s)
    nxt = checks[0] if checks else Leg(other, 1, current.rate_c_per_min)
    return Decision(False, replace(nxt, sweeps=1), True,
                    f"crossing to {other:g} degC now: predicted {remaining_s / 60:.0f} min to every target",
                    remaining_s)


def _other_end(chamber: ChamberModel, end_c: float) -> float:
    """The range end across from the one the air target end_c serves."""
    lo, hi = chamber.range_c
    return hi if range_end_of(chamber, end_c) == lo else lo


def _stay_options(budget: int) -> list[int]:
    """0, 1, 2, 4, 8, ... up to the budget: how many more sweeps to stay before crossing."""
    out, k = [0, 1], 2
    while k < budget:
        out.append(k)
        k *= 2
    return out



def interior_temperatures(range_c: tuple[float, float], checks_c: Sequence[float], count: int) -> list[float]:
    """Up to `count` interior temperatures to add to the model check: the midpoints of the largest gaps
    between the range's ends and the check temperatures so far (every gap as large as the largest, so a
    symmetric set stays symmetric), to a tenth of a degree. [] when count < 1."""
    lo, hi = sorted(range_c)
    at = sorted({lo, hi, *(c for c in checks_c if lo < c < hi)})
    gaps = [(b - a, 0.5 * (a + b)) for a, b in zip(at, at[1:], strict=False)]
    largest = max(g for g, _ in gaps)
    mids = [round(m, 1) for g, m in gaps if g >= largest * (1 - 1e-9)]
    return [m for m in mids if m not in at][:max(count, 0)]
