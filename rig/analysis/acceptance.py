"""Acceptance per DUT: the plan's `acceptance:` limits turned into PASS or FAIL, with the failed criteria.

    verdicts = judge_session(session.path, plan, station, fits)   # after the fits of a completed run
    record(session, verdicts)                                      # the session's `acceptance` table
    write_summary_csv(path, session_name, station_name, verdicts)  # for a production line

Criteria (each only when the plan gives it; names as they appear in `failed`):
    heldout_rms        RMS error on held-out points (k-fold over whole points, rig/analysis/heldout.py):
                       vector error for vector models, |B| error for scalar ones
    fit_rms            RMS residual of the full fit
    uncertainty        the calibration's expanded vector uncertainty (its budget, rig/reference/budget.py); a
                       calibration without a budget fails it
    std_error.<name>   largest standard error of parameter <name>
    bounds.<name>      every element of parameter <name> within [low, high]
    lag                thermal lag time constant (calib/lag.py); data with no lag information (step and
                       dwell) is not judged on it, and says so in `notes`
    coverage           always: the DUT temperatures its calibration's data covers (the fit's
                       `temperature_range_c`, at the element where the lag was corrected) reach both ends of
                       the plan's range within the plan's stability band; a calibration that would
                       extrapolate over part of the range fails
A DUT whose model could not be fitted fails with criterion "fit".
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from calib.atomic import atomic_write
from rig.core.errors import ERRORS

PASS, FAIL = "PASS", "FAIL"
CSV_COLUMNS = ("session", "station", "dut", "type", "model", "verdict", "failed", "heldout_rms_nt",
               "fit_rms_nt", "expanded_uncertainty_nt", "lag_s", "samples", "notes")


@dataclass
class Verdict:
    dut: str
    model: str
    failed: list[str] = field(default_factory=list)
    figures: dict[str, float | None] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    dut_type: str = ""
    samples: int = 0

    @property
    def passed(self) -> bool:
        return not self.failed

    @property
    def verdict(self) -> str:
        return PASS if self.passed else FAIL

    def line(self) -> str:
        """`mmc0 PASS` or `mmc0 FAIL (heldout_rms 212 nT > 150, bounds.b_nt)`."""
        return f"{self.dut} {self.verdict}" + (f" ({', '.join(self.failed)})" if self.failed else "")


def _finite(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def heldout_rms_nt(ds, model: str, robust: bool) -> float | None:
    """RMS error on held-out points: k-fold with whole points held out (as the report does)."""
    import calib
    from calib.models import REGISTRY
    from rig.analysis import heldout

    points = ds.columns.get("point")
    folds, _ = heldout.fold_of_each_row(ds, labels=points if points is not None else ds.group)
    score = heldout.cross_validate(ds, model, lambda d, m: calib.fit(d, m, robust=robust), folds)
    return _finite(score.heldout_vector_rms if REGISTRY[model].vector else score.heldout_norm_rms)


def _lag_s(ds) -> tuple[float | None, str | None]:
    from calib.lag import estimate_lag

    t = ds.columns.get("t")
    if t is None or ds.temp_c is None or ds.ref_nt is None:
        return None, "lag not judged: no times, temperatures or reference vectors"
    result = estimate_lag(t, ds.h_nt, ds.temp_c, ds.ref_nt)
    return (result.tau_s, None) if result.identifiable else (None, f"lag not judged: {result.message}")


def coverage_problem(cal, range_c: tuple[float, float] | None, band_c: float | None,
                     figures: dict) -> str | None:
    """What the calibration's data misses of the plan's range (None: it covers it within band_c)."""
    covered = cal.stats.get("temperature_range_c")
    if range_c is None or band_c is None or covered is None:
        return None
    low, high = covered
    figures["temperature_low_c"], figures["temperature_high_c"] = low, high
    lo, hi = range_c
    if low <= lo + band_c and high >= hi - band_c:
        return None
    return (f"coverage {low:.2f} .. {high:.2f} degC at the DUT does not reach the plan's {lo:g} .. {hi:g} "
            f"degC within {band_c:g}")


def judge(acceptance, ds, cal, *, robust: bool = False, range_c: tuple[float, float] | None = None,
          band_c: float | None = None) -> tuple[list[str], dict, list[str]]:
    """(failed criteria, figures, notes) of one DUT's calibration `cal` fitted to `ds`; `range_c` and
    `band_c`: the plan's temperature range and stability band its data must cover."""
    failed: list[str] = []
    notes: list[str] = []
    figures: dict[str, float | None] = {"fit_rms_nt": _finite(cal.stats.get("rms_after_nt"))}
    if problem := coverage_problem(cal, range_c, band_c, figures):
        failed.append(problem)
    figures["heldout_rms_nt"] = heldout_rms_nt(ds, cal.model, robust)
    figures["expanded_uncertainty_nt"] = _finite((cal.uncertainty or {}).get("expanded_vector_error_nt"))
    for name, limit, figure in (("heldout_rms", acceptance.max_heldout_rms_nt, "heldout_rms_nt"),
                                ("fit_rms", acceptance.max_rms_nt, "fit_rms_nt"),
                                ("uncertainty", acceptance.max_expanded_uncertainty_nt,
                                 "expanded_uncertainty_nt")):
        if limit is None:
            continue
        value = figures[figure]
        if value is None or value > limit:
            shown = "not computable" if value is None else f"{value:.4g} nT"
            failed.append(f"{name} {shown} > {limit:g}")
    for name, limit in acceptance.max_std_error.items():
        se = float(np.max(np.abs(cal.std_errors[name])))
        figures[f"std_error.{name}"] = se
        if not se <= limit:
            failed.append(f"std_error.{name} {se:.3g} > {limit:g}")
    for name, (low, high) in acceptance.bounds.items():
        values = np.asarray(cal.params[name], float)
        outside = values[(values < low) | (values > high)]
        if outside.size:
            failed.append(f"bounds.{name} {float(outside[np.argmax(np.abs(outside))]):.4g} "
                          f"outside [{low:g}, {high:g}]")
    if acceptance.max_lag_s is not None:
        lag, note = _lag_s(ds)
        figures["lag_s"] = lag
        if note:
            notes.append(note)
        elif lag is not None and lag > acceptance.max_lag_s:
            failed.append(f"lag {lag:.0f} s > {acceptance.max_lag_s:g}")
    return failed, figures, notes


def judge_session(session_path, plan, station, fits: list[dict]) -> list[Verdict]:
    """One verdict per DUT of the station, on the plan's acceptance model (the first fitted model unless
    `acceptance.model` names another)."""
    from rig.session.reader import each_dataset

    acceptance = plan.acceptance
    model = plan.judged_model
    out = []
    for dut, ds in each_dataset(session_path, station.duts):
        v = Verdict(dut.name, model, dut_type=dut.device_type)
        entry = next((f for f in fits if f["dut"] == dut.name and f["model"] == model), None)
        if entry is None or entry.get("calibration") is None:
            v.failed.append("fit")
            v.notes.append(str((entry or {}).get("error") or f"no {model} fit"))
            out.append(v)
            continue
        try:
            if isinstance(ds, Exception):
                raise ds  # handled below: the DUT could not be read
            v.samples = len(ds)
            v.failed, v.figures, v.notes = judge(acceptance, ds, entry["calibration"], robust=plan.fit.robust,
                                                 range_c=plan.temperatures.covered_c(),
                                                 band_c=plan.temperatures.band_c())
        except ERRORS as exc:
            v.failed.append("fit")
            v.notes.append(str(exc))
        out.append(v)
    return out


def rows(verdicts: list[Verdict]) -> list[dict[str, Any]]:
    """The `acceptance` table's rows (`passed` is what the fleet database reads)."""
    return [{"dut": v.dut, "model": v.model, "passed": int(v.passed), "verdict": v.verdict,
             "failed": "; ".join(v.failed), "heldout_rms_nt": v.figures.get("heldout_rms_nt"),
             "fit_rms_nt": v.figures.get("fit_rms_nt"), "lag_s": v.figures.get("lag_s"),
             "notes": "; ".join(v.notes)} for v in verdicts]


def summary_csv_path(session_path: str | Path) -> Path:
    """The production summary beside the session: <session stem>.acceptance.csv."""
    session_path = Path(session_path)
    return session_path.with_name(session_path.name.removesuffix(".session") + ".acceptance.csv")


def write_summary_csv(path: Path, session: str, station: str, verdicts: list[Verdict]) -> Path:
    """One row per DUT, written atomically (never half a file)."""
    with atomic_write(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(CSV_COLUMNS)
        for v in verdicts:
            fig = {k: ("" if v.figures.get(k) is None else f"{v.figures[k]:.6g}")
                   for k in ("heldout_rms_nt", "fit_rms_nt", "expanded_uncertainty_nt", "lag_s")}
            writer.writerow([session, station, v.dut, v.dut_type, v.model, v.verdict, "; ".join(v.failed),
                             fig["heldout_rms_nt"], fig["fit_rms_nt"], fig["expanded_uncertainty_nt"],
                             fig["lag_s"], v.samples, "; ".join(v.notes)])
    return path


def verdict_text(recorded: list[dict]) -> str:
    """`rig sessions`' column: "PASS 16/16", "FAIL 2/16: mmc03, ser1", or "-" without acceptance."""
    if not recorded:
        return "-"
    failed = [r["dut"] for r in recorded if not r["passed"]]
    if not failed:
        return f"PASS {len(recorded)}/{len(recorded)}"
    return f"FAIL {len(failed)}/{len(recorded)}: {', '.join(failed)}"
