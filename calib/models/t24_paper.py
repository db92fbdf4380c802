"""The paper's own closed form for T24 (seed 000, equations 13-21), kept as a reference.

Raw sums with absolute tau, elimination of b and kb through (14), the 6x6 system (15), block elimination
(17)-(19) and Cramer's rule (20), (21). Exact in exact arithmetic; in floating point it loses digits when
the columns have very different scales or the temperature span is narrow, which is why calib.models.gram
centres and scales instead. `exact_solution` solves the same normal equations in high precision (mpmath) to
measure how many digits each method keeps.
"""

from __future__ import annotations

import itertools

import numpy as np


def _cramer(a: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    det = np.linalg.det(a)
    out = np.empty(len(rhs))
    for k in range(len(rhs)):
        ak = a.copy()
        ak[:, k] = rhs
        out[k] = np.linalg.det(ak) / det
    return out


def paper_solution(h_nt: np.ndarray, temp_c: np.ndarray, ref_nt: np.ndarray) -> dict[str, np.ndarray]:
    """T24 parameters (absolute tau) by the paper's formulas, in float64."""
    h, tau, big_b = np.asarray(h_nt, float), np.asarray(temp_c, float), np.asarray(ref_nt, float)
    n = float(len(h))
    t_sum, r_sum = tau.sum(), (tau**2).sum()
    a_sum, c_sum = big_b.sum(0), (tau[:, None] * big_b).sum(0)
    g_sum, h_sum, l_sum = (tau[:, None] * h).sum(0), h.sum(0), (tau[:, None] ** 2 * h).sum(0)
    m_mat = h.T @ h
    p_mat = (tau[:, None] * h).T @ h
    q_mat = (tau[:, None] ** 2 * h).T @ h
    d_mat = big_b.T @ h  # D_ij = sum B_i h_j
    f_mat = (tau[:, None] * big_b).T @ h
    den = t_sum**2 - n * r_sum
    alpha = np.empty((6, 3))
    beta = np.empty((6, 3))
    gamma = np.empty((6, 3))
    for j in range(3):
        for k in range(3):
            alpha[j, k] = (
                den * m_mat[k, j]
                + h_sum[j] * (r_sum * h_sum[k] - t_sum * g_sum[k])
                + g_sum[j] * (n * g_sum[k] - t_sum * h_sum[k])
            )
            alpha[j + 3, k] = (
                den * p_mat[k, j]
                + g_sum[j] * (r_sum * h_sum[k] - t_sum * g_sum[k])
                + l_sum[j] * (n * g_sum[k] - t_sum * h_sum[k])
            )
            beta[j, k] = (
                den * p_mat[k, j]
                + h_sum[j] * (r_sum * g_sum[k] - t_sum * l_sum[k])
                + g_sum[j] * (n * l_sum[k] - t_sum * g_sum[k])
            )
            beta[j + 3, k] = (
                den * q_mat[k, j]
                + g_sum[j] * (r_sum * g_sum[k] - t_sum * l_sum[k])
                + l_sum[j] * (n * l_sum[k] - t_sum * g_sum[k])
            )
        for i in range(3):
            gamma[j, i] = (
                den * d_mat[i, j]
                + h_sum[j] * (r_sum * a_sum[i] - t_sum * c_sum[i])
                + g_sum[j] * (n * c_sum[i] - t_sum * a_sum[i])
            )
            gamma[j + 3, i] = (
                den * f_mat[i, j]
                + g_sum[j] * (r_sum * a_sum[i] - t_sum * c_sum[i])
                + l_sum[j] * (n * c_sum[i] - t_sum * a_sum[i])
            )
    # rows j1<j2<j3 with a non-zero 3x3 minor in the first three columns: take the largest one
    first = max(itertools.combinations(range(6), 3), key=lambda rows: abs(np.linalg.det(alpha[list(rows)])))
    rest = [j for j in range(6) if j not in first]
    om11, om12 = alpha[list(first)], beta[list(first)]
    om21, om22 = alpha[rest], beta[rest]
    om11_inv = np.linalg.inv(om11)
    schur = om22 - om21 @ om11_inv @ om12  # (19)
    s_mat, k_mat = np.empty((3, 3)), np.empty((3, 3))
    b_vec, kb_vec = np.empty(3), np.empty(3)
    for i in range(3):
        g1, g2 = gamma[list(first), i], gamma[rest, i]
        lam = _cramer(schur, g2 - om21 @ om11_inv @ g1)  # (20)
        sig = _cramer(om11, g1 - om12 @ lam)  # (21)
        k_mat[i], s_mat[i] = lam, sig
        b_vec[i] = (
            t_sum * c_sum[i]
            - r_sum * a_sum[i]
            + (r_sum * h_sum - t_sum * g_sum) @ sig
            + (r_sum * g_sum - t_sum * l_sum) @ lam
        ) / den  # (14)
        kb_vec[i] = (
            t_sum * a_sum[i]
            - n * c_sum[i]
            + (n * g_sum - t_sum * h_sum) @ sig
            + (n * l_sum - t_sum * g_sum) @ lam
        ) / den
    return {"S": s_mat, "K": k_mat, "b_nt": b_vec, "kb_nt_per_c": kb_vec}


def exact_solution(h_nt, temp_c, ref_nt, dps: int = 60) -> dict[str, np.ndarray]:
    """The least-squares T24 solution computed with `dps` decimal digits (mpmath), rounded to float64.

    The inputs are taken as exact binary numbers; only test and benchmark code calls this.
    """
    import mpmath

    with mpmath.workdps(dps):
        rows = [
            [
                mpmath.mpf(1),
                mpmath.mpf(t),
                *(mpmath.mpf(x) for x in hv),
                *(mpmath.mpf(t) * mpmath.mpf(x) for x in hv),
            ]
            for hv, t in zip(
                np.asarray(h_nt, float).tolist(), np.asarray(temp_c, float).tolist(), strict=True
            )
        ]
        x = mpmath.matrix(rows)
        y = mpmath.matrix(np.asarray(ref_nt, float).tolist())
        gram = x.T * x
        rhs = x.T * y
        out = np.empty((8, 3))
        for i in range(3):
            col = mpmath.lu_solve(gram, rhs[:, i])
            out[:, i] = [float(v) for v in col]
    return {
        "S": out[2:5].T.copy(),
        "K": out[5:8].T.copy(),
        "b_nt": out[0].copy(),
        "kb_nt_per_c": out[1].copy(),
    }


def digits_kept(estimate: dict, exact: dict) -> float:
    """Worst-case number of correct significant digits over all parameters (relative to each block's size)."""
    worst = np.inf
    for key, ref in exact.items():
        err = np.max(np.abs(np.asarray(estimate[key]) - ref))
        size = np.max(np.abs(ref))
        worst = min(worst, 16.0 if err == 0 else -np.log10(err / size))
    return float(worst)
