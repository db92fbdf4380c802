"""T24 or T36 for one DUT, decided on the session's own data when T24's linearity in temperature fails.

    record_temperature_model(cal24, ds)   # cal24.stats["temperature_model"] when its check failed
    wants_t36(cal24)                      # whether the post-run fits add a T36 calibration
    share_choice(cal24, cal36)            # the same record in the T36 calibration's stats

A T24 calibration whose linearity-in-temperature check (calib/checks/model_checks.py) fails on data that can
show a curve (the check ran: three or more temperatures) gets calib/models/tempmodel.py's choice: both models
fitted to held-out blocks of the same rows, T36 chosen only when it validates better beyond the fold noise.
The record holds the two held-out errors, which one won and why. rig/analysis/judged.py follows it: where the
plan judges T24 and T36 won, the DUT's judged calibration is its T36.
"""

from __future__ import annotations

from calib.checks.model_checks import TEMPERATURE
from rig.core.errors import ERRORS

CHOICE_KEY = "temperature_model"


def temperature_check(stats: dict) -> dict | None:
    """The recorded linearity-in-temperature check of a calibration's stats (None: not recorded)."""
    return next((c for c in stats.get("model_checks") or [] if isinstance(c, dict) and c.get("name") ==
                 TEMPERATURE), None)


def record_temperature_model(cal, ds) -> None:
    """For a T24 calibration whose linearity in temperature fails: the choice between T24 and T36
    (calib/models/tempmodel.py) in its stats; a choice that cannot be made is recorded as T24, with why."""
    from calib.models.tempmodel import choose_temperature_model

    check = temperature_check(cal.stats)
    if check is None or check.get("verdict") != "fails":
        return
    why = (f"T24's linearity in temperature fails (statistic {check['statistic']:.4g}, p "
           f"{check['p']:.2g}): T36 fitted too and both validated on held-out blocks of this session's data")
    try:
        choice = choose_temperature_model(ds).as_dict()
    except (*ERRORS, ValueError, ArithmeticError) as exc:
        choice = {"model": "t24", "heldout_rms_nt": {}, "message": f"t24: no choice could be made ({exc})"}
    cal.stats[CHOICE_KEY] = {**choice, "why": why}


def wants_t36(cal) -> bool:
    """Whether a T24 calibration asks for a T36 beside it (its linearity in temperature failed)."""
    return cal is not None and isinstance(cal.stats.get(CHOICE_KEY), dict)


def share_choice(t24_cal, t36_cal) -> None:
    """The T24 calibration's choice, recorded in the T36's stats as well."""
    t36_cal.stats[CHOICE_KEY] = dict(t24_cal.stats[CHOICE_KEY])
