"""Exports of a calibration for other tools: a C header for flight software, JSON, CSV; and of a
session's samples as CSV (`write_samples_csv`).

Every model is brought to one "flight form" a small computer evaluates with a few multiply-adds:

    tau = temp_c - temp_ref_c
    M   = matrix + tau * matrix_per_c            (3x3)
    o   = offset_nt + tau * offset_nt_per_c      (3)
    B   = M h + o          (T24: S, K, b, kb with absolute tau, temp_ref_c = 0)
    B   = M (h - o)        (P12: M = (Q P)^-1, o = b; scalar: its matrix and centre)

Temperature terms are omitted when the model has none.

Text from the calibration file (software version, creation time, source hash, DUT name) is hostile
until proven otherwise: in the C header it only appears through `c_comment_text` (a short run of
harmless characters, everything else spelt as <U+XXXX>, so no `*/`, newline, backslash, trigraph or
`#` can end the comment or start a directive), `c_string` (escaped literal) and rig/core/names.py's
identifiers and guard. JSON goes through json.dumps (ASCII, escaped); CSV holds only parameter
labels of the model's own names and numbers.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass

import numpy as np

from calib.calibration import to_plain
from rig import __version__
from rig.core import names
from rig.core.errors import DataError

FORMATS = ("c-header", "json", "csv")
MAX_BUDGET_LINES = 16


# ---------------------------------------------------------------------------------------------- samples
def write_samples_csv(stream, rows: list[dict]) -> None:
    """One DUT's samples (rig.session.reader.SessionReader.sample_rows) as CSV in the reader's EXPORT_COLUMNS:
    what `rig export` writes and `rig refit` reads back."""
    from rig.session.reader import EXPORT_COLUMNS

    writer = csv.writer(stream)
    writer.writerow(EXPORT_COLUMNS)
    for r in rows:
        writer.writerow(["" if r[c] is None else r[c] for c in EXPORT_COLUMNS])


@dataclass(frozen=True)
class FlightForm:
    """A calibration as the arrays a flight computer needs (see the module docstring)."""

    model: str
    matrix: np.ndarray
    offset_nt: np.ndarray
    offset_first: bool
    matrix_per_c: np.ndarray | None = None
    offset_nt_per_c: np.ndarray | None = None
    temp_ref_c: float = 0.0

    def apply(self, h_nt: np.ndarray, temp_c: np.ndarray | float | None) -> np.ndarray:
        """The same arithmetic as the C function, in numpy: rows of h_nt (N, 3) to field (N, 3)."""
        h = np.atleast_2d(np.asarray(h_nt, dtype=float))
        tau = np.zeros(len(h)) if temp_c is None else np.broadcast_to(np.asarray(temp_c, float), len(h))
        tau = tau - self.temp_ref_c
        m = self.matrix[None] + tau[:, None, None] * (0 if self.matrix_per_c is None else self.matrix_per_c)
        o = self.offset_nt[None] + tau[:, None] * (
            0 if self.offset_nt_per_c is None else self.offset_nt_per_c
        )
        v = h - o if self.offset_first else h
        out = np.einsum("nij,nj->ni", m, v)
        return out if self.offset_first else out + o


def t24_form(S: np.ndarray, K: np.ndarray, b_nt: np.ndarray, kb_nt_per_c: np.ndarray) -> FlightForm:
    """T24 in the absolute-tau convention: B = (S + tau K) h + b + tau kb."""
    return FlightForm("t24", _mat(S), _vec(b_nt), False, _mat(K), _vec(kb_nt_per_c), 0.0)


def inverse_form(
    model: str,
    matrix: np.ndarray,
    offset_nt: np.ndarray,
    matrix_per_c: np.ndarray | None = None,
    offset_nt_per_c: np.ndarray | None = None,
    temp_ref_c: float = 0.0,
) -> FlightForm:
    """Offset-first models: B = (M + tau M1)(h - (o + tau o1)), tau = temp_c - temp_ref_c."""
    return FlightForm(
        model,
        _mat(matrix),
        _vec(offset_nt),
        True,
        None if matrix_per_c is None else _mat(matrix_per_c),
        None if offset_nt_per_c is None else _vec(offset_nt_per_c),
        float(temp_ref_c),
    )


def _mat(a) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.shape != (3, 3):
        raise DataError(f"calibration matrix must be 3x3, got shape {a.shape}")
    return a


def _vec(a) -> np.ndarray:
    a = np.asarray(a, dtype=float).reshape(-1)
    if a.shape != (3,):
        raise DataError(f"calibration vector must have 3 elements, got {a.size}")
    return a


# ---------------------------------------------------------------------------------------------- C header


c_identifier = names.c_identifier  # kept here: tests and callers know it by this address

COMMENT_SAFE = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789 _-.,:;+=()[]@")
MAX_COMMENT_TEXT = 120


def c_comment_text(text: object) -> str:
    """Any text made safe inside a C block comment, on one line, at most MAX_COMMENT_TEXT characters."""
    text = str(text)
    out = "".join(ch if ch in COMMENT_SAFE else f"<U+{ord(ch):04X}>" for ch in text[:MAX_COMMENT_TEXT])
    return out + ("..." if len(text) > MAX_COMMENT_TEXT else "")


def c_string(text: str) -> str:
    """A C string literal of `text` (UTF-8 bytes; anything but plain printable ASCII as octal escapes)."""
    body = "".join(chr(b) if 0x20 <= b < 0x7F and chr(b) not in '"\\?' else f"\\{b:03o}"
                   for b in text.encode("utf-8", "replace"))
    return f'"{body}"'


def _c_num(x: float) -> str:
    if not np.isfinite(x):
        raise DataError(f"calibration parameter is not finite ({x}); cannot export it")
    return f"{float(x):.17g}"


def _c_array(name: str, a: np.ndarray) -> str:
    if a.ndim == 1:
        body = ", ".join(_c_num(v) for v in a)
        return f"static const MAGRIG_REAL {name}[3] = {{{body}}};"
    rows = ",\n    ".join("{" + ", ".join(_c_num(v) for v in row) + "}" for row in a)
    return f"static const MAGRIG_REAL {name}[3][3] = {{\n    {rows}\n}};"


def uncertainty_comment(uncertainty: dict | None) -> list[str]:
    """Comment lines of a calibration's uncertainty (calib/uncertainty.py), every text made safe."""
    if not uncertainty:
        return [" * Uncertainty: not stated."]

    def num(x: object) -> str:
        try:
            value = float(x)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            return "?"
        return f"{value:.3g}" if math.isfinite(value) else "?"

    k = num(uncertainty.get("coverage_factor"))
    within = num(uncertainty.get("expanded_vector_error_nt"))
    lines = [f" * Uncertainty (k = {k}): calibrated field within {within} nT (95 %) over the plan's fields",
             " * and temperatures.",
             " * Budget, standard uncertainty of the calibrated field (nT):"]
    for item in (uncertainty.get("budget") or [])[:MAX_BUDGET_LINES]:
        if isinstance(item, dict):
            source = c_comment_text(item.get("source", "?"))
            lines.append(f" *   {source}: {num(item.get('contribution_nt'))}")
    expanded = uncertainty.get("expanded") or {}
    largest = [f"{c_comment_text(key)} {num(np.max(np.abs(np.asarray(value, float))))}"
               for key, value in expanded.items() if _numeric(value)]
    if largest:
        lines.append(" * Largest expanded uncertainty per parameter: " + ", ".join(largest) + ".")
    return lines


def _numeric(value: object) -> bool:
    try:
        return bool(np.all(np.isfinite(np.asarray(value, float))))
    except (TypeError, ValueError):
        return False


def c_header(
    form: FlightForm, *, name: str, source_sha256: str = "", version: str = __version__,
    description: str = "", uncertainty: dict | None = None,
) -> str:
    """A self-contained C99 header: the constants plus `static inline void <name>_apply(...)`; the
    calibration's uncertainty budget, when it has one, in its opening comment."""
    ident = c_identifier(name)
    macro = ident.upper()
    guard = names.header_guard(name)
    description = c_comment_text(description) if description else ""
    has_t_m = form.matrix_per_c is not None
    has_t_o = form.offset_nt_per_c is not None
    equation = "B = M(tau) (h - o(tau))" if form.offset_first else "B = M(tau) h + o(tau)"
    lines = [
        f"/* {ident}.h: magnetometer calibration exported by magrig {c_comment_text(version)}.",
        f" * model: {c_comment_text(form.model)}{' (' + description + ')' if description else ''}",
        f" * source sha256: {c_comment_text(source_sha256) if source_sha256 else 'unknown'}",
        f" * {equation}, with M(tau) = M + tau*M_PER_C, o(tau) = O + tau*O_PER_C,",
        f" * tau = temp_c - ({_c_num(form.temp_ref_c)}) degC;",
        " * h and B in nT, in the axes the sensor reports.",
    ]
    if not (has_t_m or has_t_o):
        lines.append(" * This model has no temperature terms: temp_c is ignored.")
    lines += uncertainty_comment(uncertainty)
    lines += [
        " * MAGRIG_REAL is double by default (the export is checked against the host fit to 1e-6 relative",
        " * in double); define it as float before including this file on a single-precision target.",
        " */",
        f"#ifndef {guard}",
        f"#define {guard}",
        "",
        "#ifndef MAGRIG_REAL",
        "#define MAGRIG_REAL double",
        "#endif",
        "",
        f"#define {macro}_MODEL {c_string(form.model)}",
        f"#define {macro}_TEMP_REF_C ({_c_num(form.temp_ref_c)})",
        _c_array(f"{macro}_M", form.matrix),
        _c_array(f"{macro}_O", form.offset_nt),
    ]
    if has_t_m:
        lines.append(_c_array(f"{macro}_M_PER_C", form.matrix_per_c))
    if has_t_o:
        lines.append(_c_array(f"{macro}_O_PER_C", form.offset_nt_per_c))
    m_term = f"{macro}_M[i][j] + tau * {macro}_M_PER_C[i][j]" if has_t_m else f"{macro}_M[i][j]"
    o_term = f"{macro}_O[i] + tau * {macro}_O_PER_C[i]" if has_t_o else f"{macro}_O[i]"
    v_term = f"h_nt[i] - ({o_term})" if form.offset_first else "h_nt[i]"
    lines += [
        "",
        "/* Calibrated field b_nt[3] from the raw reading h_nt[3] at DUT temperature temp_c (degC). */",
        f"static inline void {ident}_apply(const MAGRIG_REAL h_nt[3], MAGRIG_REAL temp_c,",
        "                                  MAGRIG_REAL b_nt[3])",
        "{",
        f"    const MAGRIG_REAL tau = temp_c - {macro}_TEMP_REF_C;",
        "    MAGRIG_REAL v[3];",
        "    int i, j;",
    ]
    if not (has_t_m or has_t_o):
        lines.append("    (void)tau;")
    lines += [
        f"    for (i = 0; i < 3; ++i) v[i] = {v_term};",
        "    for (i = 0; i < 3; ++i) {",
        f"        MAGRIG_REAL acc = {'0' if form.offset_first else o_term};",
        f"        for (j = 0; j < 3; ++j) acc += ({m_term}) * v[j];",
        "        b_nt[i] = acc;",
        "    }",
        "}",
        "",
        f"#endif /* {guard} */",
        "",
    ]
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------- JSON / CSV


def form_dict(form: FlightForm) -> dict:
    d = {
        "model": form.model,
        "equation": "B = M(tau) (h - o(tau))" if form.offset_first else "B = M(tau) h + o(tau)",
        "tau": "temp_c - temp_ref_c",
        "temp_ref_c": form.temp_ref_c,
        "matrix": form.matrix.tolist(),
        "offset_nt": form.offset_nt.tolist(),
    }
    if form.matrix_per_c is not None:
        d["matrix_per_c"] = form.matrix_per_c.tolist()
    if form.offset_nt_per_c is not None:
        d["offset_nt_per_c"] = form.offset_nt_per_c.tolist()
    return d


def to_jsonable(x):
    """numpy arrays and scalars to plain lists and numbers (calib's to_plain); NaN and inf, which JSON
    cannot spell, to None."""
    return _finite_or_none(to_plain(x))


def _finite_or_none(x):
    if isinstance(x, dict):
        return {k: _finite_or_none(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_finite_or_none(v) for v in x]
    return None if isinstance(x, float) and not math.isfinite(x) else x


def json_export(form: FlightForm, params: dict, std_errors: dict, extra: dict) -> str:
    """Parameters, standard errors and the flight form, plus `extra` (stats, source, software)."""
    doc = {"format": "magrig-calibration-export", "version": 1, "software": f"magrig {__version__}"}
    doc.update(to_jsonable(extra))
    doc["params"] = to_jsonable(params)
    doc["std_errors"] = to_jsonable(std_errors)
    doc["flight_form"] = to_jsonable(form_dict(form))
    return json.dumps(doc, indent=2, sort_keys=False) + "\n"


def csv_export(params: dict, std_errors: dict, expanded: dict | None = None) -> str:
    """One row per scalar parameter: `parameter,value,std_error,expanded_uncertainty` with indices, e.g.
    S[0][1] (the last column empty without an uncertainty budget)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["parameter", "value", "std_error", "expanded_uncertainty"])

    def cell(table: dict | None, key: str, index: tuple, shape: tuple) -> str:
        arr = np.asarray((table or {}).get(key, np.nan), dtype=float)
        value = arr[index] if arr.shape == shape else np.nan
        return "" if not np.isfinite(value) else repr(float(value))

    for key, value in params.items():
        values = np.asarray(value, dtype=float)
        for index in np.ndindex(values.shape):
            label = key + "".join(f"[{i}]" for i in index)
            writer.writerow([label, repr(float(values[index])), cell(std_errors, key, index, values.shape),
                             cell(expanded, key, index, values.shape)])
    return buf.getvalue()


# ---------------------------------------------------------------------------------------------- calibration


def flight_form(cal) -> FlightForm:
    """The flight form of a calib.Calibration (parameter names as in calib.models)."""
    from calib import models

    p = cal.params
    if cal.model == "t24":
        return t24_form(p["S"], p["K"], p["b_nt"], p["kb_nt_per_c"])
    if cal.model == "p12":
        return inverse_form("p12", np.linalg.inv(models.p12_matrix(p["k"], p["angles_deg"])), p["b_nt"])
    if cal.model == "scalar":
        return inverse_form(
            "scalar", p["A"], p["c_nt"], p.get("KA_per_c"), p.get("kc_nt_per_c"), cal.temp_ref_c or 0.0
        )
    raise DataError(f"cannot export model {cal.model!r} (known: t24, p12, scalar)")


def export_calibration(cal, fmt: str, name: str) -> str:
    """The text of one export format (see FORMATS) of a calib.Calibration; `name` names the C symbols."""
    form = flight_form(cal)
    source = cal.source or {}
    if fmt == "c-header":
        return c_header(
            form,
            name=name,
            source_sha256=str(source.get("sha256", "")),
            version=cal.software_version,
            description=f"fitted {cal.created_utc}" if cal.created_utc else "",
            uncertainty=cal.uncertainty,
        )
    if fmt == "json":
        extra = {
            "model": cal.model,
            "temp_ref_c": cal.temp_ref_c,
            "stats": cal.stats,
            "source": source,
            "fitted_with": f"magrig {cal.software_version}",
            "created_utc": cal.created_utc,
            "uncertainty": cal.uncertainty,
        }
        return json_export(form, cal.params, cal.std_errors, extra)
    if fmt == "csv":
        return csv_export(cal.params, cal.std_errors, (cal.uncertainty or {}).get("expanded"))
    raise DataError(f"unknown export format {fmt!r} (known: {', '.join(FORMATS)})")
