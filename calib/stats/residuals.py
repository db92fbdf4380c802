"""Residual statistics of a calibration on a dataset: overall, per axis and per temperature step."""

from __future__ import annotations

import numpy as np

from calib.dataset import Dataset

AXES = "xyz"
STEP_GAP_C = 1.0  # temperatures further apart than this belong to different steps


def default_temp_ref_c(temp_c: np.ndarray) -> float:
    """Centre of the temperature range, rounded to 0.1 degC so files show a tidy number."""
    return round(float(0.5 * (np.min(temp_c) + np.max(temp_c))), 1)


def temperature_steps(temp_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(step of each sample, numbered from 0 at the coldest; mean temperature of each step): the sorted
    temperatures split where a gap exceeds STEP_GAP_C."""
    t = np.asarray(temp_c, float)
    t_sorted = np.sort(t)
    below_gap = t_sorted[np.flatnonzero(np.diff(t_sorted) > STEP_GAP_C)]  # the last value before each gap
    steps = np.searchsorted(below_gap, t, side="left")
    count = np.bincount(steps, minlength=below_gap.size + 1)
    return steps, np.bincount(steps, weights=t, minlength=below_gap.size + 1) / np.maximum(count, 1)


def group_codes(ds: Dataset) -> tuple[np.ndarray, list[str]] | None:
    """(group number of each row, the groups' labels): the dataset's group column, else its
    temperature steps (labelled by their mean temperature), else None."""
    if ds.group is not None:
        return _factorize(np.asarray(ds.group))
    if ds.temp_c is not None:
        steps, mean_c = temperature_steps(ds.temp_c)
        return steps, [f"{m:.1f}C" for m in mean_c]
    return None


def _factorize(labels: np.ndarray) -> tuple[np.ndarray, list[str]]:
    if labels.dtype.kind in "biuf":  # numbers sort in C; group labels read from a CSV are floats
        values, codes = np.unique(labels, return_inverse=True)
        return codes.reshape(-1), [_label_text(v) for v in values.tolist()]
    index: dict = {}
    codes = np.fromiter((index.setdefault(v, len(index)) for v in labels.tolist()), np.int64, len(labels))
    return codes, [str(v) for v in index]


def _rms(sum_of_squares: float, count: int) -> float:
    return float(np.sqrt(sum_of_squares / count)) if count else float("nan")


def known_norm(ds: Dataset) -> np.ndarray | None:
    """|B| per sample when known: the given magnitude, else the norm of the reference vector."""
    if ds.ref_norm_nt is not None:
        return np.asarray(ds.ref_norm_nt, float)
    if ds.ref_nt is not None:
        return np.linalg.norm(ds.ref_nt, axis=1)
    return None


def residual_stats(
    ds: Dataset,
    field_nt: np.ndarray | None,
    *,
    vector: bool,
    used: np.ndarray | None = None,
    norm_nt=None,
    error_nt: np.ndarray | None = None,
) -> dict:
    """RMS before (raw h against the reference) and after calibration, on the rows marked `used`.

    vector=True compares field vectors with ref_nt (T24, P12): give field_nt, or error_nt = field - ref_nt
    when the caller has it already. Otherwise magnitudes of field_nt with norm_nt (a constant or
    per-sample array; default: the known |B| of the dataset).
    """
    used = np.ones(len(ds), bool) if used is None else np.asarray(used, bool)
    every_row = bool(used.all())

    def rows(x: np.ndarray) -> np.ndarray:
        return x if every_row else x[used]

    if vector:  # one axis at a time: 1-D passes whatever the arrays' layouts, one scratch column
        ref = rows(ds.ref_nt)
        after = rows(field_nt) - ref if error_nt is None else rows(error_nt)
        sums = {"before": _square_sums([rows(ds.h_nt)[:, i] - ref[:, i] for i in range(3)]),
                "after": _square_sums([after[:, i] for i in range(3)])}
    else:
        norm = known_norm(ds) if norm_nt is None else norm_nt
        norm = rows(norm) if np.ndim(norm) else norm
        field = rows(field_nt)
        sums = {"before": _square_sums([np.linalg.norm(rows(ds.h_nt), axis=1) - norm]),
                "after": _square_sums([np.linalg.norm(field, axis=1) - norm])}
    n_used = int(used.sum())
    width = 3 if vector else 1
    stats: dict = {f"rms_{name}_nt": _rms(sum(totals), n_used * width) for name, (totals, _) in sums.items()}
    if vector:
        stats["per_axis"] = {
            a: {f"rms_{name}_nt": _rms(sums[name][0][i], n_used) for name in sums} for i, a in enumerate(AXES)
        }
    else:
        mag = np.linalg.norm(field, axis=1)
        stats["norm_spread_pct"] = float(100 * np.std(mag) / np.mean(mag))
    groups = group_codes(ds)
    if groups is not None:
        row_squares = {name: row for name, (_, row) in sums.items()}
        stats["per_group"] = _per_group(ds, groups, used, row_squares, width)
    return stats


def _square_sums(columns: list[np.ndarray]) -> tuple[list[float], np.ndarray]:
    """(sum of squares of each column, per-row sum of squares over the columns). Each column is either a
    fresh array (squared in place) or a view (squared into one scratch array): no other allocation."""
    row = np.zeros(len(columns[0]))
    scratch = np.empty_like(row)
    totals = []
    for column in columns:
        out = column if column.base is None and column.flags.writeable else scratch
        np.square(column, out=out)
        totals.append(float(out.sum()))
        row += out
    return totals, row


def _per_group(ds: Dataset, groups, used: np.ndarray, row_squares: dict, width: int) -> dict:
    """Samples, RMS before and after (and mean temperature) per group, in order of first appearance;
    one bincount over the used rows' squares, whatever the number of groups."""
    codes, labels = groups
    k = len(labels)
    first_row = np.full(k, len(codes))
    np.minimum.at(first_row, codes, np.arange(len(codes)))
    codes_used = codes[used]

    def per_code(weights=None):
        return np.bincount(codes_used, weights=weights, minlength=k)

    n = per_code()
    sums = {name: per_code(sq) for name, sq in row_squares.items()}
    temp_sum = per_code(np.asarray(ds.temp_c, float)[used]) if ds.temp_c is not None else None
    per_group = {}
    for code in np.argsort(first_row, kind="stable"):  # every label has rows: codes come from them
        entry = {"n": int(n[code])}
        entry.update({f"rms_{name}_nt": _rms(total[code], n[code] * width) for name, total in sums.items()})
        if temp_sum is not None and n[code]:
            entry["temp_c"] = float(temp_sum[code] / n[code])
        per_group[labels[code]] = entry
    return per_group


def _label_text(label) -> str:
    """Group labels read from a CSV arrive as floats: 3.0 prints as '3'."""
    if isinstance(label, float) and label.is_integer():
        return str(int(label))
    return str(label)
