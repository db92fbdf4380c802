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
  tolerance, a significant digit of that spread). A draw still moving after MAX_SCALAR_STEPS, or
  diverged, is taken on by Levenberg-Marquardt steps with its own Jacobian and a line search along each
  step (the fit's own method, for draws the fixed matrix is too far from: a turntable's scalar fit); one
  that does not converge there either counts as failed.
"""

from __future__ import annotations

import hashlib

import numpy as np

from calib.errors import FitError
from calib.uncertainty.linearise import LinearInReference, ScalarGaussNewton

MAX_TENSOR_TERMS = 4096  # q^(x k) terms kept per power before the sums are taken per draw instead
MAX_SCALAR_STEPS = 8
MAX_DAMPED_STEPS = 150
STEP_TOLERANCE = 1e-3
CHUNK_DRAWS = 512
# draws x rows a scalar refit holds at once: its (m,N,3) arrays stay near 25 MB (every draw is refitted on
# its own, so the chunks change nothing but the memory; with 141k rows a draw is 3.4 MB)
CHUNK_ROWS = 1 << 20
# draws x rows the damped refits take at once: each holds its Jacobians (P values a row), so that their
# arrays stay near 10 MB
DAMPED_ROWS = 1 << 16


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
        s = self.scale
        theta = _solve(g / np.outer(s, s), b / s[:, None]) / s[:, None]
        failed = ~np.all(np.isfinite(theta.reshape(m, -1)), axis=1)  # a singular draw's
        theta[failed] = 0.0
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

    def _calibrated(self, theta, h, t):
        """(A, KA (None without temperature terms), v = h - c - t kc, y = (A + t KA) v, |y|) of every draw
        at theta (m,P); h (m|1,3,N)."""
        a = _upper(theta[:, :6])
        v = h - theta[:, 6:9, None]
        ka = None
        if self.temp:
            v = v - t[:, None, :] * theta[:, 15:18, None]
            ka = _upper(theta[:, 9:15])
        y = a @ v
        if self.temp:
            y += t[:, None, :] * (ka @ v)
        return a, ka, v, y, np.sqrt(y[:, 0] ** 2 + y[:, 1] ** 2 + y[:, 2] ** 2)

    def _gradient(self, theta, h, fn, t):
        """J^T W r for every draw (m,P), in the column order of calib.models.scalar's Jacobian; h (m|1,3,N):
        the readings component by component (each a contiguous row, for the sums over the rows)."""
        a, ka, v, y, norm = self._calibrated(theta, h, t)
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
                    tolerance = STEP_TOLERANCE * np.maximum(self.u, _robust_spread(step))
                # a draw stops when its step is within the tolerance, or once it has diverged (not finite)
                going = ~np.all(np.abs(step) <= tolerance, axis=1) & np.all(np.isfinite(step), axis=1)
                moving = moving[going]
                if moving.size == 0:
                    break
        failed = np.zeros(m, bool)
        failed[moving] = True  # still moving after MAX_SCALAR_STEPS, or diverged
        failed |= ~np.all(np.isfinite(theta), axis=1)
        for part in np.array_split(np.flatnonzero(failed), -(-failed.sum() * h.shape[2] // DAMPED_ROWS) or 1):
            if part.size:  # the fixed matrix was too far from these draws' own: damped steps of their own
                theta[part], failed[part] = self._damped(theta[part], _rows(h, part), fn[part], t[part],
                                                         tolerance)
        return theta, failed

    def _damped(self, start, h, fn, t, tolerance) -> tuple[np.ndarray, np.ndarray]:
        """Levenberg-Marquardt for each draw with the draw's own Jacobian (as calib.models.scalar fits), from
        where the fixed-matrix steps left it if that fits it better than the calibration's solution:
        (solutions (d,P), failed (d,)). A draw is done when its Gauss-Newton step is within the tolerance; one
        that no step lowers the cost of (however damped) short of that, still going after MAX_DAMPED_STEPS, or
        not finite, is failed."""
        w = self.lin.w

        def at(rows, x, jacobian=False):
            return self._residuals(x, _rows(h, rows), fn[rows], t[rows], jacobian)

        def cost_at(rows, x):
            return np.sum(w * at(rows, x) ** 2, axis=1)

        every = np.arange(len(fn))
        theta = np.repeat(self.lin.theta[None], len(fn), axis=0)
        done, failed, mu = np.zeros(len(fn), bool), np.zeros(len(fn), bool), np.full(len(fn), 1e-3)
        eye = np.eye(theta.shape[1])
        with np.errstate(over="ignore", invalid="ignore"):
            nearer = cost_at(every, start) < cost_at(every, theta)
            theta[nearer] = start[nearer]
            r, jac = at(every, theta, jacobian=True)
            cost = np.sum(w * r**2, axis=1)
            for _ in range(MAX_DAMPED_STEPS):
                going = np.flatnonzero(~done & ~failed)
                if going.size == 0:
                    break
                jw = jac[going] * w
                normal, grad = jw @ jac[going].transpose(0, 2, 1), np.einsum("dpn,dn->dp", jw, r[going])
                scale = np.sqrt(np.maximum(np.einsum("dpp->dp", normal), np.finfo(float).tiny))
                normal /= scale[:, :, None] * scale[:, None, :]
                newton = _solve(normal, grad / scale) / scale
                close = np.all(np.abs(newton) <= tolerance, axis=1)
                theta[going[close]] -= newton[close]  # the last step, within the tolerance
                done[going[close]] = True
                going, normal, grad, scale = going[~close], normal[~close], grad[~close], scale[~close]
                step = -_solve(normal + mu[going, None, None] * eye, grad / scale) / scale
                trial, cost_new = _along(lambda x, g=going: cost_at(g, x), theta[going], step,
                                         2 * np.sum(grad * step, axis=1), cost[going])
                better = cost_new <= cost[going]  # NaN: not better
                took = going[better]
                theta[took], cost[took] = trial[better], cost_new[better]
                r[took], jac[took] = at(took, theta[took], jacobian=True)
                mu[took] = np.maximum(mu[took] / 10, 1e-12)
                mu[going[~better]] *= 10
                failed |= (mu > 1e10) | ~np.all(np.isfinite(theta), axis=1)
        return theta, failed | ~done

    def _residuals(self, theta, h, fn, t, jacobian=False):
        """The residuals |y| - |B| (d,N) of the drawn data at theta (d,P), h (d|1,3,N), and with jacobian
        their Jacobians (d,P,N), in calib.models.scalar's column order."""
        a, ka, v, y, norm = self._calibrated(theta, h, t)
        if not jacobian:
            return norm - fn
        unit = y / norm[:, None, :]
        jac = np.empty((len(theta), theta.shape[1], norm.shape[1]))
        for k, (i, j) in enumerate(zip(*np.triu_indices(3), strict=True)):
            jac[:, k] = unit[:, i] * v[:, j]
        at_u = a.transpose(0, 2, 1) @ unit  # (A + t KA)^T y/|y|
        if self.temp:
            at_u += t[:, None, :] * (ka.transpose(0, 2, 1) @ unit)
            jac[:, 9:15] = t[:, None, :] * jac[:, :6]
            jac[:, 15:18] = -t[:, None, :] * at_u
        jac[:, 6:9] = -at_u
        return norm - fn, jac


def _along(cost_at, theta, step, slope, cost) -> tuple[np.ndarray, np.ndarray]:
    """(theta, cost) at the better of the full step and the minimum of the cost's parabola along it (from
    the cost, its slope and the full step's cost). Where the Gauss-Newton model leaves out the large
    residuals' curvature, its steps overshoot a narrow valley (a turntable's scalar fit: offset against
    scale along the axis the site field never reverses) and zigzag down it for hundreds of steps; the
    parabola's minimum takes a few."""
    full = theta + step
    full_cost = cost_at(full)
    curve = full_cost - cost - slope
    alpha = np.where(curve > 0, np.clip(-slope / (2 * np.where(curve > 0, curve, 1.0)), 0.1, 1.0), 1.0)
    part = theta + alpha[:, None] * step
    part_cost = cost_at(part)
    take = part_cost < full_cost
    return np.where(take[:, None], part, full), np.where(take, part_cost, full_cost)


def _rows(h: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """The readings of these draws: h (m|1,3,N), one set shared by every draw when m is 1."""
    return h[rows] if h.shape[0] > 1 else h


def _robust_spread(x: np.ndarray) -> np.ndarray:
    """The spread of the rows of x (m,P) by their median absolute deviation (x1.4826: the standard deviation
    of normal draws), of the finite rows only: a draw far off or not finite does not loosen (or, NaN,
    void) every other draw's tolerance."""
    x = x[np.all(np.isfinite(x), axis=1)]
    if len(x) < 2:
        return np.zeros(x.shape[1])
    return 1.4826 * np.median(np.abs(x - np.median(x, axis=0)), axis=0)


def _solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a^-1 b per draw (a (m,P,P), b (m,P) or (m,P,K)); a singular draw's solution is NaN (then failed), not
    an error for every draw: one singular draw spoils the stacked solve, so the draws are then solved one by
    one."""
    column = b.ndim == 2
    rhs = b[:, :, None] if column else b
    try:
        x = np.linalg.solve(a, rhs)
    except np.linalg.LinAlgError:
        x = np.full(rhs.shape, np.nan)
        for i in range(len(a)):
            try:
                x[i] = np.linalg.solve(a[i], rhs[i])
            except np.linalg.LinAlgError:
                continue
    return x[:, :, 0] if column else x


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
    lin = getattr(lin, "plain", lin)  # a corrected linearisation's refits are its plain fit's (second order)
    if isinstance(lin, ScalarGaussNewton):
        return ScalarRefit(lin)
    if isinstance(lin, LinearInReference) and a_temp is not None:
        # the law's check (calib/uncertainty/lawcheck.py) and the Monte Carlo refit the same temperature
        # sources: their sums over the rows are taken once per linearisation and sensitivity
        a_temp = np.ascontiguousarray(a_temp, float)
        key = (a_temp.shape, hashlib.blake2b(a_temp.tobytes(), digest_size=16).digest())
        made = lin.__dict__.setdefault("_temperature_refits", {})
        if key not in made:
            made[key] = TemperatureRefit(lin, a_temp)
        return made[key]
    if a_temp is not None and np.any(a_temp):
        raise FitError("temperature changes of a model without temperature terms")
    return None
