"""Model checks: does T24 describe the data, or does the sensor show what T24 leaves out?

    checks = model_checks(ds, direction=None)   # [Check]: temperature, hysteresis, field linearity
    [c.as_dict() for c in checks]               # plain values for a calibration's stats

Each check fits T24 and T24 plus the terms of one deviation to the same rows, per output axis, and tests
whether the larger model fits significantly better (calib/checks/nested.py: an F test on the drop of the
residual sum of squares). It reports the statistic, its degrees of freedom, the p-value, and the size of
the effect in nT over the data's range (`magnitude_nt`):

- linearity in temperature (calib/checks/linearity.py): a quadratic temperature term (tau - tm)^2 (Q h + q);
  its largest change of the field over the range. Needs three distinct temperatures.
- thermal hysteresis: given the thermal direction of every sample (+1 heating, -1 cooling, 0 unknown or
  held), an offset d per axis, +d heating and -d cooling (optionally a direction-dependent scale D h as
  well); the magnitude is the largest heating-cooling difference, 2 |d| (2 |d + D h| with the scale).
  Needs samples taken heating and samples taken cooling.
- linearity in the field: a cubic term per axis, c_i |h|^2 h_i / (50 uT)^2: c_i is its size relative to
  the field at 50 uT (ppm), and c_i |h|^3 / (50 uT)^2 its size at the data's largest field (nT). Needs two
  or more field magnitudes (a single one makes |h|^2 h_i a multiple of h_i).

The verdict rule: a check "fails" only when the effect is both statistically significant (p < p_fail,
1e-3) and larger than `practical_ratio` (0.5) times the fit's noise (the per-sample residual RMS, pooled
over the axes). An effect below half the noise adds at most 12 % to the RMS error of a single reading
(sqrt(1 + 0.5^2) = 1.118), so a tiny but significant effect on very many samples is reported ("holds",
with its p and size) but does not fail a DUT. "not testable" when the data cannot show the effect.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from calib.checks.linearity import linearity_with_test
from calib.checks.nested import NestedTest, nested_test, t24_design
from calib.dataset import Dataset
from calib.errors import DataError

P_FAIL = 1e-3
PRACTICAL_RATIO = 0.5
FIELD_SCALE_NT = 50_000.0  # the cubic term is stated relative to the field at 50 uT
MIN_ROWS_PER_DIRECTION = 10  # heating and cooling each
MAGNITUDE_GAP = 0.05  # field magnitudes further apart than 5 % are distinct
MIN_ROWS_PER_MAGNITUDE = 10

TEMPERATURE, HYSTERESIS, FIELD = "linearity in temperature", "thermal hysteresis", "linearity in the field"


@dataclass(frozen=True)
class Check:
    name: str
    testable: bool
    verdict: str  # "holds", "fails" or "not testable"
    message: str
    statistic: float | None = None  # chi-square like: sum over the axes of the residual drop over the noise
    dof: int | None = None  # of the statistic (3 x the extra terms per axis)
    dof_residual: int | None = None  # of the noise estimate (the p-value's F denominator)
    p: float | None = None
    magnitude_nt: float | None = None  # the effect's size over the data's range
    noise_nt: float | None = None  # the fit's residual noise per sample, pooled over the axes
    details: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return asdict(self)


def verdict(p: float, magnitude_nt: float, noise_nt: float, *, p_fail: float = P_FAIL,
            practical_ratio: float = PRACTICAL_RATIO) -> str:
    """"fails" when the effect is significant (p < p_fail) and larger than practical_ratio x the noise."""
    return "fails" if p < p_fail and magnitude_nt > practical_ratio * noise_nt else "holds"


def _judged(name: str, test: NestedTest, magnitude_nt: float, what: str, details: dict, p_fail: float,
            practical_ratio: float) -> Check:
    said = verdict(test.p, magnitude_nt, test.noise, p_fail=p_fail, practical_ratio=practical_ratio)
    limit = f"{practical_ratio:g} x the noise {test.noise:.2f} nT"
    if test.p >= p_fail:
        why = "not significant"
    else:
        why = f"significant, {'larger than' if said == 'fails' else 'within'} {limit}"
    return Check(name, True, said, f"T24's {name} {said}: {what} (p {test.p:.2g}: {why})",
                 test.statistic, test.dof, test.dof_residual, test.p, magnitude_nt, test.noise, details)


def temperature_linearity(ds: Dataset, *, p_fail: float = P_FAIL,
                          practical_ratio: float = PRACTICAL_RATIO) -> Check:
    """T24 plus (tau - tm)^2 (Q h + q) against T24 (calib/checks/linearity.py)."""
    if ds.temp_c is None or ds.ref_nt is None:
        return _untestable(TEMPERATURE, "it needs temperatures and reference vectors")
    result, test = linearity_with_test(ds.h_nt, ds.temp_c, ds.ref_nt)
    if test is None:
        return _untestable(TEMPERATURE, result["message"].split(": ", 1)[1])
    lo, hi = result["range_c"]
    what = (f"a quadratic term changes the field by up to {result['quadratic_nt']:.2f} nT over "
            f"{lo:.1f} .. {hi:.1f} degC")
    return _judged(TEMPERATURE, test, result["quadratic_nt"], what,
                   {"range_c": [lo, hi], "temperatures": result["temperatures"]}, p_fail, practical_ratio)


def hysteresis(ds: Dataset, direction, *, scale: bool = False, p_fail: float = P_FAIL,
               practical_ratio: float = PRACTICAL_RATIO) -> Check:
    """T24 plus +d heating / -d cooling per axis (and +-D h with `scale`) against T24."""
    if direction is None:
        return _untestable(HYSTERESIS, "no thermal direction (heating / cooling) was given for the samples")
    if ds.temp_c is None or ds.ref_nt is None:
        return _untestable(HYSTERESIS, "it needs temperatures and reference vectors")
    d = np.asarray(direction, float).ravel()
    if d.shape != (len(ds),) or not np.all(np.isin(d, (-1.0, 0.0, 1.0))):
        raise DataError(f"thermal direction: expected {len(ds)} values of +1 (heating), -1 (cooling) or 0, "
                        f"got {d.size} values" + ("" if d.size != len(ds) else " with others among them"))
    heating, cooling = int(np.sum(d > 0)), int(np.sum(d < 0))
    if min(heating, cooling) < MIN_ROWS_PER_DIRECTION or np.ptp(ds.temp_c) < 0.5:
        return _untestable(HYSTERESIS, f"it needs {MIN_ROWS_PER_DIRECTION} or more samples taken heating "
                           f"and as many cooling ({heating} heating, {cooling} cooling) over a temperature "
                           "range")
    base, _, u = t24_design(ds.h_nt, ds.temp_c)
    extra = d[:, None] if not scale else np.column_stack([d, d[:, None] * u])
    test = nested_test(base, extra, ds.ref_nt)
    offset = test.extra_coef[0]  # (3,) nT
    if scale:
        moving = d != 0
        split = 2 * (offset[None, :] + u[moving] @ test.extra_coef[1:])  # heating minus cooling, per row
        magnitude = float(np.max(np.abs(split)))
    else:
        magnitude = float(2 * np.max(np.abs(offset)))
    what = (f"heating and cooling differ by up to {magnitude:.2f} nT (2 d = "
            f"{', '.join(f'{2 * v:+.2f}' for v in offset)} nT{' plus the scale term' if scale else ''})")
    details = {"offset_nt": offset.tolist(), "heating_rows": heating, "cooling_rows": cooling,
               "scale_term": scale}
    return _judged(HYSTERESIS, test, magnitude, what, details, p_fail, practical_ratio)


def field_linearity(ds: Dataset, *, p_fail: float = P_FAIL,
                    practical_ratio: float = PRACTICAL_RATIO) -> Check:
    """T24 plus c_i |h|^2 h_i / (50 uT)^2 per axis against T24."""
    if ds.ref_nt is None:
        return _untestable(FIELD, "it needs reference vectors")
    levels = field_magnitudes_nt(ds.ref_nt)
    if len(levels) < 2:
        return _untestable(FIELD, "it needs two or more field magnitudes (5 % apart, "
                           f"{MIN_ROWS_PER_MAGNITUDE} samples each); the data have "
                           + (f"one, {levels[0]:.0f} nT" if levels else "none"))
    if ds.temp_c is None or np.ptp(ds.temp_c) < 0.5:  # one temperature: the P12-like base without t terms
        base = np.column_stack([np.ones(len(ds)), ds.h_nt])
    else:
        base = t24_design(ds.h_nt, ds.temp_c)[0]
    norm2 = np.sum(ds.h_nt**2, axis=1) / FIELD_SCALE_NT**2
    extra = np.stack([(norm2 * ds.h_nt[:, i])[:, None] for i in range(3)])  # (3, N, 1)
    test = nested_test(base, extra, ds.ref_nt)
    c = test.extra_coef[0]  # (3,) dimensionless
    largest = float(np.max(np.linalg.norm(ds.h_nt, axis=1)))
    at_largest = np.abs(c) * largest**3 / FIELD_SCALE_NT**2
    magnitude = float(at_largest.max())
    what = (f"a cubic term of {', '.join(f'{1e6 * v:+.1f}' for v in c)} ppm at 50 uT, up to "
            f"{magnitude:.2f} nT at {largest / 1000:.1f} uT")
    details = {"cubic_ppm_at_50ut": (1e6 * c).tolist(), "at_largest_field_nt": at_largest.tolist(),
               "largest_field_nt": largest, "field_magnitudes_nt": levels}
    return _judged(FIELD, test, magnitude, what, details, p_fail, practical_ratio)


def field_magnitudes_nt(ref_nt: np.ndarray) -> list[float]:
    """The distinct field magnitudes of the references (|B| sorted and cut where it jumps by more than
    MAGNITUDE_GAP), each with at least MIN_ROWS_PER_MAGNITUDE samples: their mean values."""
    norm = np.sort(np.linalg.norm(ref_nt, axis=1))
    if norm.size == 0:
        return []
    cuts = np.flatnonzero(np.diff(norm) > MAGNITUDE_GAP * np.maximum(norm[1:], 1e-300)) + 1
    groups = np.split(norm, cuts)
    return [float(g.mean()) for g in groups if g.size >= MIN_ROWS_PER_MAGNITUDE and g.mean() > 0]


def model_checks(ds: Dataset, direction=None, *, scale_hysteresis: bool = False, p_fail: float = P_FAIL,
                 practical_ratio: float = PRACTICAL_RATIO) -> list[Check]:
    """Every model check of T24 on `ds`, in a fixed order. direction: the thermal direction of every
    sample (+1 heating, -1 cooling, 0 unknown or held), or None."""
    options = {"p_fail": p_fail, "practical_ratio": practical_ratio}
    return [temperature_linearity(ds, **options),
            hysteresis(ds, direction, scale=scale_hysteresis, **options),
            field_linearity(ds, **options)]


def _untestable(name: str, why: str) -> Check:
    return Check(name, False, "not testable", f"T24's {name} not tested: {why}")
