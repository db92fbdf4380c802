"""Exports of a calibration for other tools: a C header for flight software (rig/report/cheader.py),
JSON, CSV; and of a session's samples as CSV (`write_samples_csv`).

Every model is brought to one "flight form" a small computer evaluates with a few multiply-adds:

    tau = temp_c             (T24: the DUT temperature in degC as measured, the file's `tau: absolute_c`)
    tau = temp_c - tau_0_c   (a model whose equation subtracts a constant: the scalar model's tau_0_c)
    M   = matrix + tau * matrix_per_c (+ tau^2 * matrix_per_c2)           (3x3)
    o   = offset_nt + tau * offset_nt_per_c (+ tau^2 * offset_nt_per_c2)  (3)
    B   = M h + o          (T24: S, K, b, kb; T36: also K2, kb2)
    B   = M (h - o)        (P12: M = (Q P)^-1, o = h0_nt; scalar: its matrix and centre)

Temperature terms are omitted when the model has none. Every export states the measurand as the
calibration file does (rig/analysis/measurand.py): the C header in its opening comment, the JSON in the
file's own keys (`reading`, `tau_source`, `frame`, `indexing`, `reference_chain`, `source`), the CSV in `#`
lines above its header; each says where no commissioned reference chain stands behind the field.
Parameter names are the file's (calib/equations.py parameter_label: `S[0][1]`, zero-based, row = output
axis of B). Text from the calibration file is hostile until proven otherwise (rig/report/cheader.py for
the C header); JSON goes through json.dumps (ASCII, escaped); CSV's `#` lines are folded to one line each,
and its rows hold only parameter labels of the model's own names and numbers.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass

import numpy as np

from calib.calibration import MEASURAND, to_plain
from calib.equations import parameter_label
from rig import __version__
from rig.core import names
from rig.core.errors import DataError
from rig.report import cheader

FORMATS = ("c-header", "json", "csv")


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
    tau_0_c: float | None = None  # None: tau is temp_c as measured
    matrix_per_c2: np.ndarray | None = None  # T36's quadratic terms
    offset_nt_per_c2: np.ndarray | None = None

    def apply(self, h_nt: np.ndarray, temp_c: np.ndarray | float | None) -> np.ndarray:
        """The same arithmetic as the C function, in numpy: rows of h_nt (N, 3) to field (N, 3)."""
        h = np.atleast_2d(np.asarray(h_nt, dtype=float))
        tau = np.zeros(len(h)) if temp_c is None else np.broadcast_to(np.asarray(temp_c, float), len(h))
        tau = tau - (self.tau_0_c or 0.0)
        m = self.matrix[None] + tau[:, None, None] * (0 if self.matrix_per_c is None else self.matrix_per_c)
        o = self.offset_nt[None] + tau[:, None] * (
            0 if self.offset_nt_per_c is None else self.offset_nt_per_c
        )
        if self.matrix_per_c2 is not None:
            m = m + (tau**2)[:, None, None] * self.matrix_per_c2
        if self.offset_nt_per_c2 is not None:
            o = o + (tau**2)[:, None] * self.offset_nt_per_c2
        v = h - o if self.offset_first else h
        out = np.einsum("nij,nj->ni", m, v)
        return out if self.offset_first else out + o


def t24_form(S: np.ndarray, K: np.ndarray, b_nt: np.ndarray, kb_nt_per_c: np.ndarray) -> FlightForm:
    """T24 in the absolute-tau convention: B = (S + tau K) h + b + tau kb."""
    return FlightForm("t24", _mat(S), _vec(b_nt), False, _mat(K), _vec(kb_nt_per_c), None)


def t36_form(S, K, K2, b_nt, kb_nt_per_c, kb2_nt_per_c2) -> FlightForm:
    """T36 in the absolute-tau convention: B = (S + tau K + tau^2 K2) h + b + tau kb + tau^2 kb2."""
    return FlightForm("t36", _mat(S), _vec(b_nt), False, _mat(K), _vec(kb_nt_per_c), None,
                      _mat(K2), _vec(kb2_nt_per_c2))


def inverse_form(
    model: str,
    matrix: np.ndarray,
    offset_nt: np.ndarray,
    matrix_per_c: np.ndarray | None = None,
    offset_nt_per_c: np.ndarray | None = None,
    tau_0_c: float | None = None,
) -> FlightForm:
    """Offset-first models: B = (M + tau M1)(h - (o + tau o1)), tau = temp_c - tau_0_c."""
    return FlightForm(
        model,
        _mat(matrix),
        _vec(offset_nt),
        True,
        None if matrix_per_c is None else _mat(matrix_per_c),
        None if offset_nt_per_c is None else _vec(offset_nt_per_c),
        None if tau_0_c is None else float(tau_0_c),
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
# in rig/report/cheader.py; its names are kept here too: tests and callers know them by this address
c_identifier = names.c_identifier
c_header, c_comment_text, c_string = cheader.c_header, cheader.c_comment_text, cheader.c_string
uncertainty_comment = cheader.uncertainty_comment


# ---------------------------------------------------------------------------------------------- JSON / CSV


def form_dict(form: FlightForm) -> dict:
    has_tau = form.matrix_per_c is not None or form.offset_nt_per_c is not None
    d = {
        "model": form.model,
        "indexing": "matrix[row][column], zero-based, row = output axis of B",
        "names_in_file": FORM_NAMES.get(form.model, ""),
        "equation": "B = M(tau) (h - o(tau))" if form.offset_first else "B = M(tau) h + o(tau)",
        "tau": ("not used" if not has_tau else "temp_c (degC, absolute)" if form.tau_0_c is None
                else "temp_c - tau_0_c"),
        **({"tau_0_c": form.tau_0_c} if has_tau and form.tau_0_c is not None else {}),
        "matrix": form.matrix.tolist(),
        "offset_nt": form.offset_nt.tolist(),
    }
    if form.matrix_per_c is not None:
        d["matrix_per_c"] = form.matrix_per_c.tolist()
    if form.offset_nt_per_c is not None:
        d["offset_nt_per_c"] = form.offset_nt_per_c.tolist()
    if form.matrix_per_c2 is not None:
        d["matrix_per_c2"] = form.matrix_per_c2.tolist()
    if form.offset_nt_per_c2 is not None:
        d["offset_nt_per_c2"] = form.offset_nt_per_c2.tolist()
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


def csv_export(params: dict, std_errors: dict, expanded: dict | None = None,
               comments: list[tuple[str, str]] | tuple = ()) -> str:
    """`comments` as `# label: words` lines (each on one line), then one row per scalar parameter:
    `parameter,value,std_error,expanded_uncertainty` named as the file names them, e.g. S[0][1] (the last
    column empty without an uncertainty budget)."""
    buf = io.StringIO()
    for label, words in comments:
        buf.write("# " + " ".join(f"{label}: {words}".split()) + "\n")
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["parameter", "value", "std_error", "expanded_uncertainty"])

    def cell(table: dict | None, key: str, index: tuple, shape: tuple) -> str:
        arr = np.asarray((table or {}).get(key, np.nan), dtype=float)
        value = arr[index] if arr.shape == shape else np.nan
        return "" if not np.isfinite(value) else repr(float(value))

    for key, value in params.items():
        values = np.asarray(value, dtype=float)
        for index in np.ndindex(values.shape):
            label = parameter_label(key, index)
            writer.writerow([label, repr(float(values[index])), cell(std_errors, key, index, values.shape),
                             cell(expanded, key, index, values.shape)])
    return buf.getvalue()


# ---------------------------------------------------------------------------------------------- calibration


def flight_form(cal) -> FlightForm:
    """The flight form of a calib.Calibration (parameter names as in calib.models.registry)."""
    from calib.models import registry

    p = cal.params
    if cal.model == "t24":
        return t24_form(p["S"], p["K"], p["b_nt"], p["kb_nt_per_c"])
    if cal.model == "t36":
        return t36_form(p["S"], p["K"], p["K2"], p["b_nt"], p["kb_nt_per_c"], p["kb2_nt_per_c2"])
    if cal.model == "p12":
        return inverse_form("p12", np.linalg.inv(registry.p12_matrix(p["k"], p["angles_deg"])), p["h0_nt"])
    if cal.model == "scalar":
        return inverse_form("scalar", p["A"], p["c_nt"], p.get("KA_per_c"), p.get("kc_nt_per_c"),
                            cal.equation_keys().get("tau_0_c"))
    raise DataError(f"cannot export model {cal.model!r} (known: t24, t36, p12, scalar)")


def header_notes(cal) -> list[str]:
    """The opening comment's lines about the calibration: its file's equation, its residual beside its
    stated uncertainty (flagged when the residual is the larger), what dominates that uncertainty."""
    from rig.analysis.judged import quality_of

    keys = cal.equation_keys()
    q = quality_of(cal)
    notes = [f"calibration file: equation {keys['equation']}; tau: {keys['tau']}"]
    if q.rms_nt is not None:
        notes.append(f"fit residual RMS {q.rms_nt:.1f} nT")
    if q.exceeds:
        notes.append("WARNING: " + q.exceeds_text())
    if q.dominant:
        notes.append(f"largest uncertainty contribution: {q.dominant}")
    if isinstance(choice := cal.stats.get("temperature_model"), dict):  # rig/analysis/tempchoice.py
        notes.append(f"temperature model chosen by held-out validation: {choice.get('message', '?')}")
    return notes


# which of the calibration file's parameters each array of the flight form holds
FORM_NAMES = {
    "t24": "M = S, M_PER_C = K, O = b_nt, O_PER_C = kb_nt_per_c.",
    "t36": "M = S, M_PER_C = K, M_PER_C2 = K2, O = b_nt, O_PER_C = kb_nt_per_c, O_PER_C2 = kb2_nt_per_c2.",
    "p12": "M = inv(Q P) of k and angles_deg, O = h0_nt.",
    "scalar": "M = A, O = c_nt, M_PER_C = KA_per_c, O_PER_C = kc_nt_per_c.",
}


def export_calibration(cal, fmt: str, name: str) -> str:
    """The text of one export format (see FORMATS) of a calib.Calibration; `name` names the C symbols."""
    from rig.analysis.measurand import measurand_rows, reference_chain_words

    form = flight_form(cal)
    source = cal.source or {}
    if fmt == "c-header":
        return c_header(
            form,
            name=name,
            source_sha256=str(source.get("sha256") or ""),
            version=cal.software_version,
            description=f"fitted {cal.created_utc}" if cal.created_utc else "",
            uncertainty=cal.uncertainty,
            notes=header_notes(cal),
            measurand=measurand_rows(cal),
            names_in_file=FORM_NAMES.get(cal.model, ""),
        )
    if fmt == "json":
        extra = {
            "model": cal.model,
            **cal.equation_keys(),
            **{key: getattr(cal, key) for key in MEASURAND},
            "reference_chain_statement": reference_chain_words(cal.reference_chain),
            "not_stated": cal.missing_measurand(),
            "stats": cal.stats,
            "source": source,
            "fitted_with": f"magrig {cal.software_version}",
            "created_utc": cal.created_utc,
            "uncertainty": cal.uncertainty,
        }
        return json_export(form, cal.params, cal.std_errors, extra)
    if fmt == "csv":
        equation = cal.equation_keys()["equation"]
        comments = [("magrig calibration export", f"model {cal.model}; equation {equation}"),
                    *measurand_rows(cal)]
        return csv_export(cal.params, cal.std_errors, (cal.uncertainty or {}).get("expanded"), comments)
    raise DataError(f"unknown export format {fmt!r} (known: {', '.join(FORMATS)})")
