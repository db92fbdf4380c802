"""The offset's wander between temperature steps, as a line of the budget.

An AMR's offset wanders slowly (1/f noise and a random walk, hardware-notes 9.1), and so does whatever
the reference misses in the lab (a chamber's compressor field): the samples of one temperature step
share an offset error that the next step does not. The fit's statistics take every sample as
independent, so they miss it, and a plan that visits each temperature once cannot tell it from a
temperature curvature (a few steps are all used by T24 and the model checks' terms).

It shows within a step, though: the means of consecutive points (a few seconds to a minute apart)
differ by more than their white noise. Their Allan variance at that spacing, A (half the mean square
difference, less the white noise's share), is the same at every averaging time for a 1/f noise; the
offset of a step (a few minutes' average) against the run's mean then varies by about 2.5 A for a 1/f
noise from a second to hours (the components slower than a step, against the flat Allan variance), and
a random walk adds to it: WANDER_FACTOR x A per step. A is a small difference of large numbers (the
white noise's share dominates): it counts only when its mean over the three axes is SIGNIFICANCE
standard errors above zero, and then each axis takes at least that mean (an AMR's offset noise is alike
on its axes). The source: one offset per step and axis, independent; it changes the data (the
parameters absorb it, b and kb most), never the true field.

The consecutive difference also holds what each point has of its own (a pose's reference error, a
misfit from one field to the next), which a step's mean averages out: on a turntable the point means'
variogram is about flat from 1 to 8 points apart. Read from its growth alone, though, the wander leaves
b and kb under-covered (bench/README.md): the DUT's components slower than a step move the steps'
offsets by more than a step's points show. The difference is the bound the data give, and it is taken.
"""

from __future__ import annotations

import numpy as np

from calib.uncertainty.propagation import Estimated, InputSource
from calib.uncertainty.rowgroups import RowGroups

WANDER_FACTOR = 3.0
SIGNIFICANCE = 3.0


def _point_means(ds, resid: np.ndarray, used: np.ndarray):
    """Per point in time order: (mean residual (P,k), samples (P,), group label (P,))."""
    points = np.asarray(ds.columns["point"], object).astype(str)[used]
    times = np.asarray(ds.columns["t"], float)[used]
    groups = np.asarray(ds.group if ds.group is not None else ds.columns["point"], object).astype(str)[used]
    labels, index = np.unique(points, return_inverse=True)
    counts = np.bincount(index, minlength=len(labels))
    means = np.stack([np.bincount(index, resid[used, i], len(labels)) for i in range(resid.shape[1])],
                     axis=1) / np.maximum(counts, 1)[:, None]
    first = np.full(len(labels), np.inf)
    np.minimum.at(first, index, times)
    group_of = np.empty(len(labels), object)
    group_of[index] = groups
    order = np.argsort(first, kind="stable")
    return means[order], counts[order], group_of[order]


def wander_source(ds, resid: np.ndarray, noise_nt: np.ndarray,
                  weights=None) -> tuple[InputSource | None, str, np.ndarray | None]:
    """(the source, what was found, its variance per step and axis) from the fit's residuals (N,3) and
    the white noise per axis."""
    if ds.columns.get("point") is None or ds.columns.get("t") is None:
        return None, "offset wander: the samples carry no points or times", None
    used = np.ones(len(ds), bool) if weights is None else np.asarray(weights, float) > 0
    means, counts, groups = _point_means(ds, resid, used)
    same = groups[1:] == groups[:-1]
    if not same.any() or not np.all(np.isfinite(noise_nt)):
        return None, "offset wander: no step with two points and a known noise, not in the budget", None
    diff2 = (means[1:] - means[:-1])[same] ** 2
    white = noise_nt**2 * (1.0 / counts[1:] + 1.0 / counts[:-1])[same][:, None]
    excess = (diff2 - white) / 2.0  # (differences, axes)
    pooled = float(np.mean(excess))
    se = float(np.std(np.mean(excess, axis=1), ddof=1) / np.sqrt(len(excess))) if len(excess) > 1 else np.inf
    if pooled <= SIGNIFICANCE * se:
        allan = np.zeros(3)
    else:
        allan = np.maximum(np.mean(excess, axis=0), pooled)
    variance = WANDER_FACTOR * allan
    labels, index = np.unique(np.asarray(ds.group if ds.group is not None else ds.columns["point"],
                                         object).astype(str), return_inverse=True)
    a = RowGroups.offsets(index, len(labels))  # compact: a dense (N,3,3 steps) would be N x steps x 9
    deviation = ", ".join(f"{v:.1f}" for v in np.sqrt(allan))
    said = (f"consecutive points within a step: Allan deviation ({deviation}) nT beyond the noise; "
            f"{WANDER_FACTOR:g} x its variance per step, {len(labels)} steps")
    sigma = np.diag(np.tile(variance, len(labels)))
    # estimated from the point differences within steps: one estimate per axis, that many degrees of freedom
    steps = np.arange(len(labels))
    estimated = tuple(Estimated(3 * steps + i, np.full(len(steps), variance[i]), len(excess))
                      for i in range(3) if variance[i] > 0)
    return InputSource("offset wander", sigma, ref_nt=a, origin=said, estimated=estimated), said, variance
