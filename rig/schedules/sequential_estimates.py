"""What a sequential run knows of its DUTs, measured by itself (rig/schedules/sequential_run.py decides
with it): each DUT's data so far (`DutRows`) and what they show (`measure`: Gram, noise, worst target
ratio, the element's temperature through the lag the data show); each DUT's lag behind the air and where it
settles relative to the air, from its recorded temperature against the air the run logs
(calib/thermal/response.py `first_order_fit`), and its noise.

After every sweep each DUT's lag is fitted again from all the data so far; the estimate in use is replaced
when the new one differs from it by more than ADOPT_SIGMAS of their standard errors and ADOPT_SHARE of the
lag (or the offset by more than ADOPT_OFFSET_C), or when there was none: the run then re-plans with it.
The estimates in use are recorded with every decision, so a resume takes exactly them up again.

Noise: the T24 fit's residual sigma once the data identify T24, before that the last sweep's residual about
an affine model of the reference in the reading and the temperature (a sweep spans a small part of the
range: what it leaves is the noise, and a little model error, which errs on the safe side).
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, field

import numpy as np

from calib.errors import DataError
from calib.thermal.response import FirstOrderFit, first_order_fit
from rig.core.errors import ERRORS

log = logging.getLogger("magrig.seqrun")

ADOPT_SIGMAS = 3.0
ADOPT_SHARE = 0.1
ADOPT_OFFSET_C = 0.1


@dataclass(frozen=True)
class Estimate:
    """One DUT as the run plans with it (JSON-ready for the decision record)."""

    lag_s: float
    lag_se_s: float | None
    offset_c: float
    noise_nt: float | None
    source: str  # "measured by this run", or where a prior came from

    def as_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> Estimate:
        return cls(float(data["lag_s"]), None if data.get("lag_se_s") is None else float(data["lag_se_s"]),
                   float(data.get("offset_c") or 0.0),
                   None if data.get("noise_nt") is None else float(data["noise_nt"]),
                   str(data.get("source", "recorded")))


class AirLog:
    """The air the run saw, in time order: one reading per point (and the session's log on a resume)."""

    def __init__(self) -> None:
        self.t: list[float] = []
        self.air: list[float] = []

    def add(self, t: float | None, air_c: float | None) -> None:
        if t is None or air_c is None or (self.t and t <= self.t[-1]):
            return
        self.t.append(float(t))
        self.air.append(float(air_c))

    def fit(self, t_s: np.ndarray, temp_c: np.ndarray) -> FirstOrderFit | None:
        """The DUT's temperature (time-ordered rows) against the air; None before there is enough of both."""
        if len(self.t) < 2 or len(t_s) < 2:
            return None
        try:
            return first_order_fit(self.t, self.air, t_s, temp_c)
        except DataError:
            return None


def adopted(in_use: Estimate | None, fit: FirstOrderFit | None, noise_nt: float | None) -> Estimate | None:
    """The new estimate when `fit` differs enough from the one in use (module docstring), else None."""
    if fit is None or not fit.identifiable:
        return None
    new = Estimate(fit.tau_s, fit.tau_se_s, fit.offset_c, noise_nt, "measured by this run")
    if in_use is None:
        return new
    se = math.hypot(fit.tau_se_s or 0.0, in_use.lag_se_s or 0.0)
    lag_moved = abs(fit.tau_s - in_use.lag_s) > max(ADOPT_SIGMAS * se, ADOPT_SHARE * in_use.lag_s)
    offset_moved = abs(fit.offset_c - in_use.offset_c) > ADOPT_OFFSET_C
    return new if lag_moved or offset_moved else None


def affine_sigma_nt(h_nt: np.ndarray, temp_c: np.ndarray, ref_nt: np.ndarray) -> float | None:
    """The largest per-axis residual sigma of the reference about [1, h, temperature] (None: too few rows)."""
    h, ref = np.asarray(h_nt, float).reshape(-1, 3), np.asarray(ref_nt, float).reshape(-1, 3)
    x = np.column_stack([np.ones(len(h)), h, np.asarray(temp_c, float) - np.mean(temp_c)])
    if len(h) <= 2 * x.shape[1]:
        return None
    scale = np.maximum(np.abs(x).max(axis=0), 1e-12)  # centred and scaled before solving
    coef, *_ = np.linalg.lstsq(x / scale, ref, rcond=None)
    residual = ref - (x / scale) @ coef
    return float(np.sqrt(np.max(np.sum(residual**2, axis=0)) / (len(h) - x.shape[1])))


MIN_LAG_ROWS = 200  # fewer rows than this: the lag is not estimated yet
LAG_REFIT_GROWTH = 1.25  # within a leg, the lag is fitted again once the rows grew by this factor


@dataclass
class DutRows:
    """One DUT's samples so far, in time order (t, h, recorded temperature, reference)."""

    t: list = field(default_factory=list)
    h: list = field(default_factory=list)
    temp: list = field(default_factory=list)
    ref: list = field(default_factory=list)
    # the lag model found first (calib/thermal/lag.py); kept after, as fitting both is slow
    direction: str = "auto"
    lag: tuple[float, float | None] | None = None  # the last identifiable (tau, its se)
    lag_rows: int = 0  # the rows of the last lag fit
    lag_leg: int | None = None  # the leg of the last lag fit

    def extend(self, t, h, temp, ref) -> None:
        self.t.extend(np.asarray(t, float).tolist())
        self.h.extend(np.asarray(h, float).reshape(-1, 3).tolist())
        self.temp.extend(np.asarray(temp, float).tolist())
        self.ref.extend(np.asarray(ref, float).reshape(-1, 3).tolist())

    def arrays(self):
        return (np.array(self.t), np.array(self.h).reshape(-1, 3), np.array(self.temp),
                np.array(self.ref).reshape(-1, 3))


@dataclass
class Measured:
    """What one DUT's data says now."""

    gram: np.ndarray
    sigma_nt: float | None
    ratio: float
    element_c: float | None
    lag_s: float | None
    lag_se_s: float | None
    covered_c: tuple[float, float] | None = None  # its lowest and highest element temperature so far
    element_temps_c: np.ndarray | None = None  # every row's, for the model check


def measure(rows: DutRows, targets: dict[str, float], temp_ref_c: float, leg: int | None = None) -> Measured:
    """Gram, noise, worst target ratio and element temperature of one DUT from its rows so far."""
    from calib.design.targets import check_targets
    from calib.models.gram import GramAccumulator
    from calib.thermal.lag import element_temperature, estimate_lag

    t, h, temp, ref = rows.arrays()
    acc = GramAccumulator(temp_ref_c)
    if len(t) == 0:
        return Measured(acc.gram[:8, :8].copy(), None, math.inf, None, None, None)
    corrected, lag, lag_se = temp, None, None
    # a lag fit is a grid of T24 fits over every row: made in each new leg and once the rows grew by
    # LAG_REFIT_GROWTH; in between, the last lag found (if any) is applied to the new rows
    due = leg != rows.lag_leg or len(t) >= LAG_REFIT_GROWTH * rows.lag_rows
    if len(t) >= MIN_LAG_ROWS and not due:
        if rows.lag is not None:
            lag, lag_se = rows.lag
            corrected = element_temperature(t, temp, lag, rows.direction)
    elif len(t) >= MIN_LAG_ROWS:
        rows.lag_rows, rows.lag_leg = len(t), leg
        try:
            res = estimate_lag(t, h, temp, ref, direction=rows.direction)
        except ERRORS as exc:
            log.info("lag not estimated: %s", exc)
        else:
            if res.identifiable:
                corrected, lag, lag_se = res.temp_element_c, res.tau_s, res.tau_se_s
                rows.direction = res.direction
                rows.lag = (lag, lag_se)
    acc.add(h, corrected, ref)
    status = check_targets(acc, targets)
    sigma = None
    if math.isfinite(status.worst_ratio):
        sigma = max(acc.solve().stats["sigma_nt"].values())
    return Measured(acc.gram[:8, :8].copy(), sigma, status.worst_ratio, float(corrected[-1]), lag, lag_se,
                    (float(np.min(corrected)), float(np.max(corrected))), np.asarray(corrected, float))
