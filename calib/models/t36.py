"""T36: T24 plus quadratic temperature terms, B = (S + tau K + tau^2 K2) h + b + tau kb + tau^2 kb2.

tau is the DUT temperature in degC (absolute, the paper's convention, as T24's). Per output axis the fit is
linear in 12 unknowns with regressors x = [1, t, t^2, h1..h3, t h1..t h3, t^2 h1..t^2 h3], t = tau -
temp_ref_c (centred at a reference fixed before any data arrives, so the sums merge exactly). As in
calib/models/gram.py the three axes share one 12x12 Gram; the accumulator holds the 15x15 Gram of [x, B], so
it streams in constant memory and gives the residual sum of squares without a second pass. The solve scales
the columns to a unit diagonal, refuses a singular design with the parameters it cannot identify, and
converts the centred parameters to the absolute-tau ones exactly (`absolute_transform`), the covariance
sigma^2 G^-1 with them.

The sums come from a numpy pass (blocks of CHUNK_ROWS rows handed to BLAS): T24's compiled kernel sums
powers of t up to 2 only, T36 needs 4.
"""

from __future__ import annotations

import numpy as np

from calib.calibration import Calibration
from calib.checks.nested import MIN_CURVATURE_SHARE
from calib.dataset import Dataset
from calib.equations import t36_regressors
from calib.errors import DataError, FitError
from calib.models.gram import MIN_TEMP_SPAN_C, RCOND_SINGULAR, RCOND_WARN, SumsAccumulator
from calib.stats.residuals import default_temp_ref_c

N_PARAMS = 12  # per output axis: b, kb, kb2, S_i1..3, K_i1..3, K2_i1..3
AXES = "xyz"
PARAM_NAMES = ["b", "kb", "kb2", "S1", "S2", "S3", "K1", "K2", "K3", "K2_1", "K2_2", "K2_3"]
GROUP_OF_PARAM = ["offset b", "offset drift kb", "offset curvature kb2", "S", "S", "S", "K", "K", "K",
                  "K2", "K2", "K2"]
CHUNK_ROWS = 8192


class T36Accumulator(SumsAccumulator):
    """Sums for a T36 fit: add() chunks, merge() accumulators, solve() at any time (12x12 algebra)."""

    SIZE = N_PARAMS + 3
    NAME = "T36 sums"

    def _system(self):
        return _ScaledSystem(self)

    def add(self, h_nt, temp_c, ref_nt, weights=None) -> None:
        """Add samples: h (N,3) raw nT, temp_c (N,) or scalar degC, ref_nt (N,3) nT, optional weights (N,)."""
        h = np.asarray(h_nt, dtype=float).reshape(-1, 3)
        ref = np.asarray(ref_nt, dtype=float).reshape(-1, 3)
        if ref.shape != h.shape:
            raise DataError(f"reference field has {ref.shape[0]} rows, readings have {h.shape[0]}")
        t = np.broadcast_to(np.asarray(temp_c, dtype=float), (h.shape[0],))
        w = np.ones(len(h)) if weights is None else np.broadcast_to(np.asarray(weights, float), (len(h),))
        used = w > 0  # rows with zero weight (flagged outliers) do not count
        if not used.any():
            return
        for lo in range(0, len(h), CHUNK_ROWS):
            rows = slice(lo, lo + CHUNK_ROWS)
            z = np.column_stack([t36_regressors(h[rows], t[rows], self.temp_ref_c), ref[rows]])
            self.gram += z.T @ (z * w[rows, None])
        self.n += int(used.sum())
        self.temp_min_c = min(self.temp_min_c, float(t[used].min()))
        self.temp_max_c = max(self.temp_max_c, float(t[used].max()))


def curvature_share(gram: np.ndarray, temp_min_c: float, temp_max_c: float, temp_ref_c: float) -> float:
    """How much of the temperatures' curvature a line cannot explain: with s the temperature scaled to
    -1..1 over the range, the residual mean square of s^2 regressed on [1, s] (from the Gram's moments of
    [1, t, t^2]), as calib.checks.nested.curvature_share does from the temperatures themselves."""
    half = 0.5 * (temp_max_c - temp_min_c)
    if not half > 0:
        return 0.0
    mid = 0.5 * (temp_max_c + temp_min_c) - temp_ref_c  # in t
    # [1, s, s^2] = T [1, t, t^2], s = (t - mid) / half
    tr = np.array([[1.0, 0.0, 0.0],
                   [-mid / half, 1.0 / half, 0.0],
                   [mid**2 / half**2, -2.0 * mid / half**2, 1.0 / half**2]])
    m = tr @ gram[:3, :3] @ tr.T / gram[0, 0]
    return float(max(m[2, 2] - m[2, :2] @ np.linalg.solve(m[:2, :2], m[:2, 2]), 0.0))


class _ScaledSystem:
    """The normal equations with columns scaled to unit diagonal, checked for identifiability."""

    def __init__(self, acc: T36Accumulator):
        n = acc.n
        if n <= N_PARAMS:
            raise FitError(f"T36: {n} samples, more than {N_PARAMS} needed (12 parameters per axis); "
                           "collect more points")
        span = acc.temp_max_c - acc.temp_min_c
        if span < MIN_TEMP_SPAN_C:
            raise FitError(f"T36: all samples within {span:.2f} degC: the temperature terms K, kb, K2 and "
                           "kb2 are not identifiable; add temperature steps or fit P12")
        share = curvature_share(acc.gram, acc.temp_min_c, acc.temp_max_c, acc.temp_ref_c)
        if share < MIN_CURVATURE_SHARE:
            raise FitError(f"T36: fewer than three distinct temperatures (between {acc.temp_min_c:.1f} and "
                           f"{acc.temp_max_c:.1f} degC): K2 and kb2 cannot be identified; add an interior "
                           "temperature step or fit T24")
        flat = _missing_field_direction(acc)
        if flat is not None:
            raise FitError("T36: the reference field spans fewer than three directions (nothing along "
                           f"[{flat[0]:.2f}, {flat[1]:.2f}, {flat[2]:.2f}]): the matrices S, K and K2 are "
                           "not identifiable; add coil directions out of that plane")
        self.acc = acc
        g = acc.gram[:N_PARAMS, :N_PARAMS]
        d = np.sqrt(np.diag(g))
        if np.any(d == 0):
            zero = [PARAM_NAMES[i] for i in np.flatnonzero(d == 0)]
            raise FitError(f"T36: regressors {', '.join(zero)} are zero for every sample")
        gs = g / np.outer(d, d)
        w, v = np.linalg.eigh(gs)
        self.rcond = float(w[0] / w[-1])
        if self.rcond < RCOND_SINGULAR:
            raise FitError(_explain_null_space(v[:, 0]))
        self.d = d
        self.gs_inv = (v / w) @ v.T
        rhs = acc.gram[:N_PARAMS, N_PARAMS:] / d[:, None]
        beta_s = self.gs_inv @ rhs
        beta_s += self.gs_inv @ (rhs - gs @ beta_s)  # one step of iterative refinement
        self.beta = beta_s / d[:, None]  # (12,3): column i holds axis i's centred parameters

    def residual_ss(self) -> np.ndarray:
        g = self.acc.gram
        bb = np.diag(g[N_PARAMS:, N_PARAMS:])
        return np.maximum(bb - np.einsum("pi,pi->i", self.beta, g[:N_PARAMS, N_PARAMS:]), 0.0)

    def calibration(self) -> Calibration:
        acc = self.acc
        n = acc.n
        rss = self.residual_ss()
        sigma2 = rss / (n - N_PARAMS)
        to_abs = absolute_transform(acc.temp_ref_c)
        cov_abs = to_abs @ (self.gs_inv / np.outer(self.d, self.d)) @ to_abs.T
        g = acc.gram
        raw_ss = np.maximum(np.diag(g[3:6, 3:6]) - 2 * np.diag(g[3:6, N_PARAMS:])
                            + np.diag(g[N_PARAMS:, N_PARAMS:]), 0.0)
        stats = {
            "n": n, "n_used": n, "n_outliers": 0,
            "rms_before_nt": float(np.sqrt(raw_ss.sum() / (3 * n))),
            "rms_after_nt": float(np.sqrt(rss.sum() / (3 * n))),
            "sigma_nt": {a: float(np.sqrt(s)) for a, s in zip(AXES, sigma2, strict=True)},
            "per_axis": {a: {"rms_after_nt": float(np.sqrt(r / n))} for a, r in zip(AXES, rss, strict=True)},
            "temp_span_c": [float(acc.temp_min_c), float(acc.temp_max_c)],
            "rcond_scaled_gram": self.rcond,
        }
        if self.rcond < RCOND_WARN:
            stats["warnings"] = [f"poorly conditioned design (rcond {self.rcond:.1e}); check the std errors"]
        return Calibration(
            model="t36",
            params=unpack(to_abs @ self.beta),
            std_errors=unpack(np.sqrt(np.outer(np.diag(cov_abs), sigma2))),
            temp_ref_c=acc.temp_ref_c,
            stats=stats,
            source={"kind": "gram"},
        )


def absolute_transform(temp_ref_c: float) -> np.ndarray:
    """The 12x12 map from the centred parameters to the absolute-tau ones. With t = tau - tr:
    c0 + c1 t + c2 t^2 = (c0 - tr c1 + tr^2 c2) + (c1 - 2 tr c2) tau + c2 tau^2, for the offset
    (b, kb, kb2) and for each column j of the matrices (S_ij, K_ij, K2_ij). Covariances go as A C A^T."""
    tr = float(temp_ref_c)
    one = np.array([[1.0, -tr, tr * tr], [0.0, 1.0, -2.0 * tr], [0.0, 0.0, 1.0]])
    to_abs = np.zeros((N_PARAMS, N_PARAMS))
    to_abs[:3, :3] = one
    for j in range(3):
        idx = [3 + j, 6 + j, 9 + j]
        to_abs[np.ix_(idx, idx)] = one
    return to_abs


def unpack(beta: np.ndarray) -> dict[str, np.ndarray]:
    """(12,3) per-axis columns -> named T36 parameters."""
    return {
        "S": beta[3:6].T.copy(),
        "K": beta[6:9].T.copy(),
        "K2": beta[9:12].T.copy(),
        "b_nt": beta[0].copy(),
        "kb_nt_per_c": beta[1].copy(),
        "kb2_nt_per_c2": beta[2].copy(),
    }


def pack(params: dict) -> np.ndarray:
    """Named T36 parameters -> (12,3) per-axis columns (the inverse of `unpack`)."""
    return np.vstack([params["b_nt"], params["kb_nt_per_c"], params["kb2_nt_per_c2"],
                      np.asarray(params["S"]).T, np.asarray(params["K"]).T, np.asarray(params["K2"]).T])


def _missing_field_direction(acc: T36Accumulator) -> np.ndarray | None:
    """The direction the reference field never varies along (unit vector), if any (as
    calib/models/gram.py)."""
    g = acc.gram
    mean_b = g[0, N_PARAMS:] / g[0, 0]
    cov_b = g[N_PARAMS:, N_PARAMS:] / g[0, 0] - np.outer(mean_b, mean_b)
    ev, evec = np.linalg.eigh(cov_b)
    return evec[:, 0] if ev[0] <= 1e-6 * max(ev[-1], 1e-300) else None


def _explain_null_space(null_vec: np.ndarray) -> str:
    groups: dict[str, float] = {}
    for name, wgt in zip(GROUP_OF_PARAM, null_vec**2, strict=True):
        groups[name] = groups.get(name, 0.0) + float(wgt)
    involved = [name for name, wgt in sorted(groups.items(), key=lambda kv: -kv[1]) if wgt > 0.05]
    what = f"{involved[0]} is" if len(involved) == 1 else f"{' and '.join(involved)} are"
    return (f"T36: the design is singular: {what} not identifiable from these samples; add field directions "
            "out of a plane at three or more temperature steps, or fit T24")


def fit_weighted(ds: Dataset, weights: np.ndarray | None, temp_ref_c: float | None):
    """(Calibration, vector residuals (N,3)) of a weighted T36 fit."""
    if ds.temp_c is None:
        raise DataError("T36 needs the DUT temperature of every sample (column temp); fit P12 without it")
    if ds.ref_nt is None:
        raise DataError("T36 needs the reference field vector of every sample (columns bx,by,bz)")
    acc = T36Accumulator(default_temp_ref_c(ds.temp_c) if temp_ref_c is None else temp_ref_c)
    acc.add(ds.h_nt, ds.temp_c, ds.ref_nt, weights)
    cal = acc.solve()
    residuals = cal.apply(ds.h_nt, ds.temp_c) - ds.ref_nt
    return cal, residuals


def reference_map(ds: Dataset, weights: np.ndarray | None, temp_ref_c: float):
    """The T36 parameters are linear in the reference vectors: the function from a change of the
    references (N,3) to the change of every parameter (as calib.models.t24.reference_map)."""
    x = t36_regressors(ds.h_nt, ds.temp_c, temp_ref_c)
    w = np.ones(len(ds)) if weights is None else np.asarray(weights, float)
    scale = np.linalg.norm(x * np.sqrt(w)[:, None], axis=0)
    xs = x / scale
    solve = np.linalg.solve(xs.T @ (xs * w[:, None]), (xs * w[:, None]).T) / scale[:, None]  # (12,N)
    to_abs = absolute_transform(temp_ref_c)

    def change(ref_change_nt: np.ndarray) -> dict[str, np.ndarray]:
        return unpack(to_abs @ (solve @ ref_change_nt))

    return change
