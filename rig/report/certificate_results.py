"""The certificate's results: every parameter of every calibration file with its expanded uncertainty
U = k u and coverage factor k, in the file's own numbering; where Monte Carlo (GUM S1) decided a budget,
the S1 coverage interval beside U; the calibrated field's figures under the file's own names; the budget.

    rows = parameter_rows(cal_file)          # what the results table and the DCC state (ParamValue)
    p, said = coverage_probability(record)   # the one coverage probability of the certificate

One coverage probability for every figure: 95.45 %, for which k = 2 with infinite degrees of freedom
(GUM G.2; calib/stats/student.py COVERAGE_PROBABILITY); the coverage factors of every file are t_95.45 of
their effective degrees of freedom. A file of format 2 labels its uncertainty `coverage_probability:
0.95` beside those k: the certificate states 95.45 % and says which file labels it otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calib.uncertainty.linearise import ParamLayout
from rig.report.calsection import PARAM_UNITS
from rig.report.html import ItemList, Section, Table

try:  # the one coverage probability, defined once in calib (calib/stats/student.py, issue 46)
    from calib.stats.student import COVERAGE_PROBABILITY
except ImportError:  # a calib before it: the probability for which k = 2 (P_K2), as format 3 rounds it
    from calib.stats.student import P_K2

    COVERAGE_PROBABILITY = round(P_K2, 4)
S1_KINDS = {"probabilistically_symmetric": "probabilistically symmetric (between the draws' 2.275 % and "
                                           "97.725 % quantiles)",
            "shortest": "the shortest interval holding 95.45 % of the draws"}


@dataclass(frozen=True)
class ParamValue:
    """One element of one parameter, as the certificate and the DCC state it."""

    label: str  # the calibration file's numbering: S[0][1], b_nt[2]
    name: str  # its parameter: S, b_nt
    value: float
    expanded: float  # U = k u
    k: float
    unit: str
    s1: tuple[float, float] | None = None  # the S1 coverage interval, where Monte Carlo decided


def labels(cal_file) -> list[str]:
    """The file's own numbering of its parameters' elements: its covariance's `parameters` where it lists
    them, else zero-based [row][column] in the order of `params` (the same rule)."""
    layout = ParamLayout.of(cal_file.cal.params)
    stated = ((cal_file.uncertainty.get("covariance") or {}).get("parameters")) or []
    return list(stated) if len(stated) == layout.size else layout.labels()


def s1_interval(cal_file) -> dict | None:
    """The file's `uncertainty.s1_interval` (format 3, where Monte Carlo decided), or None."""
    stated = cal_file.uncertainty.get("s1_interval")
    return stated if isinstance(stated, dict) and stated.get("parameters") else None


def parameter_rows(cal_file) -> list[ParamValue]:
    cal, u = cal_file.cal, cal_file.uncertainty
    expanded, factors = u.get("expanded") or {}, u.get("coverage_factors") or {}
    s1 = (s1_interval(cal_file) or {}).get("parameters") or {}
    names = iter(labels(cal_file))
    out = []
    for name, value in cal.params.items():
        flat = np.ravel(value)
        big_u = np.ravel(expanded.get(name, np.full(flat.shape, np.nan)))
        k = np.broadcast_to(np.ravel(factors.get(name, u.get("coverage_factor", np.nan))), flat.shape)
        low, high = (np.ravel(s1[name][i]) if name in s1 else None for i in (0, 1))
        for i, v in enumerate(flat):
            out.append(ParamValue(next(names), name, float(v), float(big_u[i]), float(k[i]),
                                  PARAM_UNITS.get(name, "-"),
                                  None if low is None else (float(low[i]), float(high[i]))))
    return out


def coverage_probability(record) -> tuple[float, list[str]]:
    """(95.45 %, what a file of format 2 says otherwise)."""
    said = []
    for cal_file in record.cals.values():
        stated = cal_file.uncertainty.get("coverage_probability")
        if stated is not None and not math.isclose(float(stated), COVERAGE_PROBABILITY, abs_tol=5e-5):
            said.append(f"{cal_file.path.name} labels its uncertainty coverage_probability {stated:g}; its "
                        "coverage factors are t_95.45 of their effective degrees of freedom (2 for "
                        "infinite), so its U are 95.45 % intervals; its field radius "
                        "(expanded_vector_error_nt) was made at 95 % (format 2)")
    return COVERAGE_PROBABILITY, said


def _fig(x, spec: str) -> str:
    return "-" if x is None or not np.isfinite(x) else format(float(x), spec)


def results_sections(record) -> list[Section]:
    """Results (every parameter with U, k and any S1 interval; the field's figures) and the budget."""
    p, said = coverage_probability(record)
    any_s1 = any(s1_interval(c) for c in record.cals.values())
    rows = []
    for model, cal_file in record.cals.items():
        for r in parameter_rows(cal_file):
            row = [model.upper(), r.label, _fig(r.value, ".8g"), r.unit, _fig(r.expanded, ".3g"),
                   _fig(r.k, ".3g")]
            if any_s1:
                row.append("-" if r.s1 is None else f"[{r.s1[0]:.8g}, {r.s1[1]:.8g}]")
            rows.append(row)
    header = ["model", "parameter (the file's numbering)", "value", "unit", "U = k u", "k"]
    header += ["S1 coverage interval"] if any_s1 else []
    blocks: list = [
        f"Every parameter with its expanded uncertainty U = k u (u its standard uncertainty), for a coverage "
        f"probability of {p * 100:.2f} %: k = t_{p * 100:.2f} of its effective degrees of freedom (GUM G.4), "
        "2 where every input is well known. Units: the table's; a temperature coefficient per degC is the "
        "same per kelvin. The calibration files hold the parameters' full covariance.",
        *_s1_said(record, p), *said,
        Table(header, rows, caption="Results (after adjustment: the calibration's parameters)")]
    budgets = []
    for model, cal_file in record.cals.items():
        u = cal_file.uncertainty
        blocks.append(_field_text(model, cal_file))
        lines = [[b["source"], _fig(b.get("contribution_nt"), ".3g"), b.get("method", ""), b.get("note", "")]
                 for b in u.get("budget", [])]
        budgets += [f"{model.upper()} ({cal_file.path.name}): method: {u.get('method', 'not stated')}",
                    Table(["source", "contribution (nT, standard uncertainty)", "propagation", "origin"],
                          lines, caption=f"{model.upper()} budget"),
                    ItemList(list(u.get("notes", [])), empty_text="no notes")]
    return [Section("Results", blocks), Section("Uncertainty budget", budgets)]


def _s1_said(record, p: float) -> list[str]:
    """Where Monte Carlo decided a budget: the S1 interval and its kind, or that the file states none."""
    out = []
    for model, cal_file in record.cals.items():
        s1 = s1_interval(cal_file)
        if s1 is not None:
            kind = S1_KINDS.get(s1.get("kind"), f"of kind {s1.get('kind')!r}")
            percent = float(s1.get("probability", p)) * 100
            out.append(f"{model.upper()}: Monte Carlo (GUM S1) decided its budget: beside U = k u, every "
                       f"parameter's {percent:.2f} % coverage interval from the draws (column S1 coverage "
                       f"interval): {kind}" + (
                           f"; the calibrated field's S1 radius {s1['vector_radius_nt']:.4g} nT"
                           if s1.get("vector_radius_nt") is not None else "") + ".")
        elif cal_file.uncertainty.get("monte_carlo"):
            out.append(f"{model.upper()}: Monte Carlo (GUM S1) decided its budget, but {cal_file.path.name} "
                       "(format 2) states no S1 interval at this probability and of a stated kind: only "
                       "U = k u is given.")
    return out


def _field_text(model: str, cal_file) -> str:
    """The calibrated field's figures, each under the file's own key."""
    u = cal_file.uncertainty
    parts = [f"combined_standard_nt {_fig(u.get('combined_standard_nt'), '.4g')} nT (u, RMS over the plan's "
             "fields and temperatures)",
             f"expanded_vector_error_nt {_fig(u.get('expanded_vector_error_nt'), '.4g')} nT (the largest "
             "radius of the calibrated field's error over those points)"]
    for key, what in (("vector_radius_nt", "the calibrated field's error radius"),
                      ("expanded_norm_error_nt", "the largest interval of |B|'s error")):
        if u.get(key) is not None:
            parts.append(f"{key} {_fig(u.get(key), '.4g')} nT ({what})")
    return f"{model.upper()} ({cal_file.path.name}), the calibrated field: " + "; ".join(parts) + "."
