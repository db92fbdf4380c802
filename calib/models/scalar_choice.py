"""Which variant of the scalar fit to use, chosen by validation inside the rows given to the fit.

The options the caller leaves open (orientation balancing, temperature terms) give the candidates; the
plain variant (no balancing, no temperature terms: the unweighted least-squares ellipsoid, the estimator
that is efficient when the noise is white) is kept unless another one validates clearly better.

Validation is blocked cross-validation over the rows in their recorded order. The rows are cut into
FOLDS * BLOCKS_PER_FOLD contiguous blocks and fold k holds out blocks k, k + FOLDS, ...: each held-out
block keeps its stretch of drift together (real recordings wander over seconds), while each fold's
training rows still span the whole recording, its orientations and its temperatures, as the final fit's do.
Holding out one long stretch per fold instead removes a region of orientations the final fit will have,
and then favours balancing for a gap that does not exist.

Score: the held-out |B| error, RMS in % of |B| (against the known norm, else against the held-out rows'
mean |B|). An alternative replaces the plain variant only when it scores lower in every fold and its mean
gain exceeds T_LIMIT standard errors of the paired fold differences. With a robust fit, rows the plain
variant's Huber fit flags are left out of the validation.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from calib.calibration import Calibration
from calib.dataset import Dataset
from calib.errors import FitError
from calib.models.scalar import (
    MIN_SAMPLES_TO_BALANCE,
    MIN_TEMP_SPAN_C,
    UNEVEN_COVERAGE_SHARE,
    effective_share,
    field_norm,
    fit_weighted,
    orientation_balance_weights,
)
from calib.stats.residuals import default_temp_ref_c, known_norm
from calib.stats.robust import irls

FOLDS = 5
BLOCKS_PER_FOLD = 2
T_LIMIT = 2.0
METHOD = (
    f"blocked cross-validation: {FOLDS} folds, each holding out {BLOCKS_PER_FOLD} of "
    f"{FOLDS * BLOCKS_PER_FOLD} contiguous blocks of the rows in their order"
)
RULE = (
    f"the plain variant unless another scores lower in every fold and its mean gain exceeds "
    f"{T_LIMIT:g} standard errors"
)


@dataclass(frozen=True)
class Variant:
    balance: bool
    temperature: bool

    @property
    def name(self) -> str:
        parts = (["balanced"] if self.balance else []) + (["temperature"] if self.temperature else [])
        return "+".join(parts) or "plain"


def fold_of_rows(n: int) -> np.ndarray:
    """Fold number of each of n rows: contiguous blocks, block b in fold b % FOLDS."""
    return (np.arange(n) * (FOLDS * BLOCKS_PER_FOLD) // n) % FOLDS


def norm_error_pct(field_nt: np.ndarray, norm_nt: np.ndarray | None) -> float:
    """RMS of |B| against the known norm (or the rows' mean |B| when unknown), in % of |B|."""
    b = np.linalg.norm(field_nt, axis=1)
    target = np.full(len(b), b.mean()) if norm_nt is None else norm_nt
    return float(100 * np.sqrt(np.mean(((b - target) / target) ** 2)))


def decide(scores_pct: dict[str, np.ndarray], baseline: str) -> tuple[str, dict[str, str]]:
    """The chosen candidate and, for each alternative, why it was kept or not.

    scores_pct: per-fold held-out scores of each candidate (same folds). An alternative qualifies when it
    is lower than the baseline in every fold and its mean gain exceeds T_LIMIT standard errors of the
    paired differences; the qualifying one with the lowest mean wins.
    """
    base = np.asarray(scores_pct[baseline], float)
    chosen, best_mean, verdicts = baseline, float(base.mean()), {}
    for name, scores in scores_pct.items():
        if name == baseline:
            continue
        gain = base - np.asarray(scores, float)
        se = float(gain.std(ddof=1) / np.sqrt(len(gain))) if len(gain) > 1 else np.inf
        wins = int(np.sum(gain > 0))
        qualifies = wins == len(gain) and gain.mean() > T_LIMIT * se
        verdicts[name] = (
            f"lower in {wins} of {len(gain)} folds, mean gain {gain.mean():+.4f} % "
            f"({gain.mean() / se if se > 0 else np.inf:+.1f} standard errors)"
        )
        if qualifies and float(np.mean(scores)) < best_mean:
            chosen, best_mean = name, float(np.mean(scores))
    return chosen, verdicts


def choose(
    ds: Dataset,
    robust: bool,
    *,
    temp_ref_c: float | None = None,
    field_norm_nt: float | None = None,
    temperature_terms: bool | None = None,
    balance_orientations: bool | None = None,
) -> tuple[Callable, dict]:
    """(fit_weighted(weights) of the chosen variant, the stats that record the choice). The options are
    calib.fit's (see calib.models.scalar.fit_weighted); None = chosen here."""
    span_c = 0.0 if ds.temp_c is None else float(np.ptp(ds.temp_c))
    if temp_ref_c is None and span_c >= MIN_TEMP_SPAN_C and temperature_terms is not False:
        temp_ref_c = default_temp_ref_c(ds.temp_c)  # one centre for every fold and the final fit

    def fitter(part: Dataset, variant: Variant, balance: np.ndarray | None = None) -> Callable:
        def fit(weights):
            return fit_weighted(part, weights, temp_ref_c=temp_ref_c, field_norm_nt=field_norm_nt,
                                temperature_terms=variant.temperature, balance=balance)
        return fit

    unbalanced = Variant(False, bool(temperature_terms))
    rows = np.ones(len(ds), bool)
    if robust:  # validate on the rows a robust fit of the unbalanced variant keeps
        rows = ~irls(fitter(ds, unbalanced), len(ds))[2]
    stats: dict = {}
    balance = None
    if balance_orientations is not False and np.count_nonzero(rows) >= MIN_SAMPLES_TO_BALANCE:
        balance = _balance_weights(ds, fitter(ds, unbalanced)(rows.astype(float))[0])
        stats["coverage_effective_share"] = effective_share(balance[rows])
    candidates = [
        Variant(b, t)
        for b in _open(balance_orientations, stats.get("coverage_effective_share", 1.0)
                       < UNEVEN_COVERAGE_SHARE)
        for t in _open(temperature_terms, span_c >= MIN_TEMP_SPAN_C)
    ]
    chosen = candidates[0]
    if len(candidates) > 1:
        known = field_norm_nt is not None or known_norm(ds) is not None
        norm = field_norm(ds, field_norm_nt)[0][rows] if known else None
        chosen, stats["validation"] = _validate(ds.subset(rows), norm, candidates, fitter)
    if chosen.balance and balance is None:  # asked for explicitly, on fewer than MIN_SAMPLES_TO_BALANCE rows
        balance = _balance_weights(ds, fitter(ds, Variant(False, chosen.temperature))(rows.astype(float))[0])
    return fitter(ds, chosen, balance if chosen.balance else None), stats


def _open(given: bool | None, worth_trying: bool) -> list[bool]:
    """Values to validate for an option: the given one, else off, and on when the data allows it."""
    if given is not None:
        return [given]
    return [False, True] if worth_trying else [False]


def _balance_weights(ds: Dataset, unbalanced: Calibration) -> np.ndarray:
    """Orientation balance weights of every row, from the field directions of an unbalanced fit."""
    return orientation_balance_weights(unbalanced.apply(ds.h_nt, ds.temp_c))


def _fold_scores(train: Dataset, held: Dataset, held_norm, candidates: list[Variant], fitter) -> dict:
    """Held-out score of each candidate fitted on `train`, or the FitError that stopped it."""
    out: dict[str, float | FitError] = {}
    unbalanced: dict[bool, Calibration | FitError] = {}
    for variant in candidates:
        if variant.temperature not in unbalanced:
            try:
                unbalanced[variant.temperature] = fitter(train, Variant(False, variant.temperature))(None)[0]
            except FitError as err:
                unbalanced[variant.temperature] = err
        cal = unbalanced[variant.temperature]
        try:
            if variant.balance and isinstance(cal, Calibration):
                cal = fitter(train, variant, _balance_weights(train, cal))(None)[0]
        except FitError as err:
            cal = err
        out[variant.name] = cal if isinstance(cal, FitError) else norm_error_pct(
            cal.apply(held.h_nt, held.temp_c), held_norm)
    return out


def _validate(ds: Dataset, norm: np.ndarray | None, candidates: list[Variant], fitter):
    """(chosen variant, record): every candidate on every fold, chosen by `decide` against the first."""
    fold = fold_of_rows(len(ds))
    scores: dict[str, list[float]] = {v.name: [] for v in candidates}
    failed: dict[str, str] = {}
    for k in range(FOLDS):
        held_norm = None if norm is None else norm[fold == k]
        for name, score in _fold_scores(ds.subset(fold != k), ds.subset(fold == k), held_norm, candidates,
                                        fitter).items():
            if isinstance(score, FitError):
                failed.setdefault(name, f"not identifiable in fold {k + 1}: {score}")
            else:
                scores[name].append(score)
    baseline = candidates[0]
    record: dict = {"method": METHOD, "rule": RULE, "score": "held-out |B| error, RMS in % of |B|"}
    if baseline.name in failed:  # too few rows to cut into folds: keep the plain variant
        record.update({"chosen": baseline.name, "verdicts": failed})
        return baseline, record
    complete = {name: np.array(s) for name, s in scores.items() if name not in failed}
    name, verdicts = decide(complete, baseline.name)
    record.update({
        "scores_pct": {n: s.tolist() for n, s in complete.items()},
        "mean_pct": {n: float(s.mean()) for n, s in complete.items()},
        "chosen": name,
        "verdicts": {**verdicts, **failed},
    })
    return next(v for v in candidates if v.name == name), record
