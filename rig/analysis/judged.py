"""The calibration a session's plan judges, and what a calibration's numbers mean, in the words every
display uses: `rig run`'s summary, `rig sessions`, the cockpit, the report and the C header read them
here, so they give one answer.

    model, fits = judged_fits(reader)      # the plan's judged model, each DUT's last recorded judged fit
    judged_for_dut("t24", {"t24": cal24, "t36": cal36})   # "t36" when T24's temperature check chose it
    q = quality(cal.stats, cal.uncertainty)
    q.rms_nt, q.radius_nt, q.exceeds, q.dominant     # residual, stated 95 % radius, flag, what dominates
    f = field_figures(cal.uncertainty)               # u, k, U = k u and the radius, each by its own name

The phrase for what dominates an uncertainty comes from the calibration's own budget lines (their
source and note), never from the station or its simulator.

Every number keeps its own name: the combined standard uncertainty u of the calibrated field (RMS over the
plan's fields and temperatures), its expanded uncertainty U = k u (labelled "expanded (k = K)", and always
K times u), and the largest radius holding 95 % of the 3-D error at any of those points (a radius over a
grid, not k u: RADIUS_LABEL).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

from rig.core.errors import ERRORS

MAX_NAMED_DUTS = 3  # a listing's cell names each DUT's residual up to this many, else the largest
RADIUS_LABEL = "95 % error radius (nT, largest over the plan's grid)"  # every table's column for radius_nt
RADIUS_KEYS = ("vector_radius_nt", "expanded_vector_error_nt")  # the uncertainty section's name for it

# what to do about the largest budget line: (source, words its note must contain, advice)
ADVICE = (
    ("coil matrix", "not commissioned", "run `rig commission`"),
    ("table axes", "not commissioned", "run `rig commission`"),
    ("fit (statistical)", "", "more samples per point, or a quieter sensor"),
)


def _number(x: object) -> float | None:
    if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
        return None
    return float(x)


@dataclass(frozen=True)
class Quality:
    """A calibration's residual beside the uncertainty it states."""

    rms_nt: float | None
    radius_nt: float | None  # the largest 95 % radius of the 3-D error over the plan's grid
    dominant: str | None  # what dominates that uncertainty, in one phrase
    coverage_factor: float | None = None

    @property
    def exceeds(self) -> bool:
        """The fit's residual is larger than the error it claims: the model does not describe the sensor
        to its stated uncertainty, or the sensor's noise alone is larger than it."""
        return self.rms_nt is not None and self.radius_nt is not None and self.rms_nt > self.radius_nt

    def exceeds_text(self) -> str:
        """One sentence for a flagged fit ("" when it is not flagged)."""
        if not self.exceeds:
            return ""
        return (f"residual RMS {self.rms_nt:.1f} nT is above its stated 95 % error radius "
                f"{self.radius_nt:.1f} nT: the fit leaves more than the budget states (a model error, or "
                "noise above the stated uncertainty)")

    def uncertainty_text(self) -> str:
        return "-" if self.radius_nt is None else f"{self.radius_nt:.1f}"


@dataclass(frozen=True)
class FieldFigures:
    """The calibrated field's uncertainty figures of a calibration's `uncertainty:` section, each by the
    name it is shown under (module doc)."""

    standard_nt: float | None  # u: the combined standard uncertainty (RMS over the plan's grid)
    coverage_factor: float | None  # k
    radius_nt: float | None  # the largest radius holding 95 % of the 3-D error at a grid point

    @property
    def expanded_nt(self) -> float | None:
        """U = k u: what "expanded (k = K)" labels, K times the standard uncertainty shown beside it."""
        if self.standard_nt is None or self.coverage_factor is None:
            return None
        return self.coverage_factor * self.standard_nt


def field_figures(uncertainty: dict | None) -> FieldFigures:
    u = uncertainty if isinstance(uncertainty, dict) else {}
    return FieldFigures(_number(u.get("combined_standard_nt")), _number(u.get("coverage_factor")),
                        vector_radius_nt(u))


def vector_radius_nt(uncertainty: dict | None) -> float | None:
    """The section's largest 95 % radius of the 3-D error (RADIUS_KEYS: its name, and the older one)."""
    u = uncertainty if isinstance(uncertainty, dict) else {}
    return next((_number(u[key]) for key in RADIUS_KEYS if _number(u.get(key)) is not None), None)


def quality(stats: dict | None, uncertainty: dict | None) -> Quality:
    stats = stats if isinstance(stats, dict) else {}
    u = uncertainty if isinstance(uncertainty, dict) else {}
    return Quality(_number(stats.get("rms_after_nt")), vector_radius_nt(u), dominant_phrase(u),
                   _number(u.get("coverage_factor")))


def quality_of(cal) -> Quality:
    """Of a calib Calibration, or of its dict (a calibration file's or a session's record)."""
    if isinstance(cal, dict):
        return quality(cal.get("stats"), cal.get("uncertainty"))
    return quality(cal.stats, cal.uncertainty)


def dominant_phrase(uncertainty: dict | None) -> str | None:
    """The largest line of the budget in one phrase, e.g. "coil matrix 1227 nT (declared, 10000 ppm per
    element: not commissioned): run `rig commission`"; None without a budget."""
    lines = [b for b in (uncertainty or {}).get("budget") or []
             if isinstance(b, dict) and _number(b.get("contribution_nt")) is not None]
    if not lines:
        return None
    top = max(lines, key=lambda b: b["contribution_nt"])
    source, note = str(top.get("source", "?")), str(top.get("note") or "")
    text = f"{source} {top['contribution_nt']:.4g} nT" + (f" ({note})" if note else "")
    advice = next((a for s, words, a in ADVICE if s == source and words in note), None)
    return text + (f": {advice}" if advice else "")


# --- a session's judged calibration ------------------------------------------------------------------
def _stats_of(cal: object) -> dict:
    stats = cal.get("stats") if isinstance(cal, dict) else getattr(cal, "stats", None)
    return stats if isinstance(stats, dict) else {}


def chosen_temperature_model(t24: object) -> str | None:
    """What a T24 calibration's temperature-model choice chose ("t24" or "t36"; rig/analysis/tempchoice.py),
    None when none was made (its linearity in temperature did not fail)."""
    choice = _stats_of(t24).get("temperature_model")
    return choice.get("model") if isinstance(choice, dict) else None


def judged_for_dut(plan_model: str | None, calibrations: dict[str, object]) -> str | None:
    """One DUT's judged model among its calibrations ({model: Calibration or its dict}): the plan's, except
    T36 where the plan judges T24, T24's linearity in temperature failed and T36 validated better on
    held-out blocks of the session's own data."""
    if plan_model == "t24" and "t36" in calibrations and \
            chosen_temperature_model(calibrations.get("t24")) == "t36":
        return "t36"
    return plan_model


def judged_model(info: dict, models_recorded: list[str]) -> str | None:
    """The model the session's recorded plan judges (rig.config.Plan.judged_model); for a plan that can no
    longer be read, the first model recorded."""
    from rig.config import Plan
    from rig.core.yamlload import load_model

    try:
        return load_model(Plan, "recorded plan", info["plan_text"]).judged_model
    except (*ERRORS, KeyError):
        return models_recorded[0] if models_recorded else None


def judged_fits(reader) -> tuple[str | None, dict[str, dict]]:
    """(the plan's judged model, {DUT: its last recorded fit of its judged model (judged_for_dut; the fit's
    `model` says which), `calibration` parsed}) of a session."""
    fits = reader.fits()
    model = judged_model(reader.info(), list(dict.fromkeys(f["model"] for f in fits)))
    last: dict[str, dict[str, dict]] = {}
    for fit in fits:
        try:
            calibration = json.loads(fit["calibration_json"])
        except (ValueError, TypeError):
            calibration = {}
        last.setdefault(fit["dut"], {})[fit["model"]] = {
            **fit, "calibration": calibration if isinstance(calibration, dict) else {}}
    out: dict[str, dict] = {}
    for dut, by_model in last.items():
        chosen = judged_for_dut(model, {m: f["calibration"] for m, f in by_model.items()})
        if chosen in by_model:
            out[dut] = by_model[chosen]
    return model, out


def judged_cell(model: str | None, fits: dict[str, dict]) -> str:
    """The judged calibration's residual in one cell: `t24 RMS: mmc0 29.0, serial0 17.4 nT`, or the largest
    of many DUTs; a DUT judged on another model than the plan's (T36 chosen) named with it; flagged DUTs
    named after `RMS > radius:`."""
    if model is None or not fits:
        return "no fit" if model is None else f"no {model} fit"
    rms = {dut: fit.get("residual_rms_nt") for dut, fit in fits.items()}
    known = {d: r for d, r in rms.items() if r is not None}

    def named(dut: str) -> str:
        other = fits[dut].get("model", model)
        return dut if other == model else f"{dut} ({other})"

    if not known:
        text = f"{model} (no residual)"
    elif len(known) <= MAX_NAMED_DUTS:
        text = f"{model} RMS: " + ", ".join(f"{named(d)} {r:.1f}" for d, r in known.items()) + " nT"
    else:
        worst = max(known, key=known.get)
        text = f"{model} RMS: largest {known[worst]:.1f} nT ({named(worst)}) of {len(known)} DUTs"
        others = sorted({str(f.get("model")) for f in fits.values()} - {model})
        if others:
            text += f"; {sum(f.get('model') != model for f in fits.values())} judged on {', '.join(others)}"
    flagged = [d for d, fit in fits.items() if quality_of(fit["calibration"]).exceeds]
    return text + (f" [RMS > radius: {', '.join(flagged)}]" if flagged else "")
