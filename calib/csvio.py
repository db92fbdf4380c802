"""The CSV contract: header with hx,hy,hz (raw), optional temp (degC), bx,by,bz (reference, nT),
bnorm (known |B|, nT) and group (temperature step / point id). Other columns are carried along.

Real recordings can be read as they are: `columns` maps our names to theirs
(e.g. {"hx": "mx_gauss", ...}) and `raw_unit` / `counts_per_unit` convert the raw readings to nT.
Any problem raises DataError naming the file, the line and the column.
"""

from __future__ import annotations

import csv
import hashlib
import io
import os
import re
from pathlib import Path

import numpy as np

from calib.atomic import atomic_write
from calib.dataset import Dataset
from calib.errors import DataError

NT_PER_UNIT = {"nt": 1.0, "ut": 1e3, "mt": 1e6, "gauss": 1e5, "mgauss": 1e2}
RAW_COLUMNS = ("hx", "hy", "hz")
REF_COLUMNS = ("bx", "by", "bz")
NUMERIC_COLUMNS = (*RAW_COLUMNS, "temp", *REF_COLUMNS, "bnorm")


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
) -> Dataset:
    """Read a CSV into a Dataset. `Dataset.columns` holds every input column by its header name."""
    p = Path(path)
    scale = nt_per_raw_unit(raw_unit, counts_per_unit)
    try:
        raw = p.read_bytes()
    except OSError as err:
        raise DataError(f"{p}: cannot read ({err.strerror or err})") from None
    text = _decode(raw, p)
    header_end = text.find("\n")
    header_line = text if header_end < 0 else text[:header_end]
    header = [h.strip().strip('"') for h in header_line.rstrip("\r").split(",")]
    if not header_line.strip():
        raise DataError(f"{p}: empty file (expected a header line with hx,hy,hz)")
    dup = {h for h in header if header.count(h) > 1}
    if dup:
        raise DataError(f"{p} line 1: column {sorted(dup)[0]!r} appears twice")
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
    body = text[header_end + 1 :] if header_end >= 0 else ""
    if not body.strip():
        raise DataError(f"{p}: no data rows after the header")
    numeric_needed = [mapping[k] for k in NUMERIC_COLUMNS if k in mapping]
    table = _parse_fast(raw, len(header))
    if table is None:
        cols = _parse_slow(body, header, numeric_needed, p)
    else:
        cols = {h: table[:, i] for i, h in enumerate(header)}
    n = len(cols[header[0]])
    for ours in NUMERIC_COLUMNS:
        if ours in mapping:
            _check_finite(cols[mapping[ours]], mapping[ours], p)

    def block(names):
        if not all(k in mapping for k in names):
            return None
        return np.column_stack([cols[mapping[k]] for k in names]).astype(float)

    ds = Dataset(
        h_nt=block(RAW_COLUMNS) * scale,
        temp_c=cols[mapping["temp"]].astype(float) if "temp" in mapping else None,
        ref_nt=block(REF_COLUMNS),
        ref_norm_nt=cols[mapping["bnorm"]].astype(float) if "bnorm" in mapping else None,
        group=cols[mapping["group"]] if "group" in mapping else None,
        columns=cols,
        source={
            "kind": "csv",
            "path": str(p),
            "sha256": hashlib.sha256(raw).hexdigest(),
            "rows_total": n,
            "rows_used": n,
            "rows_rejected": 0,
            "raw_unit": raw_unit,
            "nt_per_raw_unit": scale,
        },
    )
    return ds


def _decode(raw: bytes, p: Path) -> str:
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        line = raw[: err.start].count(b"\n") + 1
        raise DataError(f"{p} line {line}: not UTF-8 text") from None


def _parse_fast(raw: bytes, n_cols: int) -> np.ndarray | None:
    """All-numeric, rectangular body through numpy's C parser; None when anything is unusual."""
    try:
        table = np.loadtxt(io.BytesIO(raw), delimiter=",", skiprows=1, ndmin=2, dtype=float, comments=None)
    except ValueError:
        return None
    return table if table.shape[1] == n_cols else None


def _parse_slow(body: str, header: list[str], numeric: list[str], p: Path) -> dict[str, np.ndarray]:
    """Row by row, to name the line and column of a problem; non-numeric extra columns kept as text."""
    rows = [r for r in csv.reader(io.StringIO(body))]
    line_of = []
    kept = []
    for i, r in enumerate(rows):
        if not r or all(not c.strip() for c in r):
            continue  # blank line
        if len(r) != len(header):
            raise DataError(f"{p} line {i + 2}: {len(r)} cells, the header has {len(header)}")
        kept.append(r)
        line_of.append(i + 2)
    cols = {}
    for j, name in enumerate(header):
        cells = [r[j] for r in kept]
        try:
            cols[name] = np.array(cells, dtype=float)
        except ValueError:
            if name in numeric:
                for k, cell in enumerate(cells):
                    try:
                        float(cell)
                    except ValueError:
                        raise DataError(
                            f"{p} line {line_of[k]}, column {name!r}: {cell!r} is not a number"
                        ) from None
            cols[name] = np.array(cells, dtype=object)
    return cols


def _check_finite(values: np.ndarray, name: str, p: Path) -> None:
    bad = ~np.isfinite(values.astype(float))
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
