"""A sequential run's model check on its own data (rig/schedules/sequential_run.py decides with it).

    added = AddedChecks(plan.temperatures.max_added_checks)
    decision, found = decide_with_checks(added, chamber, lambda ch: next_leg(..., ch, ...), datasets)

After every leg (a decision that stops or starts a new leg) T24's linearity in temperature
(calib/checks/model_checks.py) is run on each DUT's data so far, its temperatures at the element. When it
fails for a DUT (significant and larger than half the noise: the check's own verdict), the run does not finish
on data that cannot tell T24 from a curve: it adds interior temperatures (the midpoints of the largest gaps
between the range's ends and the check temperatures so far, calib/design/sequential.py
`interior_temperatures`) as further check legs, up to `temperatures.max_added_checks`, and decides again
with them. The decision records which check failed, for which DUTs, and what was added; the temperatures
added so far are recorded with every later decision, so a resume goes on with them.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace

from calib.checks.model_checks import TEMPERATURE, temperature_linearity
from calib.dataset import Dataset
from calib.design.planner import ChamberModel
from calib.design.sequential import Decision, interior_temperatures


@dataclass
class AddedChecks:
    """The interior temperatures a run added to its model check, and how many it may add."""

    max_added: int
    added_c: list[float] = field(default_factory=list)

    def chamber(self, chamber: ChamberModel) -> ChamberModel:
        """The chamber model with the added temperatures among its checks."""
        return replace(chamber, checks_c=tuple(sorted({*chamber.checks_c, *self.added_c})))

    def after_leg(self, chamber: ChamberModel, data: Mapping[str, Dataset]) -> dict | None:
        """T24's linearity in temperature on each DUT's data so far; when it fails for any: the record (the
        check, the DUTs with statistic and p, the temperatures added now, none once the bound is reached),
        the added temperatures grown by those. None when it fails for none."""
        failed = linearity_failures(data)
        if not failed:
            return None
        room = self.max_added - len(self.added_c)
        new = interior_temperatures(chamber.range_c, self.chamber(chamber).checks_c, room)
        self.added_c.extend(new)
        return {"check": TEMPERATURE, "failed": failed, "added_c": new,
                "bound": f"{len(self.added_c)} of at most {self.max_added} interior temperatures added"}


def linearity_failures(data: Mapping[str, Dataset]) -> dict[str, dict]:
    """{DUT: statistic, dof, p, magnitude} of each DUT whose T24 linearity in temperature fails (a DUT
    whose data cannot run the check is not among them)."""
    out = {}
    for dut, ds in data.items():
        check = temperature_linearity(ds)
        if check.verdict == "fails":
            out[dut] = {"statistic": float(check.statistic), "dof": int(check.dof), "p": float(check.p),
                        "magnitude_nt": float(check.magnitude_nt)}  # plain values: the decision is JSON
    return out


def decide_with_checks(added: AddedChecks, chamber: ChamberModel, decide: Callable[[ChamberModel], Decision],
                       data: Callable[[], Mapping[str, Dataset]]) -> tuple[Decision, dict | None]:
    """`decide(chamber)` (calib/design/sequential.py `next_leg` on the run's state) with the added
    temperatures among the checks; after a leg the model check on `data()`, and when it adds temperatures the
    decision taken again with them (the run then does not stop). Returns (decision, the check's record or
    None)."""
    chamber = added.chamber(chamber)
    decision = decide(chamber)
    if not (decision.stop or decision.new_leg):
        return decision, None
    found = added.after_leg(chamber, data())
    if found is None:
        return decision, None
    duts = ", ".join(f"{d} p {f['p']:.2g}" for d, f in list(found["failed"].items())[:4])
    said = f"T24's {TEMPERATURE} fails ({duts})"
    if found["added_c"]:
        decision = decide(added.chamber(chamber))
        said += f": interior temperatures {', '.join(f'{c:g}' for c in found['added_c'])} degC added"
    else:
        said += f": {found['bound']}, none more"
    return replace(decision, reason=f"{decision.reason} ({said})"), found
