"""The fast path of the CSV reader: the compiled scanner (calib.csvscan) parses the wanted columns
straight into float64 arrays, on every core, one block of the file at a time, while another thread
hashes the same bytes. Memory stays bounded by the result plus one block, whatever the file's size.

It takes the common shape of a numeric CSV (unquoted numbers, optional spaces around them, LF or CRLF,
blank lines skipped; values exactly as Python's float() reads them) and returns None for anything
else: a quote, a text or empty cell, a wrong cell count, no numba (or MAGRIG_NO_NUMBA=1). The columnar
reader in csvio then reads the file, and names the line and column of any problem.
"""

from __future__ import annotations

import hashlib
import os
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

# bytes read per block
BLOCK_BYTES = 1 << 24
# cells that need float() (see calib.csvscan) collected per scan before Python reads them
SLOW_CELLS = 4096

_SCANNER: list = []  # [the csvscan module, or None] once tried


def _scanner():
    """calib.csvscan, compiled; None when numba is absent, disabled (MAGRIG_NO_NUMBA=1) or fails."""
    if _SCANNER:
        return _SCANNER[0]
    scanner = None
    if os.environ.get("MAGRIG_NO_NUMBA", "") not in ("1", "true", "yes"):
        try:
            from calib import csvscan

            _parse_piece(csvscan, np.frombuffer(b"1,x\n", np.uint8), 0, 4, np.array([0, -1]), 1, 4)
            scanner = csvscan
        except ImportError:
            scanner = None
        except Exception as err:  # any compile failure: the columnar reader does the work
            warnings.warn(f"compiled CSV scanner not used ({err}); using pyarrow", stacklevel=2)
    _SCANNER.append(scanner)
    return scanner


class _NotFast(Exception):
    """This file is not in the shape the scanner takes: the columnar reader reads it."""


def _parse_piece(scan, buf: np.ndarray, start: int, end: int, slots: np.ndarray, nslots: int,
                 line_bytes: int) -> np.ndarray:
    """The whole lines of buf[start:end] parsed: an (nslots, rows) array."""
    out = np.empty((nslots, (end - start) // max(1, line_bytes) + 16))
    slow = np.empty((SLOW_CELLS, 4), np.int64)
    row, status = 0, scan.FULL
    while status in (scan.FULL, scan.TOO_MANY_SLOW):
        if status == scan.FULL and row == out.shape[1]:  # lines shorter than the first: grow
            out = np.concatenate([out, np.empty_like(out)], axis=1)
        status, row, nslow, start = scan.parse(
            buf, start, end, row, slots, out, out.view(np.uint64), slow,
            scan.POW10_HI, scan.POW10_LO, scan.EXACT_POW10,
        )
        if status not in (scan.OK, scan.FULL, scan.TOO_MANY_SLOW):
            raise _NotFast
        for slot, cell_row, first, last in slow[:nslow]:
            out[slot, cell_row] = float(buf[first:last].tobytes())
    return out[:, :row]


def read_numeric(path: Path, header: list[str], wanted: list[str]) -> tuple[dict, str] | None:
    """({column: float64 array} for the wanted columns, sha256 of the file), or None when the file is
    not in the shape the scanner takes: then the caller reads it another way."""
    scan = _scanner()
    if scan is None:
        return None
    slots = np.array([wanted.index(name) if name in wanted else -1 for name in header], np.int64)
    threads = max(1, min(8, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 1))
    digest = hashlib.sha256()
    pieces: list[np.ndarray] = []
    buf = bytearray(BLOCK_BYTES)
    carry = 0  # bytes of an unfinished line kept from the block before
    data_start = None  # where the data lines start in buf (after the header in the first block)
    line_bytes = 1
    with open(path, "rb") as f, ThreadPoolExecutor(threads + 1) as pool:
        while True:
            if carry == len(buf):  # one line longer than the block: grow it
                buf.extend(bytes(len(buf)))
            with memoryview(buf) as free:
                n = f.readinto(free[carry:])
            filled, at_eof = carry + n, n == 0
            hashed = pool.submit(_hash, digest, buf, carry, filled)  # while the scanner parses
            try:
                if data_start is None:  # the header line is in buf from offset 0
                    header_end = buf.find(b"\n", 0, filled) + 1 or filled
                    first_end = buf.find(b"\n", header_end, filled) + 1 or filled
                    if first_end == filled and not at_eof:  # the first data line is not all in yet
                        carry = filled
                        continue
                    data_start = header_end
                    if not _numeric_cells(bytes(buf[data_start:first_end]), slots):
                        return None
                    line_bytes = first_end - data_start
                end = filled if at_eof else buf.rfind(b"\n", 0, filled) + 1
                if end <= data_start and not at_eof:  # no whole data line yet: keep it all, read more
                    carry = filled
                    continue
                view = np.frombuffer(buf, np.uint8)
                jobs = [
                    pool.submit(_parse_piece, scan, view, a, b, slots, len(wanted), line_bytes)
                    for a, b in _cuts(buf, data_start, end, threads)
                ]
                del view
                pieces.extend(job.result() for job in jobs)
            except _NotFast:
                return None
            finally:
                hashed.result()
            if at_eof:
                break
            buf[: filled - end] = buf[end:filled]
            carry, data_start = filled - end, 0
    columns = {name: np.concatenate([p[k] for p in pieces]) if pieces else np.zeros(0)
               for k, name in enumerate(wanted)}
    return columns, digest.hexdigest()


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
