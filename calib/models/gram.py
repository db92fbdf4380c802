"""Streaming T24 least squares: an 11x11 Gram matrix of [1, t, h, t h, B] summed over samples.

t = T - temp_ref_c (the temperature centred at a reference fixed before any data arrives), so the
accumulator is exact under merging and never holds samples: memory does not grow with N. The 8x8 block
of the regressors x = [1, t, h1, h2, h3, t h1, t h2, t h3] is the paper's Gram matrix G (with centred
tau), the x-B block holds the three right-hand sides and the B-B block gives the residual sum of squares
without a second pass. The sums come from one fused pass over the raw columns (calib.models.gram_kernel).
"""

from __future__ import annotations

import numpy as np

from calib.calibration import Calibration
from calib.errors import DataError, FitError
from calib.models.gram_kernel import gram_sums

N_PARAMS = 8  # per output axis: b, kb, S_i1..3, K_i1..3
MIN_TEMP_SPAN_C = 0.5  # below this the temperature terms are not identifiable
RCOND_SINGULAR = 1e-13  # of the column-scaled Gram: below it the design is treated as singular
RCOND_WARN = 1e-9
AXES = "xyz"
PARAM_NAMES = ["b", "kb", "S1", "S2", "S3", "K1", "K2", "K3"]
GROUP_OF_PARAM = ["offset b", "offset drift kb", "S", "S", "S", "K", "K", "K"]


class SumsAccumulator:
    """What every streaming least-squares accumulator shares: the Gram of [x, B] centred at a fixed
    temperature, merging, and a solve through the model's scaled system (`_system`)."""

    SIZE = 0  # regressors per axis + the three right-hand sides
    NAME = ""  # in messages: "Gram sums", "T36 sums"

    def __init__(self, temp_ref_c: float = 25.0):
        self.temp_ref_c = float(temp_ref_c)
        self.gram = np.zeros((self.SIZE, self.SIZE))
        self.n = 0
        self.temp_min_c = np.inf
        self.temp_max_c = -np.inf

    def _system(self):
        raise NotImplementedError

    def merge(self, other):
        """Add another accumulator's sums into this one (same reference temperature required)."""
        if other.temp_ref_c != self.temp_ref_c:
            raise FitError(f"cannot merge {self.NAME} centred at {other.temp_ref_c} degC into sums centred "
                           f"at {self.temp_ref_c} degC")
        self.gram += other.gram
        self.n += other.n
        self.temp_min_c = min(self.temp_min_c, other.temp_min_c)
        self.temp_max_c = max(self.temp_max_c, other.temp_max_c)
        return self

    def identifiability(self) -> str | None:
        """None when a fit can be made, else a sentence saying what cannot be identified and why."""
        try:
            self._system()
        except FitError as err:
            return str(err)
        return None

    def solve(self) -> Calibration:
        """The calibration from the sums so far, or FitError naming the parameters the data cannot fix."""
        return self._system().calibration()


class GramAccumulator(SumsAccumulator):
    """Sums for a T24 fit. add() chunks, merge() accumulators, solve() at any time (cheap: 8x8 algebra)."""

    SIZE = 11
    NAME = "Gram sums"

    def _system(self):
        return _ScaledSystem(self)

    def add(self, h_nt, temp_c, ref_nt, weights=None) -> None:
        """Add samples: h (N,3) raw nT, temp_c (N,) or scalar degC, ref_nt (N,3) nT, optional weights (N,)."""
        h = np.asarray(h_nt, dtype=float).reshape(-1, 3)
        ref = np.asarray(ref_nt, dtype=float).reshape(-1, 3)
        if ref.shape != h.shape:
            raise DataError(f"reference field has {ref.shape[0]} rows, readings have {h.shape[0]}")
        if h.shape[0] == 0:
            return
        t = np.asarray(temp_c, dtype=float)
        t = t.reshape(1) if t.size == 1 else np.broadcast_to(t, (h.shape[0],))  # (1,): one temperature
        w = None if weights is None else np.broadcast_to(np.asarray(weights, dtype=float), (h.shape[0],))
        gram, n_used, t_min, t_max = gram_sums(h, t, ref, w, self.temp_ref_c)
        if n_used == 0:
            return
        self.gram += gram
        self.n += n_used  # rows with zero weight (flagged outliers) do not count
        self.temp_min_c = min(self.temp_min_c, t_min)
        self.temp_max_c = max(self.temp_max_c, t_max)

class _ScaledSystem:
    """The normal equations with columns scaled to unit diagonal, checked for identifiability."""

    def __init__(self, acc: GramAccumulator):
        n = acc.n
        if n <= N_PARAMS:
            raise FitError(
                f"T24: {n} samples, more than {N_PARAMS} needed (8 parameters per axis); collect more points"
            )
        span = acc.temp_max_c - acc.temp_min_c
        if span < MIN_TEMP_SPAN_C:
            mid = 0.5 * (acc.temp_max_c + acc.temp_min_c)
            raise FitError(
                f"T24: all samples within {span:.2f} degC (at {mid:.1f} degC): the temperature terms "
                "K and kb are not identifiable; add a temperature step or fit P12"
            )
        flat = _missing_field_direction(acc)
        if flat is not None:
            raise FitError(
                "T24: the reference field spans fewer than three directions (nothing along "
                f"[{flat[0]:.2f}, {flat[1]:.2f}, {flat[2]:.2f}]): the matrices S and K are not identifiable; "
                "add coil directions out of that plane"
            )
        self.acc = acc
        g = acc.gram[:N_PARAMS, :N_PARAMS]
        d = np.sqrt(np.diag(g))
        if np.any(d == 0):
            zero = [PARAM_NAMES[i] for i in np.flatnonzero(d == 0)]
            raise FitError(f"T24: regressors {', '.join(zero)} are zero for every sample")
        gs = g / np.outer(d, d)
        w, v = np.linalg.eigh(gs)
        self.rcond = float(w[0] / w[-1])
        if self.rcond < RCOND_SINGULAR:
            raise FitError(_explain_null_space(acc, v[:, 0]))
        self.d = d
        self.gs_inv = (v / w) @ v.T  # inverse of the scaled Gram
        rhs = acc.gram[:N_PARAMS, N_PARAMS:] / d[:, None]
        # one step of iterative refinement recovers the digits lost in the eigen-solve
        beta_s = self.gs_inv @ rhs
        beta_s += self.gs_inv @ (rhs - gs @ beta_s)
        self.beta = beta_s / d[:, None]  # (8,3): column i holds axis i's [b', kb, S'_i., K_i.]

    def residual_ss(self) -> np.ndarray:
        """Residual sum of squares per axis, from the sums: B'B - beta' X'B (normal equations hold)."""
        g = self.acc.gram
        bb = np.diag(g[N_PARAMS:, N_PARAMS:])
        xb = g[:N_PARAMS, N_PARAMS:]
        return np.maximum(bb - np.einsum("pi,pi->i", self.beta, xb), 0.0)

    def raw_ss(self) -> np.ndarray:
        """Sum of squares of (h - B) per axis: the misfit of an uncalibrated sensor."""
        g = self.acc.gram
        hh = np.diag(g[2:5, 2:5])
        bb = np.diag(g[N_PARAMS:, N_PARAMS:])
        hb = np.diag(g[2:5, N_PARAMS:])
        return np.maximum(hh - 2 * hb + bb, 0.0)

    def calibration(self) -> Calibration:
        """Parameters in the absolute-tau convention, covariance sigma^2 G^-1 carried over to them."""
        acc = self.acc
        rss = self.residual_ss()
        sigma2 = rss / (acc.n - N_PARAMS)
        cov_centred = self.gs_inv / np.outer(self.d, self.d)
        tr = acc.temp_ref_c
        to_abs = absolute_transform(tr)
        beta_abs = to_abs @ self.beta
        cov_abs = to_abs @ cov_centred @ to_abs.T
        se = np.sqrt(np.outer(np.diag(cov_abs), sigma2))  # (8,3)
        params = unpack(beta_abs)
        std_errors = unpack(se)
        n = acc.n
        stats = {
            "n": n,
            "n_used": n,
            "n_outliers": 0,
            "rms_before_nt": float(np.sqrt(self.raw_ss().sum() / (3 * n))),
            "rms_after_nt": float(np.sqrt(rss.sum() / (3 * n))),
            "sigma_nt": {a: float(np.sqrt(s)) for a, s in zip(AXES, sigma2, strict=True)},
            "per_axis": {a: {"rms_after_nt": float(np.sqrt(r / n))} for a, r in zip(AXES, rss, strict=True)},
            "temp_span_c": [float(acc.temp_min_c), float(acc.temp_max_c)],
            "rcond_scaled_gram": self.rcond,
        }
        if self.rcond < RCOND_WARN:
            stats["warnings"] = [f"poorly conditioned design (rcond {self.rcond:.1e}); check the std errors"]
        return Calibration(
            model="t24",
            params=params,
            std_errors=std_errors,
            temp_ref_c=tr,
            stats=stats,
            source={"kind": "gram"},
        )


def absolute_transform(temp_ref_c: float) -> np.ndarray:
    """The 8x8 map from the centred-tau parameters [b', kb, S'_i., K_i.] to the absolute-tau ones:
    b = b' - tr kb, S = S' - tr K (tr the reference temperature); covariances go as A C A^T."""
    to_abs = np.eye(N_PARAMS)
    to_abs[0, 1] = -temp_ref_c
    to_abs[2:5, 5:8] = -temp_ref_c * np.eye(3)
    return to_abs


def unpack(beta: np.ndarray) -> dict[str, np.ndarray]:
    """(8,3) per-axis columns -> named T24 parameters."""
    return {
        "S": beta[2:5].T.copy(),
        "K": beta[5:8].T.copy(),
        "b_nt": beta[0].copy(),
        "kb_nt_per_c": beta[1].copy(),
    }


def _missing_field_direction(acc: GramAccumulator) -> np.ndarray | None:
    """The direction the reference field never varies along (unit vector), if any.

    Judged on the reference vectors, which carry no sensor noise, so a planar coil sequence is caught
    even though noisy raw readings scatter out of the plane.
    """
    g = acc.gram
    mean_b = g[0, N_PARAMS:] / acc.n
    cov_b = g[N_PARAMS:, N_PARAMS:] / acc.n - np.outer(mean_b, mean_b)
    ev, evec = np.linalg.eigh(cov_b)
    return evec[:, 0] if ev[0] <= 1e-6 * max(ev[-1], 1e-300) else None


def _explain_null_space(acc: GramAccumulator, null_vec: np.ndarray) -> str:
    """A sentence naming the parameters a (near-)singular design cannot separate, and what would help."""
    weight = null_vec**2
    groups: dict[str, float] = {}
    for name, wgt in zip(GROUP_OF_PARAM, weight, strict=True):
        groups[name] = groups.get(name, 0.0) + float(wgt)
    involved = [name for name, wgt in sorted(groups.items(), key=lambda kv: -kv[1]) if wgt > 0.05]
    hint = "add field directions out of a plane at two or more temperature steps, or fit P12"
    what = f"{involved[0]} is" if len(involved) == 1 else f"{' and '.join(involved)} are"
    return f"T24: the design is singular: {what} not identifiable from these samples; {hint}"
