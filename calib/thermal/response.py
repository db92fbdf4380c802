"""How a chamber's air and each DUT's temperature really move: the numbers a plan is made with, measured.

    fit = first_order_fit(t_air, air_c, t_dut, dut_c)      # the DUT behind the air: lag, offset, start
    motion = air_motion(t_s, setpoint_c, air_c)            # the air after set-point changes: rate, overshoot

## A DUT behind the air

A DUT's temperature T follows its place in the chamber, the air A plus a constant offset c (its place is
warmer or colder than the air the controller sees, hardware-notes §9.5), with one first-order lag tau:

    dT/dt = (A + c - T) / tau,   T(t0) = s

For A linear between its rows the response is exact (calib/thermal/lag.py `lag_filter`): with F the filtered
air started at A(t0) and e = exp(-(t - t0)/tau),

    T = F + c (1 - e) + (s - A(t0)) e

linear in (c, s) for a given tau. tau minimises the residual sum of squares (a grid on log tau, then a
golden-section search), c and s by least squares at each tau; its standard error comes from the profile's
curvature (var = 2 sigma^2 / RSS''). The lag is identifiable only when the air moved during the rows and
the rows cover enough of the response; otherwise `identifiable` is False and says why. The recorded
temperature (a probe beside the DUT, or its own sensor) may itself lag the element: the fit gives the
chain's lag as one first-order lag, the planner's model (calib/design/planner.py).

## The air

After a set-point change of at least MIN_STEP_C the air's rate is the least-squares slope over the middle
of its way (from 20 % to 80 % of the change, where a real chamber runs at its full pace), and its
overshoot the furthest it goes beyond the set point afterwards (0 when it never passes it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calib.errors import DataError
from calib.thermal.lag import _golden, lag_filter

GRID_POINTS = 32
LOG_TOL = 1e-4
MIN_ROWS = 8
MIN_AIR_SPAN_C = 1.0  # the air must move this much during the rows for a lag to show
MAX_RELATIVE_SE = 0.5  # a lag known worse than this is not identified
MIN_STEP_C = 2.0  # smaller set-point changes say little about the chamber's pace
RAMP_FRACTION = (0.2, 0.8)  # the part of a change whose slope is the chamber's pace


@dataclass(frozen=True)
class FirstOrderFit:
    """A DUT's temperature behind the air: its lag (s), where it settles relative to the air (degC), where
    it started, the residual RMS; tau_s is None when not identifiable (`message` says why)."""

    identifiable: bool
    tau_s: float | None
    tau_se_s: float | None
    offset_c: float | None
    start_c: float | None
    rms_c: float | None
    message: str


def _response_basis(t_air, air, t_dut, tau_s):
    """(F at the DUT's times, e at the DUT's times) for lag tau_s (see the module docstring)."""
    filtered = lag_filter(t_air, air, tau_s, np.zeros(len(t_air), int))
    f = np.interp(t_dut, t_air, filtered)
    e = np.exp(-(t_dut - t_air[0]) / tau_s)
    return f, e


def _solve(t_air, air, t_dut, dut, tau_s) -> tuple[float, float, float]:
    """(RSS, offset, start) at lag tau_s."""
    f, e = _response_basis(t_air, air, t_dut, tau_s)
    x = np.column_stack([1.0 - e, e])
    y = dut - f + air[0] * e
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    r = y - x @ coef
    return float(r @ r), float(coef[0]), float(coef[1])


def first_order_fit(t_air_s, air_c, t_dut_s, dut_c, *, tau_max_s: float | None = None) -> FirstOrderFit:
    """The first-order lag and offset of a DUT's temperature (dut_c at t_dut_s) behind the air (air_c at
    t_air_s); both series sorted by time. Rows of the DUT outside the air's times are left out."""
    t_air, air = _series(t_air_s, air_c, "air")
    t_dut, dut = _series(t_dut_s, dut_c, "DUT temperature")
    keep = (t_dut >= t_air[0]) & (t_dut <= t_air[-1])
    t_dut, dut = t_dut[keep], dut[keep]
    span_s = float(t_air[-1] - t_air[0])
    air_span = float(np.ptp(air))
    if len(t_dut) < MIN_ROWS or air_span < MIN_AIR_SPAN_C:
        return FirstOrderFit(False, None, None, None, None, None,
                             f"lag not identifiable: {len(t_dut)} temperature rows while the air moved "
                             f"{air_span:.2g} degC (need {MIN_ROWS} rows and {MIN_AIR_SPAN_C:g} degC)")
    dt = float(np.median(np.diff(t_dut))) if len(t_dut) > 1 else 1.0
    lo, hi = max(dt / 10.0, 1.0), tau_max_s or max(2.0 * span_s, 10.0)
    grid = np.geomspace(lo, hi, GRID_POINTS)
    rss = np.array([_solve(t_air, air, t_dut, dut, tau)[0] for tau in grid])
    i = int(np.argmin(rss))
    a, b = np.log(grid[max(i - 1, 0)]), np.log(grid[min(i + 1, GRID_POINTS - 1)])
    tau = math.exp(_golden(lambda u: _solve(t_air, air, t_dut, dut, math.exp(u))[0], a, b, tol=LOG_TOL))
    rss_min, offset, start = _solve(t_air, air, t_dut, dut, tau)
    n_dof = max(len(t_dut) - 3, 1)
    sigma2 = rss_min / n_dof
    step = 0.02 * tau
    curvature = (_solve(t_air, air, t_dut, dut, tau + step)[0] - 2 * rss_min
                 + _solve(t_air, air, t_dut, dut, tau - step)[0]) / step**2
    se = math.sqrt(2 * sigma2 / curvature) if curvature > 0 else math.inf
    rms = math.sqrt(rss_min / len(t_dut))
    if i in (0, GRID_POINTS - 1) or not se <= MAX_RELATIVE_SE * tau:
        edge = " (at the edge of the search)" if i in (0, GRID_POINTS - 1) else ""
        return FirstOrderFit(False, None, None, offset, start, rms,
                             f"lag not identifiable: {tau:.3g} +- {se:.2g} s{edge}; the rows do not show "
                             "enough of the response to the air")
    return FirstOrderFit(True, tau, se, offset, start, rms,
                         f"lag {tau:.0f} +- {se:.0f} s, settles {offset:+.2f} degC from the air")


@dataclass(frozen=True)
class AirMotion:
    """The air's fastest measured pace (degC/min) and its overshoot after that change (degC); None when
    no set-point change of at least MIN_STEP_C shows them."""

    rate_c_per_min: float | None
    overshoot_c: float | None
    changes: int
    message: str


def air_motion(t_s, setpoint_c, air_c) -> AirMotion:
    """The air's pace and overshoot after each change of the set point (rows sorted by time); the fastest
    change is reported, with its overshoot."""
    t, air = _series(t_s, air_c, "air")
    setpoint = np.asarray(setpoint_c, float).ravel()
    if setpoint.size != t.size:
        raise DataError(f"air motion: {t.size} times but {setpoint.size} set points")
    starts = np.flatnonzero(np.concatenate([[True], np.diff(setpoint) != 0]))
    ends = np.concatenate([starts[1:], [len(t)]])
    best: tuple[float, float] | None = None
    changes = 0
    for a, b in zip(starts, ends, strict=True):
        target, start = setpoint[a], air[a]
        delta = target - start
        if abs(delta) < MIN_STEP_C or b - a < 4:
            continue
        way = (air[a:b] - start) / delta
        mid = (way >= RAMP_FRACTION[0]) & (way <= RAMP_FRACTION[1])
        if mid.sum() < 3:
            continue
        changes += 1
        rate = abs(float(np.polyfit(t[a:b][mid], air[a:b][mid], 1)[0])) * 60.0
        beyond = float(np.max((air[a:b] - target) * math.copysign(1.0, delta)))
        if best is None or rate > best[0]:
            best = (rate, max(beyond, 0.0))
    if best is None:
        return AirMotion(None, None, 0, f"no set-point change of {MIN_STEP_C:g} degC or more shows the air's "
                         "pace")
    return AirMotion(best[0], best[1], changes, f"{best[0]:.3g} degC/min, overshoot {best[1]:.2g} degC "
                     f"(the fastest of {changes} set-point change(s))")


def _series(t_s, values, what: str) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(t_s, float).ravel()
    v = np.asarray(values, float).ravel()
    if t.size != v.size:
        raise DataError(f"{what}: {t.size} times but {v.size} values")
    if t.size < 2:
        raise DataError(f"{what}: {t.size} rows; a time series is needed")
    if np.any(np.diff(t) < 0):
        raise DataError(f"{what}: time goes backwards; sort the rows by time")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v))):
        raise DataError(f"{what}: a time or a value is not finite")
    return t, v
