"""Thermal lag between the recorded temperature column and the sensing element, estimated from ramps.

## Model

Notation: `T_m(t)` the recorded temperature (a probe beside the DUT, the chamber air, or the DUT's own die
sensor), `T_e(t)` the temperature of the sensing element, which is the `tau` the T24 model needs, and
`tau_s` one first-order time constant in seconds. Two directions, one parameter each:

    element_lags:  dT_e/dt = (T_m - T_e) / tau_s     the element follows the recorded temperature
    sensor_lags:   dT_m/dt = (T_e - T_m) / tau_s     the recorded sensor follows the element,
                   so T_e = T_m + tau_s dT_m/dt

`element_lags` is the simulator's model (drivers.sim.world: each DUT's temperature follows the chamber
air with `DutTruth.thermal_lag_s`), right when the column is the air or a probe that reacts faster than
the DUT. `sensor_lags` fits a slow probe on a fast die. On a steady ramp of rate r both come to
T_e = T_m -+ r tau_s, with opposite signs, so `direction="auto"` can tell them apart.

`element_lags` integrates exactly for a recorded temperature linear between samples, starting at
equilibrium (T_e = T_m) at the first row and after every gap longer than `max_gap_s` (a dwell is taken as
settled). `sensor_lags` uses a least-squares slope over `slope_window_s`, so noise is not differentiated.

## Estimate

tau_s minimises the residual sum of squares of a T24 fit (calib.models.gram) of the readings against the
reference field with T_e as temperature: a grid on log tau_s (and tau_s = 0), then a golden-section
search on log tau_s. On a ramp, a wrong tau_s shifts T_e by -+ r dtau on the way up and down alike, which
no T24 parameter can absorb. Standard error from the curvature of the profile: -2 log L = RSS / sigma^2,
so var(tau_s) = 2 sigma^2 / RSS''. The lag is identifiable only from rows recorded while the temperature
moves: without enough ramp rows (step-and-dwell data) nothing is estimated and the column is kept as is.
After the correction, T24 fits to the up-ramp and down-ramp rows alone are compared on a common grid of
raw readings and temperatures; a difference above `disagree_nt` is a warning (another lag model, a
gradient across the DUT, hysteresis).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from calib.calibration import Calibration
from calib.errors import DataError, FitError
from calib.models.gram import GramAccumulator

DIRECTIONS = ("element_lags", "sensor_lags")
MIN_RAMP_C_PER_MIN = 0.1  # slower than this a row counts as a dwell
MIN_RAMP_ROWS = 50
MIN_RAMP_SPAN_C = 2.0  # the ramp rows must cover this much temperature
GAP_FACTOR = 20.0  # default max_gap_s: this many median sample intervals
GRID_POINTS = 24
LOG_TOL = 1e-4  # golden-section tolerance on ln tau_s
EXP_SPAN = 600.0  # element_lags sums in blocks spanning at most this many tau_s (exp(600) ~ 1e260)
MAX_STEP_DECAY = 40.0  # dt/tau_s beyond this forgets the past anyway (exp(-40) ~ 4e-18): capped so a
# tiny tau_s still leaves >= 15 rows per block
N_T24_PARAMS = 24
COMPARE_TEMPS = 5


@dataclass
class LagResult:
    """tau_s is None when the lag is not identifiable; temp_element_c is then the input column."""

    identifiable: bool
    direction: str
    tau_s: float | None
    tau_se_s: float | None
    temp_element_c: np.ndarray
    message: str
    updown_before_nt: float | None = None  # largest up/down T24 difference on the common grid
    updown_after_nt: float | None = None
    warnings: list[str] = field(default_factory=list)
    profile: tuple[np.ndarray, np.ndarray] | None = None  # (tau_s grid, RSS) for plots


# --- the two lag models --------------------------------------------------------------------------------
def segments(t_s: np.ndarray, max_gap_s: float) -> np.ndarray:
    """Segment number of every row: a new segment starts after a gap longer than max_gap_s."""
    return np.concatenate([[0], np.cumsum(np.diff(t_s) > max_gap_s)])


def windowed_slope(t_s: np.ndarray, x: np.ndarray, seg: np.ndarray, window_s: float) -> np.ndarray:
    """Least-squares slope dx/dt at every row over the rows within +-window_s/2 of the same segment."""
    slope = np.zeros_like(x, dtype=float)
    for s in np.unique(seg):
        idx = np.flatnonzero(seg == s)
        tt, xx = t_s[idx] - t_s[idx[0]], x[idx]
        lo = np.searchsorted(tt, tt - window_s / 2, side="left")
        hi = np.searchsorted(tt, tt + window_s / 2, side="right")
        cs = [np.concatenate([[0.0], np.cumsum(v)]) for v in (np.ones_like(tt), tt, xx, tt * tt, tt * xx)]
        n, st, sx, stt, stx = (c[hi] - c[lo] for c in cs)
        den = n * stt - st * st
        with np.errstate(invalid="ignore", divide="ignore"):
            slope[idx] = np.where(den > 0, (n * stx - st * sx) / np.where(den > 0, den, 1.0), 0.0)
    return slope


def lag_filter(t_s: np.ndarray, x: np.ndarray, tau_s: float, seg: np.ndarray) -> np.ndarray:
    """T_e for dT_e/dt = (x - T_e)/tau_s, x linear between rows, T_e = x at each segment's first row."""
    if tau_s <= 0:
        return x.astype(float).copy()
    out = np.empty(len(x))
    for s in np.unique(seg):  # segments are runs of consecutive rows
        idx = np.flatnonzero(seg == s)
        out[idx] = x[idx] + _lag_error(t_s[idx], x[idx], tau_s)
    return out


def _lag_error(t: np.ndarray, x: np.ndarray, tau_s: float) -> np.ndarray:
    """e = T_e - x in one segment, e_0 = 0. Exact for x linear between rows: with a = exp(-dt/tau) and
    g = tau/dt (1 - a), e_k = a_k e_(k-1) + c_k, c_k = -g_k (x_k - x_(k-1)); summed in closed form,
    e_k = sum_j c_j exp(-(t_k - t_j)/tau), over blocks short enough for the exponentials to stay finite."""
    dt = np.diff(t)
    g = np.where(dt > 0, -np.expm1(-dt / tau_s) * tau_s / np.where(dt > 0, dt, 1.0), 1.0)
    c = np.concatenate([[0.0], -g * np.diff(x)])
    decay = np.concatenate([[0.0], np.cumsum(np.minimum(dt / tau_s, MAX_STEP_DECAY))])
    e = np.empty_like(c)
    carry, start = 0.0, 0
    while start < len(c):
        stop = int(np.searchsorted(decay, decay[start] + EXP_SPAN, side="right"))
        rel = decay[start:stop] - decay[start]
        before = decay[start - 1] if start else decay[0]
        e[start:stop] = carry * np.exp(-(decay[start:stop] - before)) + np.exp(-rel) * np.cumsum(
            c[start:stop] * np.exp(rel)
        )
        carry, start = e[stop - 1], stop
    return e


def element_temperature(
    t_s, temp_c, tau_s: float, direction: str = "element_lags", *, max_gap_s: float | None = None,
    slope_window_s: float = 120.0,
) -> np.ndarray:
    """The corrected temperature column T_e for a lag tau_s (see the module's model)."""
    t, temp = _checked(t_s, temp_c)
    seg = segments(t, _gap(t, max_gap_s))
    return _element(t, temp, tau_s, direction, seg, windowed_slope(t, temp, seg, slope_window_s))


def _element(t, temp, tau_s, direction, seg, slope) -> np.ndarray:
    if direction == "element_lags":
        return lag_filter(t, temp, tau_s, seg)
    if direction == "sensor_lags":
        return temp + tau_s * slope
    raise DataError(f"lag direction {direction!r}: must be one of {', '.join(DIRECTIONS)} or auto")


# --- estimate ------------------------------------------------------------------------------------------
def estimate_lag(
    t_s, h_nt, temp_c, ref_nt, *, direction: str = "element_lags", tau_max_s: float | None = None,
    max_gap_s: float | None = None, slope_window_s: float = 120.0, disagree_nt: float | None = None,
) -> LagResult:
    """Lag time constant from time-ordered rows (t_s, raw h (N,3) nT, temperature degC, reference (N,3) nT).

    direction: "element_lags", "sensor_lags" or "auto" (both fitted, the smaller residual kept).
    disagree_nt: up/down difference that triggers a warning (default 3 x the fit's noise sigma)."""
    t, temp = _checked(t_s, temp_c)
    h = np.asarray(h_nt, float).reshape(-1, 3)
    ref = np.asarray(ref_nt, float).reshape(-1, 3)
    if h.shape[0] != t.size or ref.shape[0] != t.size:
        raise DataError(f"lag: {t.size} times, {h.shape[0]} readings, {ref.shape[0]} reference rows")
    seg = segments(t, _gap(t, max_gap_s))
    slope = windowed_slope(t, temp, seg, slope_window_s)
    ramp = np.abs(slope) * 60.0 >= MIN_RAMP_C_PER_MIN
    span = float(np.ptp(temp[ramp])) if ramp.any() else 0.0
    if ramp.sum() < MIN_RAMP_ROWS or span < MIN_RAMP_SPAN_C:
        return LagResult(
            False, direction, None, None, temp.copy(),
            f"lag not identifiable: {int(ramp.sum())} rows on a ramp (>= {MIN_RAMP_C_PER_MIN} degC/min) "
            f"covering {span:.1f} degC; need {MIN_RAMP_ROWS} rows over {MIN_RAMP_SPAN_C} degC "
            "(step-and-dwell data carries no lag information); temperature column unchanged",
        )
    if direction == "auto":
        fits = [_fit(t, h, temp, ref, d, seg, slope, tau_max_s) for d in DIRECTIONS]
        best = min(fits, key=lambda f: f[1])
    else:
        best = _fit(t, h, temp, ref, direction, seg, slope, tau_max_s)
    return _judge(best, t, h, temp, ref, seg, slope, disagree_nt)


def _fit(t, h, temp, ref, direction, seg, slope, tau_max_s):
    """(direction, RSS at the minimum, tau_s, RSS function, grid, grid RSS, search limit)."""
    ref_c = round(float(0.5 * (temp.min() + temp.max())), 1)

    def rss(tau: float) -> float:
        acc = GramAccumulator(ref_c)
        acc.add(h, _element(t, temp, tau, direction, seg, slope), ref)
        return float(acc.solve().stats["rms_after_nt"] ** 2 * 3 * acc.n)

    dt = float(np.median(np.diff(t)))
    hi = tau_max_s or min(0.5 * float(t[-1] - t[0]), 6 * 3600.0)
    grid = np.concatenate([[0.0], np.geomspace(max(dt, 1.0), hi, GRID_POINTS)])
    values = np.array([rss(tau) for tau in grid])
    i = int(np.argmin(values))
    if i == 0:
        tau = _golden(rss, 0.0, grid[1], tol=LOG_TOL * grid[1])
    else:
        lo_hi = np.log(grid[max(i - 1, 1)]), np.log(grid[min(i + 1, GRID_POINTS)])
        tau = math.exp(_golden(lambda u: rss(math.exp(u)), *lo_hi, tol=LOG_TOL))
    best = min((rss(tau), tau), (values[i], grid[i]))
    return direction, best[0], best[1], rss, grid, values, hi


def _judge(best, t, h, temp, ref, seg, slope, disagree_nt) -> LagResult:
    direction, rss_min, tau, rss, grid, values, hi = best
    n_dof = 3 * t.size - N_T24_PARAMS
    sigma2 = rss_min / n_dof
    step = max(0.02 * tau, 1e-3 * hi)
    if tau < 2 * step:  # near zero: one-sided second difference
        curvature = (rss(tau + 2 * step) - 2 * rss(tau + step) + rss_min) / step**2
    else:
        curvature = (rss(tau + step) - 2 * rss_min + rss(tau - step)) / step**2
    se = math.sqrt(2 * sigma2 / curvature) if curvature > 0 else math.inf
    profile = (grid, values)
    if se > hi:
        return LagResult(
            False, direction, None, None, temp.copy(),
            f"lag not identifiable: the T24 residual hardly changes with the lag (standard error "
            f"{se:.3g} s over a {hi:.0f} s search range); the DUT's temperature terms are too small to show "
            "it; temperature column unchanged", profile=profile,
        )
    corrected = _element(t, temp, tau, direction, seg, slope)
    limit = disagree_nt if disagree_nt is not None else 3 * math.sqrt(sigma2)
    warnings = []
    if tau >= 0.99 * hi:
        warnings.append(f"lag at the search limit {hi:.0f} s: give a larger tau_max_s or check the data")
    before, note = updown_disagreement_nt(h, temp, ref, slope)
    after, _ = updown_disagreement_nt(h, corrected, ref, slope)
    if note:
        warnings.append(note)
    elif after is not None and after > limit:
        warnings.append(
            f"up and down ramps still disagree by {after:.1f} nT after the lag correction (limit "
            f"{limit:.1f} nT; {before:.1f} nT before): the first-order {direction} model does not explain "
            "all of the hysteresis"
        )
    message = f"thermal lag {tau:.1f} +- {se:.1f} s ({direction})"
    if before is not None and after is not None:
        message += f"; up/down T24 difference {before:.1f} nT before, {after:.1f} nT after"
    return LagResult(
        True, direction, tau, se, corrected, message,
        updown_before_nt=before, updown_after_nt=after, warnings=warnings, profile=profile,
    )


def updown_disagreement_nt(h, temp_c, ref, slope) -> tuple[float | None, str | None]:
    """Largest |B_up - B_down| (nT) of T24 fits to up-ramp and down-ramp rows, over a common grid: the
    26 cube directions at the median raw magnitude, at temperatures across the ranges both ramps cover."""
    rate = slope * 60.0
    masks = rate >= MIN_RAMP_C_PER_MIN, rate <= -MIN_RAMP_C_PER_MIN
    lo = max(temp_c[m].min() for m in masks) if all(m.any() for m in masks) else math.inf
    hi = min(temp_c[m].max() for m in masks) if all(m.any() for m in masks) else -math.inf
    if hi - lo < MIN_RAMP_SPAN_C:
        return None, "up/down ramps not compared: they do not overlap over 2 degC"
    try:
        cals: list[Calibration] = []
        for m in masks:
            acc = GramAccumulator(round(float(0.5 * (lo + hi)), 1))
            acc.add(h[m], temp_c[m], ref[m])
            cals.append(acc.solve())
    except FitError as err:
        return None, f"up/down ramps not compared: {err}"
    dirs = np.array([p for p in itertools.product((-1, 0, 1), repeat=3) if any(p)], float)
    grid_h = dirs / np.linalg.norm(dirs, axis=1, keepdims=True) * np.median(np.linalg.norm(h, axis=1))
    worst = 0.0
    for temp in np.linspace(lo, hi, COMPARE_TEMPS):
        col = np.full(len(grid_h), temp)
        diff = cals[0].apply(grid_h, col) - cals[1].apply(grid_h, col)
        worst = max(worst, float(np.linalg.norm(diff, axis=1).max()))
    return worst, None


# --- the lag behind the air, from a dwell -----------------------------------------------------------------
MIN_SETTLING_OFFSET_C = 0.03  # a few TMP117 steps (7.8 mdegC): closer to the target the log is noise
MIN_SETTLING_ROWS = 10
MIN_SETTLING_DECAY = 2.0  # the offset must fall by this factor over the rows: less is too short to tell


def settling_lag_s(t_s, temp_c, target_c: float) -> float | None:
    """Time constant of a temperature settling on a constant air temperature `target_c` (a dwell or an
    end hold): late in a first-order approach log|T - target| falls as -t/tau, the slowest lag of the
    chain (the element's behind the air, when the probe is faster). Least squares over the rows at least
    MIN_SETTLING_OFFSET_C from the target on the side they approach from; None when the rows show no
    decay (too few, too close, moving away, or falling by less than MIN_SETTLING_DECAY)."""
    t, temp = _checked(t_s, temp_c)
    off = temp - float(target_c)
    side = np.sign(np.median(off))
    keep = side * off >= MIN_SETTLING_OFFSET_C
    if side == 0 or keep.sum() < MIN_SETTLING_ROWS:
        return None
    tk, log_off = t[keep] - t[keep][0], np.log(side * off[keep])
    slope, intercept = np.polyfit(tk, log_off, 1)
    if slope >= 0 or -slope * (tk[-1] - tk[0]) < math.log(MIN_SETTLING_DECAY):
        return None
    return float(-1.0 / slope)


# --- helpers --------------------------------------------------------------------------------------------
def _checked(t_s, temp_c) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(t_s, float).ravel()
    temp = np.asarray(temp_c, float).ravel()
    if t.size != temp.size:
        raise DataError(f"lag: {t.size} times but {temp.size} temperatures")
    if t.size < 3:
        raise DataError(f"lag: {t.size} rows; a time series is needed")
    bad = np.flatnonzero(np.diff(t) < 0)
    if bad.size:
        raise DataError(f"lag: time goes backwards at row {int(bad[0]) + 1}; sort the rows by time")
    for name, a in (("time", t), ("temperature", temp)):
        if not np.all(np.isfinite(a)):
            raise DataError(f"lag: {name} is not finite at row {int(np.flatnonzero(~np.isfinite(a))[0])}")
    return t, temp


def _gap(t: np.ndarray, max_gap_s: float | None) -> float:
    return max_gap_s if max_gap_s is not None else GAP_FACTOR * float(np.median(np.diff(t)))


def _golden(f: Callable[[float], float], a: float, b: float, *, tol: float) -> float:
    """Minimum of a unimodal f on [a, b] by golden-section search."""
    inv_phi = (math.sqrt(5) - 1) / 2
    c, d = b - inv_phi * (b - a), a + inv_phi * (b - a)
    fc, fd = f(c), f(d)
    while b - a > tol:
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - inv_phi * (b - a)
            fc = f(c)
        else:
            a, c, fc = c, d, fd
            d = a + inv_phi * (b - a)
            fd = f(d)
    return 0.5 * (a + b)
