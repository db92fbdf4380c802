"""Refits of many Monte Carlo draws at once, using the structure of each model instead of calling the fit.

- `TemperatureRefit` (T24, T36): drawn temperature changes d_n = a_n . q move the regressors to
  x(t + d) = X0 + d X1 (+ d^2 X2 for T36) exactly, so the Gram and the right-hand sides are polynomials in
  q whose coefficients are sums over the samples, taken once: every draw then costs a few small matrix
  products and a 12x12 solve, whatever the number of samples. The refit is exact (not linearised).
- `ScalarRefit`: the scalar fit re-solved for every draw by Newton-type steps from the calibration's own
  solution (warm start) with the exact gradient J^T W r of the drawn data and the step matrix
  (J^T W J)^-1 taken once at the solution: the fixed point is the drawn data's least-squares solution;
  the steps shrink by the factor the Jacobian moves (~1e-4 for noise alone; ~0.05 where an uncommissioned
  coil matrix moves it by 1 %). A draw stops when its step is below STEP_TOLERANCE of every parameter's
  scale: its statistical uncertainty, or how far the draws' first steps spread, whichever is larger (a
  thousandth of what the draws move a parameter by is far inside the Monte Carlo's own numerical
  tolerance, a significant digit of that spread). One still moving after MAX_SCALAR_STEPS counts as
  failed.
"""

from __future__ import annotations

import hashlib

import numpy as np

from calib.errors import FitError
from calib.linearise import LinearInReference, ScalarGaussNewton

MAX_TENSOR_TERMS = 4096  # q^(x k) terms kept per power before the sums are taken per draw instead
MAX_SCALAR_STEPS = 8
STEP_TOLERANCE = 1e-3
CHUNK_DRAWS = 512
# draws x rows a scalar refit holds at once: its (m,N,3) arrays stay near 25 MB (every draw is refitted on
# its own, so the chunks change nothing but the memory; with 141k rows a draw is 3.4 MB)
CHUNK_ROWS = 1 << 20


def draw_chunks(m: int, n: int) -> list[slice]:
    """The m draws of data of n rows in chunks of at most CHUNK_DRAWS draws and CHUNK_ROWS rows."""
    size = max(1, min(CHUNK_DRAWS, CHUNK_ROWS // max(n, 1)))
    return [slice(lo, min(lo + size, m)) for lo in range(0, m, size)]


def _kron_power(a: np.ndarray, k: int) -> np.ndarray:
    """Rows of a (N,Q) raised to the k-th Kronecker power: (N, Q^k)."""
    out = np.ones((a.shape[0], 1))
    for _ in range(k):
        out = np.einsum("na,nb->nab", out, a).reshape(a.shape[0], -1)
    return out


class TemperatureRefit:
    """Exact T24 / T36 refits for temperatures changed by a_temp q (q (m,Q) per draw)."""

    def __init__(self, lin: LinearInReference, a_temp: np.ndarray):
        ds, w, reg = lin.ds, lin.w, lin.regressors
        t = ds.temp_c
        x0, up, down = reg(ds.h_nt, t), reg(ds.h_nt, t + 1.0), reg(ds.h_nt, t - 1.0)
        xs = [x0, 0.5 * (up - down), 0.5 * (up + down) - x0]  # x(t + d) = sum_j d^j xs[j], exactly
        degree = lin.temp_degree  # T24's regressors are linear in t, T36's quadratic
        xs = xs[:degree + 1]
        p = lin.p
        self.lin, self.p, self.a = lin, p, a_temp
        self.g0 = (xs[0] * w[:, None]).T @ xs[0]
        self.b0 = (xs[0] * w[:, None]).T @ ds.ref_nt
        self.scale = np.sqrt(np.diag(self.g0))
        self.theta0 = self._solve(self.g0[None], self.b0[None])[0]
        self.terms = []  # (power k, coefficient tensor (Q^k or N, p*p + 3p)) per power k >= 1
        for k in range(1, 2 * degree + 1):
            pairs = [(j, k - j) for j in range(max(0, k - degree), min(k, degree) + 1)]
            if a_temp.shape[1] ** k <= MAX_TENSOR_TERMS:  # the weighted sums, one (p,p) product each
                kron = _kron_power(a_temp, k) * w[:, None]
                coef = np.zeros((kron.shape[1], p * p + 3 * p))
                for i in range(kron.shape[1]):
                    coef[i, :p * p] = sum((xs[j] * kron[:, i, None]).T @ xs[l] for j, l in pairs).ravel()
                    if k <= degree:
                        coef[i, p * p:] = ((xs[k] * kron[:, i, None]).T @ ds.ref_nt).ravel()
                self.terms.append((k, True, coef))
                continue
            both = sum(xs[j][:, :, None] * xs[l][:, None, :] for j, l in pairs).reshape(len(t), -1)
            rhs = (xs[k][:, :, None] * ds.ref_nt[:, None, :]).reshape(len(t), -1) if k <= degree else \
                np.zeros((len(t), 3 * p))
            self.terms.append((k, False, np.column_stack([both, rhs]) * w[:, None]))

    def _solve(self, g: np.ndarray, b: np.ndarray) -> np.ndarray:
        s = self.scale
        return np.linalg.solve(g / np.outer(s, s), b / s[:, None]) / s[:, None]

    def __call__(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(parameter changes (m,P) in the layout's order, failed (m,))."""
        m, p = q.shape[0], self.p
        total = np.zeros((m, p * p + 3 * p))
        d = None
        for k, tensor, coef in self.terms:
            if tensor:
                total += _kron_power(q, k) @ coef
            else:
                d = q @ self.a.T if d is None else d
                total += (d**k) @ coef
        g = self.g0 + total[:, :p * p].reshape(m, p, p)
        b = self.b0 + total[:, p * p:].reshape(m, p, 3)
        failed = np.zeros(m, bool)
        try:
            theta = self._solve(g, b)
        except np.linalg.LinAlgError:  # one singular draw spoils the stacked solve: solve them one by one
            theta = np.zeros((m, p, 3))
            for i in range(m):
                try:
                    theta[i] = self._solve(g[i:i + 1], b[i:i + 1])[0]
                except np.linalg.LinAlgError:
                    failed[i] = True
        change = np.einsum("ab,mbi->mai", self.lin.to_abs, theta - self.theta0)
        return change.reshape(m, -1)[:, self.lin.index], failed


class ScalarRefit:
    """Scalar refits of drawn data: readings h + dh, reference norms |ref + dref| (when the fit took |B|
    from the references), temperatures t + dt; every argument (m,N,3), (m,N,3) or (m,N), or None."""

    def __init__(self, lin: ScalarGaussNewton):
        self.lin = lin
        self.step = lin.n_inv  # (P,P), symmetric
        self.u = np.sqrt(np.diag(lin.n_inv) * lin.sigma2)
        self.temp = lin.temp

    def _gradient(self, theta, h, fn, t):
        """J^T W r for every draw (m,P), in the column order of calib.scalar's Jacobian; h (m|1,3,N): the
        readings component by component (each a contiguous row: 3x3 products on long arrays stay
        element-wise, which numpy's batched matmul would not)."""
        a = _upper(theta[:, :6])
        c = theta[:, 6:9, None]
        v = h - c if not self.temp else h - c - t[:, None, :] * theta[:, 15:18, None]
        y = _times(a, v)
        if self.temp:
            ka = _upper(theta[:, 9:15])
            y += t[:, None, :] * _times(ka, v)
        norm = np.sqrt(y[:, 0] ** 2 + y[:, 1] ** 2 + y[:, 2] ** 2)
        wu = y * (self.lin.w * (norm - fn) / norm)[:, None, :]  # w r u, u = y / |y|
        g_a = _upper_sums(wu, v)
        su = wu.sum(axis=2)
        if not self.temp:
            return np.column_stack([g_a, -np.einsum("mji,mj->mi", a, su)])
        wut = wu * t[:, None, :]
        g_ka = _upper_sums(wut, v)
        sut = wut.sum(axis=2)
        sutt = np.einsum("min,mn->mi", wut, t)
        g_c = -(np.einsum("mji,mj->mi", a, su) + np.einsum("mji,mj->mi", ka, sut))
        g_kc = -(np.einsum("mji,mj->mi", a, sut) + np.einsum("mji,mj->mi", ka, sutt))
        return np.column_stack([g_a, g_c, g_ka, g_kc])

    def own_solution(self) -> np.ndarray | None:
        """The least-squares solution (P free,) of the data as they are, by the same steps from lin.theta
        (None if they do not converge): what draws move from where lin.theta is not that data's own
        solution (a thinned dataset)."""
        theta, failed = self._refitted(np.zeros((1, len(self.lin.ds), 3)), None, None)
        return None if failed[0] else theta[0]

    def __call__(self, dh=None, dref=None, dt=None) -> tuple[np.ndarray, np.ndarray]:
        """(parameter changes (m,P) in the layout's order, failed (m,))."""
        theta, failed = self._refitted(dh, dref, dt)
        return (theta - self.lin.theta) @ self.lin.select.T, failed

    def _refitted(self, dh, dref, dt) -> tuple[np.ndarray, np.ndarray]:
        """(the drawn datasets' solutions (m,P free), failed (m,))."""
        lin = self.lin
        m = next(x.shape[0] for x in (dh, dref, dt) if x is not None)
        h = lin.ds.h_nt[None] if dh is None else lin.ds.h_nt[None] + dh
        h = np.ascontiguousarray(h.transpose(0, 2, 1))  # (m|1,3,N)
        if dref is not None and lin.norm_from_ref:
            fn = np.linalg.norm(lin.ds.ref_nt[None] + dref, axis=2)
        else:
            fn = np.broadcast_to(lin.fn, (m, len(lin.fn)))
        t = np.broadcast_to(lin.t, (m, len(lin.t))) if dt is None or not self.temp else lin.t + dt
        theta = np.repeat(lin.theta[None], m, axis=0)
        moving = np.arange(m)  # the draws still taking steps
        tolerance = STEP_TOLERANCE * self.u
        with np.errstate(over="ignore", invalid="ignore"):  # a draw that diverges is counted failed below
            for k in range(MAX_SCALAR_STEPS):
                step = self._gradient(theta[moving], h[moving] if h.shape[0] > 1 else h, fn[moving],
                                      t[moving]) @ self.step
                theta[moving] -= step
                if k == 0 and m > 1:  # the draws' spread: the first step is the first-order map of each draw
                    tolerance = STEP_TOLERANCE * np.maximum(self.u, np.std(step, axis=0))
                # a draw stops when its step is within the tolerance, or once it has diverged (not finite)
                going = ~np.all(np.abs(step) <= tolerance, axis=1) & np.all(np.isfinite(step), axis=1)
                moving = moving[going]
                if moving.size == 0:
                    break
        failed = np.zeros(m, bool)
        failed[moving] = True  # still moving after MAX_SCALAR_STEPS: not converged
        failed |= ~np.all(np.isfinite(theta), axis=1)
        return theta, failed


def _times(mat: np.ndarray, x: np.ndarray) -> np.ndarray:
    """mat @ x per draw, mat (m,3,3), x (m|1,3,N) component by component."""
    out = np.empty((max(len(mat), len(x)),) + x.shape[1:])
    for i in range(3):
        out[:, i] = (mat[:, i, 0, None] * x[:, 0] + mat[:, i, 1, None] * x[:, 1]
                     + mat[:, i, 2, None] * x[:, 2])
    return out


def _upper_sums(x: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(m,6): sum over the rows of x_i v_j for the upper entries (i, j); x, v (m,3,N)."""
    upper = np.triu_indices(3)
    return np.column_stack([np.einsum("mn,mn->m", x[:, i], v[:, j]) for i, j in zip(*upper, strict=True)])


def _upper(entries: np.ndarray) -> np.ndarray:
    """(m,6) upper-triangular entries (row by row) -> (m,3,3)."""
    out = np.zeros((entries.shape[0], 3, 3))
    out[:, np.triu_indices(3)[0], np.triu_indices(3)[1]] = entries
    return out


def refit_for(lin, a_temp: np.ndarray | None):
    """The batch refit a model's Monte Carlo draws need, or None when its draws are linear maps."""
    if isinstance(lin, ScalarGaussNewton):
        return ScalarRefit(lin)
    if isinstance(lin, LinearInReference) and a_temp is not None:
        # the law's check (calib/lawcheck.py) and the Monte Carlo refit the same temperature sources: their
        # sums over the rows are taken once per linearisation and sensitivity
        a_temp = np.ascontiguousarray(a_temp, float)
        key = (a_temp.shape, hashlib.blake2b(a_temp.tobytes(), digest_size=16).digest())
        made = lin.__dict__.setdefault("_temperature_refits", {})
        if key not in made:
            made[key] = TemperatureRefit(lin, a_temp)
        return made[key]
    if a_temp is not None and np.any(a_temp):
        raise FitError("temperature changes of a model without temperature terms")
    return None
