"""A small valid plan for the sim station, and variants of it with one piece of text replaced."""

from __future__ import annotations

PLAN = """\
name: p
temperatures:
  steps: [0, 25]
  ramp_c_per_min: 3
fields: {kind: cube24, magnitude_nt: 50000}
samples_per_point: 2
settle_s: 0.5
"""


def plan_with(old: str, new: str) -> str:
    """PLAN with `old` replaced by `new` (`old` must be in it, so a changed PLAN cannot go unnoticed)."""
    assert old in PLAN
    return PLAN.replace(old, new)
