"""What `rig run` says before and after a campaign, as lines and table rows (the CLI prints them):
which station (its file), whether it is simulated (and which devices), what will dominate the
uncertainty, and after the run each calibration's residual beside its stated uncertainty, flagged where
the residual is the larger, with what dominates that uncertainty in one phrase.

    header_lines(station, station_path)        # before the first point
    outcome_lines(outcome), calibration_rows(outcome), calibration_files(outcome),
    calibration_notes(outcome)                                                        # after the run
"""

from __future__ import annotations

from pathlib import Path

from rig.analysis.judged import RADIUS_LABEL, judged_for_dut, quality_of
from rig.core.errors import ERRORS
from rig.session.reader import SessionReader, runs_on_simulated_clock, simulated_text

CALIBRATION_COLUMNS = ("DUT", "model", "samples", "residual RMS (nT)", RADIUS_LABEL, "check")
LEGEND = ("judged: the model the plan judges (its acceptance.model, else the first of fit.models; T36 for a "
          "DUT whose T24 failed its linearity in temperature and whose T36 validated better); "
          "95 % error radius: the largest radius holding 95 % of the calibrated field's 3-D error at a point "
          "of the plan's fields and temperatures (a radius over that grid, not k u); check: RMS > radius "
          "where the residual exceeds it")


def station_line(name: str, path: str | Path | None, simulated: dict[str, bool]) -> str:
    clock = ("; on a simulated clock: hours of chamber time pass in seconds of wall time"
             if runs_on_simulated_clock(simulated) else "")
    return f"station {name} ({path or 'path not recorded'}): {simulated_text(simulated)}{clock}"


def header_lines(station, station_path: str | Path | None) -> list[str]:
    """The first lines of a run: the station and, when there is one, why the uncertainties will be large."""
    lines = [station_line(station.name, station_path, station.simulated_devices())]
    caveat = station.field_source.uncertainty_caveat()
    return lines + ([f"note: {caveat}"] if caveat else [])


def outcome_lines(outcome) -> list[str]:
    """The session, its status, and its times: the wall clock, and a simulated clock beside it."""
    r = outcome.result
    clock = ""
    try:
        with SessionReader(outcome.session_path) as reader:
            info = reader.info()
    except ERRORS:
        info = None
    if info is not None and runs_on_simulated_clock(info["simulated"]) and info["ended"] is not None:
        clock = f" ({(info['ended'] - info['started']) / 3600:.2f} h on the simulated clock)"
    lines = [f"session {outcome.session_path}: {r.status} ({r.reason}); {r.points_done} points; "
             f"wall time {outcome.wall_s:.1f} s{clock}"]
    if info is not None:
        lines.append(station_line(info["station_name"], info["station_path"], info["simulated"]))
    return lines


def judged_model(outcome) -> str | None:
    return getattr(outcome, "judged_model", None)


def judged_models(outcome) -> dict[str, str | None]:
    """{DUT: its judged model} (rig/analysis/judged.py `judged_for_dut`: the plan's, or T36 where chosen)."""
    fitted: dict[str, dict] = {}
    for f in outcome.fits:
        if f.get("calibration") is not None:
            fitted.setdefault(f["dut"], {})[f["model"]] = f["calibration"]
    return {dut: judged_for_dut(judged_model(outcome), cals) for dut, cals in fitted.items()}


def calibration_rows(outcome) -> list[list[str]]:
    """One row per fit: the judged model marked (the one the plan judges: acceptance.model, else the first
    of fit.models), the residual beside the stated 95 % error radius, and the check (`RMS > radius` where
    the residual is the larger)."""
    rows = []
    judged = judged_models(outcome)
    for f in outcome.fits:
        cal = f.get("calibration")
        q = quality_of(cal) if cal is not None else None
        rms = "-" if f.get("rms_nt") is None else f"{f['rms_nt']:.1f}"
        check = ("not fitted" if q is None else "-" if q.radius_nt is None
                 else "RMS > radius" if q.exceeds else "ok")
        model = f["model"] + (" (judged)" if f["model"] == judged.get(f["dut"]) else "")
        rows.append([f["dut"], model, str(f.get("n", "-")), rms, "-" if q is None else q.uncertainty_text(),
                     check])
    return rows


def calibration_files(outcome) -> list[str]:
    """Each file written, on a line of its own (operators copy them), or why a fit has none."""
    return [f"wrote {f['path']}" if f.get("path") else
            f"{f['dut']} {f['model']}: not fitted: {f.get('error')}" for f in outcome.fits]


def calibration_notes(outcome) -> list[str]:
    """Under the table: what dominates each judged calibration's uncertainty, every flagged fit, and what
    the calibrations' field rests on where no commissioned reference stands behind it."""
    from rig.analysis.measurand import reference_chain_words

    judged = judged_models(outcome)
    lines, dominant, chains = [], {}, {}
    for f in outcome.fits:
        cal = f.get("calibration")
        if cal is None:
            continue
        if not (cal.reference_chain or {}).get("traceable"):
            chains.setdefault(reference_chain_words(cal.reference_chain), []).append(f["dut"])
        q = quality_of(cal)
        if f["model"] == judged.get(f["dut"]) and q.dominant:
            dominant.setdefault((q.dominant, f["model"]), []).append(f["dut"])
        if q.exceeds:
            lines.append(f"{f['dut']} {f['model']}: {q.exceeds_text()}")
    shared = [f"uncertainty of {', '.join(duts)} {model}: largest contribution {phrase}"
              for (phrase, model), duts in dominant.items()]
    chained = [f"{', '.join(dict.fromkeys(duts))}: {words}" for words, duts in chains.items()]
    return [LEGEND, *shared, *chained, *lines]


def next_steps(outcome) -> list[str]:
    """What a user does next with a completed session."""
    if not outcome.fits:
        return []
    return [f"next: rig report {outcome.session_path} -o report/   (the report: figures, budgets, checks); "
            f"rig sessions {Path(outcome.session_path).parent}   (every session there)"]
