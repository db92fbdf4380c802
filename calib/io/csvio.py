"""The CSV contract: header with hx,hy,hz (raw), optional temp (degC), bx,by,bz (reference, nT),
bnorm (known |B|, nT) and group (temperature step / point id). Other columns are carried along.

Real recordings can be read as they are: `columns` maps our names to theirs
(e.g. {"hx": "mx_gauss", ...}) and `raw_unit` / `counts_per_unit` convert the raw readings to nT.
Any problem raises DataError naming the file, the line and the column.

A numeric file is parsed by a compiled scanner on every core (calib.io.csvfast); anything else (text or
quoted cells, no numba) by pyarrow's columnar reader, block by block; only when that refuses a file does
a line-by-line scan run, to name the line and column of the problem. Every path reads the same values.
"""

from __future__ import annotations

import csv
import hashlib
import io
import os
import re
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv

import calib.compiled as compiled
import calib.io.csvfast as csvfast
from calib.dataset import Dataset
from calib.errors import DataError
from calib.io.atomic import atomic_write

NT_PER_UNIT = {"nt": 1.0, "ut": 1e3, "mt": 1e6, "gauss": 1e5, "mgauss": 1e2}
RAW_COLUMNS = ("hx", "hy", "hz")
REF_COLUMNS = ("bx", "by", "bz")
NUMERIC_COLUMNS = (*RAW_COLUMNS, "temp", *REF_COLUMNS, "bnorm")
# bytes parsed per block: memory stays bounded by the result, not by the file (which may exceed memory)
BLOCK_BYTES = csvfast.BLOCK_BYTES


def nt_per_raw_unit(raw_unit: str = "nT", counts_per_unit: str | float | None = None) -> float:
    """nT per raw reading unit. raw_unit: nT, uT, mT, gauss, mgauss or counts; for counts,
    counts_per_unit is 'X' or 'X/UNIT' (counts per UNIT, default per gauss), e.g. '1090/gauss'."""
    unit = raw_unit.strip().lower()
    if unit in NT_PER_UNIT:
        if counts_per_unit is not None:
            raise DataError(f"--counts-per-unit only applies to --raw-unit counts, not {raw_unit}")
        return NT_PER_UNIT[unit]
    if unit != "counts":
        raise DataError(f"raw unit {raw_unit!r} unknown: use nT, uT, mT, gauss, mgauss or counts")
    if counts_per_unit is None:
        raise DataError("--raw-unit counts needs --counts-per-unit X[/UNIT] (e.g. 1090/gauss)")
    m = re.fullmatch(r"\s*([^/\s]+)\s*(?:/\s*(\w+))?\s*", str(counts_per_unit))
    per = (m.group(2) or "gauss").lower() if m else ""
    try:
        counts = float(m.group(1)) if m else float("nan")
    except ValueError:
        counts = float("nan")
    if not (np.isfinite(counts) and counts > 0) or per not in NT_PER_UNIT:
        raise DataError(
            f"--counts-per-unit {counts_per_unit!r}: expected a positive number, optionally /UNIT"
        )
    return NT_PER_UNIT[per] / counts


def parse_column_map(text: str | None) -> dict[str, str]:
    """'hx=mx_gauss,hy=my_gauss' -> {'hx': 'mx_gauss', 'hy': 'my_gauss'}."""
    if not text:
        return {}
    out = {}
    for item in text.split(","):
        ours, sep, theirs = item.partition("=")
        if not sep or not ours.strip() or not theirs.strip():
            raise DataError(f"--columns item {item!r}: expected OURS=THEIRS, e.g. hx=mx_gauss")
        if ours.strip() not in (*NUMERIC_COLUMNS, "group"):
            raise DataError(
                f"--columns item {item!r}: {ours.strip()!r} is not one of {', '.join(NUMERIC_COLUMNS)}, group"
            )
        out[ours.strip()] = theirs.strip()
    return out


def read_csv(
    path: str | os.PathLike,
    *,
    raw_unit: str = "nT",
    counts_per_unit: str | float | None = None,
    columns: dict[str, str] | None = None,
    extra_columns: bool = True,
) -> Dataset:
    """Read a CSV into a Dataset. `Dataset.columns` holds every input column by its header name
    (only the contract's columns with extra_columns=False, which a fit does not need and skips)."""
    p = Path(path)
    scale = nt_per_raw_unit(raw_unit, counts_per_unit)
    header = _read_header(p)
    mapping = _column_mapping(header, columns, p)
    numeric = [mapping[k] for k in NUMERIC_COLUMNS if k in mapping]
    wanted = header if extra_columns else [h for h in header if h in mapping.values()]
    # both readers' tables put hx,hy,hz and bx,by,bz side by side: the blocks below are views of them
    order = list(dict.fromkeys([mapping[k] for k in (*RAW_COLUMNS, *REF_COLUMNS) if k in mapping] + wanted))
    slot = {name: k for k, name in enumerate(order)}
    table = None
    try:
        fast = None
        if compiled.worth_compiled(p.stat().st_size, csvfast.COMPILED_BREAK_EVEN_BYTES):
            fast = csvfast.read_numeric(p, header, order)
        if fast is not None:
            table, sha256 = fast
            cols = {name: table[:, slot[name]] for name in wanted}
        else:
            digest = hashlib.sha256()
            by_name, table = _read_columnar(p, header, numeric, order, digest)
            cols = {name: by_name[name] for name in wanted}  # in the file's order
            sha256 = digest.hexdigest()
    except (pa.ArrowInvalid, UnicodeDecodeError):
        _locate_problem(p, header, numeric)  # raises the DataError naming line and column
        cols = _parse_slow(p, header, wanted)  # cells Python reads as numbers, the columnar parser not
        sha256 = hashlib.sha256(p.read_bytes()).hexdigest()
    except OSError as err:
        raise DataError(f"{p}: cannot read ({err.strerror or err})") from None
    n = len(cols[wanted[0]])
    if n == 0:
        raise DataError(f"{p}: no data rows after the header")
    if table is None or not np.isfinite(table).all():  # one contiguous pass when all is well
        for ours in NUMERIC_COLUMNS:
            if ours in mapping:
                _check_finite(cols[mapping[ours]], mapping[ours], p)

    def block(names):
        if not all(k in mapping for k in names):
            return None
        first = slot[mapping[names[0]]]
        if table is not None and [slot[mapping[k]] for k in names] == list(range(first, first + len(names))):
            return table[:, first : first + len(names)]  # adjacent columns of the table: a view
        return np.column_stack([cols[mapping[k]] for k in names])

    h = block(RAW_COLUMNS)
    return Dataset(
        h_nt=h * scale if scale != 1.0 else h,
        temp_c=cols[mapping["temp"]] if "temp" in mapping else None,
        ref_nt=block(REF_COLUMNS),
        ref_norm_nt=cols[mapping["bnorm"]] if "bnorm" in mapping else None,
        group=cols[mapping["group"]] if "group" in mapping else None,
        columns=cols,
        source={
            "kind": "csv",
            "path": str(p),
            "sha256": sha256,
            "rows_total": n,
            "rows_used": n,
            "rows_rejected": 0,
            "raw_unit": raw_unit,
            "nt_per_raw_unit": scale,
        },
    )


def _read_header(p: Path) -> list[str]:
    try:
        with open(p, "rb") as f:
            first = f.readline()
    except OSError as err:
        raise DataError(f"{p}: cannot read ({err.strerror or err})") from None
    try:
        line = first.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise DataError(f"{p} line 1: not UTF-8 text") from None
    if not line.strip():
        raise DataError(f"{p}: empty file (expected a header line with hx,hy,hz)")
    header = [h.strip().strip('"') for h in line.rstrip("\r\n").split(",")]
    dup = {h for h in header if header.count(h) > 1}
    if dup:
        raise DataError(f"{p} line 1: column {sorted(dup)[0]!r} appears twice")
    return header


def _column_mapping(header: list[str], columns: dict[str, str] | None, p: Path) -> dict[str, str]:
    """Our column name -> the file's, for the contract's columns present (or mapped)."""
    mapping = {name: name for name in (*NUMERIC_COLUMNS, "group") if name in header}
    for ours, theirs in (columns or {}).items():
        if theirs not in header:
            raise DataError(
                f"{p} line 1: column {theirs!r} (given for {ours}) not in header {','.join(header)}"
            )
        mapping[ours] = theirs
    for name in RAW_COLUMNS:
        if name not in mapping:
            raise DataError(
                f"{p} line 1: missing column {name!r} (header: {','.join(header)}); "
                "map yours with --columns hx=NAME,hy=NAME,hz=NAME"
            )
    return mapping


class _HashingReader(io.RawIOBase):
    """A binary file that feeds every byte read into a hash: the file is read once for both."""

    def __init__(self, f, digest):
        self._f, self._digest = f, digest

    def readable(self) -> bool:
        return True

    def readinto(self, buffer) -> int:
        n = self._f.readinto(buffer)
        self._digest.update(memoryview(buffer)[:n])
        return n


def _read_columnar(p: Path, header: list[str], numeric: list[str], order: list[str], digest):
    """(columns by name, table): the `order` columns parsed by pyarrow block by block (BLOCK_BYTES at a
    time); the contract's numeric columns as float64, other numeric columns as float64, text as objects.
    When every column is numeric they are copied once into one table (N, len(order)) whose columns are
    contiguous (column-major), and the returned columns are views of it; else table is None."""
    read = pacsv.ReadOptions(column_names=header, skip_rows=1, block_size=BLOCK_BYTES)
    convert = pacsv.ConvertOptions(
        include_columns=order,
        column_types={name: pa.float64() for name in numeric},
        null_values=[],  # an empty or 'NA' cell in a numeric column is an error, not a silent NaN
        strings_can_be_null=False,
        quoted_strings_can_be_null=False,
    )
    parts: dict[str, list] = {name: [] for name in order}
    with open(p, "rb", buffering=0) as raw, _HashingReader(raw, digest) as f:
        reader = pacsv.open_csv(io.BufferedReader(f, BLOCK_BYTES), read_options=read, convert_options=convert)
        for batch in reader:
            for name, column in zip(batch.schema.names, batch.columns, strict=True):
                parts[name].append(column)
    if all(chunks and _is_number(chunks[0].type) for chunks in parts.values()):
        n = sum(len(chunk) for chunk in parts[order[0]])
        table = np.empty((len(order), n))  # column-major: each column one contiguous copy of its chunks
        for k, name in enumerate(order):
            row = 0
            for chunk in parts[name]:
                table[k, row : row + len(chunk)] = chunk.to_numpy()
                row += len(chunk)
        return {name: table[k] for k, name in enumerate(order)}, table.T
    cols = {name: _to_numpy(pa.chunked_array(chunks) if chunks else None) for name, chunks in parts.items()}
    return cols, None


def _is_number(arrow_type) -> bool:
    return pa.types.is_floating(arrow_type) or pa.types.is_integer(arrow_type)


def _to_numpy(column) -> np.ndarray:
    if column is None:
        return np.zeros(0)
    if _is_number(column.type):
        return column.to_numpy().astype(float, copy=False)
    if pa.types.is_binary(column.type) or pa.types.is_large_binary(column.type):
        raise pa.ArrowInvalid("text column is not UTF-8")  # the line scan names the line
    return np.array(column.to_pylist(), dtype=object)


def _locate_problem(p: Path, header: list[str], numeric: list[str]) -> None:
    """Scan the file line by line and raise a DataError at the first line the columnar parser refused."""
    index = {name: header.index(name) for name in numeric}
    with open(p, "rb") as f:
        for line_no, line in enumerate(f, start=1):
            try:
                text = line.decode("utf-8-sig" if line_no == 1 else "utf-8")
            except UnicodeDecodeError:
                raise DataError(f"{p} line {line_no}: not UTF-8 text") from None
            if line_no == 1 or not text.strip():
                continue
            cells = next(csv.reader([text]))
            if len(cells) != len(header):
                raise DataError(f"{p} line {line_no}: {len(cells)} cells, the header has {len(header)}")
            for name, j in index.items():
                try:
                    float(cells[j])
                except ValueError:
                    raise DataError(
                        f"{p} line {line_no}, column {name!r}: {cells[j]!r} is not a number"
                    ) from None


def _parse_slow(p: Path, header: list[str], wanted: list[str]) -> dict[str, np.ndarray]:
    """Row by row through Python: cells that Python reads as numbers but the columnar parser did not."""
    with open(p, encoding="utf-8-sig", newline="") as f:
        rows = [r for r in csv.reader(f)][1:]
    rows = [r for r in rows if r and any(c.strip() for c in r)]
    cols = {}
    for name in wanted:
        cells = [r[header.index(name)] for r in rows]
        try:
            cols[name] = np.array(cells, dtype=float)
        except ValueError:
            cols[name] = np.array(cells, dtype=object)
    return cols


def _check_finite(values: np.ndarray, name: str, p: Path) -> None:
    bad = ~np.isfinite(np.asarray(values, float))  # no copy of a float column
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        raise DataError(
            f"{p} data row {row + 1} (line {row + 2}), column {name!r}: {values[row]} is not finite"
        )


def contract_columns(ds: Dataset) -> dict[str, np.ndarray]:
    """A dataset as CSV-contract columns (hx,hy,hz in nT, then temp, bx,by,bz, bnorm, group when present)."""
    cols = {name: ds.h_nt[:, i] for i, name in enumerate(RAW_COLUMNS)}
    if ds.temp_c is not None:
        cols["temp"] = ds.temp_c
    if ds.ref_nt is not None:
        cols.update({name: ds.ref_nt[:, i] for i, name in enumerate(REF_COLUMNS)})
    if ds.ref_norm_nt is not None:
        cols["bnorm"] = ds.ref_norm_nt
    if ds.group is not None:
        cols["group"] = ds.group
    return cols


def write_csv(path: str | os.PathLike, columns: dict[str, np.ndarray]) -> None:
    """Write columns (name -> (N,) array) atomically; floats in their shortest exact form."""
    names = list(columns)
    arrays = [np.asarray(columns[k]) for k in names]
    # %r of a python float is its shortest exact decimal form; text columns go out as they came in
    row_format = ",".join("%r" if a.dtype.kind in "fiu" else "%s" for a in arrays)
    lists = [a.tolist() for a in arrays]
    with atomic_write(path, newline="") as f:
        f.write(",".join(names) + "\n")
        for lo in range(0, len(lists[0]) if lists else 0, 65536):
            rows = zip(*(col[lo : lo + 65536] for col in lists), strict=True)
            f.write("".join([row_format % r + "\n" for r in rows]))
