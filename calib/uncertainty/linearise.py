"""How a calibration's parameters move when its data move: the Jacobians uncertainty propagation needs.

    lin = linearised(ds, cal, weights)           # one per calibration
    lin.ref_jacobian(a_ref)                      # (P,Q): d params / d q for reference changes a_ref (N,3,Q) q
    lin.temp_jacobian(a_temp)                    # (P,Q): for temperature changes a_temp (N,Q) q
    lin.statistical_covariance()                 # (P,P): the fit's own covariance
    field_jacobian(cal, h_nt, temp_c)            # (G,3,P): d calibrated field / d params at G points

Parameters are flattened in the calibration's order (`ParamLayout`). What is exact and what is first order:

- T24 and T36 are linear in the references: theta = G^-1 X^T W B per axis, so a reference change A q moves
  them by exactly G^-1 X^T W A q (`exact_in_reference`). Their regressors hold the temperature, so a
  temperature change moves them to first order: d theta = G^-1 (dX^T W r - X^T W dX theta), r the
  residuals. Their statistical covariance is sigma_i^2 G^-1 per axis.
- P12's row fits regress the raw axis on the references: a reference change moves the regressors, to
  first order d c = G^-1 (dX^T W r - X^T W dX c) per row; k and the angles follow from the rows by central
  differences. It has no temperature.
- The scalar fit (Gauss-Newton, first order): d theta = -(J^T W J)^-1 J^T W dr, dr the change of the
  residuals |A (h - c)| - |B| the data change makes; its covariance sigma^2 (J^T W J)^-1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import calib.models.gram as gram
import calib.models.t36 as t36
from calib.calibration import Calibration
from calib.dataset import Dataset
from calib.equations import apply, p12_angles_from_rows, parameter_label, t24_regressors, t36_regressors
from calib.errors import FitError
from calib.models.scalar import UPPER, _residuals_jacobian, orientation_balance_weights
from calib.stats.residuals import known_norm
from calib.uncertainty.rowgroups import RowGroups


@dataclass(frozen=True)
class ParamLayout:
    """A calibration's parameters as one flat vector, in the calibration's order, each array row-major."""

    names: tuple[str, ...]
    shapes: tuple[tuple[int, ...], ...]

    @classmethod
    def of(cls, params: dict) -> ParamLayout:
        return cls(tuple(params), tuple(np.shape(v) for v in params.values()))

    @property
    def size(self) -> int:
        return sum(int(np.prod(s)) for s in self.shapes)

    def flatten(self, params: dict) -> np.ndarray:
        return np.concatenate([np.asarray(params[n], float).ravel() for n in self.names])

    def unflatten(self, vec: np.ndarray) -> dict[str, np.ndarray]:
        """(..., P) -> {name: (..., *shape)}."""
        out, at = {}, 0
        for name, shape in zip(self.names, self.shapes, strict=True):
            size = int(np.prod(shape))
            out[name] = vec[..., at:at + size].reshape(vec.shape[:-1] + shape)
            at += size
        return out

    def labels(self) -> list[str]:
        """`S[0][1]`-style names of the flat entries (calib/equations.py INDEXING)."""
        return [parameter_label(name, idx) for name, shape in zip(self.names, self.shapes, strict=True)
                for idx in np.ndindex(*shape)]


def linearised(ds: Dataset, cal: Calibration, weights: np.ndarray | None = None,
               noise_nt: np.ndarray | None = None):
    """The Jacobians of `cal`'s parameters with respect to its data (see the module doc); noise_nt (3,):
    the readings' noise in the field where it is known apart from the residual, which also holds a model
    error the caller budgets on its own (it would count twice): the fit's statistics then use it."""
    if cal.model in ("t24", "t36"):
        lin = LinearInReference(ds, cal, weights)
    elif cal.model == "p12":
        lin = P12Rows(ds, cal, weights)
    elif cal.model == "scalar":
        return ScalarGaussNewton(ds, cal, weights)
    else:
        raise FitError(f"no linearisation of model {cal.model!r}")
    if noise_nt is not None:
        lin.take_noise(noise_nt)
    return lin


def _scaled_inverse(g: np.ndarray, what: str) -> np.ndarray:
    d = np.sqrt(np.diag(g))
    if np.any(d == 0):
        raise FitError(f"{what}: a regressor is zero for every sample")
    w, v = np.linalg.eigh(g / np.outer(d, d))
    if w[0] < gram.RCOND_SINGULAR * w[-1]:
        raise FitError(f"{what}: the design is singular; no uncertainty can be propagated")
    return (v / w) @ v.T / np.outer(d, d)


def _weights(ds: Dataset, weights) -> np.ndarray:
    return np.ones(len(ds)) if weights is None else np.asarray(weights, float)


def _layout_index(layout: ParamLayout, unpack, rows: int) -> np.ndarray:
    """For each flat parameter, its index in the (rows, 3) per-axis coefficient array (row-major)."""
    index = unpack(np.arange(rows * 3, dtype=float).reshape(rows, 3))
    return np.rint(layout.flatten(index)).astype(int)


class LinearInReference:
    """T24 and T36: linear least squares per axis on regressors of (h, temperature), shared by the axes."""

    exact_in_reference = True

    def __init__(self, ds: Dataset, cal: Calibration, weights):
        self.layout = ParamLayout.of(cal.params)
        tr = float(cal.temp_ref_c)
        self.temp_degree = 1 if cal.model == "t24" else 2
        if cal.model == "t24":
            self.regressors = lambda h, t: t24_regressors(h, t, tr)
            to_abs, unpack = gram.absolute_transform(tr), gram.unpack
        else:
            self.regressors = lambda h, t: t36_regressors(h, t, tr)
            to_abs, unpack = t36.absolute_transform(tr), t36.unpack
        self.ds, self.w = ds, _weights(ds, weights)
        x = self.regressors(ds.h_nt, ds.temp_c)
        self.x, self.p = x, x.shape[1]
        xw = x * self.w[:, None]
        self.g_inv = _scaled_inverse(xw.T @ x, cal.model)
        self.theta = self.g_inv @ (xw.T @ ds.ref_nt)  # (p,3), centred temperature
        self.r = ds.ref_nt - x @ self.theta
        n_used = int(np.count_nonzero(self.w))
        self.sigma2 = np.sum(self.w[:, None] * self.r**2, axis=0) / (n_used - self.p)
        self.to_abs = to_abs
        self.reference_map = to_abs @ self.g_inv @ xw.T  # (p,N)
        self.index = _layout_index(self.layout, unpack, self.p)

    def take_noise(self, noise_nt: np.ndarray) -> None:
        """The fit's statistics from the readings' noise (3,) in the field, known apart from the residual."""
        self.sigma2 = np.broadcast_to(np.asarray(noise_nt, float) ** 2, (3,)).copy()

    def _flat(self, per_axis: np.ndarray) -> np.ndarray:
        """(p,3,Q) per-axis coefficient changes -> (P,Q) in the layout's order."""
        return per_axis.reshape(self.p * 3, -1)[self.index]

    def ref_jacobian(self, a_ref) -> np.ndarray:
        if isinstance(a_ref, RowGroups):
            return self._flat(np.einsum("gk,giq->kiq", a_ref.sums(self.reference_map.T), a_ref.per_group))
        return self._flat(np.einsum("kn,niq->kiq", self.reference_map, a_ref))

    def temp_jacobian(self, a_temp: np.ndarray) -> np.ndarray:
        t = self.ds.temp_c
        dx = 0.5 * (self.regressors(self.ds.h_nt, t + 1.0) - self.regressors(self.ds.h_nt, t - 1.0))  # exact
        slope = dx @ self.theta  # (N,3): d fitted field / d temperature at every sample
        out = np.empty((self.p, 3, a_temp.shape[1]))
        for i in range(3):
            m = dx.T * (self.w * self.r[:, i]) - self.x.T * (self.w * slope[:, i])  # (p,N)
            out[:, i] = self.to_abs @ (self.g_inv @ (m @ a_temp))
        return self._flat(out)

    def statistical_covariance(self) -> np.ndarray:
        c = self.to_abs @ self.g_inv @ self.to_abs.T
        full = np.einsum("kl,ij,j->kilj", c, np.eye(3), self.sigma2).reshape(self.p * 3, self.p * 3)
        return full[np.ix_(self.index, self.index)]


def _p12_params(coef: list[np.ndarray]) -> np.ndarray:
    """(k, angles_deg, h0_nt) from the three row fits' coefficients [m_i1..m_ii, h0_i]."""
    m = np.zeros((3, 3))
    for i, c in enumerate(coef):
        m[i, :i + 1] = c[:-1]
    k = np.linalg.norm(m, axis=1) * np.sign(np.diag(m))
    return np.concatenate([k, p12_angles_from_rows(m / k[:, None]), [c[-1] for c in coef]])


class P12Rows:
    """P12: raw axis i fitted on (B_1..B_i, 1); k, angles and b from the rows (first order in B)."""

    exact_in_reference = False

    def __init__(self, ds: Dataset, cal: Calibration, weights):
        self.layout = ParamLayout.of(cal.params)
        if self.layout.names != ("k", "angles_deg", "h0_nt"):
            raise FitError("P12: unexpected parameters " + ", ".join(self.layout.names))
        self.ds, self.w = ds, _weights(ds, weights)
        n_used = int(np.count_nonzero(self.w))
        self.rows = []
        for i in range(3):
            x = np.column_stack([ds.ref_nt[:, :i + 1], np.ones(len(ds))])
            g_inv = _scaled_inverse((x * self.w[:, None]).T @ x, f"P12 axis {i + 1}")
            c = g_inv @ ((x * self.w[:, None]).T @ ds.h_nt[:, i])
            r = ds.h_nt[:, i] - x @ c
            self.rows.append((x, g_inv, c, r, np.sum(self.w * r * r) / (n_used - (i + 2))))
        coef = [row[2] for row in self.rows]
        flat = np.concatenate(coef)
        self.jac = np.empty((9, flat.size))  # d (k, angles, b) / d (row coefficients), central differences
        for j in range(flat.size):
            step = 1e-6 * max(abs(flat[j]), 1e-3 * np.max(np.abs(flat)))
            up, down = flat.copy(), flat.copy()
            up[j] += step
            down[j] -= step
            self.jac[:, j] = (_p12_params(_split(up)) - _p12_params(_split(down))) / (2 * step)

    def take_noise(self, noise_nt: np.ndarray) -> None:
        """The rows' statistics from the noise (3,) of the fitted field, known apart from the residual
        (which holds what P12 cannot follow): raw axis i = sum_j m_ij B_j + b_i, so its noise is
        sqrt(sum_j m_ij^2 noise_j^2)."""
        noise2 = np.broadcast_to(np.asarray(noise_nt, float) ** 2, (3,))
        self.rows = [(x, g_inv, c, r, float(c[:-1] ** 2 @ noise2[:i + 1]))
                     for i, (x, g_inv, c, r, _) in enumerate(self.rows)]

    def ref_jacobian(self, a_ref) -> np.ndarray:
        parts = []
        for i, (x, g_inv, c, r, _) in enumerate(self.rows):
            if isinstance(a_ref, RowGroups):  # the same sums over the rows, taken per group first
                a = a_ref.per_group[:, :i + 1, :]  # (K, i+1, Q)
                sums = a_ref.sums(np.column_stack([self.w * r, x * self.w[:, None]]))  # (K, 1 + i+2)
                first = np.vstack([np.einsum("gjq,g->jq", a, sums[:, 0]), np.zeros((1, a.shape[2]))])
                parts.append(g_inv @ (first - sums[:, 1:].T @ np.einsum("gjq,j->gq", a, c[:-1])))
                continue
            a = a_ref[:, :i + 1, :]  # (N, i+1, Q): the change of the regressors B_1..B_i
            first = np.vstack([np.einsum("njq,n->jq", a, self.w * r), np.zeros((1, a.shape[2]))])
            moved = np.einsum("njq,j->nq", a, c[:-1])  # dX c
            parts.append(g_inv @ (first - (x * self.w[:, None]).T @ moved))
        return self.jac @ np.vstack(parts)

    def temp_jacobian(self, a_temp: np.ndarray) -> np.ndarray:
        return np.zeros((9, a_temp.shape[1]))

    def statistical_covariance(self) -> np.ndarray:
        blocks = [s2 * g_inv for (_, g_inv, _, _, s2) in self.rows]
        c = np.zeros((9, 9))
        at = 0
        for b in blocks:
            c[at:at + len(b), at:at + len(b)] = b
            at += len(b)
        return self.jac @ c @ self.jac.T


def _split(flat: np.ndarray) -> list[np.ndarray]:
    return [flat[:2], flat[2:5], flat[5:9]]


class ScalarGaussNewton:
    """The scalar fit |(A + t KA)(h - c - t kc)| = |B|, linearised at its solution (nT units)."""

    exact_in_reference = False

    def __init__(self, ds: Dataset, cal: Calibration, weights):
        self.layout = ParamLayout.of(cal.params)
        p = cal.params
        self.temp = "KA_per_c" in p
        parts = [p["A"][UPPER], p["c_nt"]] + ([p["KA_per_c"][UPPER], p["kc_nt_per_c"]] if self.temp else [])
        self.theta = np.concatenate(parts)
        self.t = (ds.temp_c - cal.temp_ref_c) if self.temp else np.zeros(len(ds))
        given = "field_norm_nt" in cal.stats or str(cal.stats.get("field_norm", "")).startswith("unknown")
        # |B| follows the reference vectors only when the fit took it from them
        # (calib.models.scalar.field_norm)
        self.norm_from_ref = not given and ds.ref_norm_nt is None and ds.ref_nt is not None
        if "field_norm_nt" in cal.stats:
            fn = np.full(len(ds), float(cal.stats["field_norm_nt"]))
        elif str(cal.stats.get("field_norm", "")).startswith("unknown"):
            fn = np.full(len(ds), float(np.mean(np.linalg.norm(cal.apply(ds.h_nt, ds.temp_c), axis=1))))
        else:
            fn = known_norm(ds)
        self.ds, self.fn = ds, fn
        w = _weights(ds, weights)
        if cal.stats.get("balance_orientations"):  # the balance weights, from the fitted field's directions
            w = w * orientation_balance_weights(cal.apply(ds.h_nt, ds.temp_c))
        self.w = w
        self.r, self.jac = _residuals_jacobian(self.theta, ds.h_nt, fn, self.t, self.temp)
        field = cal.apply(ds.h_nt, ds.temp_c)  # y = (A + t KA)(h - c - t kc), d r / d h = (A + t KA)^T y/|y|
        unit = field / np.linalg.norm(field, axis=1, keepdims=True)
        self.dr_dh = unit @ p["A"] + (self.t[:, None] * (unit @ p["KA_per_c"]) if self.temp else 0.0)
        self.n_inv = _scaled_inverse((self.jac * w[:, None]).T @ self.jac, "scalar")
        n_used = int(np.count_nonzero(w))
        self.sigma2 = float(np.sum(w * self.r**2) / (n_used - self.theta.size))
        self.select = self._selection()

    def _selection(self) -> np.ndarray:
        """(P, free): the named (flat) parameters as the free ones; A's lower entries are fixed at zero."""
        free = {"A": 6, "c_nt": 3, "KA_per_c": 6, "kc_nt_per_c": 3}
        sel = np.zeros((self.layout.size, self.theta.size))
        row, col = 0, 0
        for name, shape in zip(self.layout.names, self.layout.shapes, strict=True):
            if shape == (3, 3):
                for k, (i, j) in enumerate(zip(*UPPER, strict=True)):
                    sel[row + 3 * i + j, col + k] = 1.0
            else:
                sel[row:row + 3, col:col + 3] = np.eye(3)
            row += int(np.prod(shape))
            col += free[name]
        return sel

    def _through_fit(self, dr: np.ndarray) -> np.ndarray:
        """(P,Q) parameter change for residual changes dr (N,Q)."""
        return self.select @ (-self.n_inv @ ((self.jac * self.w[:, None]).T @ dr))

    def ref_jacobian(self, a_ref) -> np.ndarray:
        if not self.norm_from_ref:
            return np.zeros((self.layout.size, a_ref.shape[2]))
        unit = self.ds.ref_nt / np.linalg.norm(self.ds.ref_nt, axis=1, keepdims=True)
        if isinstance(a_ref, RowGroups):  # (J W)^T dr summed per group first, dr = -unit . a_ref
            jw_u = a_ref.sums((self.jac * self.w[:, None])[:, :, None] * unit[:, None, :])  # (K,free,3)
            return self.select @ (self.n_inv @ np.einsum("gfi,giq->fq", jw_u, a_ref.per_group))
        return self._through_fit(-np.einsum("ni,niq->nq", unit, a_ref))  # r = |y| - |B|

    def temp_jacobian(self, a_temp: np.ndarray) -> np.ndarray:
        if not self.temp:
            return np.zeros((self.layout.size, a_temp.shape[1]))
        step = 0.5
        up = _residuals_jacobian(self.theta, self.ds.h_nt, self.fn, self.t + step, True)[0]
        down = _residuals_jacobian(self.theta, self.ds.h_nt, self.fn, self.t - step, True)[0]
        return self._through_fit(((up - down) / (2 * step))[:, None] * a_temp)

    def reading_change(self, dh: np.ndarray) -> np.ndarray:
        """(m,P): first-order parameter changes for changes of the raw readings dh (m,N,3)."""
        return self._through_fit(np.einsum("nj,mnj->nm", self.dr_dh, dh)).T

    def statistical_covariance(self) -> np.ndarray:
        """sigma^2 N^-1 (J^T W^2 J) N^-1 (N = J^T W J): sigma^2 N^-1 when the weights are 0 or 1."""
        jw = self.jac * self.w[:, None]
        inner = self.n_inv @ (jw.T @ jw) @ self.n_inv
        return self.sigma2 * self.select @ inner @ self.select.T


def field_jacobian(cal: Calibration, h_nt: np.ndarray, temp_c: np.ndarray | None) -> np.ndarray:
    """(G,3,P): the calibrated field's derivative with respect to the flat parameters at raw readings h_nt
    (G,3) and temperatures (G,), by central differences (exact for T24 and T36, which are linear in their
    parameters at a fixed reading)."""
    layout = ParamLayout.of(cal.params)
    flat = layout.flatten(cal.params)
    typical = np.concatenate([np.full(int(np.prod(s)), np.mean(np.abs(cal.params[n])) + 1e-12)
                              for n, s in zip(layout.names, layout.shapes, strict=True)])
    out = np.empty((len(h_nt), 3, flat.size))
    for j in range(flat.size):
        step = 1e-5 * (abs(flat[j]) + typical[j])
        up, down = flat.copy(), flat.copy()
        up[j] += step
        down[j] -= step
        out[:, :, j] = (apply(cal.model, layout.unflatten(up), h_nt, temp_c, cal.temp_ref_c)
                        - apply(cal.model, layout.unflatten(down), h_nt, temp_c, cal.temp_ref_c)) / (2 * step)
    return out
