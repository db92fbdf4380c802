"""Stop when good enough: are the T24 standard errors of the sums so far below their targets?

    status = check_targets(acc, {"S": 1e-4, "K": 1e-6, "kb": 0.5, "b": 5})
    status.met, status.worst, status.worst_ratio     # e.g. False, "K", 3.2

Targets are per parameter group, in the units of the calibration file: S dimensionless, K per degC,
b in nT, kb in nT/degC (group names "S", "K", "b", "kb", or the file's keys "b_nt", "kb_nt_per_c").
The standard errors are those the fit reports (sigma^2 G^-1, absolute-tau convention, so b is the offset
at 0 degC); a group's ratio is its largest standard error over the target. One call costs one 8x8 solve
of the accumulated sums, whatever the number of samples, so it can run after every point.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from calib.errors import DataError, FitError
from calib.models.gram import GramAccumulator

GROUP_KEYS = {  # group name -> key of the calibration file; the file's keys are accepted as they are
    "S": "S", "K": "K", "b": "b_nt", "kb": "kb_nt_per_c", "b_nt": "b_nt", "kb_nt_per_c": "kb_nt_per_c",
}
MIN_SAMPLES = 50  # below this the noise estimate behind every standard error is itself too uncertain


@dataclass(frozen=True)
class TargetStatus:
    met: bool
    worst: str  # the group furthest from its target (largest ratio)
    worst_ratio: float  # its standard error / target; inf when the fit cannot be made yet
    ratios: dict[str, float]
    message: str


def check_targets(
    acc: GramAccumulator, targets: Mapping[str, float], *, min_samples: int = MIN_SAMPLES
) -> TargetStatus:
    """Whether every group's largest T24 standard error is at or below its target, and which is worst."""
    keys = _checked(targets)
    try:
        cal = acc.solve()
    except FitError as err:
        ratios = dict.fromkeys(targets, math.inf)
        first = next(iter(targets))
        return TargetStatus(False, first, math.inf, ratios, f"targets not met: no fit yet: {err}")
    ratios = {
        group: float(np.max(cal.std_errors[key])) / float(targets[group])
        for group, key in zip(targets, keys, strict=True)
    }
    worst = max(ratios, key=ratios.__getitem__)
    enough = acc.n >= min_samples
    met = enough and ratios[worst] <= 1.0
    if met:
        message = f"all targets met ({worst} closest: {ratios[worst]:.2f} of its target)"
    elif not enough:
        message = f"targets not met: {acc.n} samples, at least {min_samples} before trusting the errors"
    else:
        message = f"targets not met: {worst} at {ratios[worst]:.2f} x its target"
    return TargetStatus(met, worst, ratios[worst], ratios, message)


def _checked(targets: Mapping[str, float]) -> list[str]:
    if not targets:
        raise DataError("targets: none given (e.g. {'S': 1e-4, 'K': 1e-6, 'kb': 0.5, 'b': 5})")
    keys = []
    for group, target in targets.items():
        if group not in GROUP_KEYS:
            raise DataError(f"targets: unknown parameter group {group!r} (known: S, K, b, kb)")
        try:
            good = math.isfinite(float(target)) and float(target) > 0
        except (TypeError, ValueError):
            good = False
        if not good:
            raise DataError(f"targets: {group} = {target!r}: must be a positive number")
        keys.append(GROUP_KEYS[group])
    return keys
