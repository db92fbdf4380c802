"""The fast path of the CSV reader: the compiled scanner (calib.io.csvscan) parses the wanted columns
straight into float64 arrays, on every core, one block of the file at a time, while another thread
hashes the same bytes. Memory stays bounded by the result plus one block, whatever the file's size.

It takes the common shape of a numeric CSV (unquoted numbers, optional spaces around them, LF or CRLF,
blank lines skipped; values exactly as Python's float() reads them) and returns None for anything
else: a quote, a text or empty cell, a wrong cell count, no numba (or MAGRIG_NO_NUMBA=1). The columnar
reader in csvio then reads the file, and names the line and column of any problem. csvio hands a file
to it only when the file is large enough to repay loading numba (COMPILED_BREAK_EVEN_BYTES).
"""

from __future__ import annotations

import hashlib
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

import calib.compiled as compiled

# file size from which the scanner repays loading numba in a new process: it saves ~2 ns/byte over the
# columnar reader (bench/csv_refit.py), loading costs ~1 s (bench/startup.py)
COMPILED_BREAK_EVEN_BYTES = 1 << 29
# bytes read per block
BLOCK_BYTES = 1 << 22
# pieces per thread and block: the threads share the block's pieces and its hashing evenly
PIECES_PER_THREAD = 4
# cells that need float() (see calib.io.csvscan) collected per scan before Python reads them
SLOW_CELLS = 4096

_SCANNER: list = []  # [the csvscan module, or None] once tried


def _scanner():
    """calib.io.csvscan, compiled; None when numba is absent, disabled (MAGRIG_NO_NUMBA=1) or fails."""
    if _SCANNER:
        return _SCANNER[0]
    scanner = None
    if compiled.numba_allowed():
        try:
            import calib.io.csvscan as csvscan

            _parse_piece(csvscan, np.frombuffer(b"1,x\n", np.uint8), 0, 4, np.array([0, -1]), 1, 4)
            scanner = csvscan
        except ImportError:  # no numba: the columnar reader does the work
            pass
        except Exception as err:  # any compile failure: the columnar reader does the work
            warnings.warn(f"compiled CSV scanner not used ({err}); using pyarrow", stacklevel=2)
    _SCANNER.append(scanner)
    return scanner


class _NotFast(Exception):
    """This file is not in the shape the scanner takes: the columnar reader reads it."""


def _parse_piece(scan, buf: np.ndarray, start: int, end: int, slots: np.ndarray, nslots: int,
                 line_bytes: int) -> np.ndarray:
    """The whole lines of buf[start:end] parsed: a (rows, nslots) array."""
    out = np.empty(((end - start) // max(1, line_bytes) + 16, nslots))
    slow = np.empty((SLOW_CELLS, 4), np.int64)
    row, status = 0, scan.FULL
    while status in (scan.FULL, scan.TOO_MANY_SLOW):
        if status == scan.FULL and row == out.shape[0]:  # lines shorter than the first: grow
            out = np.concatenate([out, np.empty_like(out)])
        status, row, nslow, start = scan.parse(buf, start, end, row, slots, out, out.view(np.uint64), slow)
        if status not in (scan.OK, scan.FULL, scan.TOO_MANY_SLOW):
            raise _NotFast
        for slot, cell_row, first, last in slow[:nslow]:
            out[cell_row, slot] = float(buf[first:last].tobytes())
    return out[:row]


def read_numeric(path: Path, header: list[str], wanted: list[str]) -> tuple[np.ndarray, str] | None:
    """(an (N, len(wanted)) float64 table, one column per wanted name in that order; sha256 of the file),
    or None when the file is not in the shape the scanner takes: then the caller reads it another way.
    Each wanted name appears once.

    Two buffers take turns: while the threads parse one block, the next is read into the other (which
    first takes the block's unfinished last line), and one more thread hashes each block in file order.
    """
    scan = _scanner()
    if scan is None:
        return None
    slot_of = {name: k for k, name in enumerate(wanted)}
    slots = np.array([slot_of.get(name, -1) for name in header], np.int64)
    threads = min(8, compiled.cores())
    digest = hashlib.sha256()
    pieces: list[np.ndarray] = []
    bufs = [bytearray(BLOCK_BYTES), bytearray(BLOCK_BYTES)]  # [being filled, in the threads' hands]
    carry = 0  # bytes of an unfinished line at the start of bufs[0]
    data_start = None  # where the data lines start in bufs[0] (after the header in the first block)
    line_bytes = 1
    in_flight: list = []  # the parse jobs of the block in bufs[1]
    hashing = None  # the hash job of the block in bufs[1]
    with open(path, "rb") as f, ThreadPoolExecutor(threads) as pool, ThreadPoolExecutor(1) as hasher:
        try:
            while True:
                buf = bufs[0]
                with memoryview(buf) as free:
                    n = f.readinto(free[carry:])
                filled, at_eof = carry + n, n == 0
                hashed = hasher.submit(_hash, digest, buf, carry, filled)
                if data_start is None:  # the header line is in buf from offset 0
                    header_end = buf.find(b"\n", 0, filled) + 1 or filled
                    first_end = buf.find(b"\n", header_end, filled) + 1 or filled
                    if first_end < filled or at_eof:
                        data_start = header_end
                        if not _numeric_cells(bytes(buf[data_start:first_end]), slots):
                            return None
                        line_bytes = first_end - data_start
                end = filled if at_eof else buf.rfind(b"\n", 0, filled) + 1
                if data_start is None or (end <= data_start and not at_eof):  # no whole line yet
                    hashed.result()
                    if filled == len(buf):  # one line longer than the block: a larger buffer
                        bufs[0] = bytearray(2 * len(buf))
                        bufs[0][:filled] = buf[:filled]
                    carry = filled
                    continue
                view = np.frombuffer(buf, np.uint8)
                jobs = [
                    pool.submit(_parse_piece, scan, view, a, b, slots, len(wanted), line_bytes)
                    for a, b in _cuts(buf, data_start, end, PIECES_PER_THREAD * threads)
                ]
                del view
                pieces.extend(job.result() for job in in_flight)  # the block before: bufs[1] is free
                if hashing is not None:
                    hashing.result()
                in_flight, hashing = jobs, hashed
                if at_eof:
                    break
                carry = filled - end
                if len(bufs[1]) < len(buf):
                    bufs[1] = bytearray(len(buf))
                bufs[1][:carry] = buf[end:filled]
                bufs.reverse()
                data_start = 0
            pieces.extend(job.result() for job in in_flight)
            hashing.result()
        except _NotFast:
            return None
    table = np.concatenate(pieces) if pieces else np.zeros((0, len(wanted)))
    return table, digest.hexdigest()


def _hash(digest, buf: bytearray, start: int, end: int) -> None:
    with memoryview(buf) as view:
        digest.update(view[start:end])  # hashlib lets go of the GIL for large buffers


def _cuts(buf: bytearray, start: int, end: int, parts: int) -> list[tuple[int, int]]:
    """[start, end) cut at line ends into about `parts` pieces of similar size."""
    cuts, a = [], start
    for k in range(1, parts):
        b = buf.find(b"\n", max(a, start + (end - start) * k // parts), end)
        if b < 0:
            break
        cuts.append((a, b + 1))
        a = b + 1
    if end > a:
        cuts.append((a, end))
    return cuts


def _numeric_cells(line: bytes, slots: np.ndarray) -> bool:
    """Whether the wanted cells of the first data line read as numbers: a text column (a label, a
    point id) sends the file to the columnar reader at once, not after a wasted scan."""
    cells = line.rstrip(b"\r\n").split(b",")
    if len(cells) != len(slots):
        return False
    try:
        return all(np.isfinite(float(cells[j])) for j in np.flatnonzero(slots >= 0))
    except ValueError:
        return False
