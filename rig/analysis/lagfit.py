"""The lag-corrected fit of a continuous ramp: each sample's temperature moved to its DUT element's.

A ramp shows each DUT's thermal lag (calib/thermal/lag.py estimates it from the up and down legs); the fit
then uses the element's temperature instead of the probe's. Used by the post-run fits
(rig/analysis/postrun.py) and
`rig refit` of a ramp session.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from rig.core.errors import ERRORS


def lag_corrected(ds) -> tuple[Any, dict]:
    """The dataset in time order with its temperature column moved to the element's (calib/thermal/lag.py),
    and what was estimated (JSON-ready, for the calibration's stats)."""
    ds, info, element_c = _estimated(ds)
    info["applied"] = element_c is not None
    if element_c is not None:
        ds = dataclasses.replace(ds, temp_c=element_c)
    return ds, info


def lag_estimated(ds) -> dict:
    """The element's lag behind the recorded temperature, without moving the temperatures: for data taken
    with the DUTs stable, where the lag is only judged (a plan's acceptance.max_lag_s)."""
    _, info, _ = _estimated(ds, "element_lags")
    info["applied"] = False
    return info


def _estimated(ds, direction: str = "auto") -> tuple[Any, dict, np.ndarray | None]:
    """(the dataset in time order, the estimate as JSON-ready data, the element's temperatures where the
    lag is identifiable, else None); `direction` as calib.thermal.lag.estimate_lag's."""
    from calib.thermal.lag import estimate_lag

    if ds.columns.get("t") is None or ds.temp_c is None or ds.ref_nt is None:
        return ds, {"identifiable": False, "message": "thermal lag not estimated: no times, temperatures "
                    "or reference vectors", "warnings": []}, None
    ds = ds.subset(np.argsort(ds.columns["t"], kind="stable"))
    try:
        res = estimate_lag(ds.columns["t"], ds.h_nt, ds.temp_c, ds.ref_nt, direction=direction)
    except ERRORS as exc:
        return ds, {"identifiable": False, "message": f"thermal lag not estimated: {exc}",
                    "warnings": []}, None
    info = {"identifiable": res.identifiable, "direction": res.direction, "tau_s": _num(res.tau_s),
            "tau_se_s": _num(res.tau_se_s), "updown_before_nt": _num(res.updown_before_nt),
            "updown_after_nt": _num(res.updown_after_nt), "message": res.message,
            "warnings": list(res.warnings)}
    return ds, info, res.temp_element_c if res.identifiable else None


def annotate(cal, info: dict) -> None:
    """Record the lag estimate in the calibration's stats; its warnings join the fit's."""
    cal.stats["thermal_lag"] = {k: v for k, v in info.items() if k != "warnings"}
    if info["warnings"]:
        cal.stats["warnings"] = [*cal.stats.get("warnings", []), *info["warnings"]]


def session_is_ramp(path: str | Path) -> bool:
    """Whether a session file recorded a plan that samples while the temperature moves (a continuous ramp,
    a designed or sequential schedule): its lag is then estimated and applied."""
    from rig.config import Plan
    from rig.core.yamlload import load_model
    from rig.session.reader import SessionReader
    from rig.session.schema import looks_like_session

    if not looks_like_session(Path(path)):
        return False
    with SessionReader(path) as reader:
        text = reader.info()["plan_text"]
    try:
        return load_model(Plan, f"{path} (recorded plan)", text).moving
    except ERRORS:
        return False


def _num(value) -> float | None:
    return None if value is None else float(value)
