"""The fused pass of the streaming T24 fit: the 11x11 Gram's moments straight from the raw columns.

Per sample, y = [1, h1, h2, h3, B1, B2, B3] (each times sqrt(weight) when weighted) and t = T - temp_ref.
Every entry of the Gram of x = [1, t, h, t h, B] is a sum of t^k y_a y_b with k = 0, 1 or 2, and only 60
of them are distinct: k = 0 for all pairs of y (28), k = 1 for pairs with a in (1, h) (22), k = 2 for
pairs within (1, h) (10). The compiled kernel copies a block of rows into an L1-resident column buffer
(the raw values only: no design matrix), then makes six passes over it, each with at most 11 sums so
they stay in vector registers. Reading memory once and ~60 multiply-adds per row: it runs near
memory speed. The numpy path fills a cache-sized design block and hands it to BLAS syrk instead.

Inputs of more than 2 x PARALLEL_ROWS rows are cut into one contiguous part per core, each summed by
the kernel (which runs without the GIL) and the parts added in a fixed order.

numba is optional: without it, or when compiling fails, the numpy path gives the same sums (to
rounding). Compiled code is cached on disk (cache=True) so only the first run on a machine pays for it;
even so, loading numba costs a new process about a second, so the kernel runs only for inputs large
enough to repay that (COMPILED_BREAK_EVEN_ROWS), whatever the process loaded before.
"""

# ruff: noqa: E702 - the kernel puts short statements side by side so its 60 sums read as a table

from __future__ import annotations

import warnings
from concurrent.futures import ThreadPoolExecutor

import numpy as np

import calib.compiled as compiled

# rows from which the compiled kernel repays loading numba in a new process: it saves ~40 ns/row over
# the numpy path (bench/throughput.py), loading costs ~1 s (bench/startup.py)
COMPILED_BREAK_EVEN_ROWS = 1 << 24
# rows per kernel call: bounds the copy when an input is not C-contiguous, costs nothing otherwise
KERNEL_ROWS = 1 << 16
# rows per core below which one thread does it all: starting threads costs more than it saves
PARALLEL_ROWS = 1 << 18
# rows per column-buffer block in the kernel: 8 x 256 doubles (16 kB) stay in L1
BLOCK_ROWS = 256
# numpy path: the 8192 x 12 design block (0.8 MB) stays in L2; fewer rows pay more per-call costs
CHUNK_ROWS = 8192
# numpy path: the 11 Gram columns plus one of zeros: OpenBLAS's syrk runs ~1.5x faster on 12 than on 11
BUF_COLS = 12
# Gram column -> (index in y, power of t): 1, t, h1..h3, t h1..t h3, B1..B3
X_OF_Y = [(0, 0), (0, 1), (1, 0), (2, 0), (3, 0), (1, 1), (2, 1), (3, 1), (4, 0), (5, 0), (6, 0)]


def _moments_kernel(h, t_all, ref, w_all, temp_ref, t_is_scalar, weighted):
    """(m, rows with w > 0, their min and max temperature): m[k, a, b] = sum of t^k y_a y_b for a <= b
    (see the module doc). h, ref (N,3); t_all and w_all (N,) or (1,) with the flags saying which."""
    m = np.zeros((3, 7, 7))
    buf = np.empty((8, BLOCK_ROWS))  # rows y0..y6, t
    n_used = 0
    t_min = np.inf
    t_max = -np.inf
    for lo in range(0, h.shape[0], BLOCK_ROWS):
        rows = min(BLOCK_ROWS, h.shape[0] - lo)
        for j in range(rows):
            i = lo + j
            w = w_all[i] if weighted else 1.0
            temp = t_all[0] if t_is_scalar else t_all[i]
            if w > 0:
                n_used += 1
                t_min = min(t_min, temp)
                t_max = max(t_max, temp)
            sw = np.sqrt(w)
            buf[0, j] = sw
            buf[1, j] = sw * h[i, 0]; buf[2, j] = sw * h[i, 1]; buf[3, j] = sw * h[i, 2]
            buf[4, j] = sw * ref[i, 0]; buf[5, j] = sw * ref[i, 1]; buf[6, j] = sw * ref[i, 2]
            buf[7, j] = temp - temp_ref
        # six passes over the block, each with few enough sums to stay in registers
        s000 = s001 = s002 = s003 = s004 = s005 = s006 = s055 = s056 = s066 = 0.0
        for j in range(rows):
            y0 = buf[0, j]; y1 = buf[1, j]; y2 = buf[2, j]; y3 = buf[3, j]
            y4 = buf[4, j]; y5 = buf[5, j]; y6 = buf[6, j]
            s000 += y0 * y0; s001 += y0 * y1; s002 += y0 * y2; s003 += y0 * y3
            s004 += y0 * y4; s005 += y0 * y5; s006 += y0 * y6; s055 += y5 * y5
            s056 += y5 * y6; s066 += y6 * y6
        m[0, 0, 0] += s000; m[0, 0, 1] += s001; m[0, 0, 2] += s002; m[0, 0, 3] += s003
        m[0, 0, 4] += s004; m[0, 0, 5] += s005; m[0, 0, 6] += s006; m[0, 5, 5] += s055
        m[0, 5, 6] += s056; m[0, 6, 6] += s066
        s011 = s012 = s013 = s014 = s015 = s016 = s044 = s045 = s046 = s233 = 0.0
        for j in range(rows):
            y1 = buf[1, j]; y2 = buf[2, j]; y3 = buf[3, j]; y4 = buf[4, j]
            y5 = buf[5, j]; y6 = buf[6, j]; t = buf[7, j]
            ty3 = t * y3; tty3 = t * ty3
            s011 += y1 * y1; s012 += y1 * y2; s013 += y1 * y3; s014 += y1 * y4
            s015 += y1 * y5; s016 += y1 * y6; s044 += y4 * y4; s045 += y4 * y5
            s046 += y4 * y6; s233 += tty3 * y3
        m[0, 1, 1] += s011; m[0, 1, 2] += s012; m[0, 1, 3] += s013; m[0, 1, 4] += s014
        m[0, 1, 5] += s015; m[0, 1, 6] += s016; m[0, 4, 4] += s044; m[0, 4, 5] += s045
        m[0, 4, 6] += s046; m[2, 3, 3] += s233
        s022 = s023 = s024 = s025 = s026 = s033 = s034 = s035 = s036 = s222 = s223 = 0.0
        for j in range(rows):
            y2 = buf[2, j]; y3 = buf[3, j]; y4 = buf[4, j]; y5 = buf[5, j]
            y6 = buf[6, j]; t = buf[7, j]
            ty2 = t * y2; tty2 = t * ty2
            s022 += y2 * y2; s023 += y2 * y3; s024 += y2 * y4; s025 += y2 * y5
            s026 += y2 * y6; s033 += y3 * y3; s034 += y3 * y4; s035 += y3 * y5
            s036 += y3 * y6; s222 += tty2 * y2; s223 += tty2 * y3
        m[0, 2, 2] += s022; m[0, 2, 3] += s023; m[0, 2, 4] += s024; m[0, 2, 5] += s025
        m[0, 2, 6] += s026; m[0, 3, 3] += s033; m[0, 3, 4] += s034; m[0, 3, 5] += s035
        m[0, 3, 6] += s036; m[2, 2, 2] += s222; m[2, 2, 3] += s223
        s100 = s101 = s102 = s103 = s104 = s105 = s106 = s200 = s201 = s202 = s203 = 0.0
        for j in range(rows):
            y0 = buf[0, j]; y1 = buf[1, j]; y2 = buf[2, j]; y3 = buf[3, j]
            y4 = buf[4, j]; y5 = buf[5, j]; y6 = buf[6, j]; t = buf[7, j]
            ty0 = t * y0; tty0 = t * ty0
            s100 += ty0 * y0; s101 += ty0 * y1; s102 += ty0 * y2; s103 += ty0 * y3
            s104 += ty0 * y4; s105 += ty0 * y5; s106 += ty0 * y6; s200 += tty0 * y0
            s201 += tty0 * y1; s202 += tty0 * y2; s203 += tty0 * y3
        m[1, 0, 0] += s100; m[1, 0, 1] += s101; m[1, 0, 2] += s102; m[1, 0, 3] += s103
        m[1, 0, 4] += s104; m[1, 0, 5] += s105; m[1, 0, 6] += s106; m[2, 0, 0] += s200
        m[2, 0, 1] += s201; m[2, 0, 2] += s202; m[2, 0, 3] += s203
        s111 = s112 = s113 = s114 = s115 = s116 = s211 = s212 = s213 = 0.0
        for j in range(rows):
            y1 = buf[1, j]; y2 = buf[2, j]; y3 = buf[3, j]; y4 = buf[4, j]
            y5 = buf[5, j]; y6 = buf[6, j]; t = buf[7, j]
            ty1 = t * y1; tty1 = t * ty1
            s111 += ty1 * y1; s112 += ty1 * y2; s113 += ty1 * y3; s114 += ty1 * y4
            s115 += ty1 * y5; s116 += ty1 * y6; s211 += tty1 * y1; s212 += tty1 * y2
            s213 += tty1 * y3
        m[1, 1, 1] += s111; m[1, 1, 2] += s112; m[1, 1, 3] += s113; m[1, 1, 4] += s114
        m[1, 1, 5] += s115; m[1, 1, 6] += s116; m[2, 1, 1] += s211; m[2, 1, 2] += s212
        m[2, 1, 3] += s213
        s122 = s123 = s124 = s125 = s126 = s133 = s134 = s135 = s136 = 0.0
        for j in range(rows):
            y2 = buf[2, j]; y3 = buf[3, j]; y4 = buf[4, j]; y5 = buf[5, j]
            y6 = buf[6, j]; t = buf[7, j]
            ty2 = t * y2; ty3 = t * y3
            s122 += ty2 * y2; s123 += ty2 * y3; s124 += ty2 * y4; s125 += ty2 * y5
            s126 += ty2 * y6; s133 += ty3 * y3; s134 += ty3 * y4; s135 += ty3 * y5
            s136 += ty3 * y6
        m[1, 2, 2] += s122; m[1, 2, 3] += s123; m[1, 2, 4] += s124; m[1, 2, 5] += s125
        m[1, 2, 6] += s126; m[1, 3, 3] += s133; m[1, 3, 4] += s134; m[1, 3, 5] += s135
        m[1, 3, 6] += s136
    return m, n_used, t_min, t_max


def _gram_from_moments(m: np.ndarray) -> np.ndarray:
    """The symmetric 11x11 Gram from the kernel's moments m[k, a, b] (filled for a <= b)."""
    m = np.triu(m) + np.triu(m, 1).transpose(0, 2, 1)
    gram = np.empty((11, 11))
    for p, (a, ka) in enumerate(X_OF_Y):
        for q, (b, kb) in enumerate(X_OF_Y):
            gram[p, q] = m[ka + kb, a, b]
    return gram


def gram_numba(h, t, ref, w, temp_ref: float):
    """(Gram, rows with w > 0, their min and max temperature) through the compiled kernel.

    h, ref (N,3); t (N,) or (1,) for one temperature; w (N,) or None. Large inputs are cut into one
    contiguous part per core, summed in a fixed order: the same result whatever the scheduling.
    """
    kernel = _compiled()
    if kernel is None:
        raise RuntimeError("numba kernel unavailable")
    n = h.shape[0]
    parts = max(1, min(compiled.cores(), n // PARALLEL_ROWS))
    bounds = [n * k // parts for k in range(parts + 1)]

    def part(k):
        return _moments_of_rows(kernel, h, t, ref, w, temp_ref, bounds[k], bounds[k + 1])

    if parts == 1:
        results = [part(0)]
    else:
        with ThreadPoolExecutor(parts) as pool:  # the kernel runs without the GIL
            results = list(pool.map(part, range(parts)))
    total = sum(r[0] for r in results)
    n_used = sum(r[1] for r in results)
    t_min = min(r[2] for r in results)
    t_max = max(r[3] for r in results)
    return _gram_from_moments(total), n_used, t_min, t_max


def _moments_of_rows(kernel, h, t, ref, w, temp_ref, start: int, stop: int):
    """The kernel's moments, used-row count and temperature range over rows start..stop."""
    total = np.zeros((3, 7, 7))
    n_used, t_min, t_max = 0, np.inf, -np.inf
    scalar_t = t.shape[0] == 1
    ones = np.ones(1)
    for lo in range(start, stop, KERNEL_ROWS):
        hi = min(lo + KERNEL_ROWS, stop)
        m, n, block_min, block_max = kernel(
            np.ascontiguousarray(h[lo:hi]),
            t if scalar_t else np.ascontiguousarray(t[lo:hi]),
            np.ascontiguousarray(ref[lo:hi]),
            ones if w is None else np.ascontiguousarray(w[lo:hi]),
            float(temp_ref),
            scalar_t,
            w is not None,
        )
        total += m
        n_used += n
        t_min, t_max = min(t_min, block_min), max(t_max, block_max)
    return total, n_used, t_min, t_max


def gram_numpy(h, t, ref, w, temp_ref: float):
    """The same as gram_numba through numpy and BLAS: a design block [1, t, h, t h, B, 0] per chunk."""
    n_rows = h.shape[0]
    t = np.broadcast_to(t, (n_rows,))
    buf = np.zeros((min(CHUNK_ROWS, n_rows), BUF_COLS), order="F")  # column fills are contiguous writes
    buf[:, 0] = 1.0
    sw = None if w is None else np.sqrt(w)
    gram = np.zeros((BUF_COLS, BUF_COLS))
    for lo in range(0, n_rows, CHUNK_ROWS):
        hi = min(lo + CHUNK_ROWS, n_rows)
        z = buf[: hi - lo]
        np.subtract(t[lo:hi], temp_ref, out=z[:, 1])
        z[:, 2:5] = h[lo:hi]
        np.multiply(z[:, 1:2], z[:, 2:5], out=z[:, 5:8])
        z[:, 8:11] = ref[lo:hi]
        if sw is not None:
            z[:, 1:] *= sw[lo:hi, None]
            z[:, 0] = sw[lo:hi]
        gram += z.T @ z  # numpy hands z.T @ z to BLAS syrk
    used = t if w is None else t[w > 0]  # zero weight: a flagged outlier, not counted
    if used.size == 0:
        return gram[:11, :11], 0, np.inf, -np.inf
    return gram[:11, :11], int(used.size), float(used.min()), float(used.max())


_KERNEL: list = []  # [compiled kernel or None] once tried


def _compiled():
    """The compiled kernel, or None when numba is absent, disabled (MAGRIG_NO_NUMBA=1) or fails."""
    if _KERNEL:
        return _KERNEL[0]
    kernel = None
    if compiled.numba_allowed():
        try:
            import numba
        except ImportError:
            numba = None
        if numba is not None:
            try:
                # reassoc lets LLVM split each sum over vector lanes; contract fuses multiply and add
                kernel = numba.njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})(_moments_kernel)
                kernel(np.zeros((1, 3)), np.zeros(1), np.zeros((1, 3)), np.ones(1), 0.0, False, False)
            except Exception as err:  # any compile failure: the numpy path gives the same sums
                warnings.warn(f"numba kernel for the Gram sums not used ({err}); using numpy", stacklevel=2)
                kernel = None
    _KERNEL.append(kernel)
    return kernel


def gram_sums(h, t, ref, w, temp_ref: float):
    """(Gram, rows with w > 0, min and max temperature of those rows): compiled when the input is big
    enough to repay loading numba (calib.compiled.worth_compiled)."""
    if compiled.worth_compiled(h.shape[0], COMPILED_BREAK_EVEN_ROWS) and _compiled() is not None:
        return gram_numba(h, t, ref, w, temp_ref)
    return gram_numpy(h, t, ref, w, temp_ref)
