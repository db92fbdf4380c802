"""T24 or T36? Chosen by blocked cross-validation over the session's own data.

    choice = choose_temperature_model(ds, blocks=None)   # .model, .heldout_rms_nt, .fold_rms_nt, .message

Each fold holds out one block of rows, fits both models to the rest (with one temperature reference for
every fit) and scores each by the held-out RMS of the calibrated field's vector error. T36 has 12 more
parameters than T24: on data T24 describes it validates slightly worse, on curved data clearly better.
It is chosen only when it validates better in every fold and its mean gain (the paired per-fold
difference of the mean squared errors) exceeds MARGIN standard errors of those differences: a gain beyond
the fold noise, as calib/models/scalar_choice.py decides between the scalar fit's variants.

Blocks: any label per row (contiguous stretches in time, temperature steps, ...). By default
`blocks_within_steps`: every temperature step cut into FOLDS contiguous pieces in row order, fold k
holding out piece k of every step, so each fold's training rows keep every temperature (holding out a
whole step would ask T36 to extrapolate its curve and T24 to bridge a gap neither final fit has).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib.dataset import Dataset
from calib.errors import DataError, FitError
from calib.models.t24 import fit_weighted as fit_t24
from calib.models.t36 import fit_weighted as fit_t36
from calib.stats.residuals import default_temp_ref_c, temperature_steps

FOLDS = 5
MARGIN = 2.0
FITS = {"t24": fit_t24, "t36": fit_t36}


@dataclass(frozen=True)
class TemperatureModelChoice:
    model: str  # "t24" or "t36"
    heldout_rms_nt: dict[str, float]  # over every held-out row, per model
    fold_rms_nt: dict[str, list[float]] = field(default_factory=dict)
    gain_nt2: float | None = None  # mean over the folds of (T24's - T36's held-out mean squared error)
    gain_se_nt2: float | None = None
    message: str = ""

    def as_dict(self) -> dict:
        return {"model": self.model, "heldout_rms_nt": dict(self.heldout_rms_nt),
                "fold_rms_nt": {k: list(v) for k, v in self.fold_rms_nt.items()}, "gain_nt2": self.gain_nt2,
                "gain_se_nt2": self.gain_se_nt2, "message": self.message,
                "rule": f"t36 when better in every fold by more than {MARGIN:g} standard errors of the gain"}


def blocks_within_steps(temp_c: np.ndarray, folds: int = FOLDS) -> np.ndarray:
    """Fold of every row: each temperature step's rows, in their order, cut into `folds` contiguous pieces."""
    steps, _ = temperature_steps(temp_c)
    out = np.empty(len(steps), int)
    for step in np.unique(steps):
        rows = np.flatnonzero(steps == step)
        out[rows] = np.arange(rows.size) * folds // rows.size
    return out


def choose_temperature_model(ds: Dataset, blocks=None, *, margin: float = MARGIN) -> TemperatureModelChoice:
    """T24 unless T36 validates better beyond the fold noise. blocks: a label per row (each label one
    held-out fold), or None for `blocks_within_steps`."""
    if ds.temp_c is None or ds.ref_nt is None:
        raise DataError("choosing the temperature model needs temperatures and reference vectors")
    labels = blocks_within_steps(ds.temp_c) if blocks is None else np.asarray(blocks).ravel()
    if labels.shape != (len(ds),):
        raise DataError(f"blocks: {labels.size} labels for {len(ds)} rows")
    folds = np.unique(labels)
    if folds.size < 3:
        raise DataError(f"blocks: {folds.size} distinct labels; cross-validation needs 3 or more")
    temp_ref_c = default_temp_ref_c(ds.temp_c)
    squares = {m: [] for m in FITS}
    sums = {m: 0.0 for m in FITS}
    for label in folds:
        held = labels == label
        train, test = ds.subset(~held), ds.subset(held)
        for model, fit in FITS.items():
            try:
                cal, _ = fit(train, None, temp_ref_c)
            except FitError as err:
                if model == "t24":
                    raise
                return TemperatureModelChoice("t24", {},
                                              message=f"t24: t36 cannot be fitted in every fold ({err})")
            err2 = np.sum((cal.apply(test.h_nt, test.temp_c) - test.ref_nt) ** 2, axis=1)
            squares[model].append(float(err2.mean()) / 3)
            sums[model] += float(err2.sum())
    heldout = {m: float(np.sqrt(sums[m] / (3 * len(ds)))) for m in FITS}
    gain = np.array(squares["t24"]) - np.array(squares["t36"])
    se = float(gain.std(ddof=1) / np.sqrt(gain.size))
    chosen = "t36" if np.all(gain > 0) and gain.mean() > margin * se else "t24"
    message = (f"{chosen}: held-out RMS t24 {heldout['t24']:.3f} nT, t36 {heldout['t36']:.3f} nT; t36 "
               f"better in {int(np.sum(gain > 0))} of {gain.size} folds, mean gain {gain.mean():+.3g} nT^2 "
               f"({gain.mean() / se if se > 0 else np.inf:+.1f} standard errors, {margin:g} needed)")
    return TemperatureModelChoice(chosen, heldout, {m: np.sqrt(v).tolist() for m, v in squares.items()},
                                  float(gain.mean()), se, message)
