"""The adaptive Monte Carlo procedure of GUM Supplement 1 (JCGM 101:2008 §7.9).

    result = adaptive_monte_carlo(draw_batch, rng, ndig=2)

`draw_batch(rng, m)` makes m draws of the output quantities and returns (values (m,K), lengths (m,R),
failed (m,)): values are quantities with a coverage interval (the parameters' deviations from their
estimates), lengths non-negative quantities judged by their one-sided 95 % quantile (the calibrated
field's error length at each grid point), failed marks draws whose refit failed.

The procedure (§7.9.4): batches of M draws (M = max(100 / (1 - p), 10^4) by default); after each batch
from the second on, the standard deviation of the batch estimates' average of every quantity's mean,
standard uncertainty u and coverage interval endpoints (of every length's 95 % quantile) is compared
with the numerical tolerance delta (§7.9.2: u written as c x 10^l with c an ndig-digit integer gives
delta = 10^l / 2). It stops when twice each is below its delta, or when max_draws is reached (the result
then says so: `converged` False). The final estimates use all draws together (§7.9.4 g).

Coverage intervals (§7.7): probabilistically symmetric (the 2.5 % and 97.5 % quantiles) or the shortest
interval holding 95 % of the draws; "auto" takes the shortest for a quantity whose first batch shows a
skewness beyond 3 standard errors (sqrt(6 / M)), where the two differ, else the symmetric one.

A failed draw is counted (`failed`) and left out of the statistics; when more than MAX_FAILED_SHARE of
the draws fail, `stated` is False and the message says the uncertainty cannot be stated.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

S1_MIN_BATCH = 10_000
MAX_DRAWS = 200_000
MAX_FAILED_SHARE = 0.01
INTERVALS = ("symmetric", "shortest", "auto")


def numerical_tolerance(value, ndig: int) -> np.ndarray:
    """delta of §7.9.2: |value| = c x 10^l with c an ndig-digit integer, delta = 10^l / 2 (0 for 0)."""
    v = np.abs(np.asarray(value, float))
    with np.errstate(divide="ignore"):
        exponent = np.floor(np.log10(np.where(v > 0, v, 1.0))) - (ndig - 1)
    return np.where(v > 0, 0.5 * 10.0**exponent, 0.0)


def shortest_interval(sorted_draws: np.ndarray, probability: float) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) of the shortest interval holding `probability` of the draws (columns sorted)."""
    m = sorted_draws.shape[0]
    q = int(probability * m + 0.5)
    widths = sorted_draws[q - 1:] - sorted_draws[:m - q + 1]
    start = np.argmin(widths, axis=0)
    cols = np.arange(sorted_draws.shape[1])
    return sorted_draws[start, cols], sorted_draws[start + q - 1, cols]


def quantiles(draws: np.ndarray, probabilities) -> np.ndarray:
    """Quantiles of every column, linearly interpolated between order statistics (numpy's default), by
    one partial sort."""
    m = draws.shape[0]
    spots = [(p * (m - 1), int(np.floor(p * (m - 1)))) for p in probabilities]
    kth = sorted({k for _, lo in spots for k in (lo, min(lo + 1, m - 1))})
    part = np.partition(draws, kth, axis=0)
    return np.array([part[lo] + (at - lo) * (part[min(lo + 1, m - 1)] - part[lo]) for at, lo in spots])


def _interval(draws: np.ndarray, probability: float, shortest: np.ndarray):
    """(low, high) per column: probabilistically symmetric, or the shortest where asked."""
    tail = 0.5 * (1.0 - probability)
    low, high = quantiles(draws, [tail, 1.0 - tail])
    if shortest.any():
        low[shortest], high[shortest] = shortest_interval(np.sort(draws[:, shortest], axis=0), probability)
    return low, high


@dataclass
class AdaptiveResult:
    draws: int  # every draw made, failed ones included
    failed: int
    batches: int
    batch_size: int
    converged: bool  # the tolerance was met before max_draws
    stated: bool  # few enough draws failed for the result to stand
    mean: np.ndarray  # (K,) of the values' draws
    u: np.ndarray  # (K,) standard deviations
    low: np.ndarray  # (K,) coverage interval
    high: np.ndarray
    shortest: np.ndarray  # (K,) bool: the interval is the shortest one (else probabilistically symmetric)
    length_quantile: np.ndarray  # (R,) the lengths' `probability` quantiles (one-sided)
    length_rms: np.ndarray  # (R,)
    tolerance: np.ndarray  # (K,) delta of the values (from u)
    length_tolerance: np.ndarray  # (R,) delta of the length quantiles
    ndig: int
    probability: float
    message: str = ""
    values: np.ndarray | None = None  # (draws fitted, K): every draw of the values, for their covariance


def adaptive_monte_carlo(draw_batch: Callable, rng: np.random.Generator, *, ndig: int = 2,
                         probability: float = 0.95, batch_size: int | None = None, max_draws: int = MAX_DRAWS,
                         interval: str = "auto") -> AdaptiveResult:
    if interval not in INTERVALS:
        raise ValueError(f"interval {interval!r} (known: {', '.join(INTERVALS)})")
    m = batch_size or max(math.ceil(100 / (1 - probability)), S1_MIN_BATCH)
    values_all, lengths_all, estimates = [], [], []
    drawn = failed = 0
    shortest = None
    converged = False
    while True:
        values, lengths, bad = draw_batch(rng, m)
        drawn += m
        failed += int(np.count_nonzero(bad))
        values, lengths = values[~bad], lengths[~bad]
        if failed > MAX_FAILED_SHARE * drawn and len(values) < 2:  # nothing left to estimate from
            return _unstated(values, lengths, drawn, failed, len(estimates) + 1, m, ndig, probability)
        if shortest is None:
            shortest = (_skewed(values) if interval == "auto"
                        else np.full(values.shape[1], interval == "shortest"))
        values_all.append(values)
        lengths_all.append(lengths.astype(np.float32))
        estimates.append(_batch_estimates(values, lengths, probability, shortest))
        if len(estimates) >= 2:
            if failed > MAX_FAILED_SHARE * drawn:
                break
            # delta needs u and the quantiles to ndig digits only: the batch estimates' average gives them
            average = np.mean(estimates, axis=0)
            k = values.shape[1]
            delta = numerical_tolerance(average[k:2 * k], ndig)
            if _settled(np.array(estimates), np.concatenate([delta, delta, delta, delta,
                                                             numerical_tolerance(average[4 * k:], ndig)])):
                converged = True
                break
        if drawn + m > max(max_draws, 2 * m):
            break
    values_cat = np.concatenate(values_all)
    lengths_cat = np.concatenate(lengths_all).astype(float)
    u = values_cat.std(axis=0, ddof=1)
    low, high = _interval(values_cat, probability, shortest)
    quantile = quantiles(lengths_cat, [probability])[0]
    stated = failed <= MAX_FAILED_SHARE * drawn
    message = f"{drawn} draws in {len(estimates)} batches of {m}"
    if failed:
        message += f"; {failed} refits failed ({100 * failed / drawn:.2g} % of the draws)"
    if not stated:
        message += f": more than {100 * MAX_FAILED_SHARE:g} % failed, the uncertainty cannot be stated"
    elif not converged:
        message += f": the tolerance ({ndig} significant digits) was not met within {max_draws} draws"
    else:
        message += f", stopped at the tolerance of {ndig} significant digits (GUM S1 7.9)"
    return AdaptiveResult(drawn, failed, len(estimates), m, converged, stated, values_cat.mean(axis=0), u,
                          low, high, shortest, quantile, np.sqrt(np.mean(lengths_cat**2, axis=0)),
                          numerical_tolerance(u, ndig),
                          numerical_tolerance(quantile, ndig), ndig, probability, message, values_cat)


def _unstated(values, lengths, drawn: int, failed: int, batches: int, m: int, ndig: int,
              probability: float) -> AdaptiveResult:
    """The result when (nearly) every draw of a batch failed: nothing can be stated."""
    k, r = values.shape[1], lengths.shape[1]
    nan_k, nan_r = np.full(k, np.nan), np.full(r, np.nan)
    share = 100 * failed / drawn
    message = (f"{drawn} draws in {batches} batches of {m}; {failed} refits failed ({share:.2g} % of the "
               f"draws): more than {100 * MAX_FAILED_SHARE:g} % failed, the uncertainty cannot be stated")
    return AdaptiveResult(drawn, failed, batches, m, False, False, nan_k, nan_k, nan_k, nan_k,
                          np.zeros(k, bool), nan_r, nan_r, nan_k, nan_r, ndig, probability, message,
                          np.zeros((0, k)))


def _skewed(values: np.ndarray) -> np.ndarray:
    """Quantities whose sample skewness is beyond 3 standard errors (sqrt(6 / M))."""
    centred = values - values.mean(axis=0)
    sd = centred.std(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        g1 = np.mean(centred**3, axis=0) / sd**3
    return np.nan_to_num(np.abs(g1)) > 3.0 * np.sqrt(6.0 / max(len(values), 1))


def _batch_estimates(values, lengths, probability, shortest) -> np.ndarray:
    """One batch's mean, u, interval endpoints of every value and quantile of every length, as one row."""
    low, high = _interval(values, probability, shortest)
    return np.concatenate([values.mean(axis=0), values.std(axis=0, ddof=1), low, high,
                           quantiles(lengths, [probability])[0]])


def _settled(estimates: np.ndarray, delta: np.ndarray) -> bool:
    """Twice the standard deviation of the batch estimates' average below delta, for every quantity."""
    h = estimates.shape[0]
    s = estimates.std(axis=0, ddof=1) / np.sqrt(h)
    return bool(np.all(2.0 * s <= delta))
