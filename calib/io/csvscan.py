"""The compiled scanner behind calib.io.csvfast (needs numba; csvfast imports this module only when numba
is there). `parse` reads whole CSV lines of numeric cells into float64 columns, correctly rounded:

- digits are read eight at a time where they run that long (one 64-bit load, three multiplies);
- a mantissa of up to 15 digits with a small exponent is exact after one multiply or divide
  (Clinger's fast path); up to 19 digits, the Eisel-Lemire 128-bit product of the mantissa and a
  table of powers of ten decides the rounding, or says it cannot; more digits are decided when the
  truncated mantissa and the next one round alike;
- whatever is still undecided (a product at a rounding boundary, subnormals, overflow) is listed for
  Python's float() to read, as are cells beyond what the table covers.
"""

# ruff: noqa: E702 - the 64- and 128-bit arithmetic reads better with its short steps side by side

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.cpython.unsafe.numbers import leading_zeros, trailing_zeros
from numba.extending import intrinsic

OK, BAD_CELL, CELL_COUNT, TOO_MANY_SLOW, FULL = 0, 1, 2, 3, 4
MIN_EXP10, MAX_EXP10 = -348, 347  # the table's range of q in 10**q


def _powers_of_ten() -> tuple[np.ndarray, np.ndarray]:
    """(hi, lo) 64-bit halves of the 128-bit mantissa of 10**q (top bit set, rounded down), q in range."""
    hi = np.empty(MAX_EXP10 - MIN_EXP10 + 1, np.uint64)
    lo = np.empty_like(hi)
    for i, q in enumerate(range(MIN_EXP10, MAX_EXP10 + 1)):
        if q >= 0:
            v = 10**q
            shift = v.bit_length() - 128
            v = v >> shift if shift > 0 else v << -shift
        else:
            d = 10**-q
            v = (1 << (127 + d.bit_length())) // d  # in (2**127, 2**128): d is not a power of two
        hi[i], lo[i] = v >> 64, v & ((1 << 64) - 1)
    return hi, lo


POW10_HI, POW10_LO = _powers_of_ten()
EXACT_POW10 = np.array([10.0**k for k in range(23)])  # 10**22 is the largest power of ten a double holds

U = np.uint64
POW10_INT = np.array([10**k for k in range(9)], np.uint64)
SIGN_BIT = U(1) << U(63)


@intrinsic
def _mul_hi(typingctx, a, b):
    """The high 64 bits of the 128-bit product of two uint64 (one machine multiply)."""
    sig = types.uint64(types.uint64, types.uint64)

    def codegen(context, builder, signature, args):
        wide = ir.IntType(128)
        product = builder.mul(builder.zext(args[0], wide), builder.zext(args[1], wide))
        return builder.trunc(builder.lshr(product, ir.Constant(wide, 64)), ir.IntType(64))

    return sig, codegen


@intrinsic
def _load8(typingctx, address, i):
    """The eight bytes at address + i as a little-endian uint64, one unaligned load."""
    sig = types.uint64(types.intp, types.intp)

    def codegen(context, builder, signature, args):
        base = builder.inttoptr(args[0], ir.IntType(8).as_pointer())
        word = builder.bitcast(builder.gep(base, [args[1]]), ir.IntType(64).as_pointer())
        return builder.load(word, align=1)

    return sig, codegen


@intrinsic
def _at(typingctx, address, i):
    """The byte at address + i."""
    sig = types.uint8(types.intp, types.intp)

    def codegen(context, builder, signature, args):
        base = builder.inttoptr(args[0], ir.IntType(8).as_pointer())
        return builder.load(builder.gep(base, [args[1]]))

    return sig, codegen


@njit(inline="always")
def _non_digits(v):
    """0x80 in each byte of v from its first non-digit byte on (the bytes below it are exact)."""
    return ((v + U(0x4646464646464646)) | (v - U(0x3030303030303030))) & U(0x8080808080808080)


@njit(inline="always")
def _value_of_digits(d):
    """The number eight digit values (one per byte, first digit in the low byte) spell."""
    d = d * U(10) + (d >> U(8))
    d = ((d & U(0x000000FF000000FF)) * U(0x000F424000000064)
         + ((d >> U(16)) & U(0x000000FF000000FF)) * U(0x0000271000000001)) >> U(32)
    return d & U(0xFFFFFFFF)


@njit(inline="always")
def _eisel_lemire(man, q):
    """The float64 bits of man * 10**q correctly rounded, or 0 when this cannot decide (then float()
    must). 0 < man < 2**64, q within the table."""
    clz = leading_zeros(man)
    man = man << U(clz)
    exp2 = ((217706 * q) >> 16) + 64 + 1023 - clz  # 217706 / 2**16 ~ log2(10)
    k = q - MIN_EXP10
    x_hi = _mul_hi(man, POW10_HI[k]); x_lo = man * POW10_HI[k]
    low9 = U(0x1FF)
    if (x_hi & low9) == low9 and x_lo + man < man:  # the truncated product may be off: widen it
        y_hi = _mul_hi(man, POW10_LO[k]); y_lo = man * POW10_LO[k]
        m_hi = x_hi; m_lo = x_lo + y_hi
        if m_lo < x_lo:
            m_hi += U(1)
        if (m_hi & low9) == low9 and m_lo + U(1) == U(0) and y_lo + man < man:
            return U(0)
        x_hi = m_hi; x_lo = m_lo
    msb = x_hi >> U(63)
    mantissa = x_hi >> (msb + U(9))
    exp2 -= 1 - np.int64(msb)
    if x_lo == U(0) and (x_hi & low9) == U(0) and (mantissa & U(3)) == U(1):
        return U(0)  # exactly halfway between two doubles as far as 128 bits tell
    mantissa += mantissa & U(1)
    mantissa >>= U(1)
    if mantissa >> U(53):
        mantissa >>= U(1); exp2 += 1
    if exp2 <= 0 or exp2 >= 0x7FF:
        return U(0)  # subnormal or overflow
    return (U(exp2) << U(52)) | (mantissa & U(0xFFFFFFFFFFFFF))


@njit(inline="always")
def _run_length(v, room):
    """How many of the eight bytes of v, from the first, are digits (at most `room`, at least 0)."""
    flags = _non_digits(v)
    k = 8 if flags == U(0) else np.int64(trailing_zeros(flags)) >> 3
    return max(0, min(k, room))


@njit(inline="always")
def _first_digits(v, k):
    """The number the first k (0..8) bytes of v spell when they are digits."""
    shift = U(4 * (8 - k))  # the k digits to the top bytes, zeros below (two shifts: 64 is no shift)
    return _value_of_digits(((v - U(0x3030303030303030)) << shift) << shift)


@njit(inline="always")
def _digits(base, size, i, end, man):
    """Read the run of digits at byte i of the `size`-byte buffer at `base`: (index after it, man
    extended by them, how many). Two 8-byte loads cover runs of up to 16 digits with no branch on the
    run's length (a data-dependent branch costs more than the arithmetic here); longer runs and the
    buffer's last bytes go on eight, then one, at a time."""
    start = i
    if i + 16 <= size:
        v1 = _load8(base, i)
        v2 = _load8(base, i + 8)
        k1 = _run_length(v1, end - i)
        k2 = _run_length(v2, end - i - 8) if k1 == 8 else 0
        man = man * POW10_INT[k1] + _first_digits(v1, k1)
        man = man * POW10_INT[k2] + _first_digits(v2, k2)
        i += k1 + k2
        if k1 + k2 < 16:
            return i, man, i - start
    while i + 8 <= size:
        v = _load8(base, i)
        k = _run_length(v, end - i)
        man = man * POW10_INT[k] + _first_digits(v, k)
        i += k
        if k < 8:
            return i, man, i - start
    while i < end and 48 <= _at(base, i) <= 57:
        man = man * U(10) + U(_at(base, i) - 48); i += 1
    return i, man, i - start


@njit
def _long_mantissa(base, i, end):
    """A mantissa of more than 19 digits, re-read keeping its first 19 significant ones:
    (index after it, mantissa, power of ten, whether a nonzero digit was dropped)."""
    man = U(0); digits = 0; exp10 = 0; dropped = False
    dot = False
    while i < end:
        c = _at(base, i)
        if c == 46 and not dot:
            dot = True; i += 1
            continue
        if not 48 <= c <= 57:
            break
        d = U(c - 48)
        if digits < 19:
            if man != U(0) or d != U(0):
                man = man * U(10) + d; digits += 1
            if dot:
                exp10 -= 1
        else:
            if not dot:
                exp10 += 1
            dropped = dropped or d != U(0)
        i += 1
    return i, man, exp10, dropped


@njit(cache=True, nogil=True, error_model="numpy")
def parse(buf, start, end, row, slots, out, out_bits, slow):
    """Parse the whole lines of buf[start:end] into out[row..., slot] for the file columns whose
    slots[col] >= 0 (blank lines skipped). Returns (status, next row, cells for float(), where the scan
    stopped). Such a cell is slow[k] = (slot, row, first byte, end byte). When `slow` or `out` is full
    the scan stops at the start of its line (TOO_MANY_SLOW, FULL), to be resumed from there."""
    # the hot loops read through the buffer's address: no array (and no reference count) in their calls
    base = buf.ctypes.data
    size = buf.shape[0]
    ncols = slots.shape[0]
    nslow = 0
    i = start
    while i < end:
        line_start = i
        if _at(base, i) == 10:
            i += 1
            continue
        if _at(base, i) == 13 and i + 1 < end and _at(base, i + 1) == 10:
            i += 2
            continue
        if row == out.shape[0]:
            return FULL, row, nslow, line_start
        col = 0
        while True:
            if col >= ncols:
                return CELL_COUNT, row, nslow, line_start
            slot = slots[col]
            if slot < 0:  # a column nobody asked for: skip it, unless quoting could hide a separator
                while i < end and _at(base, i) != 44 and _at(base, i) != 10:
                    if _at(base, i) == 34:
                        return BAD_CELL, row, nslow, line_start
                    i += 1
            else:
                first = i
                while i < end and (_at(base, i) == 32 or _at(base, i) == 9):
                    i += 1
                sign = _at(base, i) if i < end else U(0)
                negative = sign == 45
                i += 1 if negative or sign == 43 else 0  # a select, not a branch: signs come at random
                mantissa_start = i
                i, man, n_int = _digits(base, size, i, end, U(0))
                n_frac = 0
                if i < end and _at(base, i) == 46:
                    i, man, n_frac = _digits(base, size, i + 1, end, man)
                if n_int + n_frac == 0:
                    return BAD_CELL, row, nslow, line_start
                exp10 = -n_frac
                dropped = False
                if n_int + n_frac > 19:  # man overflowed: keep the first 19 significant digits
                    i, man, exp10, dropped = _long_mantissa(base, mantissa_start, end)
                if i < end and (_at(base, i) == 101 or _at(base, i) == 69):
                    i += 1
                    e_negative = False
                    if i < end and (_at(base, i) == 45 or _at(base, i) == 43):
                        e_negative = _at(base, i) == 45
                        i += 1
                    if i >= end or not 48 <= _at(base, i) <= 57:
                        return BAD_CELL, row, nslow, line_start
                    e = 0
                    while i < end and 48 <= _at(base, i) <= 57:
                        if e < 100000:
                            e = e * 10 + (_at(base, i) - 48)
                        i += 1
                    exp10 += -e if e_negative else e
                last = i
                while i < end and (_at(base, i) == 32 or _at(base, i) == 9):
                    i += 1
                done = True
                if man == U(0):
                    out_bits[row, slot] = SIGN_BIT if negative else U(0)
                elif exp10 < MIN_EXP10 or exp10 > MAX_EXP10:
                    done = False
                elif not dropped and man <= U(1 << 53) and -22 <= exp10 <= 22:  # one exact operation
                    v = float(man)
                    v = v * EXACT_POW10[exp10] if exp10 >= 0 else v / EXACT_POW10[-exp10]
                    out[row, slot] = -v if negative else v
                else:
                    bits = _eisel_lemire(man, exp10)
                    if dropped and bits != _eisel_lemire(man + U(1), exp10):
                        bits = U(0)  # digits were dropped and the next mantissa up rounds elsewhere
                    done = bits != U(0)
                    if done:
                        out_bits[row, slot] = (bits | SIGN_BIT) if negative else bits
                if not done:  # float() reads it, after the scan
                    if nslow == slow.shape[0]:
                        return TOO_MANY_SLOW, row, nslow, line_start
                    slow[nslow, 0] = slot; slow[nslow, 1] = row; slow[nslow, 2] = first; slow[nslow, 3] = last
                    nslow += 1
            if i < end and _at(base, i) == 44:
                col += 1
                i += 1
                continue
            if i < end and _at(base, i) == 13:
                i += 1
            if i < end:
                if _at(base, i) != 10:
                    return BAD_CELL, row, nslow, line_start
                i += 1
            if col != ncols - 1:
                return CELL_COUNT, row, nslow, line_start
            break
        row += 1
    return OK, row, nslow, end
