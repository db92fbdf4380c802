"""The reference chain's part of `rig check`: the commissioning the field source rests on (its age and
residual), then what the field source's own kind says of its chain (coils: the declared matrix's assumed
uncertainty, and the coil field's non-uniformity over the DUT positions, refused where it exceeds the
plan's `accuracy_ppm`)."""

from __future__ import annotations


def reference_lines(plan, station, warnings: list[str]) -> list[str]:
    """Lines for `rig check`; LimitError where the plan's accuracy target cannot be met."""
    source = station.field_source
    commissioned = source.commissioned
    lines = [] if commissioned is None else [commissioned.summary(source.max_age_days)]
    return lines + source.reference_check_lines(station, plan, warnings)
