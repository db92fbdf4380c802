"""The report page: summary, figures, tables and parameters of each judged DUT, as html blocks."""

from __future__ import annotations

import numpy as np

from rig.analysis import heldout
from rig.analysis.judged import RADIUS_LABEL, field_figures, quality_of
from rig.core.names import file_stem
from rig.report import calsection, figures
from rig.report.calsection import budget_rows, fmt
from rig.report.evaluate import DutResult
from rig.report.html import Image, Section, Table
from rig.report.sources import StepInfo


def _fmt(x: float, digits: int = 4) -> str:
    return fmt(x, digits)


def summary_table(results: list[DutResult]) -> Table:
    rows = []
    for r in results:
        vec = r.errors.vector_after is not None
        kept = ~r.outliers
        before = r.errors.vector_before if vec else r.errors.norm_before
        after = r.errors.vector_after if vec else r.errors.norm_after
        q = quality_of(r.main)
        rows.append(
            [
                r.name,
                r.main.model.upper() + (" (the run's)" if _written_by_run(r) else ""),
                str(len(r.ds)),
                "vector" if vec else "|B|",
                _fmt(heldout.rms(before[kept])),
                _fmt(heldout.rms(after[kept])),
                q.uncertainty_text(),
                "-" if q.radius_nt is None else ("RMS > radius" if q.exceeds else "ok"),
                q.dominant or "-",
                str(int((~kept).sum())),
            ]
        )
    return Table(
        ["DUT", "calibration shown", "samples", "error", "RMS before (nT)", "RMS after (nT)",
         RADIUS_LABEL, "check", "largest uncertainty contribution", "outliers"], rows
    )


def _safe(name: str) -> str:
    """The file-name tag of a DUT's figures (distinct DUTs are checked to give distinct tags)."""
    return file_stem(name)


def _image(fig, caption: str, filename: str) -> Image:
    return Image(figures.png_bytes(fig), caption, filename)


def dut_figures(r: DutResult) -> dict[str, Image]:
    """The figures of one DUT, by role."""
    tag, ds, e = _safe(r.name), r.ds, r.errors
    outliers = r.outliers
    model = r.main.model.upper()
    if e.vector_after is not None:
        before, after, labels = e.vector_before, e.vector_after, ["x", "y", "z"]
    else:
        before, after, labels = e.norm_before[:, None], e.norm_after[:, None], ["|B|"]
    direction = ds.ref_nt if ds.ref_nt is not None else e.field_after
    dirs, dir_resid, per_point = heldout.systematic_error_by_point(
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
                heldout.COVERAGE_GAP_DEG,
                f"{r.name}: field directions ({model})",
                resid_label,
            ),
            f"{r.name}: direction coverage (left) and the error the calibration leaves at each field "
            + (
                "direction (right; the mean over a point's samples, so the noise averages out)"
                if per_point
                else "direction (right)"
            ),
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
    budget = budget_rows(r.uncertainty)
    if budget:
        out["budget"] = _image(
            figures.uncertainty_budget([b[0] for b in budget], [b[1] for b in budget],
                                       field_figures(r.uncertainty),
                                       f"{r.name}: uncertainty budget ({r.uncertainty_of})"),
            f"{r.name}: what each input adds to the calibrated field's error (standard uncertainties), the "
            "combined standard uncertainty u, the expanded uncertainty U = k u, and the largest radius "
            "holding 95 % of the 3-D error at a point of the plan's grid (a radius, not k u)",
            f"{tag}_uncertainty_budget.png",
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


def dut_sections(r: DutResult, steps_info: dict[int, StepInfo]) -> list[Section]:
    img = dut_figures(r)
    robust = str(r.robust).lower()
    cv_text = (
        f"A comparison, not the calibration shown: each model re-fitted here (robust: {robust}) without one "
        f"fold of the points and scored on that fold ({r.fold_text}); the outliers of the calibration shown "
        "are left out of every score. The scalar model knows the field only up to a rotation, so it is "
        "scored on |B| only."
    )
    optional = [img[k] for k in ("models",) if k in img]
    sections = [
        Section(f"DUT {r.name}", [*calsection.intro_blocks(r), img["residuals"], img["histogram"],
                                  img["directions"]]),
        Section("Parameters", [calsection.params_table(_shown_title(r), r.main)], level=3),
        Section("Uncertainty",
                [*calsection.uncertainty_blocks(r), *[img[k] for k in ("budget",) if k in img]], level=3),
        Section("Model checks", calsection.check_blocks(r.main), level=3),
        Section(
            "Per temperature step",
            [step_table(r.steps, steps_info), *[img[k] for k in ("steps",) if k in img]],
            level=3,
        ),
    ]
    if r.others:
        sections.append(Section("The run's other calibrations", [calsection.others_table(r.others)], level=3))
    sections.append(Section(f"Comparison: models re-fitted here (robust: {robust}) on held-out points",
                            [cv_text, _comparison_table(r.scores), *optional], level=3))
    return sections


def _written_by_run(r: DutResult) -> bool:
    return r.origin.startswith("the run's")


def _shown_title(r: DutResult) -> str:
    if _written_by_run(r):
        return "the calibration the run wrote"
    return "the given calibration" if r.given else f"fitted here (robust: {str(r.robust).lower()})"


def ranked_by_heldout(scores: list[heldout.ModelScore]) -> tuple[list[heldout.ModelScore], str]:
    """The models best first by their held-out error, never by their stated uncertainty: the held-out
    vector RMS where every model has one, else the held-out |B| RMS (a scalar fit knows no direction);
    models without a score last. Returns (ranked, the criterion in words)."""
    scored = [s for s in scores if s.folds]
    by_vector = bool(scored) and all(np.isfinite(s.heldout_vector_rms) for s in scored)
    key, words = (("heldout_vector_rms", "held-out vector RMS") if by_vector
                  else ("heldout_norm_rms", "held-out |B| RMS"))

    def rank(s: heldout.ModelScore) -> float:
        value = getattr(s, key)
        return value if s.folds and np.isfinite(value) else np.inf

    return sorted(scores, key=rank), words


def _comparison_table(scores: list[heldout.ModelScore]) -> Table:
    ranked, words = ranked_by_heldout(scores)
    rows = [
        [
            str(place),
            s.model.upper(),
            _fmt(s.fit_vector_rms),
            _fmt(s.fit_norm_rms),
            _fmt(s.heldout_vector_rms),
            _fmt(s.heldout_norm_rms),
            str(s.folds),
            s.note,
        ]
        for place, s in enumerate(ranked, start=1)
    ]
    return Table(
        [
            "rank",
            "model",
            "fitted: vector RMS (nT)",
            "fitted: |B| RMS (nT)",
            "held-out: vector RMS (nT)",
            "held-out: |B| RMS (nT)",
            "folds",
            "note",
        ],
        rows,
        f"models ranked by their {words} (best first); a model's stated uncertainty plays no part",
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


def step_table(steps: list[heldout.StepRow], info: dict[int, StepInfo]) -> Table:
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
