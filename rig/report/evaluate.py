"""One DUT judged: the calibration to show (the one the run wrote, or the given file's; else one fitted
here), its outliers found, the models re-fitted here and compared on held-out points (a session's: the
plan's models with the plan's options; a calibration file's: every model the data allows, robust), and the
data-quality warnings collected."""

from __future__ import annotations

import dataclasses

import numpy as np

from calib.models.registry import MODELS
from rig.analysis import heldout
from rig.core.errors import DataError, FitError
from rig.report.sources import DutInput, StepInfo, listed


@dataclasses.dataclass
class DutResult:
    name: str
    ds: object
    main: object  # the calibration whose residuals are shown
    fits: dict  # model -> Calibration fitted here
    errors: heldout.Errors
    scores: list[heldout.ModelScore]
    fold_text: str
    steps: list[heldout.StepRow]
    warnings: list[str]
    given: bool  # main came from a calibration file, not from a fit made here
    outliers: np.ndarray  # rows left out of the residuals shown (see heldout.outlier_rows)
    uncertainty: dict | None = None  # the budget to show (DutInput.uncertainty)
    uncertainty_of: str = ""
    origin: str = ""  # DutInput.origin
    others: list = dataclasses.field(default_factory=list)  # DutInput.others
    robust: bool = True  # the comparison's re-fits


def fit_model(ds, model: str, robust: bool = True):
    import calib

    return calib.fit(ds, model, robust=robust)


def analyse_dut(d: DutInput, steps_info: dict[int, StepInfo]) -> DutResult:
    ds = d.dataset
    warnings: list[str] = []
    if len(ds) == 0:
        raise DataError(f"{ds.source.get('path', d.name)}: DUT {d.name}: no usable samples")
    if heldout.reference_norm_nt(ds) is None:
        ds = _with_constant_norm(ds, d, warnings)
    fits, failures = {}, {}
    allowed = heldout.models_for(ds)
    compared = [m for m in d.compare_models if m in allowed] if d.compare_models is not None else allowed

    def refit(part, model):
        return fit_model(part, model, d.compare_robust)

    for model in compared:
        try:
            fits[model] = refit(ds, model)
        except (FitError, DataError) as exc:
            failures[model] = str(exc)
    main = d.calibration or next(iter(fits.values()), None)  # the first compared: the judged model
    if main is None:
        detail = "; ".join(f"{m}: {msg}" for m, msg in failures.items()) or "no reference in the data"
        raise FitError(f"{ds.source.get('path', d.name)}: DUT {d.name}: no model can be fitted ({detail})")
    err = heldout.errors(ds, main)
    points = ds.columns.get("point")
    folds, fold_text = heldout.fold_of_each_row(ds, labels=points if points is not None else ds.group)
    outliers = heldout.outlier_rows(main, err)
    # a model that cannot be fitted to all the data is not cross-validated: its row says why
    scores = [
        heldout.cross_validate(ds, m, refit, folds, fits[m], outliers)
        if m in fits
        else heldout.ModelScore(m, note=f"cannot fit: {failures[m]}")
        for m in MODELS
        if m in fits or m in failures
    ]
    step_rows = heldout.step_table(ds, outliers, err)
    direction = ds.ref_nt if ds.ref_nt is not None else err.field_after
    gaps = heldout.coverage_gaps(direction)
    warnings += _dut_warnings(d, ds, main, outliers, fits, failures, step_rows, steps_info, gaps)
    return DutResult(
        name=d.name,
        ds=ds,
        main=main,
        fits=fits,
        errors=err,
        scores=scores,
        fold_text=fold_text,
        steps=step_rows,
        warnings=warnings,
        given=d.calibration is not None,
        outliers=outliers,
        uncertainty=d.uncertainty,
        uncertainty_of=d.uncertainty_of,
        origin=d.origin,
        others=d.others,
        robust=d.compare_robust,
    )


def _with_constant_norm(ds, d: DutInput, warnings: list[str]):
    """No reference at all: judge |B| against a constant field, the median calibrated magnitude."""
    if d.calibration is None:
        raise DataError(
            f"{ds.source.get('path', d.name)}: no reference field (bx,by,bz) or magnitude in the "
            f"data: nothing to judge a calibration against"
        )
    norm = float(np.median(np.linalg.norm(d.calibration.apply(ds.h_nt, ds.temp_c), axis=1)))
    warnings.append(
        f"the data has no reference field: |B| errors are against a constant {norm:.6g} nT "
        f"(median calibrated magnitude); vector residuals cannot be shown"
    )
    return dataclasses.replace(ds, ref_norm_nt=np.full(len(ds), norm))


def _dut_warnings(d, ds, main, outliers, fits, failures, step_rows, steps_info, gaps) -> list[str]:
    out = []
    n_out = int(outliers.sum())
    how = "the robust fit" if main.outliers is not None else "their residual against the given calibration"
    if n_out:
        where = [f"step {r.step} ({r.temp_c:.1f} °C): {r.outliers}" for r in step_rows if r.outliers]
        points = ds.columns.get("point")
        extra = ""
        if points is not None:
            ids = sorted({str(p) for p in np.asarray(points)[outliers]})
            extra = f"; points {listed(ids)}"
        out.append(
            f"{n_out} outlier sample(s) of the {main.model.upper()} calibration, flagged by {how}, left out "
            f"({'; '.join(where)}){extra}"
        )
    for flag, ids in sorted(d.flagged.items()):
        out.append(f"{d.flagged_rows[flag]} sample(s) flagged '{flag}' (not fitted) at points {listed(ids)}")
    rejected = int(ds.source.get("rows_rejected", 0) or 0)
    if rejected and not d.flagged:
        out.append(f"{rejected} row(s) of {ds.source.get('path', 'the input')} were rejected when reading")
    for model, msg in failures.items():
        out.append(f"{model.upper()} cannot be fitted: {msg}")
    for cal in [main, *fits.values()]:
        for w in cal.stats.get("warnings", []) if isinstance(cal.stats, dict) else []:
            out.append(f"{cal.model.upper()}: {w}")
    if gaps:
        worst = max(gaps, key=lambda g: g[2])
        out.append(
            f"direction coverage: {len(gaps)} of {heldout.COVERAGE_PROBES} probe directions have no sample "
            f"within {heldout.COVERAGE_GAP_DEG:g}°; the largest gap is around az {worst[0]:.0f}°, "
            f"el {worst[1]:.0f}° (nearest sample {worst[2]:.0f}° away)"
        )
    planned = {s.temp_index for s in steps_info.values()}
    missing = sorted(planned - {r.step for r in step_rows})
    if missing:
        out.append(f"temperature step(s) {', '.join(map(str, missing))} have no usable samples")
    return list(dict.fromkeys(out))  # the main fit is usually also in fits
