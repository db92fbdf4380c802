"""The C header export of a calibration (rig/report/exports.py makes the flight form it writes).

Text from the calibration file (software version, creation time, source hash, DUT name, notes, its
measurand) is hostile until proven otherwise: it only appears through `c_comment_text` (a short run of
harmless characters, everything else spelt as <U+XXXX>, so no `*/`, `/*`, newline, backslash, trigraph or
`#` can end the comment or start a directive), `c_string` (escaped literal) and rig/core/names.py's
identifiers and guard.

The header compiles as C89 and as C99 (`gcc -std=c89 -pedantic -Werror`): declarations before statements,
no // comments, and the apply function `static inline` where the compiler knows inline (C99, or GCC's
`__inline__`), plain `static` otherwise (MAGRIG_INLINE; define it to override). Its opening comment states
the measurand as the calibration file does (rig/analysis/measurand.py measurand_rows): how h is read, the
thermometer of tau, the frames of B and h, the indexing, the reference chain, the source and its sha256.

The header states tau as the calibration file does: for T24 tau is temp_c itself (the file's
`tau: absolute_c`), so no reference temperature appears that anyone could subtract; a model whose equation
subtracts a constant (the scalar model's tau_0_c) names it `<NAME>_TAU_0_C`.
"""

from __future__ import annotations

import math
import textwrap

import numpy as np

from rig import __version__
from rig.core import names
from rig.core.errors import DataError

MAX_BUDGET_LINES = 16
NOTE_WIDTH = 96  # a note's comment lines, wrapped below c_comment_text's limit

c_identifier = names.c_identifier

COMMENT_SAFE = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789"
                         " _-.,:;+=()[]@/*'%<>^|")
MAX_COMMENT_TEXT = 120


def c_comment_text(text: object) -> str:
    """Any text made safe inside a C block comment, on one line, at most MAX_COMMENT_TEXT characters: a
    '/' or '*' that would pair with the one before it into `*/` or `/*` is spelt out too."""
    text = str(text)
    out, before = [], ""
    for ch in text[:MAX_COMMENT_TEXT]:
        pairs = ch in "/*" and before in "/*" and before != "" and before != ch
        out.append(ch if ch in COMMENT_SAFE and not pairs else f"<U+{ord(ch):04X}>")
        before = ch if ch in COMMENT_SAFE and not pairs else ""
    return "".join(out) + ("..." if len(text) > MAX_COMMENT_TEXT else "")


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
    """Comment lines of a calibration's uncertainty (calib/uncertainty/montecarlo.py), every text made
    safe."""
    if not uncertainty:
        return [" * Uncertainty: not stated."]

    def num(x: object) -> str:
        try:
            value = float(x)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            return "?"
        return f"{value:.3g}" if math.isfinite(value) else "?"

    from rig.analysis.judged import field_figures

    figures = field_figures(uncertainty)
    k = num(figures.coverage_factor)
    said = ("Uncertainty of the calibrated field over the plan's fields and temperatures: combined standard "
            f"uncertainty u = {num(figures.standard_nt)} nT (RMS over those points); expanded uncertainty "
            f"U = k u = {num(figures.expanded_nt)} nT (k = {k}); 95 % error radius "
            f"{num(figures.radius_nt)} nT (the largest radius holding 95 % of the 3-D error at any of those "
            "points, not k u).")
    lines = [f" * {piece}" for piece in textwrap.wrap(said, NOTE_WIDTH)]
    lines.append(" * Budget, standard uncertainty of the calibrated field (nT):")
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


def _comment_rows(rows) -> list[str]:
    """(label, words) rows as comment lines, each wrapped below c_comment_text's limit and made safe."""
    out = []
    for label, words in rows:
        pieces = textwrap.wrap(f"{label}: {words}".replace("`", ""), NOTE_WIDTH, subsequent_indent="  ")
        out += [f" *   {c_comment_text(piece)}" for piece in pieces]
    return out


INLINE_LINES = [
    "#ifndef MAGRIG_INLINE",
    "#if defined(__STDC_VERSION__) && __STDC_VERSION__ >= 199901L",
    "#define MAGRIG_INLINE static inline",
    "#elif defined(__GNUC__)",
    "#define MAGRIG_INLINE static __inline__",
    "#else",
    "#define MAGRIG_INLINE static",
    "#endif",
    "#endif",
]


def c_header(
    form, *, name: str, source_sha256: str = "", version: str = __version__,
    description: str = "", uncertainty: dict | None = None, notes: list[str] | tuple[str, ...] = (),
    measurand: list[tuple[str, str]] | tuple = (), names_in_file: str = "",
) -> str:
    """A self-contained C89/C99 header of `form` (rig.report.exports.FlightForm): the constants plus
    `MAGRIG_INLINE void <name>_apply(...)`; in its opening comment the measurand's (label, words) rows
    (rig/analysis/measurand.py measurand_rows: reading, raw unit, tau, frames, indexing, reference chain,
    source), which of the file's parameters each array holds (`names_in_file`), `notes` (the file's
    equation, the fit's residual and any flag) and the uncertainty budget, every text made safe."""
    ident = c_identifier(name)
    macro = ident.upper()
    guard = names.header_guard(name)
    description = c_comment_text(description) if description else ""
    has_t_m = form.matrix_per_c is not None
    has_t_o = form.offset_nt_per_c is not None
    has_t2_m = getattr(form, "matrix_per_c2", None) is not None
    has_t2_o = getattr(form, "offset_nt_per_c2", None) is not None
    has_tau = has_t_m or has_t_o
    equation = "B = M(tau) (h - o(tau))" if form.offset_first else "B = M(tau) h + o(tau)"
    if not has_tau:
        tau_lines = [f" * {equation.replace('(tau)', '')}; this model has no temperature terms: temp_c is "
                     "ignored."]
    elif has_t2_m or has_t2_o:
        tau_lines = [f" * {equation}, with M(tau) = M + tau*M_PER_C + tau^2*M_PER_C2,",
                     " * o(tau) = O + tau*O_PER_C + tau^2*O_PER_C2,",
                     " * tau = temp_c, the DUT temperature in degC as measured (absolute: nothing is",
                     " * subtracted from it);"]
    elif form.tau_0_c is None:
        tau_lines = [f" * {equation}, with M(tau) = M + tau*M_PER_C, o(tau) = O + tau*O_PER_C,",
                     " * tau = temp_c, the DUT temperature in degC as measured (absolute: nothing is",
                     " * subtracted from it);"]
    else:
        tau_lines = [f" * {equation}, with M(tau) = M + tau*M_PER_C, o(tau) = O + tau*O_PER_C,",
                     f" * tau = temp_c - {macro}_TAU_0_C, the constant the calibration file states",
                     f" * as tau_0_c ({_c_num(form.tau_0_c)} degC);"]
    lines = [
        f"/* {ident}.h: magnetometer calibration exported by magrig {c_comment_text(version)}.",
        f" * model: {c_comment_text(form.model)}{' (' + description + ')' if description else ''}",
        f" * source sha256: {c_comment_text(source_sha256) if source_sha256 else 'unknown'}",
        *tau_lines,
        " * h_nt and b_nt in nT; the arrays are indexed [row][column], zero-based, row = output axis of B,",
        " * as the calibration file's parameters are."
        + (f" {c_comment_text(names_in_file)}" if names_in_file else ""),
        " * The measurand, as the calibration file states it:",
        *_comment_rows(measurand),
        *[f" * {c_comment_text(piece)}" for note in notes
          for piece in textwrap.wrap(note.replace("`", ""), NOTE_WIDTH)],
    ]
    lines += uncertainty_comment(uncertainty)
    lines += [
        " * MAGRIG_REAL is double by default (the export is checked against the host fit to 1e-9 relative",
        " * in double); define it as float before including this file on a single-precision target.",
        " * The header is C89 and C99 (MAGRIG_INLINE: static inline where the compiler has it).",
        " */",
        f"#ifndef {guard}",
        f"#define {guard}",
        "",
        "#ifndef MAGRIG_REAL",
        "#define MAGRIG_REAL double",
        "#endif",
        *INLINE_LINES,
        "",
        f"#define {macro}_MODEL {c_string(form.model)}",
        *([f"#define {macro}_TAU_0_C ({_c_num(form.tau_0_c)})"] if has_tau and form.tau_0_c is not None
          else []),
        _c_array(f"{macro}_M", form.matrix),
        _c_array(f"{macro}_O", form.offset_nt),
    ]
    if has_t_m:
        lines.append(_c_array(f"{macro}_M_PER_C", form.matrix_per_c))
    if has_t_o:
        lines.append(_c_array(f"{macro}_O_PER_C", form.offset_nt_per_c))
    if has_t2_m:
        lines.append(_c_array(f"{macro}_M_PER_C2", form.matrix_per_c2))
    if has_t2_o:
        lines.append(_c_array(f"{macro}_O_PER_C2", form.offset_nt_per_c2))
    m_term = f"{macro}_M[i][j] + tau * {macro}_M_PER_C[i][j]" if has_t_m else f"{macro}_M[i][j]"
    o_term = f"{macro}_O[i] + tau * {macro}_O_PER_C[i]" if has_t_o else f"{macro}_O[i]"
    if has_t2_m:
        m_term += f" + tau * tau * {macro}_M_PER_C2[i][j]"
    if has_t2_o:
        o_term += f" + tau * tau * {macro}_O_PER_C2[i]"
    v_term = f"h_nt[i] - ({o_term})" if form.offset_first else "h_nt[i]"
    if not has_tau:  # C89: every declaration before the first statement
        tau_decl, tau_use = [], ["    (void)temp_c;"]
    elif form.tau_0_c is None:
        tau_decl, tau_use = ["    const MAGRIG_REAL tau = temp_c;"], []
    else:
        tau_decl, tau_use = [f"    const MAGRIG_REAL tau = temp_c - {macro}_TAU_0_C;"], []
    lines += [
        "",
        "/* Calibrated field b_nt[3] from the raw reading h_nt[3] at DUT temperature temp_c (degC). */",
        f"MAGRIG_INLINE void {ident}_apply(const MAGRIG_REAL h_nt[3], MAGRIG_REAL temp_c,",
        "                                 MAGRIG_REAL b_nt[3])",
        "{",
        *tau_decl,
        "    MAGRIG_REAL v[3];",
        "    int i, j;",
        *tau_use,
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
