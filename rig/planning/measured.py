"""What an earlier session measured of its station: the numbers `rig design --from SESSION` plans with.

    measured = measure_session(path, dut_names)
    measured.duts[name]     DutInput: noise, lag, offset (None when the session does not show them)
    measured.chamber        ChamberInput: the air's pace and overshoot, where it started (or None)
    measured.timing         Timing: one sample of every DUT, a point's own time (or None)

- each DUT's noise: the largest residual sigma of its T24 fit (lag-corrected where the temperature
  moved, rig/analysis/lagfit.py), per fitted sample and axis, as that session read it;
- its lag behind the air and where it settles relative to it: its recorded temperature (its samples and
  the session's temperature log, which follows it between points too) against the air the session logged
  (calib/thermal/response.py `first_order_fit`), else the settling in its longest hold at one nominal
  temperature (calib/thermal/lag.py `settling_lag_s`, offset unknown);
- the chamber: the air's pace and overshoot after each set-point change the session logged
  (calib/thermal/response.py `air_motion`), the air at its start;
- the pace: the median time between two samples of a point (every DUT read once), and the median time a
  point takes beyond its samples and its `settle_s` (moving and settling the field source, reading the
  chamber), from the points' times.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from rig.core.errors import ERRORS, DataError
from rig.planning.facts import ChamberInput, DutInput, Timing

DESIGN_HORIZON_S = 7 * 86_400.0  # a lag beyond this is no lag a campaign could plan with


@dataclass
class SessionMeasure:
    name: str
    duts: dict[str, DutInput]
    chamber: ChamberInput | None
    timing: Timing | None
    notes: list[str] = field(default_factory=list)


def measure_session(session: Path, dut_names: list[str]) -> SessionMeasure:
    from rig.session.reader import SessionReader

    with SessionReader(session) as reader:
        info = reader.info()
        temperatures = reader.temperatures()
        points = [p for p in reader.points() if p["state"] == "done"]
        datasets = {}
        for name in dut_names:
            try:
                datasets[name] = reader.dataset(name)
            except DataError as exc:
                raise DataError(f"--from {session}: {exc}") from None
    where = f"session {Path(session).name}"
    duts, notes = {}, []
    air = _air_log(temperatures)
    moving = _moving(info["plan_text"])
    for name, ds in datasets.items():
        try:
            duts[name], note = _dut(name, ds, air, _temps_of(name, ds, temperatures), moving, where)
        except ERRORS as exc:
            raise DataError(f"--from {session}: {name}: {exc}") from None
        if note:
            notes.append(note)
    return SessionMeasure(Path(session).name, duts, _chamber(temperatures, where),
                          _timing(points, datasets, info["plan_text"], where), notes)


def _air_log(rows: list[dict]) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(t, set point, air) of the session's temperature log, in time order (None when it has none)."""
    rows = [r for r in rows if r["air_c"] is not None and r["t"] is not None]
    if len(rows) < 2:
        return None
    t = np.array([r["t"] for r in rows], float)
    order = np.argsort(t, kind="stable")
    setpoint = np.array([r["setpoint_c"] if r["setpoint_c"] is not None else np.nan for r in rows], float)
    return t[order], setpoint[order], np.array([r["air_c"] for r in rows], float)[order]


def _temps_of(name: str, ds, rows: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    """The DUT's recorded temperature in time order: its samples and the temperature log's rows."""
    logged = [(r["t"], r["duts"][name]) for r in rows if r["duts"].get(name) is not None]
    t = np.concatenate([ds.columns["t"], [x for x, _ in logged]])
    temp = np.concatenate([ds.temp_c, [y for _, y in logged]])
    order = np.argsort(t, kind="stable")
    return t[order], temp[order]


def _moving(plan_text: str) -> bool:
    temps = (yaml.safe_load(plan_text) or {}).get("temperatures") or {}
    return isinstance(temps, dict) and temps.get("mode") in ("ramp", "designed", "sequential")


def _dut(name, ds, air, temps, moving: bool, where: str) -> tuple[DutInput, str | None]:
    import calib
    from calib.thermal.response import first_order_fit

    note = None
    if moving:
        from rig.analysis.lagfit import lag_corrected

        fitted_ds, lag_info = lag_corrected(ds)
        if lag_info.get("tau_s") is not None:
            note = (f"{name}: recorded temperature lags the element by {lag_info['tau_s']:.0f} "
                    f"+- {lag_info['tau_se_s']:.0f} s (calib/thermal/lag.py); corrected by the fit")
    else:
        fitted_ds = ds
    sigma = max(calib.fit(fitted_ds, "t24").stats["sigma_nt"].values())
    lag = offset = None
    how = "no lag shown"
    if air is not None:
        fit = first_order_fit(air[0], air[2], *temps)
        if fit.identifiable:
            lag, offset, how = fit.tau_s, fit.offset_c, "lag and offset from its temperature against the air"
    if lag is None:
        lag = _hold_lag(ds)
        if lag is not None:
            how = "lag from its holds at one temperature"
    return DutInput(name, sigma, lag, offset, f"{where}: noise from the fit residual, {how}"), note


def _hold_lag(ds) -> float | None:
    """Settling time constant in the session's longest hold: a run of two or more sweeps at one nominal
    air temperature (a ramp's end hold, a designed leg's end), the longest showing the most decay."""
    from calib.thermal.lag import settling_lag_s

    t, setpoint = ds.columns["t"], ds.columns["setpoint_c"]
    order = np.argsort(t, kind="stable")
    t, temp, setpoint, sweep = t[order], ds.temp_c[order], setpoint[order], ds.group[order]
    starts = np.flatnonzero(np.concatenate([[True], np.diff(setpoint) != 0, [True]]))
    holds = [(t[b - 1] - t[a], a, b) for a, b in zip(starts[:-1], starts[1:], strict=True)
             if len(set(sweep[a:b])) >= 2]
    for _, a, b in sorted(holds, reverse=True):
        lag = settling_lag_s(t[a:b], temp[a:b], float(setpoint[a]))
        if lag is not None and lag < 0.5 * DESIGN_HORIZON_S:
            return lag
    return None


def _chamber(rows: list[dict], where: str) -> ChamberInput | None:
    from calib.thermal.response import air_motion

    log = _air_log(rows)
    if log is None:
        return None
    t, setpoint, air = log
    known = np.isfinite(setpoint)
    motion = air_motion(t[known], setpoint[known], air[known]) if known.sum() >= 2 else None
    if motion is None or motion.rate_c_per_min is None:
        return ChamberInput(None, None, float(air[0]), f"{where}: the air at its start (no set-point change "
                            "shows the chamber's pace)")
    return ChamberInput(motion.rate_c_per_min, motion.overshoot_c, float(air[0]),
                        f"{where}: the air's pace {motion.message}, the air at its start")


def _timing(points: list[dict], datasets: dict, plan_text: str, where: str) -> Timing | None:
    """The pace of the session's points (see the module docstring)."""
    if len(points) < 3 or not datasets:
        return None
    ds = next(iter(datasets.values()))
    t, point = ds.columns["t"], ds.columns["point"]
    per_sample = []
    counts = {}
    for pid in dict.fromkeys(point):
        times = np.sort(t[point == pid])
        counts[pid] = len(times)
        if len(times) >= 2:
            per_sample.append((times[-1] - times[0]) / (len(times) - 1))
    if not per_sample:
        return None
    sample_s = float(np.median(per_sample))
    settle_s = float((yaml.safe_load(plan_text) or {}).get("settle_s", 1.0))
    gaps, collects = [], []
    for before, after in zip(points, points[1:], strict=False):
        if None in (before["finished"], after["started"]) or before["temp_index"] != after["temp_index"]:
            continue
        gaps.append(after["started"] - before["finished"])
    for p in points:
        if p["started"] is not None and p["finished"] is not None and p["id"] in counts:
            collects.append(p["finished"] - p["started"] - counts[p["id"]] * sample_s)
    if not gaps or not collects:
        return None
    overhead = max(0.0, float(np.median(gaps)) - settle_s) + max(0.0, float(np.median(collects)))
    if not (math.isfinite(sample_s) and math.isfinite(overhead)):
        return None
    return Timing(sample_s, overhead, f"{where}: {len(points)} points' times")
