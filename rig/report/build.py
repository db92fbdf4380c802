"""Build the calibration report: fit every model the data allows, compare them on held-out points,
collect data-quality warnings, draw the figures and write one self-contained HTML file plus the PNGs.

    path = build_report(SESSION_OR_CAL, data=None, dut=None, out_dir="report")
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np

from rig.errors import DataError, FitError, MagrigError
from rig.report import analysis, figures
from rig.report.html import Image, ItemList, Section, Table, images_in, render_html
from rig.report.sources import (
    DutInput,
    ReportInputs,
    StepInfo,
    from_calibration,
    from_session,
    is_session_file,
)
from rig.report.sources import listed as _listed

PARAM_UNITS = {
    "S": "-",
    "K": "1/°C",
    "b_nt": "nT",
    "kb_nt_per_c": "nT/°C",
    "k": "-",
    "angles_deg": "deg",
    "b_nt_p12": "nT",
    "A": "-",
    "c_nt": "nT",
    "KA_per_c": "1/°C",
    "kc_nt_per_c": "nT/°C",
}


def build_report(
    source: str | Path,
    *,
    data: str | Path | None = None,
    dut: str | None = None,
    out_dir: str | Path = "report",
) -> Path:
    """Write report.html and its PNG figures into out_dir; return the HTML path."""
    return write_report(read_inputs(source, data=data, dut=dut), out_dir)[0]


def write_report(inputs: ReportInputs, out_dir: str | Path) -> list[Path]:
    """Analyse, draw and write: returns [the HTML page, *the PNG figures]."""
    sections = report_sections(inputs)
    out = Path(out_dir)
    written = [out / "report.html"]
    try:
        out.mkdir(parents=True, exist_ok=True)
        for img in images_in(sections):
            written.append(out / img.filename)
            written[-1].write_bytes(img.png)
        written[0].write_text(
            render_html(inputs.title, sections, subtitle=_subtitle(inputs)), encoding="utf-8"
        )
    except OSError as exc:
        raise DataError(f"{out}: cannot write the report: {exc.strerror or exc}") from None
    return written


def read_inputs(
    source: str | Path, *, data: str | Path | None = None, dut: str | None = None
) -> ReportInputs:
    path = Path(source)
    if not path.is_file():
        raise DataError(f"{path}: no such file (expected a session file or a calibration file)")
    if is_session_file(path):
        if data is not None:
            raise DataError(f"{path}: is a session file; --data is only for a calibration file")
        return from_session(path, dut)
    return from_calibration(path, data, dut)


def _subtitle(inputs: ReportInputs) -> str:
    return "; ".join(f"{k}: {v}" for k, v in inputs.provenance[:2])


# ---------------------------------------------------------------------------------------------- analysis


@dataclasses.dataclass
class DutResult:
    name: str
    ds: object
    main: object  # the calibration whose residuals are shown
    fits: dict  # model -> Calibration
    fit_failures: dict  # model -> message
    errors: analysis.Errors
    scores: list[analysis.ModelScore]
    fold_text: str
    steps: list[analysis.StepRow]
    gaps: list[tuple[float, float, float]]
    warnings: list[str]
    given: bool  # main came from a calibration file, not from a fit made here
    outliers: np.ndarray  # rows left out of the residuals shown (see analysis.outlier_rows)


def fit_model(ds, model: str):
    import calib

    return calib.fit(ds, model, robust=True)


def analyse_dut(d: DutInput, steps_info: dict[int, StepInfo]) -> DutResult:
    ds = d.dataset
    warnings: list[str] = []
    if len(ds) == 0:
        raise DataError(f"{ds.source.get('path', d.name)}: DUT {d.name}: no usable samples")
    if analysis.reference_norm_nt(ds) is None:
        ds = _with_constant_norm(ds, d, warnings)
    fits, failures = {}, {}
    for model in analysis.models_for(ds):
        try:
            fits[model] = fit_model(ds, model)
        except (FitError, DataError) as exc:
            failures[model] = str(exc)
    main = d.calibration or fits.get("t24") or next(iter(fits.values()), None)
    if main is None:
        detail = "; ".join(f"{m}: {msg}" for m, msg in failures.items()) or "no reference in the data"
        raise FitError(f"{ds.source.get('path', d.name)}: DUT {d.name}: no model can be fitted ({detail})")
    err = analysis.errors(ds, main)
    points = ds.columns.get("point")
    folds, fold_text = analysis.fold_of_each_row(ds, labels=points if points is not None else ds.group)
    outliers = analysis.outlier_rows(main, err)
    scores = [
        analysis.cross_validate(ds, m, fit_model, folds, fits.get(m), outliers)
        for m in analysis.MODELS
        if m in fits or m in failures
    ]
    for score in scores:
        if score.model in failures:
            score.note = f"cannot fit: {failures[score.model]}"
    step_rows = analysis.step_table(ds, outliers, err)
    direction = ds.ref_nt if ds.ref_nt is not None else err.field_after
    gaps = analysis.coverage_gaps(direction)
    warnings += _dut_warnings(d, ds, main, outliers, fits, failures, step_rows, steps_info, gaps)
    return DutResult(
        d.name,
        ds,
        main,
        fits,
        failures,
        err,
        scores,
        fold_text,
        step_rows,
        gaps,
        warnings,
        d.calibration is not None,
        outliers,
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
            extra = f"; points {_listed(ids)}"
        out.append(
            f"{n_out} outlier sample(s) of the {main.model.upper()} calibration, flagged by {how}, left out "
            f"({'; '.join(where)}){extra}"
        )
    for flag, ids in sorted(d.flagged.items()):
        out.append(f"{d.flagged_rows[flag]} sample(s) flagged '{flag}' (not fitted) at points {_listed(ids)}")
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
            f"direction coverage: {len(gaps)} of 200 probe directions have no sample within "
            f"{analysis.COVERAGE_GAP_DEG:g}°; the largest gap is around az {worst[0]:.0f}°, "
            f"el {worst[1]:.0f}° (nearest sample {worst[2]:.0f}° away)"
        )
    planned = {s.temp_index for s in steps_info.values()}
    missing = sorted(planned - {r.step for r in step_rows})
    if missing:
        out.append(f"temperature step(s) {', '.join(map(str, missing))} have no usable samples")
    return list(dict.fromkeys(out))  # the main fit is usually also in fits


# ---------------------------------------------------------------------------------------------- sections


def report_sections(inputs: ReportInputs) -> list[Section]:
    results = [analyse_dut(d, inputs.steps) for d in inputs.duts]
    warnings = list(inputs.warnings) + [f"{r.name}: {w}" for r in results for w in r.warnings]
    sections = [
        Section("Summary", [_summary_table(results)]),
        Section("Data-quality warnings", [ItemList(warnings, kind="warning", empty_text="No warnings.")]),
    ]
    for r in results:
        sections += _dut_sections(r, inputs.steps)
    sections.append(Section("Provenance", [Table(["item", "value"], [list(p) for p in inputs.provenance])]))
    return sections


def _fmt(x: float, digits: int = 4) -> str:
    return "-" if x is None or not np.isfinite(x) else f"{x:.{digits}g}"


def _summary_table(results: list[DutResult]) -> Table:
    rows = []
    for r in results:
        vec = r.errors.vector_after is not None
        kept = ~r.outliers
        before = r.errors.vector_before if vec else r.errors.norm_before
        after = r.errors.vector_after if vec else r.errors.norm_after
        rows.append(
            [
                r.name,
                r.main.model.upper(),
                str(len(r.ds)),
                "vector" if vec else "|B|",
                _fmt(analysis.rms(before[kept])),
                _fmt(analysis.rms(after[kept])),
                str(int((~kept).sum())),
            ]
        )
    return Table(
        ["DUT", "model shown", "samples", "error", "RMS before (nT)", "RMS after (nT)", "outliers"], rows
    )


def _safe(name: str) -> str:
    return re.sub(r"[^0-9A-Za-z_.-]+", "_", name) or "dut"


def _image(fig, caption: str, filename: str) -> Image:
    return Image(figures.png_bytes(fig), caption, filename)


def _dut_figures(r: DutResult) -> dict[str, Image]:
    """The figures of one DUT, by role."""
    tag, ds, e = _safe(r.name), r.ds, r.errors
    outliers = r.outliers
    model = r.main.model.upper()
    if e.vector_after is not None:
        before, after, labels = e.vector_before, e.vector_after, ["x", "y", "z"]
    else:
        before, after, labels = e.norm_before[:, None], e.norm_after[:, None], ["|B|"]
    direction = ds.ref_nt if ds.ref_nt is not None else e.field_after
    dirs, dir_resid, per_point = analysis.systematic_error_by_point(
        ds.columns.get("point"), direction, after, ~outliers
    )
    resid_label = "|mean residual| of each point (nT)" if per_point else "|residual| after calibration (nT)"
    against = "DUT temperature" if ds.temp_c is not None else "sample index"
    what = "per axis" if len(labels) == 3 else "in |B|"
    out = {
        "residuals": _image(
            figures.residuals_vs_temperature(
                ds.temp_c,
                before,
                after,
                labels,
                outliers,
                f"{r.name}: residuals against {against} ({model})",
            ),
            f"{r.name}: error {what} against {against}, before and after {model} calibration; "
            "red crosses: outliers, left out of the RMS",
            f"{tag}_residuals_vs_temperature.png",
        ),
        "histogram": _image(
            figures.norm_error_histogram(
                e.norm_before[~outliers], e.norm_after[~outliers], f"{r.name}: |B| error ({model})"
            ),
            f"{r.name}: field magnitude error before and after calibration (outliers left out)",
            f"{tag}_norm_error_histogram.png",
        ),
        "directions": _image(
            figures.direction_map(
                dirs,
                dir_resid,
                analysis.COVERAGE_GAP_DEG,
                f"{r.name}: field directions ({model})",
                resid_label,
            ),
            f"{r.name}: direction coverage (left) and the error the calibration leaves at each field "
            "direction (right; the mean over a point's samples, so the noise averages out)",
            f"{tag}_directions.png",
        ),
    }
    scored = [s for s in r.scores if s.folds]
    if scored:
        fit_rms = {"|B|": [s.fit_norm_rms for s in scored]}
        held_rms = {"|B|": [s.heldout_norm_rms for s in scored]}
        if any(np.isfinite(s.heldout_vector_rms) for s in scored):
            fit_rms = {"vector": [s.fit_vector_rms for s in scored], **fit_rms}
            held_rms = {"vector": [s.heldout_vector_rms for s in scored], **held_rms}
        out["models"] = _image(
            figures.model_comparison(
                [s.model for s in scored],
                fit_rms,
                held_rms,
                f"{r.name}: models on fitted and held-out points\n({r.fold_text})",
            ),
            f"{r.name}: error RMS of each model on its fitted points and on held-out points",
            f"{tag}_model_comparison.png",
        )
    if len(r.steps) > 1 and ds.temp_c is not None:
        out["steps"] = _image(
            figures.step_rms(
                [s.temp_c for s in r.steps],
                [s.rms_before_nt for s in r.steps],
                [s.rms_after_nt for s in r.steps],
                f"{r.name}: residual per temperature step ({model})",
            ),
            f"{r.name}: residual RMS per temperature step",
            f"{tag}_steps.png",
        )
    return out


def _dut_sections(r: DutResult, steps_info: dict[int, StepInfo]) -> list[Section]:
    img = _dut_figures(r)
    given = r.given
    intro = f"{len(r.ds)} samples; residuals shown for the {r.main.model.upper()} calibration " + (
        "given in the calibration file." if given else "fitted here (robust)."
    )
    cv_text = (
        f"Each model is fitted without one fold of the points and scored on that fold ({r.fold_text}); "
        "the outliers of the calibration shown above are left out of every score. The scalar model "
        "knows the field only up to a rotation, so it is scored on |B| only."
    )
    optional = [img[k] for k in ("models",) if k in img]
    return [
        Section(f"DUT {r.name}", [intro, img["residuals"], img["histogram"], img["directions"]]),
        Section(
            "Models compared on held-out points", [cv_text, _comparison_table(r.scores), *optional], level=3
        ),
        Section(
            "Per temperature step",
            [_step_table(r.steps, steps_info), *[img[k] for k in ("steps",) if k in img]],
            level=3,
        ),
        Section("Parameters", [_params_table(name, cal) for name, cal in _param_sets(r)], level=3),
    ]


def _comparison_table(scores: list[analysis.ModelScore]) -> Table:
    rows = [
        [
            s.model.upper(),
            _fmt(s.fit_vector_rms),
            _fmt(s.fit_norm_rms),
            _fmt(s.heldout_vector_rms),
            _fmt(s.heldout_norm_rms),
            str(s.folds),
            s.note,
        ]
        for s in scores
    ]
    return Table(
        [
            "model",
            "fitted: vector RMS (nT)",
            "fitted: |B| RMS (nT)",
            "held-out: vector RMS (nT)",
            "held-out: |B| RMS (nT)",
            "folds",
            "note",
        ],
        rows,
    )


STEP_HEADERS = [
    "step",
    "setpoint (°C)",
    "mean DUT temp (°C)",
    "samples",
    "points done",
    "settle time (min)",
    "stable",
    "RMS before (nT)",
    "RMS after (nT)",
    "outliers",
]


def _stability(i: StepInfo | None) -> str:
    if i is None or i.stable is None:
        return "-"
    if not i.stable:
        return f"NO ({i.settle_timeouts} timeout(s))"
    return f"yes, after {i.settle_timeouts} timeout(s)" if i.settle_timeouts else "yes"


def _step_table(steps: list[analysis.StepRow], info: dict[int, StepInfo]) -> Table:
    """One row per temperature step: the data's numbers with what the session recorded about the step;
    planned steps without any sample are listed too."""
    by_step = {s.step: s for s in steps}
    rows = []
    for number in sorted(set(by_step) | set(info)):
        s, i = by_step.get(number), info.get(number)
        settle = "-" if i is None or i.settle_s is None else f"{i.settle_s / 60:.1f}"
        data = (
            ["-", "0", "-", "-", "0"]
            if s is None
            else [
                "-" if not np.isfinite(s.temp_c) else f"{s.temp_c:.2f}",
                str(s.samples),
                _fmt(s.rms_before_nt),
                _fmt(s.rms_after_nt),
                str(s.outliers),
            ]
        )
        rows.append(
            [
                str(number),
                "-" if i is None else f"{i.setpoint_c:g}",
                *data[:2],
                "-" if i is None else f"{i.points_done}/{i.points_planned}",
                settle,
                _stability(i),
                *data[2:],
            ]
        )
    return Table(STEP_HEADERS, rows)


def _param_sets(r: DutResult) -> list[tuple[str, object]]:
    sets = [("given calibration", r.main)] if r.given else []
    return sets + [(f"fitted here ({m.upper()}, robust)", cal) for m, cal in r.fits.items()]


def _params_table(title: str, cal) -> Table:
    rows = []
    for key, value in cal.params.items():
        values = np.asarray(value, dtype=float)
        errors = np.asarray(cal.std_errors.get(key, np.full(values.shape, np.nan)), dtype=float)
        unit = PARAM_UNITS.get(key, "")
        for index in np.ndindex(values.shape):
            label = key + "".join(f"[{i + 1}]" for i in index)
            se = errors[index] if errors.shape == values.shape else np.nan
            rows.append([label, f"{values[index]:.8g}", _fmt(se, 3), unit])
    stats = cal.stats if isinstance(cal.stats, dict) else {}
    tref = "" if cal.temp_ref_c is None else f", internal reference temperature {cal.temp_ref_c:.4g} °C"
    caption = (
        f"{cal.model.upper()}: {title}; RMS after {_fmt(stats.get('rms_after_nt', float('nan')))} nT{tref}"
    )
    return Table(["parameter", "value", "std error", "unit"], rows, caption)


def report_or_error(source, **kwargs) -> Path:
    """build_report, with unexpected numeric failures turned into one clear line."""
    try:
        return build_report(source, **kwargs)
    except MagrigError:
        raise
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise DataError(f"{source}: cannot build the report: {exc}") from None
