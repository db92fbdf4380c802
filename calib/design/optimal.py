"""Optimal experimental design for the T24 model: what field targets and DUT temperatures will teach,
before anything is measured.

    g = information(fields_nt, temps_c, samples, temp_ref_c=20.0)     # the 8x8 Gram they would give
    se = std_errors(g, sigma_nt=21.0, temp_ref_c=20.0)                  # as the fit would report them
    w, eff = optimal_weights(candidates, "D")                           # Fedorov-Wynn (multiplicative)
    counts = exact_design(w, n=24)                                      # whole points per candidate

## Model

calib/models/gram.py: per output axis B_i = x . beta_i with x = [1, t, h1, h2, h3, t h1, t h2, t h3] and
t = tau - temp_ref_c. The three axes share x, so one 8x8 information matrix G = sum_k n_k x_k x_k^T (n_k
samples at field h_k and temperature tau_k) serves all three. With white noise sigma_i on axis i, axis i's
parameters have covariance sigma_i^2 G^-1, carried to the calibration file's absolute-tau parameters
exactly as calib/models/gram.py does (`absolute_transform`). Before a campaign, h is the nominal field (the
sensor's axes taken as the lab's), as rig check's design test does.

x is the Kronecker product [1, t] (x) [1, h]: a design that visits the same field set at every
temperature has G = (sum over temperatures of [1, t][1, t]^T) (x) (sum over fields of [1, h][1, h]^T), and
D-optimal designs of such products are the products of D-optimal parts: field directions with zero mean
and a second moment proportional to the identity at the largest magnitude, temperatures split between the
two ends of the range.

## Criteria and algorithm

- D-optimal: maximise log det G (the confidence ellipsoid's volume; unchanged by scaling or centring).
- I-optimal: minimise the average prediction variance over prediction points (the plan's fields and
  temperatures): tr(G^-1 M), M their second moment.

The multiplicative algorithm (Silvey, Titterington and Torsney; of the Fedorov-Wynn family) re-weights
every candidate by its sensitivity phi_k: x_k^T G^-1 x_k for D, x_k^T G^-1 M G^-1 x_k for I (power 1/2,
which keeps the I steps monotone). The general equivalence theorem bounds the efficiency of the current
weights from below (D: p / max phi; I: tr(G^-1 M) / max phi), so the loop stops with a proven efficiency.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from calib.design.targets import GROUP_KEYS
from calib.equations import t24_regressors
from calib.errors import DataError, FitError
from calib.models.gram import RCOND_SINGULAR, absolute_transform, unpack

GROUP_ROWS = {"b_nt": [0], "kb_nt_per_c": [1], "S": [2, 3, 4], "K": [5, 6, 7]}  # rows of x per group
CRITERIA = ("D", "I")
MAX_ITERATIONS = 5000


# --- information and standard errors -------------------------------------------------------------------
def information(fields_nt, temps_c, samples=1, *, temp_ref_c: float) -> np.ndarray:
    """The 8x8 Gram a T24 fit would accumulate: samples (N,) or one count for every point."""
    x = t24_regressors(fields_nt, temps_c, temp_ref_c)
    w = np.broadcast_to(np.asarray(samples, float), (len(x),))
    return (x * w[:, None]).T @ x


def _inverse(gram: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(G^-1, singular) of one or a stack of Grams (..., 8, 8), solved with unit diagonal; where singular
    the inverse holds zeros and `singular` is True."""
    g = np.asarray(gram, float)
    d = np.sqrt(np.maximum(np.diagonal(g, axis1=-2, axis2=-1), 0.0))
    safe = np.where(d > 0, d, 1.0)
    gs = g / (safe[..., :, None] * safe[..., None, :])
    w, v = np.linalg.eigh(gs)
    bad = (w[..., 0] <= RCOND_SINGULAR * w[..., -1]) | np.any(d == 0, axis=-1)
    w = np.where(bad[..., None], 1.0, w)
    inv = (v / w[..., None, :]) @ np.swapaxes(v, -1, -2) / (safe[..., :, None] * safe[..., None, :])
    return np.where(bad[..., None, None], 0.0, inv), bad


def _scaled_inverse(gram: np.ndarray) -> np.ndarray:
    """G^-1, inf where singular."""
    inv, bad = _inverse(gram)
    return np.where(bad[..., None, None], np.inf, inv)


def covariance(gram: np.ndarray, temp_ref_c: float) -> np.ndarray:
    """Unit-noise covariance of the absolute-tau parameters [b, kb, S_i., K_i.] (..., 8, 8); inf where the
    design is singular."""
    a = absolute_transform(temp_ref_c)
    inv, bad = _inverse(gram)
    return np.where(bad[..., None, None], np.inf, a @ inv @ a.T)


def _sigma3(sigma_nt) -> np.ndarray:
    sigma = np.broadcast_to(np.asarray(sigma_nt, float), (3,))
    if not np.all(np.isfinite(sigma)) or np.any(sigma < 0):
        raise DataError(f"noise sigma {sigma_nt!r}: must be finite and >= 0 nT")
    return sigma


def std_errors(gram: np.ndarray, sigma_nt, temp_ref_c: float) -> dict[str, np.ndarray]:
    """The T24 standard errors the fit would report (keys and shapes of the calibration file);
    sigma_nt per axis (3,) or one for all. inf for parameters the design cannot identify."""
    var = np.diag(covariance(gram, temp_ref_c))
    return unpack(np.sqrt(np.outer(var, _sigma3(sigma_nt) ** 2)))


def target_ratios(gram: np.ndarray, sigma_nt, temp_ref_c: float,
                  targets: Mapping[str, float]) -> np.ndarray:
    """Largest standard error over target of each group, for one Gram (G,) or a stack (..., G), in the
    order of `targets` (groups S, K, b, kb or the file's keys; calib/design/targets.py)."""
    var = np.diagonal(covariance(gram, temp_ref_c), axis1=-2, axis2=-1)  # (..., 8)
    sigma_max = float(np.max(_sigma3(sigma_nt)))
    out = []
    for group, target in targets.items():
        rows = GROUP_ROWS[GROUP_KEYS[group]]
        out.append(sigma_max * np.sqrt(np.max(var[..., rows], axis=-1)) / float(target))
    return np.stack(out, axis=-1)


def worst_parameter(gram: np.ndarray, temp_ref_c: float, targets: Mapping[str, float]) -> tuple[str, int]:
    """(group, row of x) whose standard error is furthest above its target (unit noise: the axes share G)."""
    var = np.diag(covariance(gram, temp_ref_c))
    best = max(((group, r) for group in targets for r in GROUP_ROWS[GROUP_KEYS[group]]),
               key=lambda gr: var[gr[1]] / float(targets[gr[0]]) ** 2)
    return best


def gain_for(gram: np.ndarray, temp_ref_c: float, row: int, x: np.ndarray, samples: float) -> np.ndarray:
    """How much `samples` more at each candidate x (N, 8) lower the unit-noise variance of absolute
    parameter `row` (Sherman-Morrison): (a^T G^-1 x)^2 / (1/samples + x^T G^-1 x)."""
    inv = _scaled_inverse(gram)
    a = absolute_transform(temp_ref_c)[row]
    u = x @ (inv @ a)
    return u * u / (1.0 / samples + np.einsum("ni,ij,nj->n", x, inv, x))


# --- criteria and the multiplicative algorithm -----------------------------------------------------------
def _checked_candidates(x) -> np.ndarray:
    x = np.asarray(x, float)
    if x.ndim != 2 or x.shape[0] < x.shape[1]:
        raise DataError(f"design: {x.shape} candidates; need at least as many rows as parameters")
    if not np.all(np.isfinite(x)):
        raise DataError("design: a candidate has a non-finite regressor")
    return x


def criterion_value(x, weights, criterion: str = "D", prediction: np.ndarray | None = None) -> float:
    """log det M(w) (D, larger is better) or tr(M(w)^-1 P) (I, smaller is better), M = sum w x x^T."""
    x = _checked_candidates(x)
    m = (x * np.asarray(weights, float)[:, None]).T @ x
    if criterion == "D":
        sign, logdet = np.linalg.slogdet(m)
        return logdet if sign > 0 else -math.inf
    return float(np.trace(_scaled_inverse(m) @ _prediction(x, prediction)))


def _prediction(x: np.ndarray, prediction: np.ndarray | None) -> np.ndarray:
    """Second moment of the prediction points (rows of x); the candidates' own when none are given."""
    p = x if prediction is None else np.asarray(prediction, float)
    return p.T @ p / len(p)


def optimal_weights(x, criterion: str = "D", prediction=None, *, tol: float = 1e-3,
                    max_iterations: int = MAX_ITERATIONS) -> tuple[np.ndarray, float]:
    """Approximate optimal design over candidate regressors x (N, p): weights (N,) summing to 1 and the
    proven lower bound on its efficiency (stops once it is >= 1 - tol). `prediction`: regressors of the
    points whose average prediction variance I-optimality minimises (default: the candidates)."""
    if criterion not in CRITERIA:
        raise DataError(f"design criterion {criterion!r}: must be one of {', '.join(CRITERIA)}")
    x = _checked_candidates(x)
    scale = np.sqrt(np.mean(x * x, axis=0))
    if np.any(scale == 0):
        zero = np.flatnonzero(scale == 0).tolist()
        raise FitError(f"design: regressor(s) {zero} are zero on every candidate")
    xs = x / scale
    p_mom = _prediction(x, None if prediction is None else np.asarray(prediction, float)) / np.outer(scale,
                                                                                                     scale)
    w = np.full(len(xs), 1.0 / len(xs))
    efficiency = 0.0
    for _ in range(max_iterations):
        m_inv = _scaled_inverse((xs * w[:, None]).T @ xs)
        if not np.all(np.isfinite(m_inv)):
            raise FitError("design: the candidates cannot identify every parameter (singular information)")
        if criterion == "D":
            phi = np.einsum("ni,ij,nj->n", xs, m_inv, xs)
            efficiency = xs.shape[1] / float(phi.max())
            update = phi / xs.shape[1]
        else:
            q = m_inv @ p_mom @ m_inv
            phi = np.einsum("ni,ij,nj->n", xs, q, xs)
            total = float(np.trace(m_inv @ p_mom))
            efficiency = total / float(phi.max())
            update = np.sqrt(phi / total)
        if efficiency >= 1.0 - tol:
            break
        w = w * update
        w /= w.sum()
    return w, efficiency


def exact_design(weights, n: int, *, drop_below: float = 1e-4) -> np.ndarray:
    """Whole numbers of points (summing to n) for approximate weights: efficient rounding (Pukelsheim and
    Rieder) over the candidates whose weight is at least `drop_below` of the largest."""
    w = np.asarray(weights, float)
    if n < 1:
        raise DataError(f"exact design of {n} points: need at least one")
    support = w >= drop_below * w.max()
    ws = np.where(support, w, 0.0)
    ws /= ws.sum()
    counts = np.where(support, np.ceil((n - support.sum() / 2.0) * ws), 0).astype(int)
    while counts.sum() > n:
        ratio = np.where(counts > 0, (counts - 1) / np.where(ws > 0, ws, 1.0), -np.inf)
        counts[int(np.argmax(ratio))] -= 1
    while counts.sum() < n:
        ratio = np.where(support, counts / np.where(ws > 0, ws, 1.0), np.inf)
        counts[int(np.argmin(ratio))] += 1
    return counts


def exchange(x, n: int, criterion: str = "D", prediction=None, *, start: np.ndarray | None = None,
             max_passes: int = 100) -> np.ndarray:
    """An exact design of n distinct candidates (indices into x) by Fedorov's exchange: swap one design
    point for one candidate while the criterion improves. Each swap is judged for every candidate at once
    (rank-one updates: det(M + x x^T) = det M (1 + x^T M^-1 x), and Sherman-Morrison for tr(M^-1 P)).
    `start`: the initial indices (default: the n largest weights of the approximate optimum)."""
    x = _checked_candidates(x)
    if not x.shape[1] <= n <= len(x):
        raise DataError(f"design: {n} points from {len(x)} candidates; need {x.shape[1]} .. {len(x)}")
    if n == len(x):  # every candidate: nothing is left to exchange
        return np.arange(len(x))
    scale = np.sqrt(np.mean(x * x, axis=0))
    xs = x / np.where(scale > 0, scale, 1.0)
    p_mom = _prediction(x, None if prediction is None else np.asarray(prediction, float))
    p_mom = p_mom / np.outer(np.where(scale > 0, scale, 1.0), np.where(scale > 0, scale, 1.0))
    if start is None:
        w, _ = optimal_weights(x, criterion, prediction, tol=1e-2)
        start = np.argsort(-w, kind="stable")[:n]
    design = np.array(sorted(int(i) for i in start))
    for _ in range(max_passes):
        m = xs[design].T @ xs[design]
        best = (_value(m, p_mom, criterion), -1, -1)
        outside = np.setdiff1d(np.arange(len(xs)), design)
        for pos, i in enumerate(design):
            m_minus = m - np.outer(xs[i], xs[i])
            a, bad = _inverse(m_minus)
            if bad:
                continue
            cand = xs[outside]
            quad = np.einsum("ni,ij,nj->n", cand, a, cand)
            if criterion == "D":
                values = -(np.linalg.slogdet(m_minus)[1] + np.log1p(quad))
            else:
                ap = a @ p_mom @ a
                values = np.trace(a @ p_mom) - np.einsum("ni,ij,nj->n", cand, ap, cand) / (1.0 + quad)
            j = int(np.argmin(values))
            if values[j] < best[0] - 1e-12 * abs(best[0]):
                best = (float(values[j]), pos, int(outside[j]))
        if best[1] < 0:
            break
        design[best[1]] = best[2]
        design.sort()
    return design


def _value(m: np.ndarray, p_mom: np.ndarray, criterion: str) -> float:
    """The criterion as a loss (smaller is better): -log det M, or tr(M^-1 P)."""
    if criterion == "D":
        sign, logdet = np.linalg.slogdet(m)
        return -logdet if sign > 0 else math.inf
    inv, bad = _inverse(m)
    return math.inf if bad else float(np.trace(inv @ p_mom))
